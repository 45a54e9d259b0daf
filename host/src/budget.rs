//! `evpose budget`: what a model costs on an MCU, and what a firmware image occupies.
//!
//! Per layer: MACs (per point for point layers, per vector for FC layers, per joint for the
//! heads), weight bytes and bias/scale bytes; the scratch of the blob's engine (int8 or f32) from
//! [`evpose_core::scratch_words`]; MACs for `N` points. With an ELF (by default the firmware's
//! release image, when it has been built), flash and RAM from its section headers:
//!
//! - flash: every allocated section with contents (`.vector_table`, `.text`, `.rodata`, and
//!   `.data`'s load image);
//! - RAM: every allocated writable section (`.data`, `.bss`, `.uninit`) plus the stack
//!   reservation `_stack_start - _stack_end` (symbols of cortex-m-rt, set in `memory.x`);
//! - heap: any section named like a heap, or a global allocator's symbols (`__rust_alloc`, …).
//!
//! The ELF is read by hand (32-bit little-endian: section headers, the symbol table, and the
//! code's Thumb-2 `BL`/`B.W` instructions, decoded to find the panic paths).

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, ensure, Context, Result};
use evpose_core::model::{Bias, LayerKind, Model, Weights};
use serde::Serialize;

/// One layer's cost.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct LayerBudget {
    /// Index in the blob's layer table.
    pub index: usize,
    /// `point`, `fc`, `head_x` or `head_y`.
    pub kind: &'static str,
    /// Input width.
    pub in_dim: u32,
    /// Output width.
    pub out_dim: u32,
    /// Multiply-accumulates for one input vector.
    pub macs: u64,
    /// How often the layer runs per inference: `point` (N times), `vector` (once) or
    /// `joint` (J times).
    pub per: &'static str,
    /// Weight element type (`i8`, `i16`, `f32`).
    pub weight_type: &'static str,
    /// Bytes of weights.
    pub weight_bytes: u64,
    /// Bytes of bias and requantization scales.
    pub bias_scale_bytes: u64,
}

/// A model's cost.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct ModelBudget {
    /// Blob size in bytes.
    pub blob_bytes: u64,
    /// `i8` or `f32`.
    pub dtype: &'static str,
    /// Joints, x-axis width, y-axis height.
    pub joints: usize,
    /// SimDR x width.
    pub width: usize,
    /// SimDR y height.
    pub height: usize,
    /// The layers, in blob order.
    pub layers: Vec<LayerBudget>,
    /// MACs of the point layers, per point.
    pub macs_per_point: u64,
    /// MACs after pooling (FC layers, heads for all joints).
    pub macs_after_pooling: u64,
    /// Points per inference.
    pub points: u64,
    /// `macs_per_point × points + macs_after_pooling`.
    pub macs_total: u64,
    /// Weight bytes, all layers.
    pub weight_bytes: u64,
    /// Bias and scale bytes, all layers.
    pub bias_scale_bytes: u64,
    /// Scratch the engine needs, in 32-bit words.
    pub scratch_words: usize,
    /// The same in bytes.
    pub scratch_bytes: usize,
    /// Head outputs (`J × (W + H)` values of 4 bytes), lent by the caller.
    pub output_bytes: usize,
    /// Scratch words of the blob's engine in blocks of `MAX_BLOCK` points (what the host lends:
    /// fewer passes over the weights); `scratch_words` is the one-point minimum an MCU lends.
    pub block_scratch_words: usize,
    /// Bytes of the packed copy of the point layers' and heads' weights that a host with native packed
    /// kernels (x86 AVX-512 VNNI, AVX-VNNI) makes at load (`evpose_core::packed_bytes`); 0 for
    /// f32.
    pub packed_bytes: usize,
    /// Bytes of the widened copy of the int8 point layers' weights that the Cortex-M DSP
    /// kernel runs fastest with (`evpose_core::widened_words`, 4 bytes each; the firmware
    /// lends it as a `static` and the MCU latency assumes it by default); 0 for f32.
    pub widened_bytes: usize,
}

