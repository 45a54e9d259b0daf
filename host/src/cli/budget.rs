//! `evpose budget`: arguments and printing; the figures come from [`crate::budget`].

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Result};
use clap::Args;
use evpose_core::model::Model;

use crate::budget::{default_elf, image_budget, model_budget, Budget, ImageBudget, ModelBudget};
use crate::model;

/// Arguments of `evpose budget`.
#[derive(Args, Debug)]
pub struct BudgetArgs {
    /// The model blob (`.evq`, int8 or f32) or an `.onnx` export (imported as f32).
    #[arg(long)]
    pub model: PathBuf,
    /// Points per inference, for the total MACs.
    #[arg(long, default_value_t = evpose_core::pipeline::DEFAULT_POINTS as u64)]
    pub points: u64,
    /// Firmware image (ELF) to measure (default: the firmware's release build, if present).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `evpose budget`.
pub fn budget(a: &BudgetArgs) -> Result<()> {
    let blob = model::load_blob(&a.model)?;
    let m = Model::parse(blob.bytes()).map_err(|e| anyhow!("{}: {e}", a.model.display()))?;
    let mb = model_budget(&m, a.points);
    let elf = match &a.elf {
        Some(p) => Some(p.clone()),
        None => Some(default_elf()).filter(|p| p.exists()),
    };
    let image = elf.as_deref().map(image_budget).transpose()?;
    let b = Budget { model: mb, image };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        print_model(&a.model, &b.model);
        match &b.image {
            Some(i) => print_image(i),
            None => println!(
                "\nimage: none measured (build the firmware, or pass --elf; default {})",
                default_elf().display()
            ),
        }
    }
    Ok(())
}

fn kib(bytes: u64) -> String {
    format!("{:.1} KiB", bytes as f64 / 1024.0)
}

fn print_model(path: &Path, m: &ModelBudget) {
    println!(
        "model: {} ({} bytes, {}, {} joints, SimDR {} x {})",
        path.display(),
        m.blob_bytes,
        m.dtype,
        m.joints,
        m.width,
        m.height
    );
    println!(
        "\n{:>3}  {:<7} {:>11}  {:>9}  {:<6}  {:>14}  {:>11}",
        "#", "kind", "in -> out", "MACs", "per", "weights", "bias+scales"
    );
    for l in &m.layers {
        println!(
            "{:>3}  {:<7} {:>11}  {:>9}  {:<6}  {:>10} {:<3}  {:>11}",
            l.index,
            l.kind,
            format!("{} -> {}", l.in_dim, l.out_dim),
            l.macs,
            l.per,
            l.weight_bytes,
            l.weight_type,
            l.bias_scale_bytes
        );
    }
    println!(
        "\nweights {} bytes, bias+scales {} bytes; scratch {} words ({} bytes); head outputs {} bytes",
        m.weight_bytes, m.bias_scale_bytes, m.scratch_words, m.scratch_bytes, m.output_bytes
    );
    println!(
        "host: scratch {} words ({} bytes) for blocks of {} points; packed weights {} bytes \
         (x86 with AVX-512 VNNI)",
        m.block_scratch_words,
        4 * m.block_scratch_words,
        evpose_core::infer::MAX_BLOCK,
        m.packed_bytes
    );
    println!(
        "MACs: {} per point x {} points + {} after pooling = {} ({:.3} GMAC)",
        m.macs_per_point,
        m.points,
        m.macs_after_pooling,
        m.macs_total,
        m.macs_total as f64 / 1e9
    );
}

fn print_image(i: &ImageBudget) {
    println!("\nimage: {}", i.elf);
    println!("{:<16} {:>10}  {:>10}  in", "section", "address", "bytes");
    for s in &i.sections {
        let place = match (s.flash, s.ram) {
            (true, true) => "flash (load image) + RAM",
            (true, false) => "flash",
            (false, true) => "RAM",
            (false, false) => "-",
        };
        println!("{:<16} {:#010x}  {:>10}  {}", s.name, s.addr, s.size, place);
    }
    println!("flash: {} bytes ({})", i.flash_bytes, kib(i.flash_bytes));
    match i.stack_bytes {
        Some(st) => println!(
            "RAM:   {} bytes ({}): {} static (.data + .bss + .uninit) + {} stack",
            i.ram_bytes,
            kib(i.ram_bytes),
            i.static_ram_bytes,
            st
        ),
        None => println!(
            "RAM:   {} bytes static (.data + .bss + .uninit); no _stack_start/_stack_end symbols",
            i.static_ram_bytes
        ),
    }
    if i.heap.is_empty() {
        println!("heap:  none (no heap section, no allocator symbols)");
    } else {
        println!("heap:  FOUND: {}", i.heap.join(", "));
    }
    for (what, list) in [("RAM", &i.largest_ram), ("flash", &i.largest_flash)] {
        println!("largest in {what}:");
        for s in list {
            println!("  {:>10}  {}  ({})", s.size, s.name, s.section);
        }
    }
}
