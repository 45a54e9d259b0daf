//! Inference: the f32 and int8 engines over one [`Model`] description.
//!
//! Points go through all point layers in blocks (as many points as the lent scratch holds, up
//! to [`MAX_BLOCK`]; one on an MCU), and the last point layer is reduced on the fly into a
//! running max and a running sum, so activation memory is O(block × layer widths), never
//! O(points × widths). The caller lends the scratch memory; the model says how much it needs
//! ([`scratch_words`], [`scratch_words_for_block`]); too little is an error, not a panic.
//!
//! The int8 engine's arithmetic is defined in [`crate::quant`]; the heads' int32 accumulators
//! are the outputs (their argmax is the argmax of the dequantized logits).

use core::fmt;

use crate::kernels::packed::{packed_len, PackedI8};
use crate::kernels::Kernels;
use crate::model::{Bias, DType, Layer, LayerKind, Model, Weights, FEATURES};
use crate::quant::{self, InputCoding};

/// Why an inference did not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum InferError {
    /// The engine does not match the model's number format.
    DType,
    /// No points: pooling is undefined (sampling gives N zero points for an empty window).
    NoPoints,
    /// Too little scratch memory.
    Scratch {
        /// Words needed.
        needed: usize,
        /// Words lent.
        got: usize,
    },
    /// Too small a buffer for the packed weights ([`packed_bytes`]).
    PackBuffer {
        /// Bytes needed.
        needed: usize,
        /// Bytes lent.
        got: usize,
    },
    /// The packed weights were packed from another model.
    PackedModel,
    /// The packed weights are not in the buffer they were packed into.
    PackedBuffer,
    /// An output buffer has the wrong length.
    Output {
        /// Values needed (`J × W` or `J × H`).
        needed: usize,
        /// Values lent.
        got: usize,
    },
}

impl fmt::Display for InferError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::DType => write!(f, "engine does not match the model's number format"),
            Self::NoPoints => write!(f, "no input points"),
            Self::Scratch { needed, got } => {
                write!(f, "scratch needs {needed} words, got {got}")
            }
            Self::PackBuffer { needed, got } => {
                write!(f, "packed weights need {needed} bytes, got {got}")
            }
            Self::PackedModel => write!(f, "the packed weights belong to another model"),
            Self::PackedBuffer => {
                write!(
                    f,
                    "the packed weights are not in the buffer they were packed into"
                )
            }
            Self::Output { needed, got } => {
                write!(f, "output needs {needed} values, got {got}")
            }
        }
    }
}

impl core::error::Error for InferError {}

/// Most points an engine processes per pass over the point layers' weights (a multiple
/// of the packed x86 kernel's six-point tile).
pub const MAX_BLOCK: usize = 24;

/// 32-bit scratch words an inference with `model` needs at least (either engine; it then
/// processes one point at a time).
pub fn scratch_words(model: &Model<'_>) -> usize {
    scratch_words_for_block(model, 1)
}

/// Scratch words for the engine of `model`'s number format to process `block` points per pass
/// over the point layers' weights (`1..=MAX_BLOCK`; more scratch, fewer weight reads).
///
/// Both engines pick the largest block the lent scratch holds.
pub fn scratch_words_for_block(model: &Model<'_>, block: usize) -> usize {
    let b = block.clamp(1, MAX_BLOCK);
    let pooled = model.pooled_width() as usize;
    let fc = (2 * pooled).max(model.widest_fc()) + model.widest_fc();
    let acts = model.point_activation_width();
    match model.dtype() {
        // block of input features | block of point activations | max, sum | FC ping-pong
        DType::F32 => b * (FEATURES + acts) + 2 * pooled + fc,
        // i32: sums, block accumulators | bytes: block of i16 inputs (8 each), block of
        // activations, block of gathered layer inputs, FC ping-pong
        DType::I8 => {
            let bytes = b * (16 + acts + widest_input(model)) + fc;
            pooled + b * widest_layer(model) + bytes.div_ceil(4)
        }
    }
}

/// The largest block whose scratch fits in `words` (1 if none does; [`check_args`] refuses
/// that case first).
fn block_for(model: &Model<'_>, words: usize) -> usize {
    (1..=MAX_BLOCK)
        .rev()
        .find(|&b| scratch_words_for_block(model, b) <= words)
        .unwrap_or(1)
}