/// One section of an ELF image.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct Section {
    /// Name.
    pub name: String,
    /// Address.
    pub addr: u32,
    /// Size in bytes.
    pub size: u32,
    /// Occupies flash (allocated, with contents in the file).
    pub flash: bool,
    /// Occupies RAM (allocated, writable).
    pub ram: bool,
}

/// A static object of the image.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct Symbol {
    /// Demangled name (without the hash).
    pub name: String,
    /// Size in bytes.
    pub size: u32,
    /// Section holding it.
    pub section: String,
}

/// What a firmware image occupies.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct ImageBudget {
    /// The ELF file.
    pub elf: String,
    /// Allocated sections (size > 0).
    pub sections: Vec<Section>,
    /// Bytes of flash: allocated sections with contents (`.data` counted by its load image).
    pub flash_bytes: u64,
    /// Bytes of static RAM: allocated writable sections (`.data`, `.bss`, `.uninit`).
    pub static_ram_bytes: u64,
    /// Stack reservation `_stack_start - _stack_end`, if the symbols are there.
    pub stack_bytes: Option<u64>,
    /// `static_ram_bytes + stack_bytes`.
    pub ram_bytes: u64,
    /// Heap sections or allocator symbols found (empty: no heap).
    pub heap: Vec<String>,
    /// Largest static objects in RAM, largest first.
    pub largest_ram: Vec<Symbol>,
    /// Largest objects in flash, largest first.
    pub largest_flash: Vec<Symbol>,
    /// Functions that call into the panic machinery ([`panic_paths`]; Thumb-2 images).
    pub panic_paths: Vec<PanicPath>,
}

/// The report of `evpose budget`.
#[derive(Clone, Debug, Serialize)]
pub struct Budget {
    /// The model's cost.
    pub model: ModelBudget,
    /// The image, when one was measured.
    pub image: Option<ImageBudget>,
    /// Estimated latency per target ([`crate::latency`]).
    pub latency: Vec<crate::latency::Latency>,
}

/// Where the firmware's release build puts its ELF, relative to the repository root.
pub const FIRMWARE_ELF: &str = "firmware/target/thumbv7em-none-eabihf/release/evpose-firmware";

/// The firmware's release ELF: under the current directory if it is there, else in the
/// repository this tool was built from.
pub fn default_elf() -> PathBuf {
    let here = PathBuf::from(FIRMWARE_ELF);
    if here.exists() {
        return here;
    }
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or(here.clone(), |repo| repo.join(FIRMWARE_ELF))
}

/// Costs of a parsed model for `points` points.
pub fn model_budget(m: &Model<'_>, points: u64) -> ModelBudget {
    let mut layers = Vec::new();
    for i in 0..m.layer_count() {
        let l = m.layer(i);
        let (weight_type, weight_bytes) = match l.weights {
            Weights::I8(w) => ("i8", w.len()),
            Weights::I16(w) => ("i16", 2 * w.len()),
            Weights::F32(w) => ("f32", 4 * w.len()),
        };
        let bias = match l.bias {
            Bias::I32(b) => 4 * b.len(),
            Bias::F32(b) => 4 * b.len(),
        };
        let (kind, per) = match l.desc.kind {
            LayerKind::Point => ("point", "point"),
            LayerKind::Fc => ("fc", "vector"),
            LayerKind::HeadX => ("head_x", "joint"),
            LayerKind::HeadY => ("head_y", "joint"),
        };
        layers.push(LayerBudget {
            index: i,
            kind,
            in_dim: l.desc.in_dim,
            out_dim: l.desc.out_dim,
            macs: m.macs(i),
            per,
            weight_type,
            weight_bytes: weight_bytes as u64,
            bias_scale_bytes: (bias + 4 * l.scales.len()) as u64,
        });
    }
    let scratch = evpose_core::scratch_words(m);
    ModelBudget {
        blob_bytes: m.bytes().len() as u64,
        dtype: match m.dtype() {
            evpose_core::DType::I8 => "i8",
            evpose_core::DType::F32 => "f32",
        },
        joints: m.joints(),
        width: m.width(),
        height: m.height(),
        macs_per_point: m.macs_per_point(),
        macs_after_pooling: m.macs_after_pooling(),
        points,
        macs_total: m.macs_per_point() * points + m.macs_after_pooling(),
        weight_bytes: layers.iter().map(|l| l.weight_bytes).sum(),
        bias_scale_bytes: layers.iter().map(|l| l.bias_scale_bytes).sum(),
        layers,
        scratch_words: scratch,
        scratch_bytes: 4 * scratch,
        output_bytes: 4 * m.joints() * (m.width() + m.height()),
        block_scratch_words: evpose_core::scratch_words_for_block(m, evpose_core::infer::MAX_BLOCK),
        packed_bytes: evpose_core::packed_bytes(m),
        widened_bytes: 4 * evpose_core::widened_words(m),
    }
}

