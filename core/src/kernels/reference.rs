//! Portable scalar kernels: the definition every optimized kernel is checked against.

/// `out[o] = bias[o] + Σ_k w[o·K + k] · x[k]` in i32, `K = x.len()`, for int8 operands.
/// |product| ≤ 2^14, so the sum alone cannot overflow for K below 2^17; the additions wrap (as
/// every SIMD and DSP kernel's do, in any order: the result is the same modulo 2^32), so that
/// a blob's bias near `i32::MAX` gives defined integers, never a panic. The quantizer keeps its
/// biases far enough from the limits that nothing wraps. `K = 0` gives `out = bias` (the
/// [`super::rows`] rule).
pub fn matvec_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    if k == 0 {
        return bias_only(bias, out);
    }
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row.iter().zip(x).fold(b, |acc, (&w, &x)| {
            acc.wrapping_add(i32::from(w) * i32::from(x))
        });
    }
}

/// `out[o] = bias[o]` for the rows of a `K = 0` product (`min(out, bias)`, [`super::rows`]).
fn bias_only(bias: &[i32], out: &mut [i32]) {
    for (o, &b) in out.iter_mut().zip(bias) {
        *o = b;
    }
}

/// [`matvec_i8`] for each of several points: the specification of
/// [`super::MatmatI8`]. With `(P, O) =` [`super::matmat_dims`], point `p` (`x[p·K..][..K]`,
/// `K = k`) goes to `out[p·out_stride..][..O]`; `K = 0` gives `bias`. Nothing else in `out` is
/// written.
pub fn matmat_i8(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &mut [i32], out_stride: usize) {
    matmat_by_rows(matvec_i8, w, k, x, bias, out, out_stride);
}

/// [`matmat_i8`] with any matvec kernel called once per point: the shape rules of
/// [`super::MatmatI8`] in one place, for the kernel sets that have no blocked kernel.
#[inline(always)]
pub fn matmat_by_rows(
    matvec: impl Fn(&[i8], &[i8], &[i32], &mut [i32]),
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    let (points, rows) = super::matmat_dims(k, w.len(), x.len(), bias.len(), out.len(), out_stride);
    // `points ≥ 1` implies `out_stride ≥ 1`; `NonZero` tells the compiler so.
    let (true, Some(stride)) = (points > 0, core::num::NonZeroUsize::new(out_stride)) else {
        return;
    };
    // Slices cut with `get` (every one is in range by `matmat_dims`): no panic path in a
    // firmware image.
    let bias = bias.get(..rows).unwrap_or_default();
    for (p, y) in out.chunks_mut(stride.get()).take(points).enumerate() {
        let Some(y) = y.get_mut(..rows) else {
            return;
        };
        if k == 0 {
            for (y, &b) in y.iter_mut().zip(bias) {
                *y = b;
            }
        } else if let Some(x) = x.get(p * k..(p + 1) * k) {
            matvec(w, x, bias, y);
        }
    }
}

/// The same for int16 operands: the first layer (the quantizer's |w| ≤ 1023 and |x| ≤ 2047
/// keep every sum below 2^24) and 15-bit heads (bounded by the parser). The sums
/// wrap, as in [`matvec_i8`]: a blob's first layer may hold any i16 weights. `K = 0` gives
/// `out = bias`.
pub fn matvec_i16(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    if k == 0 {
        return bias_only(bias, out);
    }
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row.iter().zip(x).fold(b, |acc, (&w, &x)| {
            acc.wrapping_add(i32::from(w) * i32::from(x))
        });
    }
}

/// Partial sums of the f32 dot product: independent chains, so that the compiler can keep them
/// in vector registers (one running sum is a dependency chain it may not reorder).
const F32_LANES: usize = 16;

/// Adds the partial sums in a fixed order: halves lane by lane, down to one.
#[inline(always)]
fn sum_lanes(mut acc: [f32; F32_LANES]) -> f32 {
    let mut n = F32_LANES;
    while n > 1 {
        n /= 2;
        let (lo, hi) = acc.split_at_mut(n);
        for (a, &b) in lo.iter_mut().zip(&*hi) {
            *a += b;
        }
    }
    acc[0]
}

/// Rows of the f32 kernel computed together: independent chains of partial sums for the
/// CPU to overlap, each row summed exactly as alone.
const F32_ROWS: usize = 4;