fn widest_input(model: &Model<'_>) -> usize {
    (0..model.point_layer_count())
        .map(|i| model.layer(i).desc.in_dim as usize)
        .max()
        .unwrap_or(0)
}

fn widest_layer(model: &Model<'_>) -> usize {
    (0..model.layer_count())
        .map(|i| model.layer(i).desc.out_dim as usize)
        .max()
        .unwrap_or(0)
}

/// Byte offset of each point layer's output in the activation buffer, and the buffer width.
fn layer_offsets(model: &Model<'_>) -> ([usize; crate::model::MAX_POINT_LAYERS + 1], usize) {
    let mut offs = [0; crate::model::MAX_POINT_LAYERS + 1];
    for i in 0..model.point_layer_count() {
        offs[i + 1] = offs[i] + model.layer(i).desc.out_dim as usize;
    }
    (offs, offs[model.point_layer_count()])
}

/// Range of the activation buffer a point layer reads: its sources, which are contiguous
/// (checked at import; the input features are handled apart).
fn source_range(sources: u32, offs: &[usize]) -> core::ops::Range<usize> {
    let first = sources.trailing_zeros() as usize; // ≥ 1 for layer sources
    let last = 31 - sources.leading_zeros() as usize;
    offs[first - 1]..offs[last]
}

/// The checks both engines make before touching any buffer.
fn check_args(
    model: &Model<'_>,
    dtype: DType,
    points: &[[f32; FEATURES]],
    (x, y): (usize, usize),
    scratch: usize,
) -> Result<(), InferError> {
    if model.dtype() != dtype {
        return Err(InferError::DType);
    }
    if points.is_empty() {
        return Err(InferError::NoPoints);
    }
    let (nx, ny) = (
        model.joints() * model.width(),
        model.joints() * model.height(),
    );
    if x != nx {
        return Err(InferError::Output { needed: nx, got: x });
    }
    if y != ny {
        return Err(InferError::Output { needed: ny, got: y });
    }
    let needed = scratch_words(model);
    if scratch < needed {
        return Err(InferError::Scratch {
            needed,
            got: scratch,
        });
    }
    Ok(())
}

/// An intermediate result of the f32 engine, handed to an observer (calibration).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Stage {
    /// Point layer `i`'s activations for one point.
    Point(usize),
    /// The pooled vector `[max, mean]`.
    Pooled,
    /// FC layer `i`'s activations (`i` counts FC layers from 0).
    Fc(usize),
}

/// Runs the f32 engine on `points` (rows `[x, y, t_avg, p_acc, cnt]`), writing the x logits
/// (`J × W`) and y logits (`J × H`), with the kernels chosen at compile time
/// ([`Kernels::best`]).
pub fn run_f32(
    model: &Model<'_>,
    points: &[[f32; FEATURES]],
    scratch: &mut [f32],
    out_x: &mut [f32],
    out_y: &mut [f32],
) -> Result<(), InferError> {
    run_f32_with(&Kernels::best(), model, points, scratch, out_x, out_y)
}

/// [`run_f32`] with a kernel table, e.g. [`Kernels::detect`] for the CPU it runs on. Every
/// table gives the same bits (the f32 kernel sums in a fixed order), and so does every block
/// size.
pub fn run_f32_with(
    k: &Kernels,
    model: &Model<'_>,
    points: &[[f32; FEATURES]],
    scratch: &mut [f32],
    out_x: &mut [f32],
    out_y: &mut [f32],
) -> Result<(), InferError> {
    run_f32_observed(k, model, points, scratch, out_x, out_y, |_, _| {})
}

/// Weights of one row tile of an f32 point layer: every point of a block goes through the
/// tile while it is in L1 (16 KiB), instead of each point streaming the whole layer from
/// memory (the paper model's point layers are 2.3 MB in f32).
const F32_TILE_WEIGHTS: usize = 4096;