const SHT_SYMTAB: u32 = 2;
const SHT_NOBITS: u32 = 8;
const SHF_WRITE: u32 = 1;
const SHF_ALLOC: u32 = 2;
const STT_OBJECT: u8 = 1;
const STT_FUNC: u8 = 2;
/// Symbols that only exist when the image has a global allocator.
const ALLOCATOR_SYMBOLS: [&str; 5] = [
    "__rust_alloc",
    "__rg_alloc",
    "__rdl_alloc",
    "__rust_alloc_error_handler",
    "__rust_no_alloc_shim_is_unstable",
];

struct Elf<'a> {
    bytes: &'a [u8],
}

impl<'a> Elf<'a> {
    fn u16(&self, o: usize) -> Result<u16> {
        let b = self
            .bytes
            .get(o..o + 2)
            .ok_or_else(|| anyhow!("truncated at {o}"))?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&self, o: usize) -> Result<u32> {
        let b = self
            .bytes
            .get(o..o + 4)
            .ok_or_else(|| anyhow!("truncated at {o}"))?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn cstr(&self, o: usize) -> Result<&'a str> {
        let tail = self
            .bytes
            .get(o..)
            .ok_or_else(|| anyhow!("string at {o}"))?;
        let end = tail.iter().position(|&c| c == 0).unwrap_or(tail.len());
        Ok(std::str::from_utf8(&tail[..end]).unwrap_or("?"))
    }
}

struct RawSection {
    name: String,
    kind: u32,
    flags: u32,
    addr: u32,
    offset: u32,
    size: u32,
    link: u32,
}

/// The section headers of an ELF32 image, with their names.
fn read_sections(elf: &Elf<'_>) -> Result<Vec<RawSection>> {
    let shoff = elf.u32(0x20)? as usize;
    let shentsize = usize::from(elf.u16(0x2E)?);
    let shnum = usize::from(elf.u16(0x30)?);
    let shstrndx = usize::from(elf.u16(0x32)?);
    ensure!(
        shentsize >= 40,
        "section header entries of {shentsize} bytes"
    );
    let header = |i: usize| -> Result<(u32, RawSection)> {
        let o = shoff + i * shentsize;
        Ok((
            elf.u32(o)?,
            RawSection {
                name: String::new(),
                kind: elf.u32(o + 4)?,
                flags: elf.u32(o + 8)?,
                addr: elf.u32(o + 12)?,
                offset: elf.u32(o + 16)?,
                size: elf.u32(o + 20)?,
                link: elf.u32(o + 24)?,
            },
        ))
    };
    if shstrndx >= shnum {
        bail!("no section name table");
    }
    let names = header(shstrndx)?.1.offset as usize;
    let mut raw = Vec::with_capacity(shnum);
    for i in 0..shnum {
        let (name_off, mut s) = header(i)?;
        s.name = elf.cstr(names + name_off as usize)?.to_string();
        raw.push(s);
    }

    Ok(raw)
}

/// One symbol-table entry.
struct RawSymbol<'a> {
    name: &'a str,
    value: u32,
    size: u32,
    info: u8,
    shndx: usize,
}

/// The symbol table of an ELF32 image (empty when it has none).
fn read_symbols<'a>(elf: &Elf<'a>, raw: &[RawSection]) -> Result<Vec<RawSymbol<'a>>> {
    let Some(symtab) = raw.iter().find(|s| s.kind == SHT_SYMTAB) else {
        return Ok(Vec::new());
    };
    let strtab = raw
        .get(symtab.link as usize)
        .ok_or_else(|| anyhow!("symbol table without strings"))?
        .offset as usize;
    (0..(symtab.size / 16) as usize)
        .map(|i| {
            let o = symtab.offset as usize + i * 16;
            Ok(RawSymbol {
                name: elf.cstr(strtab + elf.u32(o)? as usize)?,
                value: elf.u32(o + 4)?,
                size: elf.u32(o + 8)?,
                info: *elf.bytes.get(o + 12).unwrap_or(&0),
                shndx: usize::from(elf.u16(o + 14)?),
            })
        })
        .collect()
}

