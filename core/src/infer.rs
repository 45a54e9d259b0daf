//! Inference: the f32 and int8 engines over one [`Model`] description, planned once
//! ([`Plan`]) and run many times.
//!
//! Points go through all point layers in blocks (as many points as the lent scratch holds, up
//! to [`MAX_BLOCK`]; four on the Cortex-M firmware, `kernels::arm::BLOCK_POINTS`), and the last point layer is reduced on the fly into a
//! running max and a running sum, so activation memory is O(block × layer widths), never
//! O(points × widths). The caller lends the scratch memory; the model says how much it needs
//! ([`scratch_words`], [`scratch_words_for_block`]); too little is an error, not a panic.
//!
//! The int8 engine's arithmetic is defined in [`crate::quant`]; the heads' int32 accumulators
//! are the outputs (their argmax is the argmax of the dequantized logits).

use core::fmt;

use crate::kernels::arm::{matmat_widened_i8, widen_i8, widened_row_words};
use crate::kernels::packed::{packed_len_of, Lane, Packed, PackedI16, PackedI8};
use crate::kernels::MatmatWidenedI8;
use crate::kernels::{Kernels, PointRows};
use crate::model::{Bias, DType, Layer, LayerKind, Model, Weights, FEATURES, MAX_POINT_LAYERS};
use crate::quant::{self, InputCoding, Requant};

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
    /// Too small a buffer for the widened weights ([`widened_words`]).
    WidenBuffer {
        /// Words needed.
        needed: usize,
        /// Words lent.
        got: usize,
    },
    /// The packed or widened weights were made from another model.
    PackedModel,
    /// The packed weights are not in the buffer they were packed into.
    PackedBuffer,
    /// An output buffer has the wrong length (each must be exactly its head's size).
    Output {
        /// Which head's buffer: `"x"` (`J × W`) or `"y"` (`J × H`).
        head: &'static str,
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
            Self::WidenBuffer { needed, got } => {
                write!(f, "widened weights need {needed} words, got {got}")
            }
            Self::PackedModel => {
                write!(f, "the packed or widened weights belong to another model")
            }
            Self::PackedBuffer => {
                write!(
                    f,
                    "the packed weights are not in the buffer they were packed into"
                )
            }
            Self::Output { head, needed, got } => {
                write!(
                    f,
                    "head output {head} needs exactly {needed} values, got {got}"
                )
            }
        }
    }
}

impl core::error::Error for InferError {}

/// Most points an engine processes per pass over the point layers' weights: a multiple of the
/// packed x86 kernels' six-point register tile (passes of four tiles) and of the AMX kernel's
/// 32-point tile block, so that a full block leaves no tile half empty (on an Intel Xeon with
/// AMX, a conv5 tile-loop probe ran 1.71–1.96 ms in 32-point blocks against 1.90–2.12 ms in
/// 24-point ones; the whole paper model, fastest of 100 in ten alternating rounds, 2.03 against
/// 2.24 ms at best but three wins and three losses in the six rounds where neither run looked
/// disturbed; the AVX-512 VNNI table the same either way).
pub const MAX_BLOCK: usize = 96;

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
    let fc = fc_values(model);
    let acts = model.point_activation_width();
    match model.dtype() {
        // block of input features | block of point activations | max, sum | FC ping-pong
        DType::F32 => b * (FEATURES + acts) + 2 * pooled + fc,
        // i32: sums, block accumulators | bytes: block of i16 inputs (8 each), block of
        // activations, block of gathered layer inputs, FC ping-pong
        DType::I8 => {
            let bytes = 16 * b + i8_activation_bytes(model, b);
            pooled + b * widest_layer(model) + bytes.div_ceil(4)
        }
    }
}

/// The int8 engine's bytes after its block of inputs: the block's activation rows, its
/// gathered layer inputs and the FC ping-pong buffers (what [`Plan::run_i8`] lays out from the
/// activation rows on).
fn i8_activation_bytes(model: &Model<'_>, block: usize) -> usize {
    block * (model.point_activation_width() + widest_input(model)) + fc_values(model)
}

/// Values of the FC layers' ping-pong buffers: the pooled features (max and mean) or the
/// widest FC layer, and the widest FC layer.
fn fc_values(model: &Model<'_>) -> usize {
    let pooled = model.pooled_width() as usize;
    (2 * pooled).max(model.widest_fc()) + model.widest_fc()
}

/// Scratch words that, lent beyond what a plan needs ([`Plan::scratch_words`]: make the
/// workspace's scratch `plan.scratch_words() + ALIGN_WORDS` long, after planning), let the int8
/// engine start its activation rows at a 64-byte boundary whatever the scratch's own
/// alignment: then a row of 64 activations is one cache line, not two. The x86 AMX kernel
/// reads its input tiles straight from those rows, and tile loads of rows that straddle lines
/// measured 3–7× slower on an Intel Xeon (Emerald Rapids) VM (four loads: 13–27 ns on lines,
/// 76–100 ns off them; `examples/amx_rates.rs`).
/// A host lends them; an MCU need not.
pub const ALIGN_WORDS: usize = 16;

/// The largest block whose scratch fits in `words` (1 if none does; [`Plan::new`] refuses
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
fn layer_offsets(model: &Model<'_>) -> ([usize; MAX_POINT_LAYERS + 1], usize) {
    let mut offs = [0; MAX_POINT_LAYERS + 1];
    let mut end = 0;
    for (i, o) in offs[1..].iter_mut().enumerate() {
        if i < model.point_layer_count() {
            end += model.layer(i).desc.out_dim as usize;
            *o = end;
        }
    }
    (offs, end)
}

