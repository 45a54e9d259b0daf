//! `evpose budget`: arguments and printing; the figures come from [`crate::budget`].

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Result};
use clap::Args;
use evpose_core::model::Model;

use crate::budget::{default_elf, image_budget, model_budget, Budget, ImageBudget, ModelBudget};
use crate::latency::{self, Input, Latency, Measured, Target, Weights, REAL_TIME_MS};
use crate::model;

/// Arguments of `evpose budget`.
#[derive(Args, Debug)]
pub struct BudgetArgs {
    /// The model blob (`.evq`, int8 or f32) or an `.onnx` export (imported as f32).
    #[arg(long)]
    pub model: PathBuf,
    /// Points per inference, for the total MACs and the latency (default: the `N` the blob
    /// records, else 2,048).
    #[arg(long)]
    pub points: Option<u64>,
    /// Firmware image (ELF) to measure (default: the firmware's release build, if present).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Estimate one window's latency on these targets (CORE@MHZ: cortex-m7@480,
    /// cortex-m4@168, cortex-m33@160, …) from the instruction counts the firmware measured
    /// under QEMU (`firmware/measured.json`) and a stated cycles-per-instruction assumption.
    #[arg(long, num_args = 1.., default_value = "cortex-m7@480")]
    pub target: Vec<Target>,
    /// The point layers' weights the latency assumes: `widened` (what the firmware runs,
    /// twice the int8 point layers' bytes in RAM) or `row-major` (no extra RAM).
    #[arg(long, value_enum, default_value_t = Weights::Widened)]
    pub weights: Weights,
    /// The stream the MCU reads events from, for the input's cost: `evs1` (the firmware's own
    /// words), `evt3` (a Prophesee IMX636's EVT 3.0) or `evt21` (a GenX320's EVT 2.1), each as
    /// decoded under QEMU at boot (per event, on the street window's words).
    #[arg(long, value_enum, default_value_t = Input::Evs1)]
    pub input: Input,
    /// Events per window, for the rasterization cost.
    #[arg(long, default_value_t = u64::from(evpose_core::raster::DEFAULT_WINDOW_EVENTS))]
    pub window_events: u64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `evpose budget`.
pub fn budget(a: &BudgetArgs) -> Result<()> {
    let blob = model::load_blob(&a.model)?;
    let m = Model::parse(blob.bytes()).map_err(|e| anyhow!("{}: {e}", a.model.display()))?;
    let points = a.points.unwrap_or(m.input_points() as u64);
    let mb = model_budget(&m, points);
    let elf = match &a.elf {
        Some(p) => Some(p.clone()),
        None => Some(default_elf()).filter(|p| p.exists()),
    };
    let image = elf.as_deref().map(image_budget).transpose()?;
    let measured = latency::measured()?;
    // The measured counts are the int8 engine's (its Cortex-M kernels): an f32 model's
    // latency on an MCU is not estimated from them.
    let latency = if m.dtype() == evpose_core::DType::I8 {
        a.target
            .iter()
            .map(|&t| {
                let events = (a.window_events, a.input);
                latency::estimate(&mb, events, &measured, t, a.weights)
            })
            .collect()
    } else {
        if !a.json {
            eprintln!(
                "no latency estimate: {} is an f32 model, and the Cortex-M counts are the int8 \
                 engine's (quantize it with `evpose quantize`)",
                a.model.display()
            );
        }
        Vec::new()
    };
    let b = Budget {
        model: mb,
        image,
        latency,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        print_model(&a.model, &b.model);
        print_latency(
            &b.latency,
            &measured,
            (a.window_events, b.model.points, a.input),
            (a.weights, b.model.widened_bytes),
        );
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
         (x86 with AVX-512 VNNI or AVX-VNNI)",
        m.block_scratch_words,
        4 * m.block_scratch_words,
        evpose_core::infer::MAX_BLOCK,
        m.packed_bytes
    );
    if m.widened_bytes > 0 {
        println!(
            "MCU: widened weights {} bytes (Cortex-M with DSP, `Plan::widened`; the latency \
             below assumes them unless --weights row-major, which needs no extra RAM)",
            m.widened_bytes
        );
    }
    println!(
        "MACs: {} per point x {} points + {} after pooling = {} ({:.3} GMAC)",
        m.macs_per_point,
        m.points,
        m.macs_after_pooling,
        m.macs_total,
        m.macs_total as f64 / 1e9
    );
}

fn print_latency(
    list: &[Latency],
    k: &Measured,
    (events, points, input): (u64, u64, Input),
    (weights, widened_bytes): (Weights, usize),
) {
    if list.is_empty() {
        return;
    }
    let (point, point_m4, over) = match weights {
        Weights::Widened => (
            k.instructions_per_point_mac,
            k.instructions_per_point_mac_without_arm_fpv5,
            if widened_bytes > 0 {
                format!("widened weights ({widened_bytes} bytes of RAM; --weights row-major: none)")
            } else {
                "widened weights (none in this model)".to_string()
            },
        ),
        Weights::RowMajor => (
            k.instructions_per_point_mac_row_major,
            k.instructions_per_point_mac_row_major_without_arm_fpv5,
            "the row-major weights (no extra RAM; --weights widened: faster)".to_string(),
        ),
    };
    println!(
        "\nlatency per {events}-event window at {points} points, point layers over {over}, from \
         instructions measured under QEMU (firmware/measured.json, commit {}; model {}: \
         {:.1}/event, {:.3}/point-layer MAC, {:.3}/MAC after pooling; the build for the M4, used \
         for the M4 and M33, {:.1}, {:.3} and {:.3}); cycles = instructions x CPI (assumed):",
        // The record's provenance note follows its commit hash: the hash is enough here
        // (--json has the whole note).
        k.commit.split_whitespace().next().unwrap_or("?"),
        k.model,
        k.instructions_per_event,
        point,
        k.instructions_per_vector_mac,
        k.instructions_per_event_without_arm_fpv5,
        point_m4,
        k.instructions_per_vector_mac_without_arm_fpv5
    );
    let stream = match input {
        Input::Evs1 => "the firmware's EVS1 words",
        Input::Evt3 => "EVT 3.0 words (a Prophesee IMX636's)",
        Input::Evt21 => "EVT 2.1 words (a GenX320's)",
    };
    println!(
        "input: {stream}, {:.1} instructions per event ({:.1} in the M4 build; --input \
         evs1|evt3|evt21)",
        input.per_event(k, true),
        input.per_event(k, false)
    );
    println!(
        "{:<18} {:>4} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}  {:>8}  verdict ({REAL_TIME_MS} ms)   max points",
        "target", "CPI", "input", "raster", "sample", "infer", "decode", "conf", "ms"
    );
    let m = |v: f64| format!("{:.2}M", v / 1e6);
    for l in list {
        println!(
            "{:<18} {:>4} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}  {:>8.2}  {:<20}  {}",
            l.target,
            l.cpi,
            m(l.input),
            m(l.rasterize),
            m(l.sample),
            m(l.infer),
            m(l.decode),
            m(l.confidence),
            l.ms,
            if l.real_time { "real time" } else { "too slow" },
            l.max_real_time_points
        );
    }
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
    println!(
        "panic paths: {} (functions that call into the panic machinery; --json lists them)",
        i.panic_paths.len()
    );
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