/// [`run_f32_with`], calling `observe` with every intermediate activation vector (per point
/// for the point layers, in no particular order of points).
pub fn run_f32_observed(
    k: &Kernels,
    model: &Model<'_>,
    points: &[[f32; FEATURES]],
    scratch: &mut [f32],
    out_x: &mut [f32],
    out_y: &mut [f32],
    mut observe: impl FnMut(Stage, &[f32]),
) -> Result<(), InferError> {
    check_args(
        model,
        DType::F32,
        points,
        (out_x.len(), out_y.len()),
        scratch.len(),
    )?;
    let (offs, acts_len) = layer_offsets(model);
    let pooled = model.pooled_width() as usize;
    let last = model.point_layer_count() - 1;
    let block = block_for(model, scratch.len());
    let (inputs, rest) = scratch.split_at_mut(block * FEATURES);
    let (acts, rest) = rest.split_at_mut(block * acts_len);
    let (max, rest) = rest.split_at_mut(pooled);
    let (sum, fc) = rest.split_at_mut(pooled);
    max.fill(f32::NEG_INFINITY);
    sum.fill(0.0);
    for chunk in points.chunks(block) {
        let n = chunk.len();
        for (dst, p) in inputs.chunks_exact_mut(FEATURES).zip(chunk) {
            dst.copy_from_slice(p);
        }
        for i in 0..=last {
            let l = model.layer(i);
            let (Weights::F32(w), Bias::F32(b)) = (l.weights, l.bias) else {
                return Err(InferError::DType);
            };
            let (k_in, out_dim) = (l.desc.in_dim as usize, l.desc.out_dim as usize);
            let tile = (F32_TILE_WEIGHTS / k_in.max(1)).max(1);
            for r0 in (0..out_dim).step_by(tile) {
                let rows = r0..(r0 + tile).min(out_dim);
                let (w, b) = (&w[rows.start * k_in..rows.end * k_in], &b[rows.clone()]);
                for (input, act) in inputs
                    .chunks_exact(FEATURES)
                    .zip(acts.chunks_exact_mut(acts_len))
                    .take(n)
                {
                    // A layer reads the input features or earlier layers' outputs (before
                    // its own in the row).
                    let (before, after) = act.split_at_mut(offs[i]);
                    let x: &[f32] = if l.desc.sources == 1 {
                        input
                    } else {
                        &before[source_range(l.desc.sources, &offs)]
                    };
                    k.matvec_f32(w, x, b, &mut after[rows.clone()]);
                }
            }
            for act in acts.chunks_exact_mut(acts_len).take(n) {
                let out = &mut act[offs[i]..offs[i + 1]];
                leaky_f32(out, l.desc.leaky);
                observe(Stage::Point(i), out);
            }
        }
        for act in acts.chunks_exact(acts_len).take(n) {
            for ((m, s), &v) in max
                .iter_mut()
                .zip(sum.iter_mut())
                .zip(&act[offs[last]..offs[last + 1]])
            {
                *m = m.max(v);
                *s += v;
            }
        }
    }
    let (a, b) = fc.split_at_mut((2 * pooled).max(model.widest_fc()));
    a[..pooled].copy_from_slice(max);
    let n = points.len() as f32;
    for (dst, &s) in a[pooled..2 * pooled].iter_mut().zip(sum.iter()) {
        *dst = s / n;
    }
    observe(Stage::Pooled, &a[..2 * pooled]);
    let feats = fc_chain(model, (a, b), 2 * pooled, |i, l, x, out| {
        let (Weights::F32(w), Bias::F32(bias)) = (l.weights, l.bias) else {
            return Err(InferError::DType);
        };
        k.matvec_f32(w, x, bias, out);
        leaky_f32(out, l.desc.leaky);
        observe(Stage::Fc(i), out);
        Ok(())
    })?;
    heads(model, feats, out_x, out_y, |l, f, dst| {
        let (Weights::F32(w), Bias::F32(bias)) = (l.weights, l.bias) else {
            return Err(InferError::DType);
        };
        k.matvec_f32(w, f, bias, dst);
        Ok(())
    })
}

/// The FC layers after pooling, ping-ponging between `a` (which holds the first `width`
/// features) and `b`: `layer(i, l, x, out)` computes FC layer `i` (counted from 0) from `x`
/// into `out`. Returns the last layer's activations.
fn fc_chain<'s, T>(
    model: &Model<'_>,
    (a, b): (&'s mut [T], &'s mut [T]),
    width: usize,
    mut layer: impl FnMut(usize, &Layer<'_>, &[T], &mut [T]) -> Result<(), InferError>,
) -> Result<&'s [T], InferError> {
    let (mut cur, mut width) = ((a, b), width);
    for i in model.fc_range() {
        let l = model.layer(i);
        let out_dim = l.desc.out_dim as usize;
        layer(
            i - model.point_layer_count(),
            &l,
            &cur.0[..width],
            &mut cur.1[..out_dim],
        )?;
        width = out_dim;
        cur = (cur.1, cur.0);
    }
    Ok(&cur.0[..width])
}