/// Range of the activation buffer a point layer reads: its sources, which are contiguous
/// (checked at import; the input features are handled apart).
fn source_range(sources: u32, offs: &[usize]) -> core::ops::Range<usize> {
    let first = sources.trailing_zeros() as usize; // ≥ 1 for layer sources
    let last = 31 - sources.leading_zeros() as usize;
    offset(offs, first.wrapping_sub(1))..offset(offs, last)
}

/// `offs[i]`, or 0 past the end (the plan rules that out; no panic path on an MCU).
fn offset(offs: &[usize], i: usize) -> usize {
    offs.get(i).copied().unwrap_or(0)
}

/// `s.split_at_mut(mid)`, or the scratch error (ruled out by [`Plan::check`], which a run
/// calls first: written so, an MCU image has no panic path here).
fn split<T>(s: &mut [T], mid: usize) -> Result<(&mut [T], &mut [T]), InferError> {
    let got = s.len();
    s.split_at_mut_checked(mid)
        .ok_or(InferError::Scratch { needed: mid, got })
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

/// Weights of one f32 point layer, tile after tile of rows kept in L1 (16 KiB): every point
/// of a block goes through a tile while it is in cache, instead of each point streaming the
/// whole layer from memory (the paper model's point layers are 2.3 MB in f32).
const F32_TILE_WEIGHTS: usize = 4096;

/// An inference plan (TensorFlow Lite Micro's Prepare, for the whole network): built once from
/// a parsed [`Model`], a kernel table, optional packed weights and the size of the scratch the
/// caller will lend. It fixes the engine (f32 or int8, from the model), the block of points per
/// pass over the point layers (the largest the scratch holds, up to [`MAX_BLOCK`]), every
/// layer's typed arrays, input range and requantization ([`Requant`]).
///
/// Running ([`Plan::run_f32`], [`Plan::run_i8`]) then only checks the lengths of the buffers it
/// is given: everything else was checked here.
///
/// ```
/// # fn demo(blob: &[u8]) -> Result<(), Box<dyn core::error::Error>> {
/// use evpose_core::{kernels::Kernels, scratch_words_for_block, Model, Plan};
/// let model = Model::parse(blob)?;
/// let mut scratch = vec![0i32; scratch_words_for_block(&model, 8)];
/// let plan = Plan::new(&model, Kernels::best(), scratch.len())?;
/// let points = [[1.0, 2.0, 0.5, 1.0, 1.0]; 16];
/// let (mut x, mut y) = (vec![0; plan.out_x_len()], vec![0; plan.out_y_len()]);
/// plan.run_i8(&points, &mut scratch, &mut x, &mut y)?;
/// # Ok(()) }
/// ```
///
/// A plan is small (a few hundred bytes: it borrows the model and the packed weights), so an
/// MCU keeps it on its stack.
#[derive(Clone, Copy, Debug)]
pub struct Plan<'m> {
    model: &'m Model<'m>,
    kernels: Kernels,
    /// The packed weights and the functions that run a packed layer and the packed heads: set
    /// by [`Plan::packed`] only, so that an image which never plans packed weights (an MCU's)
    /// links no packed kernel.
    packed: Option<(&'m PackedWeights<'m>, PackedFns)>,
    /// The widened int8 point layers and the kernel that runs them: set by [`Plan::widened`]
    /// only, so that an image which never plans widened weights links no widened kernel.
    widened: Option<(&'m WidenedWeights<'m>, MatmatWidenedI8)>,
    block: usize,
    /// Scratch words `block` needs.
    scratch: usize,
    /// Width of one point's activation row (all point layers' outputs side by side).
    acts_len: usize,
    /// Offset of each point layer's output in the activation row.
    offs: [usize; MAX_POINT_LAYERS + 1],
}

impl<'m> Plan<'m> {
    /// Plans `model` with the kernels `kernels` for a scratch of `scratch_words` 32-bit words
    /// (at least [`scratch_words`]; more lets the engine process more points per pass).
    pub fn new(
        model: &'m Model<'m>,
        kernels: Kernels,
        scratch_words: usize,
    ) -> Result<Self, InferError> {
        Self::build(model, kernels, None, scratch_words)
    }

    /// [`Plan::new`] for an int8 model whose point layers and heads were packed
    /// ([`pack_layers`], [`PackedLayout::weights`]) for [`Kernels::matmat_packed_i8`]
    /// (and its int16 first layer and 15-bit heads for [`Kernels::matmat_packed_i16`]): the
    /// same integers, faster where `kernels` has native packed kernels
    /// ([`Kernels::has_packed`]).
    pub fn packed(
        model: &'m Model<'m>,
        kernels: Kernels,
        packed: &'m PackedWeights<'m>,
        scratch_words: usize,
    ) -> Result<Self, InferError> {
        if packed.checksum != model.checksum() {
            return Err(InferError::PackedModel);
        }
        let mut plan = Self::build(model, kernels, Some(packed), scratch_words)?;
        // Set here, not passed to `build`: with both constructors passing the function to
        // `build`, LLVM's interprocedural constant propagation gave `Plan::new`'s unset payload
        // the same address, and an image that only calls `Plan::new` linked the packed kernels.
        plan.packed = Some((
            packed,
            PackedFns {
                layer: run_packed_layer,
                heads: packed_heads,
            },
        ));
        Ok(plan)
    }