/// Functions of the panic machinery, by demangled name: what a reachable panic calls.
pub const PANIC_MACHINERY: [&str; 9] = [
    "core::panicking::",
    "core::slice::index::",
    "core::slice::copy_from_slice_impl::len_mismatch_fail",
    "core::option::unwrap_failed",
    "core::option::expect_failed",
    "core::result::unwrap_failed",
    "core::slice::sort::shared::smallsort::panic_on_ord_violation",
    "core::cell::panic_already",
    "rust_begin_unwind",
];

/// One panic path of an image: a function outside the panic machinery that calls (or
/// tail-calls) into it.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
pub struct PanicPath {
    /// The calling function, demangled, without its hash.
    pub caller: String,
    /// The panic function it calls, demangled, without its hash.
    pub panics: String,
}

/// The panic paths of a Thumb-2 (Cortex-M) image: every `BL`/`B.W` (and conditional `B.W`)
/// from a function outside the panic machinery ([`PANIC_MACHINERY`]) to one inside it, found
/// by decoding each function's instructions from the symbol table. Calls through pointers are
/// not seen (the firmware makes none into the machinery).
pub fn panic_paths(path: &Path) -> Result<Vec<PanicPath>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let elf = Elf { bytes: &bytes };
    ensure!(
        bytes.starts_with(b"\x7fELF"),
        "{}: no ELF magic",
        path.display()
    );
    let raw = read_sections(&elf)?;
    let symbols = read_symbols(&elf, &raw)?;
    Ok(find_panic_paths(&bytes, &raw, &symbols))
}