/// The two SimDR heads, shared by all joints: `head(l, f, out)` runs head layer `l` on one
/// joint's features `f` (`head_dim` of `feats`) into that joint's row of `out_x` or `out_y`.
fn heads<T, O>(
    model: &Model<'_>,
    feats: &[T],
    out_x: &mut [O],
    out_y: &mut [O],
    mut head: impl FnMut(&Layer<'_>, &[T], &mut [O]) -> Result<(), InferError>,
) -> Result<(), InferError> {
    for (kind, out) in [(0, out_x), (1, out_y)] {
        let l = model.layer(model.head_x_index() + kind);
        let o = l.desc.out_dim as usize;
        for (f, dst) in feats
            .chunks_exact(model.head_dim())
            .zip(out.chunks_exact_mut(o))
        {
            head(&l, f, dst)?;
        }
    }
    Ok(())
}

fn leaky_f32(v: &mut [f32], alpha: Option<f32>) {
    if let Some(a) = alpha {
        for x in v {
            if *x < 0.0 {
                *x *= a;
            }
        }
    }
}

/// Alignment of the packed weights (a cache line), part of [`packed_bytes`].
const PACK_ALIGN: usize = 64;

/// Bytes of buffer [`pack_point_layers`] needs for `model`'s int8 point layers (the packed
/// weights plus up to 63 bytes to align them to a cache line). 0 for an f32 model.
pub fn packed_bytes(model: &Model<'_>) -> usize {
    let packed: usize = (0..model.point_layer_count())
        .map(|i| model.layer(i))
        .filter(|l| matches!(l.weights, Weights::I8(_)))
        .map(|l| packed_len(l.desc.out_dim as usize, l.desc.in_dim as usize).unwrap_or(usize::MAX))
        .fold(0usize, usize::saturating_add);
    if packed == 0 {
        0
    } else {
        packed.saturating_add(PACK_ALIGN - 1)
    }
}

/// Where [`pack_point_layers`] put each int8 point layer's packed weights (see
/// [`kernels::packed`]) in the caller's buffer. Small and `Copy`: keep it next to the buffer,
/// and get the weights back for [`run_i8_packed`] with [`PackedLayout::weights`].
///
/// Packing is for CPUs with a native packed kernel ([`Kernels::has_packed`]: x86 AVX-512
/// VNNI). It doubles the point layers' weight memory, so an MCU runs the blob's row-major
/// weights in place with [`run_i8`] instead.
#[derive(Clone, Copy, Debug)]
pub struct PackedLayout {
    /// `(start, len)` of each point layer's packed weights in the buffer (len 0: not packed).
    layers: [(usize, usize); crate::model::MAX_POINT_LAYERS],
    /// The model's blob checksum, to refuse packed weights of another model.
    checksum: u32,
    /// Address and length of the buffer packed into, to refuse any other buffer.
    buffer: (usize, usize),
}

impl PackedLayout {
    /// The packed weights of `model`, in `buf`, which must be the buffer (same address, same
    /// length) they were packed into: [`InferError::PackedModel`] if the layout was made for
    /// another model, [`InferError::PackedBuffer`] for another buffer. Cheap (slice checks).
    pub fn weights<'b>(
        &self,
        model: &Model<'_>,
        buf: &'b [u8],
    ) -> Result<PackedWeights<'b>, InferError> {
        if self.checksum != model.checksum() {
            return Err(InferError::PackedModel);
        }
        if self.buffer != (buf.as_ptr() as usize, buf.len()) {
            return Err(InferError::PackedBuffer);
        }
        let mut layers = [None; crate::model::MAX_POINT_LAYERS];
        for (i, (slot, &(start, len))) in layers.iter_mut().zip(&self.layers).enumerate() {
            if len > 0 {
                let l = model.layer(i);
                let bytes = buf.get(start..start.saturating_add(len));
                let (rows, k) = (l.desc.out_dim as usize, l.desc.in_dim as usize);
                *slot = Some(
                    bytes
                        .and_then(|b| PackedI8::from_packed(b, rows, k))
                        .ok_or(InferError::PackedBuffer)?,
                );
            }
        }
        Ok(PackedWeights {
            layers,
            checksum: self.checksum,
        })
    }
}

/// A model's packed point-layer weights, ready for [`run_i8_packed`] (from
/// [`PackedLayout::weights`]).
#[derive(Clone, Copy, Debug)]
pub struct PackedWeights<'b> {
    layers: [Option<PackedI8<'b>>; crate::model::MAX_POINT_LAYERS],
    checksum: u32,
}