    /// [`Plan::new`] for an int8 model whose int8 point layers were widened
    /// ([`widen_point_layers`]) for the Cortex-M DSP block kernel
    /// ([`crate::kernels::arm::matmat_widened_i8`], which runs them whatever `kernels` says:
    /// the DSP instructions in an `arm-dsp` build, their emulation elsewhere; `kernels` runs
    /// everything else): the same integers, faster on the Cortex-M DSP build (elsewhere the
    /// emulation is slower than the kernel table's own kernels). The widened
    /// weights take twice the int8 point layers' bytes (for the MCU model 38,400 bytes of RAM):
    /// an MCU trades that memory for 13 instead of 15 instructions per 16 MACs in the block
    /// kernel's loop.
    pub fn widened(
        model: &'m Model<'m>,
        kernels: Kernels,
        widened: &'m WidenedWeights<'m>,
        scratch_words: usize,
    ) -> Result<Self, InferError> {
        if widened.checksum != model.checksum() {
            return Err(InferError::PackedModel);
        }
        for (i, ww) in widened.layers.iter().enumerate() {
            if ww.len() != widened_len(model, i) {
                return Err(InferError::PackedModel);
            }
        }
        let mut plan = Self::build(model, kernels, None, scratch_words)?;
        // Set here, as `Plan::packed` sets its kernel: an image that never calls
        // `Plan::widened` then links no widened kernel.
        plan.widened = Some((widened, matmat_widened_i8));
        Ok(plan)
    }

    /// The plan without packed weights, after checking `packed` (if any) against the model.
    fn build(
        model: &'m Model<'m>,
        kernels: Kernels,
        packed: Option<&'m PackedWeights<'m>>,
        scratch_words: usize,
    ) -> Result<Self, InferError> {
        let needed = scratch_words_for_block(model, 1);
        if scratch_words < needed {
            return Err(InferError::Scratch {
                needed,
                got: scratch_words,
            });
        }
        // Every layer's arrays must be of the engine's types, and packed weights must fit
        // their layers: then running cannot meet anything else.
        for i in 0..model.layer_count() {
            let l = model.layer(i);
            let fits = match (model.dtype(), l.weights, l.bias) {
                (DType::F32, Weights::F32(_), Bias::F32(_)) => true,
                // i16: the first point layer, and 15-bit heads (blob version 3).
                (DType::I8, Weights::I16(_), Bias::I32(_)) => {
                    i < model.point_layer_count() || i >= model.head_x_index()
                }
                (DType::I8, Weights::I8(_), Bias::I32(_)) => true,
                _ => false,
            };
            if !fits {
                return Err(InferError::DType);
            }
        }
        if let Some(p) = packed {
            for (slot, i) in packed_slots(model) {
                let l = model.layer(i);
                let shape = (l.desc.out_dim as usize, l.desc.in_dim as usize);
                let fits = match (l.weights, p.layers[slot]) {
                    (Weights::I8(_), Some(PackedLayer::I8(w))) => (w.rows(), w.k()) == shape,
                    (Weights::I16(_), Some(PackedLayer::I16(w))) => (w.rows(), w.k()) == shape,
                    (Weights::F32(_), None) => true,
                    _ => false,
                };
                if !fits {
                    return Err(InferError::PackedModel);
                }
            }
        }
        let block = block_for(model, scratch_words);
        let (offs, acts_len) = layer_offsets(model);
        Ok(Self {
            model,
            kernels,
            packed: None,
            widened: None,
            block,
            scratch: scratch_words_for_block(model, block),
            acts_len,
            offs,
        })
    }

    /// The planned model.
    pub fn model(&self) -> &'m Model<'m> {
        self.model
    }

    /// The kernel table the plan runs with.
    pub fn kernels(&self) -> &Kernels {
        &self.kernels
    }

    /// Points per pass over the point layers' weights.
    pub fn block(&self) -> usize {
        self.block
    }

    /// Scratch words a run needs (for [`Plan::block`] points per pass).
    pub fn scratch_words(&self) -> usize {
        self.scratch
    }

    /// Whether the int8 point layers run over packed weights.
    pub fn is_packed(&self) -> bool {
        self.packed.is_some()
    }

    /// Whether the int8 point layers run over widened weights.
    pub fn is_widened(&self) -> bool {
        self.widened.is_some()
    }

    /// Length of the x output, `J × W`.
    pub fn out_x_len(&self) -> usize {
        self.model.joints() * self.model.width()
    }

    /// Length of the y output, `J × H`.
    pub fn out_y_len(&self) -> usize {
        self.model.joints() * self.model.height()
    }

    /// The checks of a run: buffer lengths only.
    pub(crate) fn check(
        &self,
        points: usize,
        scratch: usize,
        (x, y): (usize, usize),
    ) -> Result<(), InferError> {
        if points == 0 {
            return Err(InferError::NoPoints);
        }
        let (nx, ny) = (self.out_x_len(), self.out_y_len());
        if x != nx {
            return Err(InferError::Output {
                head: "x",
                needed: nx,
                got: x,
            });
        }
        if y != ny {
            return Err(InferError::Output {
                head: "y",
                needed: ny,
                got: y,
            });
        }
        if scratch < self.scratch {
            return Err(InferError::Scratch {
                needed: self.scratch,
                got: scratch,
            });
        }
        Ok(())
    }

    /// Runs an f32 plan on `points` (rows `[x, y, t_avg, p_acc, cnt]`), writing the x logits
    /// (`J × W`) and y logits (`J × H`). Every kernel table and every block size give the same
    /// bits (the f32 kernel sums in a fixed order). [`InferError::DType`] for an int8 plan.
    pub fn run_f32(
        &self,
        points: &[[f32; FEATURES]],
        scratch: &mut [f32],
        out_x: &mut [f32],
        out_y: &mut [f32],
    ) -> Result<(), InferError> {
        self.run_f32_observed(points, scratch, out_x, out_y, |_, _| {})
    }