fn find_panic_paths(bytes: &[u8], raw: &[RawSection], symbols: &[RawSymbol<'_>]) -> Vec<PanicPath> {
    let funcs: Vec<(String, &RawSymbol<'_>)> = symbols
        .iter()
        .filter(|s| s.info & 0xF == STT_FUNC && s.size > 0)
        .map(|s| (format!("{:#}", rustc_demangle::demangle(s.name)), s))
        .collect();
    let is_panic = |n: &str| PANIC_MACHINERY.iter().any(|p| n.starts_with(p));
    let targets: std::collections::BTreeMap<u32, &str> = funcs
        .iter()
        .filter(|(n, _)| is_panic(n))
        .map(|(n, s)| (s.value & !1, n.as_str()))
        .collect();
    let mut out = std::collections::BTreeSet::new();
    for (caller, s) in funcs.iter().filter(|(n, _)| !is_panic(n)) {
        let Some(sec) = raw.get(s.shndx) else {
            continue;
        };
        let start = (s.value & !1).wrapping_sub(sec.addr) as usize + sec.offset as usize;
        let Some(code) = bytes.get(start..start + s.size as usize) else {
            continue;
        };
        let mut i = 0;
        while i + 2 <= code.len() {
            let hw1 = u16::from_le_bytes([code[i], code[i + 1]]);
            if hw1 >> 11 < 0b11101 {
                i += 2; // a 16-bit instruction
                continue;
            }
            let Some(hw2) = code
                .get(i + 2..i + 4)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
            else {
                break;
            };
            let pc = (s.value & !1).wrapping_add(i as u32 + 4);
            if let Some(t) = thumb2_branch_target(hw1, hw2, pc) {
                if let Some(p) = targets.get(&t) {
                    out.insert(PanicPath {
                        caller: caller.clone(),
                        panics: (*p).to_string(),
                    });
                }
            }
            i += 4;
        }
    }
    out.into_iter().collect()
}

/// The target of a Thumb-2 `BL` (T1), `B.W` (T4) or conditional `B.W` (T3) at `pc` (its
/// address + 4); `None` for any other instruction.
fn thumb2_branch_target(hw1: u16, hw2: u16, pc: u32) -> Option<u32> {
    if hw1 >> 11 != 0b11110 || hw2 >> 15 != 1 {
        return None;
    }
    let (h1, h2) = (u32::from(hw1), u32::from(hw2));
    let s = (h1 >> 10) & 1;
    let (j1, j2) = ((h2 >> 13) & 1, (h2 >> 11) & 1);
    let imm11 = h2 & 0x7FF;
    let offset = match (hw2 >> 12) & 0b101 {
        // BL (T1) and B.W (T4): 11110 S imm10 / 1 1|0 J1 1 J2 imm11.
        0b101 | 0b001 => {
            let (i1, i2) = (!(j1 ^ s) & 1, !(j2 ^ s) & 1);
            let imm = (s << 24) | (i1 << 23) | (i2 << 22) | ((h1 & 0x3FF) << 12) | (imm11 << 1);
            ((imm << 7) as i32) >> 7
        }
        // B<cond>.W (T3): 11110 S cond imm6 / 10 J1 0 J2 imm11 (cond 111x is not a branch).
        0b000 if (h1 >> 7) & 0b111 != 0b111 => {
            let imm = (s << 20) | (j2 << 19) | (j1 << 18) | ((h1 & 0x3F) << 12) | (imm11 << 1);
            ((imm << 11) as i32) >> 11
        }
        _ => return None,
    };
    Some(pc.wrapping_add(offset as u32))
}

/// Reads an ELF32 little-endian image's sections, symbols and heap markers.
pub fn image_budget(path: &Path) -> Result<ImageBudget> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    image_budget_bytes(&bytes, &path.display().to_string())
        .with_context(|| format!("{}: not a readable 32-bit ELF image", path.display()))
}

fn image_budget_bytes(bytes: &[u8], name: &str) -> Result<ImageBudget> {
    let elf = Elf { bytes };
    ensure!(bytes.starts_with(b"\x7fELF"), "no ELF magic");
    ensure!(
        bytes.get(4) == Some(&1) && bytes.get(5) == Some(&1),
        "not a 32-bit little-endian ELF"
    );
    let raw = read_sections(&elf)?;

    let mut sections = Vec::new();
    let (mut flash, mut ram) = (0u64, 0u64);
    let mut heap = Vec::new();
    for s in &raw {
        if s.flags & SHF_ALLOC == 0 || s.size == 0 {
            continue;
        }
        let in_flash = s.kind != SHT_NOBITS;
        let in_ram = s.flags & SHF_WRITE != 0;
        flash += u64::from(s.size) * u64::from(in_flash);
        ram += u64::from(s.size) * u64::from(in_ram);
        if s.name.to_ascii_lowercase().contains("heap") {
            heap.push(format!("section {}", s.name));
        }
        sections.push(Section {
            name: s.name.clone(),
            addr: s.addr,
            size: s.size,
            flash: in_flash,
            ram: in_ram,
        });
    }

    let (mut stack_start, mut stack_end) = (None, None);
    let mut objects = Vec::new();
    let symbols = read_symbols(&elf, &raw)?;
    for sym in &symbols {
        match sym.name {
            "_stack_start" => stack_start = Some(sym.value),
            "_stack_end" => stack_end = Some(sym.value),
            n if ALLOCATOR_SYMBOLS.contains(&n) => heap.push(format!("symbol {n}")),
            _ => {}
        }
        if sym.info & 0xF == STT_OBJECT && sym.size > 0 {
            if let Some(s) = raw.get(sym.shndx).filter(|s| s.flags & SHF_ALLOC != 0) {
                objects.push((
                    demangle(sym.name),
                    sym.size,
                    s.name.clone(),
                    s.flags & SHF_WRITE != 0,
                ));
            }
        }
    }
    let stack = match (stack_start, stack_end) {
        (Some(a), Some(b)) if a >= b => Some(u64::from(a - b)),
        _ => None,
    };
    objects.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    let largest = |want_ram: bool| -> Vec<Symbol> {
        objects
            .iter()
            .filter(|o| o.3 == want_ram)
            .take(5)
            .map(|(name, size, section, _)| Symbol {
                name: name.clone(),
                size: *size,
                section: section.clone(),
            })
            .collect()
    };
    Ok(ImageBudget {
        elf: name.to_string(),
        flash_bytes: flash,
        static_ram_bytes: ram,
        stack_bytes: stack,
        ram_bytes: ram + stack.unwrap_or(0),
        heap,
        largest_ram: largest(true),
        largest_flash: largest(false),
        panic_paths: find_panic_paths(bytes, &raw, &symbols),
        sections,
    })
}

/// Rust's legacy mangling (`_ZN` + length-prefixed parts + `E`) to `a::b::c`, hash dropped;
/// other names unchanged.
pub fn demangle(name: &str) -> String {
    let Some(mut rest) = name.strip_prefix("_ZN") else {
        return name.to_string();
    };
    let mut parts = Vec::new();
    while let Some(digits) = rest.find(|c: char| !c.is_ascii_digit()) {
        let Ok(len) = rest[..digits].parse::<usize>() else {
            break;
        };
        let Some(part) = rest.get(digits..digits + len) else {
            break;
        };
        parts.push(part);
        rest = &rest[digits + len..];
    }
    if parts
        .last()
        .is_some_and(|p| p.len() == 17 && p.starts_with('h'))
    {
        parts.pop();
    }
    if parts.is_empty() {
        return name.to_string();
    }
    let mut name = parts.join("::");
    for (code, c) in [("$LT$", "<"), ("$GT$", ">"), ("$u7b$", "{"), ("$u7d$", "}")] {
        name = name.replace(code, c);
    }
    name
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_thumb2_branches() {
        // BL at 0x1000 to 0x2000: offset +0xffc.
        assert_eq!(thumb2_branch_target(0xF000, 0xFFFE, 0x1004), Some(0x2000));
        // B.W at 0x2000 back to 0x1000: offset -0x1004.
        assert_eq!(thumb2_branch_target(0xF7FE, 0xBFFE, 0x2004), Some(0x1000));
        // BEQ.W at 0x1000 to 0x1010 (cond 0000, offset +0xc).
        assert_eq!(thumb2_branch_target(0xF000, 0x8006, 0x1004), Some(0x1010));
        // Not branches: a data-processing instruction, BLX (T2), cond 111x.
        assert_eq!(thumb2_branch_target(0xF000, 0x0000, 0x1004), None);
        assert_eq!(thumb2_branch_target(0xF000, 0xC000, 0x1004), None);
        assert_eq!(thumb2_branch_target(0xF380, 0x8000, 0x1004), None);
    }

    #[test]
    fn demangles_legacy_names() {
        assert_eq!(
            demangle("_ZN15evpose_firmware6RASTER17h0123456789abcdefE"),
            "evpose_firmware::RASTER"
        );
        assert_eq!(demangle("__sbss"), "__sbss");
    }

    #[test]
    fn bundled_model_budget_adds_up() {
        let blob = crate::assets::default_blob();
        let m = Model::parse(blob.bytes()).unwrap();
        let b = model_budget(&m, 2048);
        // The bundled MCU model: 5·16 + 16·16 + 16·32 + 32·64 + 128·128 MACs per point.
        assert_eq!(b.macs_per_point, 19_280);
        assert_eq!(b.macs_total, 19_280 * 2048 + b.macs_after_pooling);
        assert!(b.block_scratch_words > b.scratch_words);
        // The packed copy holds every point layer and both heads in whole blocks of 64 rows by
        // one step (four int8 inputs, or two int16): 768 + 1,024 + 1,024 + 2,048 + 16,384 bytes
        // for the point layers (the int16 first one: 3 steps of one group), 24,576 + 20,480 for
        // the 15-bit heads (6 and 5 groups of 16 steps), and up to 63 bytes of alignment.
        assert_eq!(b.packed_bytes, 21_248 + 45_056 + 63);
        let point_i8: u64 = b.layers[1..m.point_layer_count()]
            .iter()
            .map(|l| l.weight_bytes)
            .sum();
        // Two bytes per int8 point-layer weight in whole steps of four (all of them here).
        assert_eq!(b.widened_bytes as u64, 2 * point_i8);
    }

    #[test]
    fn rejects_non_elf() {
        assert!(image_budget_bytes(b"not an elf at all", "x").is_err());
    }
}