/// Packs `model`'s int8 point layers into `buf` (at least [`packed_bytes`] long) and says
/// where they are; keep `buf` where it is (a `Vec`'s heap buffer stays put when the `Vec`
/// moves) and use [`PackedLayout::weights`] to run. The i16 first layer is not packed (five
/// inputs: nothing to gain). The weights start at a cache-line boundary of `buf`.
pub fn pack_point_layers(model: &Model<'_>, buf: &mut [u8]) -> Result<PackedLayout, InferError> {
    let (needed, got) = (packed_bytes(model), buf.len());
    if got < needed {
        return Err(InferError::PackBuffer { needed, got });
    }
    let mut at = buf.as_ptr().align_offset(PACK_ALIGN).min(PACK_ALIGN - 1);
    let mut layers = [(0, 0); crate::model::MAX_POINT_LAYERS];
    for (i, slot) in layers
        .iter_mut()
        .enumerate()
        .take(model.point_layer_count())
    {
        let l = model.layer(i);
        if let Weights::I8(w) = l.weights {
            let (rows, k) = (l.desc.out_dim as usize, l.desc.in_dim as usize);
            let (packed, _) = buf
                .get_mut(at..)
                .and_then(|rest| PackedI8::pack(w, rows, k, rest))
                .ok_or(InferError::PackBuffer { needed, got })?;
            *slot = (at, packed.byte_len());
            at += packed.byte_len();
        }
    }
    Ok(PackedLayout {
        layers,
        checksum: model.checksum(),
        buffer: (buf.as_ptr() as usize, got),
    })
}

/// Runs the int8 engine on `points`, writing the heads' int32 accumulators (bias included):
/// x (`J × W`) and y (`J × H`), with the kernels chosen at compile time ([`Kernels::best`]).
pub fn run_i8(
    model: &Model<'_>,
    points: &[[f32; FEATURES]],
    scratch: &mut [i32],
    out_x: &mut [i32],
    out_y: &mut [i32],
) -> Result<(), InferError> {
    run_i8_with(&Kernels::best(), model, points, scratch, out_x, out_y)
}

/// [`run_i8`] with a kernel table, e.g. [`Kernels::detect`] for the CPU it runs on. Every table
/// gives the same integers (the kernels are bit-exact with the reference).
pub fn run_i8_with(
    k: &Kernels,
    model: &Model<'_>,
    points: &[[f32; FEATURES]],
    scratch: &mut [i32],
    out_x: &mut [i32],
    out_y: &mut [i32],
) -> Result<(), InferError> {
    run_i8_impl(k, model, None, points, scratch, out_x, out_y)
}

/// [`run_i8_with`] with the point layers' weights pre-packed ([`pack_point_layers`],
/// [`PackedLayout::weights`]) for [`Kernels::matmat_packed_i8`]: the same integers, faster
/// where the table has a native packed kernel ([`Kernels::has_packed`]).
pub fn run_i8_packed(
    k: &Kernels,
    model: &Model<'_>,
    packed: &PackedWeights<'_>,
    points: &[[f32; FEATURES]],
    scratch: &mut [i32],
    out_x: &mut [i32],
    out_y: &mut [i32],
) -> Result<(), InferError> {
    if packed.checksum != model.checksum() {
        return Err(InferError::PackedModel);
    }
    run_i8_impl(k, model, Some(packed), points, scratch, out_x, out_y)
}