    /// [`Plan::run_f32`], calling `observe` with every intermediate activation vector (per
    /// point for the point layers, in no particular order of points).
    pub fn run_f32_observed(
        &self,
        points: &[[f32; FEATURES]],
        scratch: &mut [f32],
        out_x: &mut [f32],
        out_y: &mut [f32],
        mut observe: impl FnMut(Stage, &[f32]),
    ) -> Result<(), InferError> {
        if self.model.dtype() != DType::F32 {
            return Err(InferError::DType);
        }
        self.check(points.len(), scratch.len(), (out_x.len(), out_y.len()))?;
        let (m, k, offs, acts_len) = (self.model, &self.kernels, &self.offs, self.acts_len);
        let pooled = m.pooled_width() as usize;
        let last = m.point_layer_count() - 1;
        let block = self.block;
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
                let l = m.layer(i);
                let (Weights::F32(w), Bias::F32(b)) = (l.weights, l.bias) else {
                    return Err(InferError::DType); // ruled out by the plan
                };
                let (k_in, out_dim) = (l.desc.in_dim as usize, l.desc.out_dim as usize);
                let tile = (F32_TILE_WEIGHTS / k_in.max(1)).max(1);
                for r0 in (0..out_dim).step_by(tile) {
                    let rows = r0..(r0 + tile).min(out_dim);
                    let (w, b) = (&w[rows.start * k_in..rows.end * k_in], &b[rows.clone()]);
                    if l.desc.sources != 1 {
                        // Earlier layers' outputs, before this layer's own in each row: the
                        // block's points at once, several sharing each weight load.
                        let at = PointRows {
                            stride: acts_len,
                            points: n,
                            x: source_range(l.desc.sources, offs),
                            out: offs[i] + rows.start,
                        };
                        // The plan's layout is one `dims` takes: every point computed.
                        debug_assert_eq!(at.dims(w.len(), b.len(), acts.len()).2, n);
                        k.matmat_f32(w, b, acts, &at);
                        continue;
                    }
                    for (input, act) in inputs
                        .chunks_exact(FEATURES)
                        .zip(acts.chunks_exact_mut(acts_len))
                        .take(n)
                    {
                        // The input features (five, too few to share a weight load).
                        k.matvec_f32(w, input, b, &mut act[offs[i]..][rows.clone()]);
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
        let (a, b) = fc.split_at_mut((2 * pooled).max(m.widest_fc()));
        a[..pooled].copy_from_slice(max);
        let n = points.len() as f32;
        for (dst, &s) in a[pooled..2 * pooled].iter_mut().zip(sum.iter()) {
            *dst = s / n;
        }
        observe(Stage::Pooled, &a[..2 * pooled]);
        let feats = fc_chain(m, (a, b), 2 * pooled, |i, l, x, out| {
            let (Weights::F32(w), Bias::F32(bias)) = (l.weights, l.bias) else {
                return Err(InferError::DType);
            };
            k.matvec_f32(w, x, bias, out);
            leaky_f32(out, l.desc.leaky);
            observe(Stage::Fc(i), out);
            Ok(())
        })?;
        heads(m, feats, out_x, out_y, |l, f, dst| {
            let (Weights::F32(w), Bias::F32(bias)) = (l.weights, l.bias) else {
                return Err(InferError::DType);
            };
            k.matvec_f32(w, f, bias, dst);
            Ok(())
        })
    }

    /// Runs an int8 plan on `points`, writing the heads' int32 accumulators (bias included):
    /// x (`J × W`) and y (`J × H`); their argmax is the argmax of the dequantized logits. Every
    /// kernel table, block size and weight layout gives the same integers (the kernels are
    /// bit-exact with the reference). [`InferError::DType`] for an f32 plan.
    pub fn run_i8(
        &self,
        points: &[[f32; FEATURES]],
        scratch: &mut [i32],
        out_x: &mut [i32],
        out_y: &mut [i32],
    ) -> Result<(), InferError> {
        if self.model.dtype() != DType::I8 {
            return Err(InferError::DType);
        }
        self.check(points.len(), scratch.len(), (out_x.len(), out_y.len()))?;
        let (m, k, offs, acts_len) = (self.model, &self.kernels, &self.offs, self.acts_len);
        let coding = InputCoding {
            shifts: m.input_shifts(),
        };
        let pooled = m.pooled_width() as usize;
        let last = m.point_layer_count() - 1;
        let block = self.block;
        // Checked splits, casts and slices (`split`, `get`): `check` ruled every failure out,
        // and an MCU image then has no panic path in the per-point loop.
        let (sum, rest) = split(scratch, pooled)?;
        let (acc, bytes) = split(rest, block * widest_layer(m))?;
        // Neither cast fails: i32 to bytes, and an even length from the start of the
        // 4-byte-aligned scratch to i16.
        let bytes: &mut [i8] =
            bytemuck::try_cast_slice_mut(bytes).map_err(|_| InferError::DType)?;
        let (input_bytes, bytes) = split(bytes, 16 * block)?;
        let inputs: &mut [i16] =
            bytemuck::try_cast_slice_mut(input_bytes).map_err(|_| InferError::DType)?;
        // The activation rows from a 64-byte boundary, where the lent scratch has the room
        // (`ALIGN_WORDS`); else where they fall.
        let rest = i8_activation_bytes(m, block);
        let pad = bytes.as_ptr().align_offset(64);
        let pad = if bytes.len() >= rest.saturating_add(pad) {
            pad
        } else {
            0
        };
        let (_, bytes) = split(bytes, pad)?;
        let (acts, bytes) = split(bytes, block * acts_len)?;
        let (gathered, fc) = split(bytes, block * widest_input(m))?;
        let (a, b) = split(fc, (2 * pooled).max(m.widest_fc()))?;
        let (max, _) = split(a, pooled)?;
        max.fill(i8::MIN);
        sum.fill(0);
        // Point `p`'s row of `len` values in a buffer of rows `stride` apart, from `from` on.
        // (Debug builds assert what `check` guarantees, so that tests still catch a sizing bug
        // that the release build's empty fallback would hide.)
        fn row<T>(buf: &[T], p: usize, stride: usize, from: usize, len: usize) -> &[T] {
            let at = p * stride + from;
            debug_assert!(at + len <= buf.len(), "row {p} outside its buffer");
            buf.get(at..at + len).unwrap_or_default()
        }
        fn row_mut<T>(buf: &mut [T], p: usize, stride: usize, from: usize, len: usize) -> &mut [T] {
            let at = p * stride + from;
            debug_assert!(at + len <= buf.len(), "row {p} outside its buffer");
            buf.get_mut(at..at + len).unwrap_or_default()
        }
        for chunk in points.chunks(block.max(1)) {
            let n = chunk.len();
            for (dst, p) in inputs.as_chunks_mut::<8>().0.iter_mut().zip(chunk) {
                let code = coding.code(p);
                dst[..FEATURES].copy_from_slice(&code);
            }
            // Whether the last layer went straight into the pooling (a pooled kernel).
            let mut pooled_last = false;
            for i in 0..=last {
                let l = m.layer(i);
                let Bias::I32(bias) = l.bias else {
                    return Err(InferError::DType); // ruled out by the plan
                };
                let requant = Requant {
                    scales: l.scales,
                    leaky: l.desc.leaky,
                };
                let (k_in, out_dim) = (l.desc.in_dim as usize, l.desc.out_dim as usize);
                let acc = acc.get_mut(..n * out_dim).unwrap_or_default();
                let packed = self
                    .packed
                    .and_then(|(p, run)| Some((p.layers.get(i).copied()??, run.layer)));
                // Indexed loops over the points, not zips of chunk iterators: those left an
                // outlined `Zip::new` with a division panic path in the M7 image.
                match (l.weights, packed) {
                    // The coded points (8 i16 apart) or the sources, a contiguous run of each
                    // point's activation row (read in place, rows `acts_len` apart).
                    (weights, Some((layer, run))) => {
                        // (The first layer's sources are the coded points, not activations.)
                        let src = match weights {
                            Weights::I8(_) => source_range(l.desc.sources, offs).start,
                            _ => 0,
                        };
                        let coded = inputs.get(..n * 8).unwrap_or_default();
                        let inputs = ((coded, 8), (acts.get(src..).unwrap_or_default(), acts_len));
                        let pool = (i == last).then_some((requant, &mut *max, &mut *sum));
                        pooled_last = run(k, layer, inputs, n, bias, acc, out_dim, pool);
                    }
                    (Weights::I16(w), None) => {
                        for (p, y) in acc.chunks_exact_mut(out_dim.max(1)).enumerate() {
                            k.matvec_i16(w, row(inputs, p, 8, 0, FEATURES), bias, y);
                        }
                    }
                    // One point (an MCU's block): read the sources in place, no copy.
                    (Weights::I8(w), None) if n == 1 => {
                        let x = acts.get(source_range(l.desc.sources, offs));
                        k.matvec_i8(w, x.unwrap_or_default(), bias, acc);
                    }
                    // Gather each point's sources into rows of K, then one pass over the
                    // weights for the whole block.
                    (Weights::I8(w), None) => {
                        let src = source_range(l.desc.sources, offs);
                        for (p, d) in gathered.chunks_exact_mut(k_in.max(1)).take(n).enumerate() {
                            let x = row(acts, p, acts_len, src.start, k_in);
                            debug_assert_eq!(d.len(), x.len());
                            if d.len() == x.len() {
                                d.copy_from_slice(x);
                            }
                        }
                        let x = gathered.get(..n * k_in).unwrap_or_default();
                        let widened = self
                            .widened
                            .and_then(|(ws, run)| Some((*ws.layers.get(i)?, run)));
                        match widened {
                            Some((ww, run)) if !ww.is_empty() => {
                                run(ww, w, k_in, x, bias, acc, out_dim);
                            }
                            _ => k.matmat_i8(w, k_in, x, bias, acc, out_dim),
                        }
                    }
                    (Weights::F32(_), None) => return Err(InferError::DType),
                }
                if pooled_last {
                    break;
                }
                let at = offset(offs, i);
                for (p, y) in acc.chunks_exact(out_dim.max(1)).enumerate() {
                    k.requantize(y, requant, row_mut(acts, p, acts_len, at, out_dim));
                }
            }
            if !pooled_last {
                let last_layer = offset(offs, last)..offset(offs, last + 1);
                for act in acts.chunks_exact(acts_len.max(1)).take(n) {
                    k.pool_i8(max, sum, act.get(last_layer.clone()).unwrap_or_default());
                }
            }
        }
        let n = points.len() as u32;
        for (dst, &s) in a.iter_mut().skip(pooled).zip(sum.iter()) {
            *dst = quant::average(s, n, m.avg_scale());
        }
        let feats = fc_chain(m, (a, b), 2 * pooled, |_, l, x, out| {
            let (Weights::I8(w), Bias::I32(bias)) = (l.weights, l.bias) else {
                return Err(InferError::DType);
            };
            let acc = acc.get_mut(..out.len()).unwrap_or_default();
            k.matvec_i8(w, x, bias, acc);
            let requant = Requant {
                scales: l.scales,
                leaky: l.desc.leaky,
            };
            k.requantize(acc, requant, out);
            Ok(())
        })?;
        if let Some((packed, run)) = self.packed {
            return (run.heads)(m, k, packed, run.layer, feats, out_x, out_y);
        }
        heads(m, feats, out_x, out_y, |l, f, dst| {
            let Bias::I32(bias) = l.bias else {
                return Err(InferError::DType);
            };
            match l.weights {
                Weights::I8(w) => k.matvec_i8(w, f, bias, dst),
                // 15-bit weights (blob version 3): the int8 features widened to i16 (the
                // parser bounds D by MAX_I16_HEAD_DIM, so the sums are exact in i32).
                Weights::I16(w) => {
                    // Word-aligned, so that the Cortex-M kernel can load it with `LDRD`.
                    #[repr(align(4))]
                    struct Wide([i16; quant::MAX_I16_HEAD_DIM]);
                    let mut wide = Wide([0; quant::MAX_I16_HEAD_DIM]);
                    let wide = &mut wide.0[..f.len().min(quant::MAX_I16_HEAD_DIM)];
                    for (d, &v) in wide.iter_mut().zip(f) {
                        *d = i16::from(v);
                    }
                    k.matvec_i16(w, wide, bias, dst);
                }
                Weights::F32(_) => return Err(InferError::DType),
            }
            Ok(())
        })
    }
}

/// int16 values of the 15-bit heads' widened features that [`packed_heads`] keeps on the stack
/// (4 KiB): `HEAD_WIDE / D` joints at a time (all 13 for `D ≤ 157`, at least 8 for the largest
/// `D`, [`quant::MAX_I16_HEAD_DIM`]).
const HEAD_WIDE: usize = 2048;

/// The two SimDR heads over packed weights ([`PackedWeights`]): the joints' features are the
/// rows of one block, so that each weight is loaded once for all joints, not once per joint.
/// int8 heads read the features in place; 15-bit heads widen [`HEAD_WIDE`] `/ D` joints' at a
/// time to int16.
#[allow(clippy::too_many_arguments)]
fn packed_heads(
    m: &Model<'_>,
    k: &Kernels,
    packed: &PackedWeights<'_>,
    run: PackedLayerFn,
    feats: &[i8],
    out_x: &mut [i32],
    out_y: &mut [i32],
) -> Result<(), InferError> {
    let (d, joints) = (m.head_dim(), m.joints());
    for (h, out) in [(0, out_x), (1, out_y)] {
        let l = m.layer(m.head_x_index() + h);
        let layer = packed.layers.get(MAX_POINT_LAYERS + h).copied().flatten();
        // Both ruled out by the plan (the engine's types; weights packed for this model).
        let (Bias::I32(bias), Some(layer)) = (l.bias, layer) else {
            return Err(InferError::DType);
        };
        let o = l.desc.out_dim as usize;
        match layer {
            PackedLayer::I8(_) => {
                run(k, layer, ((&[], 0), (feats, d)), joints, bias, out, o, None);
            }
            PackedLayer::I16(_) => {
                let mut wide = [0i16; HEAD_WIDE];
                let block = (HEAD_WIDE / d.max(1)).max(1);
                let mut j0 = 0;
                while j0 < joints {
                    let n = (joints - j0).min(block);
                    let (Some(f), Some(dst), Some(wide)) = (
                        feats.get(j0 * d..(j0 + n) * d),
                        out.get_mut(j0 * o..),
                        wide.get_mut(..n * d),
                    ) else {
                        break;
                    };
                    for (w, &v) in wide.iter_mut().zip(f) {
                        *w = i16::from(v);
                    }
                    run(k, layer, ((wide, d), (&[], 0)), n, bias, dst, o, None);
                    j0 += n;
                }
            }
        }
    }
    Ok(())
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
    // The ping-pong buffers hold the widest FC layer (the plan sized the scratch so): the
    // checked slicing never fails, and an MCU image has no panic path here.
    let short = |needed: usize, got: usize| InferError::Scratch { needed, got };
    let (mut cur, mut width) = ((a, b), width);
    for i in model.fc_range() {
        let l = model.layer(i);
        let out_dim = l.desc.out_dim as usize;
        let (x_len, y_len) = (cur.0.len(), cur.1.len());
        let x = cur.0.get(..width).ok_or(short(width, x_len))?;
        let y = cur.1.get_mut(..out_dim).ok_or(short(out_dim, y_len))?;
        layer(i - model.point_layer_count(), &l, x, y)?;
        width = out_dim;
        cur = (cur.1, cur.0);
    }
    let got = cur.0.len();
    cur.0.get(..width).ok_or(short(width, got))
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
        let (o, d) = (l.desc.out_dim as usize, model.head_dim());
        // Indexed, as in `run_i8`: no chunk iterators, no panic path on an MCU.
        for j in 0..model.joints() {
            let (Some(f), Some(dst)) = (
                feats.get(j * d..(j + 1) * d),
                out.get_mut(j * o..(j + 1) * o),
            ) else {
                break;
            };
            head(&l, f, dst)?;
        }
    }
    Ok(())
}

fn leaky_f32(v: &mut [f32], alpha: Option<f32>) {
    if let Some(a) = alpha {
        for x in v {
            // A select with an unconditional store, so that the loop vectorizes (a store only
            // where `x < 0` compiled to a test and a branch per element).
            *x = if *x < 0.0 { *x * a } else { *x };
        }
    }
}

/// Alignment of the packed weights (a cache line), part of [`packed_bytes`].
const PACK_ALIGN: usize = 64;

/// Slots of a [`PackedLayout`]: the point layers, then the two SimDR heads.
const PACKED_SLOTS: usize = MAX_POINT_LAYERS + 2;

/// The layers [`pack_layers`] packs, as `(slot, layer index)`: every point layer (slot `i`
/// for layer `i`) and the two heads (slots `MAX_POINT_LAYERS` and `MAX_POINT_LAYERS + 1`).
fn packed_slots(model: &Model<'_>) -> impl Iterator<Item = (usize, usize)> {
    let heads = model.head_x_index();
    (0..model.point_layer_count())
        .map(|i| (i, i))
        .chain([(MAX_POINT_LAYERS, heads), (MAX_POINT_LAYERS + 1, heads + 1)])
}

/// Bytes of buffer [`pack_layers`] needs for `model`'s int8 and int16 point layers and heads
/// (the packed weights plus up to 63 bytes to align them to a cache line). 0 for an f32 model.
pub fn packed_bytes(model: &Model<'_>) -> usize {
    let packed: usize = packed_slots(model)
        .map(|(_, i)| {
            let l = model.layer(i);
            let (rows, k) = (l.desc.out_dim as usize, l.desc.in_dim as usize);
            match l.weights {
                Weights::I8(_) => packed_len_of::<i8>(rows, k),
                Weights::I16(_) => packed_len_of::<i16>(rows, k),
                Weights::F32(_) => Some(0),
            }
            .unwrap_or(usize::MAX)
        })
        .fold(0usize, usize::saturating_add);
    if packed == 0 {
        0
    } else {
        packed.saturating_add(PACK_ALIGN - 1)
    }
}

/// Where [`pack_layers`] put each int8 and int16 point layer's and SimDR head's packed weights
/// (see [`crate::kernels::packed`]) in the caller's buffer. Small and `Copy`: keep it next to the
/// buffer, and get the weights back for [`Plan::packed`] with [`PackedLayout::weights`].
///
/// Packing is for CPUs with native packed kernels ([`Kernels::has_packed`]: x86 AVX-512
/// VNNI, AVX-VNNI, AVX-512BW and AVX2). It doubles the point layers' and heads' weight memory,
/// so an MCU runs the blob's row-major weights in place with [`Plan::run_i8`] instead.
#[derive(Clone, Copy, Debug)]
pub struct PackedLayout {
    /// `(start, len)` of each packed layer's weights in the buffer (len 0: not packed), by
    /// slot ([`packed_slots`]).
    layers: [(usize, usize); PACKED_SLOTS],
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
        let mut layers = [None; PACKED_SLOTS];
        for (slot, i) in packed_slots(model) {
            let (start, len) = self.layers[slot];
            if len > 0 {
                let l = model.layer(i);
                let bytes = buf
                    .get(start..start.saturating_add(len))
                    .ok_or(InferError::PackedBuffer)?;
                let (rows, k) = (l.desc.out_dim as usize, l.desc.in_dim as usize);
                layers[slot] = Some(
                    match l.weights {
                        Weights::I8(_) => {
                            PackedI8::from_packed(bytes, rows, k).map(PackedLayer::I8)
                        }
                        Weights::I16(_) => {
                            PackedI16::from_packed(bytes, rows, k).map(PackedLayer::I16)
                        }
                        Weights::F32(_) => None,
                    }
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

/// A model's packed point-layer and head weights, ready for [`Plan::packed`] (from
/// [`PackedLayout::weights`]).
#[derive(Clone, Copy, Debug)]
pub struct PackedWeights<'b> {
    /// By slot ([`packed_slots`]).
    layers: [Option<PackedLayer<'b>>; PACKED_SLOTS],
    checksum: u32,
}

/// One packed layer: int16 (the first point layer, 15-bit heads) or int8.
#[derive(Clone, Copy, Debug)]
enum PackedLayer<'b> {
    I8(PackedI8<'b>),
    I16(PackedI16<'b>),
}

/// What runs packed weights, behind function pointers that only [`Plan::packed`] sets.
#[derive(Clone, Copy, Debug)]
struct PackedFns {
    /// [`run_packed_layer`].
    layer: PackedLayerFn,
    /// [`packed_heads`].
    heads: PackedHeadsFn,
}

/// [`packed_heads`]'s type.
type PackedHeadsFn = fn(
    &Model<'_>,
    &Kernels,
    &PackedWeights<'_>,
    PackedLayerFn,
    &[i8],
    &mut [i32],
    &mut [i32],
) -> Result<(), InferError>;

/// [`run_packed_layer`]'s type.
type PackedLayerFn = fn(
    &Kernels,
    PackedLayer<'_>,
    PackedInputs<'_>,
    usize,
    &[i32],
    &mut [i32],
    usize,
    Option<PoolInto<'_>>,
) -> bool;

/// A packed layer's inputs, each with its row stride: int16 rows for an int16 layer, int8
/// rows for an int8 one (the other is not read).
type PackedInputs<'a> = ((&'a [i16], usize), (&'a [i8], usize));

/// The last point layer's pooling: its requantization and the running max and sum.
type PoolInto<'a> = (Requant<'a>, &'a mut [i8], &'a mut [i32]);

/// One packed layer for `n` points (rows): an int16 layer over the int16 rows `wide` (the
/// coded points, 8 apart; the widened features of a 15-bit head), an int8 layer over the int8
/// rows `acts` (activation rows from the layer's sources on; a head's features); outputs
/// `out_dim` apart in `acc`. With `pool` (the last point layer), where the kernels have a
/// pooled kernel for the layer ([`Kernels::packed_pool_i8`]), the outputs go into the pooling
/// instead, `acc` untouched: returns whether they did.
#[allow(clippy::too_many_arguments)]
fn run_packed_layer(
    k: &Kernels,
    layer: PackedLayer<'_>,
    ((wide, wide_stride), (acts, acts_len)): PackedInputs<'_>,
    n: usize,
    bias: &[i32],
    acc: &mut [i32],
    out_dim: usize,
    pool: Option<PoolInto<'_>>,
) -> bool {
    if let (PackedLayer::I8(w), Some((requant, max, sum))) = (layer, pool) {
        if let Some(pooled) = k.packed_pool_i8(&w) {
            pooled(&w, acts, acts_len, n, bias, requant, max, sum);
            return true;
        }
    }
    match layer {
        PackedLayer::I16(w) => k.matmat_packed_i16(&w, wide, wide_stride, n, bias, acc, out_dim),
        PackedLayer::I8(w) => k.matmat_packed_i8(&w, acts, acts_len, n, bias, acc, out_dim),
    }
    false
}

/// Packs `model`'s point layers (int8, and the int16 first layer) and its two SimDR heads
/// (int8, or 15-bit in int16) into `buf` (at least [`packed_bytes`] long) and says where they
/// are; keep `buf` where it is (a `Vec`'s heap buffer stays put when the `Vec` moves) and use
/// [`PackedLayout::weights`] to run. The weights start at a cache-line boundary of `buf`.
///
/// The heads are shared by every joint: packed, they run as one block of the joints' features
/// (as the point layers run a block of points) instead of one matrix-vector product per joint.
pub fn pack_layers(model: &Model<'_>, buf: &mut [u8]) -> Result<PackedLayout, InferError> {
    let (needed, got) = (packed_bytes(model), buf.len());
    if got < needed {
        return Err(InferError::PackBuffer { needed, got });
    }
    let mut at = buf.as_ptr().align_offset(PACK_ALIGN).min(PACK_ALIGN - 1);
    let mut layers = [(0, 0); PACKED_SLOTS];
    for (slot, i) in packed_slots(model) {
        let l = model.layer(i);
        let (rows, k) = (l.desc.out_dim as usize, l.desc.in_dim as usize);
        let rest = buf.get_mut(at..).unwrap_or_default();
        let len = match l.weights {
            Weights::I8(w) => pack_len(w, rows, k, rest),
            Weights::I16(w) => pack_len(w, rows, k, rest),
            Weights::F32(_) => Some(0),
        }
        .ok_or(InferError::PackBuffer { needed, got })?;
        layers[slot] = (at, len);
        at += len;
    }
    Ok(PackedLayout {
        layers,
        checksum: model.checksum(),
        buffer: (buf.as_ptr() as usize, got),
    })
}

/// Packs `w` into the front of `buf`; the packed length.
fn pack_len<T: Lane>(w: &[T], rows: usize, k: usize, buf: &mut [u8]) -> Option<usize> {
    Packed::pack(w, rows, k, buf).map(|(p, _)| p.byte_len())
}

/// Widened words of point layer `i` ([`widen_point_layers`]): its rows ×
/// [`widened_row_words`] for an int8 layer, 0 for any other (the int16 first layer).
fn widened_len(model: &Model<'_>, i: usize) -> usize {
    if i >= model.point_layer_count() {
        return 0;
    }
    let l = model.layer(i);
    match l.weights {
        Weights::I8(_) => {
            (l.desc.out_dim as usize).saturating_mul(widened_row_words(l.desc.in_dim as usize))
        }
        _ => 0,
    }
}

/// 32-bit words of buffer [`widen_point_layers`] needs for `model`'s int8 point layers: two per
/// four weights (twice their bytes). 0 for an f32 model.
pub fn widened_words(model: &Model<'_>) -> usize {
    (0..MAX_POINT_LAYERS)
        .map(|i| widened_len(model, i))
        .fold(0usize, usize::saturating_add)
}

/// A model's int8 point layers widened for the Cortex-M DSP block kernel, ready for
/// [`Plan::widened`] (from [`widen_point_layers`]). Small and `Copy`: it borrows the buffer.
#[derive(Clone, Copy, Debug)]
pub struct WidenedWeights<'b> {
    /// Each point layer's words (empty: not widened).
    layers: [&'b [u32]; MAX_POINT_LAYERS],
    /// The model's blob checksum, to refuse the weights of another model.
    checksum: u32,
}

/// Widens `model`'s int8 point layers into `buf` (at least [`widened_words`] long) with
/// [`widen_i8`]: once, at start-up, what the DSP block kernel would otherwise do to every
/// weight word for every block of points.
///
/// ```
/// # fn demo(blob: &[u8]) -> Result<(), evpose_core::InferError> {
/// use evpose_core::{kernels::Kernels, scratch_words, widen_point_layers, widened_words};
/// use evpose_core::{Model, Plan};
/// let model = Model::parse(blob).expect("a model");
/// let mut buf = vec![0u32; widened_words(&model)]; // a `static` on an MCU
/// let widened = widen_point_layers(&model, &mut buf)?;
/// let plan = Plan::widened(&model, Kernels::best(), &widened, scratch_words(&model))?;
/// # Ok(()) }
/// ```
pub fn widen_point_layers<'b>(
    model: &Model<'_>,
    buf: &'b mut [u32],
) -> Result<WidenedWeights<'b>, InferError> {
    let (needed, got) = (widened_words(model), buf.len());
    if got < needed {
        return Err(InferError::WidenBuffer { needed, got });
    }
    let mut layers: [&'b [u32]; MAX_POINT_LAYERS] = [&[]; MAX_POINT_LAYERS];
    let mut rest = buf;
    let short = InferError::WidenBuffer { needed, got };
    for (i, slot) in layers
        .iter_mut()
        .enumerate()
        .take(model.point_layer_count())
    {
        let l = model.layer(i);
        let Weights::I8(w) = l.weights else {
            continue;
        };
        let (mine, tail) = core::mem::take(&mut rest)
            .split_at_mut_checked(widened_len(model, i))
            .ok_or(short)?;
        let (rows, k) = (l.desc.out_dim as usize, l.desc.in_dim as usize);
        widen_i8(w, rows, k, mine).ok_or(short)?;
        *slot = mine;
        rest = tail;
    }
    Ok(WidenedWeights {
        layers,
        checksum: model.checksum(),
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