/// Adds 16 products to their partial sums, product `j` to sum `j`.
#[inline(always)]
fn accumulate(acc: &mut [f32; F32_LANES], w: &[f32; F32_LANES], x: &[f32; F32_LANES]) {
    for ((a, &w), &x) in acc.iter_mut().zip(w).zip(x) {
        *a += w * x;
    }
}

/// One row's result from its partial sums, the dot product of the last `K mod 16` elements in
/// index order, and the bias.
#[inline(always)]
fn finish_row(acc: [f32; F32_LANES], w_tail: &[f32], x_tail: &[f32], b: f32) -> f32 {
    finish_lanes(sum_lanes(acc), tail_dot(w_tail, x_tail), b)
}

/// f32 version: `out[o] = Σ_j w[o·K + j] · x[j] + bias[o]` for the rows the three slices share
/// (`K = x.len()`; `K = 0` gives `out[o] = bias[o]`).
///
/// Element `j` of a row goes to partial sum `j mod 16` (the last `K mod 16` to a seventeenth,
/// in index order); the partial sums are added in a fixed order (`sum_lanes`), then the bias.
/// The order does not depend on the CPU, on the registers the loop is compiled for (Rust
/// never contracts `a + w · x` into a fused multiply-add) or on which rows are computed
/// together, so every kernel table gives the same bits. It is not index order: results differ
/// from a sequential sum by rounding, within the float paths' stated tolerance.
#[inline(always)]
pub fn matvec_f32(w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]) {
    let k = x.len();
    let n = super::rows(k, w.len(), bias.len(), out.len());
    let (out, bias) = (&mut out[..n], &bias[..n]);
    if k == 0 {
        out.copy_from_slice(bias);
        return;
    }
    let (x_lanes, x_tail) = x.as_chunks::<F32_LANES>();
    let (out_groups, out_rest) = out.as_chunks_mut::<F32_ROWS>();
    let (bias_groups, bias_rest) = bias.as_chunks::<F32_ROWS>();
    let (w_groups, w_rest) = w[..n * k].split_at(out_groups.len() * F32_ROWS * k);
    for ((o, b), w) in out_groups
        .iter_mut()
        .zip(bias_groups)
        .zip(w_groups.chunks_exact(F32_ROWS * k))
    {
        let row = |r: usize| w[r * k..(r + 1) * k].as_chunks::<F32_LANES>();
        let ((w0, t0), (w1, t1), (w2, t2), (w3, t3)) = (row(0), row(1), row(2), row(3));
        let mut acc = [[0.0f32; F32_LANES]; F32_ROWS];
        for ((((xv, w0), w1), w2), w3) in x_lanes.iter().zip(w0).zip(w1).zip(w2).zip(w3) {
            for (acc, wv) in acc.iter_mut().zip([w0, w1, w2, w3]) {
                accumulate(acc, wv, xv);
            }
        }
        for (((o, acc), t), &b) in o.iter_mut().zip(acc).zip([t0, t1, t2, t3]).zip(b) {
            *o = finish_row(acc, t, x_tail, b);
        }
    }
    for ((o, row), &b) in out_rest
        .iter_mut()
        .zip(w_rest.chunks_exact(k))
        .zip(bias_rest)
    {
        let (w_lanes, w_tail) = row.as_chunks::<F32_LANES>();
        let mut acc = [0.0f32; F32_LANES];
        for (wv, xv) in w_lanes.iter().zip(x_lanes) {
            accumulate(&mut acc, wv, xv);
        }
        *o = finish_row(acc, w_tail, x_tail, b);
    }
}

/// The rows of a block of points that [`matmat_f32`] reads and writes: point `p`'s row is
/// `rows[p·stride..]`, up to `stride` values (the last row may end after its outputs), its
/// inputs `x` (a range of the row) and its outputs the `O` values from `out` (`O` the rows of
/// the weights and bias). The f32 engine's layout: each point's activations in one row, a
/// layer reading earlier layers' outputs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PointRows {
    /// Distance between two points' rows, in values.
    pub stride: usize,
    /// Points in the block.
    pub points: usize,
    /// Where in a row the inputs are.
    pub x: core::ops::Range<usize>,
    /// Where in a row the outputs go (after the inputs).
    pub out: usize,
}