fn run_i8_impl(
    k: &Kernels,
    model: &Model<'_>,
    packed: Option<&PackedWeights<'_>>,
    points: &[[f32; FEATURES]],
    scratch: &mut [i32],
    out_x: &mut [i32],
    out_y: &mut [i32],
) -> Result<(), InferError> {
    check_args(
        model,
        DType::I8,
        points,
        (out_x.len(), out_y.len()),
        scratch.len(),
    )?;
    let coding = InputCoding {
        shifts: model.input_shifts(),
    };
    let (offs, acts_len) = layer_offsets(model);
    let pooled = model.pooled_width() as usize;
    let last = model.point_layer_count() - 1;
    let widest = widest_layer(model);
    let widest_in = widest_input(model);
    let block = block_for(model, scratch.len());
    let (sum, rest) = scratch.split_at_mut(pooled);
    let (acc, bytes) = rest.split_at_mut(block * widest);
    let bytes: &mut [i8] = bytemuck::cast_slice_mut(bytes);
    let (input_bytes, bytes) = bytes.split_at_mut(16 * block);
    let inputs: &mut [i16] = bytemuck::cast_slice_mut(input_bytes);
    let (acts, bytes) = bytes.split_at_mut(block * acts_len);
    let (gathered, fc) = bytes.split_at_mut(block * widest_in);
    let (a, b) = fc.split_at_mut((2 * pooled).max(model.widest_fc()));
    let (max, _) = a.split_at_mut(pooled);
    max.fill(i8::MIN);
    sum.fill(0);
    for chunk in points.chunks(block) {
        let n = chunk.len();
        for (dst, p) in inputs.chunks_exact_mut(8).zip(chunk) {
            dst[..FEATURES].copy_from_slice(&coding.code(p));
        }
        for i in 0..=last {
            let l = model.layer(i);
            let Bias::I32(bias) = l.bias else {
                return Err(InferError::DType);
            };
            let (k_in, out_dim) = (l.desc.in_dim as usize, l.desc.out_dim as usize);
            let acc = &mut acc[..n * out_dim];
            match l.weights {
                Weights::I16(w) => {
                    for (x, acc) in inputs.chunks_exact(8).zip(acc.chunks_exact_mut(out_dim)) {
                        k.matvec_i16(w, &x[..FEATURES], bias, acc);
                    }
                }
                Weights::I8(_) if packed.is_some() => {
                    // The sources are a contiguous run of each point's activation row: read
                    // them in place, rows `acts_len` apart.
                    let src = source_range(l.desc.sources, &offs);
                    let w = packed
                        .and_then(|p| p.layers[i])
                        .filter(|w| w.rows() == out_dim && w.k() == src.len())
                        .ok_or(InferError::PackedModel)?;
                    k.matmat_packed_i8(&w, &acts[src.start..], acts_len, n, bias, acc, out_dim);
                }
                Weights::I8(w) => {
                    // Gather each point's sources (a contiguous run of its activations) into
                    // rows of K, then one pass over the weights for the whole block.
                    let src = source_range(l.desc.sources, &offs);
                    if n == 1 {
                        // One point (an MCU's block): read the sources in place, no copy.
                        k.matvec_i8(w, &acts[src], bias, acc);
                    } else {
                        for (row, act) in gathered
                            .chunks_exact_mut(k_in)
                            .zip(acts.chunks_exact(acts_len))
                            .take(n)
                        {
                            row.copy_from_slice(&act[src.clone()]);
                        }
                        k.matmat_i8(w, k_in, &gathered[..n * k_in], bias, acc, out_dim);
                    }
                }
                Weights::F32(_) => return Err(InferError::DType),
            }
            for (row, act) in acc
                .chunks_exact(out_dim)
                .zip(acts.chunks_exact_mut(acts_len))
            {
                k.requantize_i8(
                    row,
                    l.scales,
                    l.desc.leaky,
                    &mut act[offs[i]..offs[i] + out_dim],
                );
            }
        }
        for act in acts.chunks_exact(acts_len).take(n) {
            k.pool_i8(max, sum, &act[offs[last]..offs[last + 1]]);
        }
    }
    let n = points.len() as u32;
    for (dst, &s) in a[pooled..2 * pooled].iter_mut().zip(sum.iter()) {
        *dst = quant::average(s, n, model.avg_scale());
    }
    let feats = fc_chain(model, (a, b), 2 * pooled, |_, l, x, out| {
        let (Weights::I8(w), Bias::I32(bias)) = (l.weights, l.bias) else {
            return Err(InferError::DType);
        };
        let acc = &mut acc[..out.len()];
        k.matvec_i8(w, x, bias, acc);
        k.requantize_i8(acc, l.scales, l.desc.leaky, out);
        Ok(())
    })?;
    heads(model, feats, out_x, out_y, |l, f, dst| {
        let (Weights::I8(w), Bias::I32(bias)) = (l.weights, l.bias) else {
            return Err(InferError::DType);
        };
        k.matvec_i8(w, f, bias, dst);
        Ok(())
    })
}

/// Which kind of layer reads the pooled features (for reports).
pub fn describe(kind: LayerKind) -> &'static str {
    match kind {
        LayerKind::Point => "point",
        LayerKind::Fc => "fc",
        LayerKind::HeadX => "head_x",
        LayerKind::HeadY => "head_y",
    }
}