impl PointRows {
    /// `(K, O, P)`: the inputs per point, the outputs [`matmat_f32`] writes per point (`O =
    /// min(bias.len(), w_len / K)`, `bias.len()` for `K = 0`) and the points it computes
    /// (those whose row holds the outputs); all 0 unless the input range is a range (start
    /// ≤ end), the inputs end before the outputs start and the outputs end within the stride.
    pub fn dims(&self, w_len: usize, bias_len: usize, rows_len: usize) -> (usize, usize, usize) {
        let Some(k) = self.x.end.checked_sub(self.x.start) else {
            return (0, 0, 0);
        };
        let o = w_len.checked_div(k).map_or(bias_len, |r| r.min(bias_len));
        match self.out.checked_add(o) {
            Some(end) if self.x.end <= self.out && end <= self.stride && o > 0 => {
                let fit = rows_len
                    .checked_sub(end)
                    .map_or(0, |rest| rest / self.stride + 1);
                (k, o, self.points.min(fit))
            }
            _ => (0, 0, 0),
        }
    }
}

/// [`matvec_f32`] for each point of a block ([`PointRows`]): point `p`'s inputs through the
/// weights into its outputs, for the `(K, O, P)` of [`PointRows::dims`]; nothing else is
/// written. The specification of the blocked kernels ([`super::Kernels::matmat_f32`]), which
/// give the same bits: every row and point is summed exactly as here.
pub fn matmat_f32(w: &[f32], bias: &[f32], rows: &mut [f32], at: &PointRows) {
    matmat_f32_by(matvec_f32, w, bias, rows, at)
}

/// [`matmat_f32`] with another [`matvec_f32`] (a kernel table's, bit-exact with it).
#[inline(always)]
pub(crate) fn matmat_f32_by(
    matvec: impl Fn(&[f32], &[f32], &[f32], &mut [f32]),
    w: &[f32],
    bias: &[f32],
    rows: &mut [f32],
    at: &PointRows,
) {
    let (k, o, points) = at.dims(w.len(), bias.len(), rows.len());
    if o == 0 {
        return;
    }
    for row in rows.chunks_mut(at.stride).take(points) {
        let (before, after) = row.split_at_mut(at.out);
        matvec(
            &w[..o * k],
            &before[at.x.clone()],
            &bias[..o],
            &mut after[..o],
        );
    }
}

/// The dot product of a row's last `K mod 16` elements, in index order from 0.0 (0.0 when
/// there are none), as [`matvec_f32`] computes it.
#[inline(always)]
pub(crate) fn tail_dot(w_tail: &[f32], x_tail: &[f32]) -> f32 {
    w_tail
        .iter()
        .zip(x_tail)
        .fold(0.0, |acc, (&w, &x)| acc + w * x)
}

/// One row's result as [`matvec_f32`] finishes it, from the sum of its 16 partial sums
/// (`sum_lanes`, which a kernel computes itself) and its [`tail_dot`]: the tail, then the
/// bias.
#[inline(always)]
pub(crate) fn finish_lanes(sum: f32, tail: f32, b: f32) -> f32 {
    sum + tail + b
}

/// Requantizes a row of int32 accumulators to int8 with [`crate::quant::requantize`]:
/// `out[i] = requantize(acc[i], scales[i], leaky)` for every `i` the three slices share.
///
/// Written as two loops without a per-element branch on the option, so that each vectorizes;
/// the x86 tables compile this same code for wider registers (IEEE arithmetic is the same in
/// every lane, so the integers are too).
#[inline(always)]
pub fn requantize_i8(acc: &[i32], scales: &[f32], leaky: Option<f32>, out: &mut [i8]) {
    use crate::quant::requantize;
    match leaky {
        Some(alpha) => {
            for ((o, &a), &s) in out.iter_mut().zip(acc).zip(scales) {
                *o = requantize(a, s, Some(alpha));
            }
        }
        None => {
            for ((o, &a), &s) in out.iter_mut().zip(acc).zip(scales) {
                *o = requantize(a, s, None);
            }
        }
    }
}

/// One point's contribution to max and sum pooling: `max[i] = max(max[i], y[i])`,
/// `sum[i] += y[i]` (wrapping) for every `i` the three slices share.
#[inline(always)]
pub fn pool_i8(max: &mut [i8], sum: &mut [i32], y: &[i8]) {
    for ((m, s), &v) in max.iter_mut().zip(sum.iter_mut()).zip(y) {
        *m = (*m).max(v);
        *s = s.wrapping_add(i32::from(v));
    }
}
