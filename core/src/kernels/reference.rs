//! Portable scalar kernels: the definition every optimized kernel is checked against.

/// `out[o] = bias[o] + Σ_k w[o·K + k] · x[k]` in i32, `K = x.len()`, for int8 operands.
/// Exact: |product| ≤ 2^14, so any K below 2^17 cannot overflow.
pub fn matvec_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row
            .iter()
            .zip(x)
            .fold(b, |acc, (&w, &x)| acc + i32::from(w) * i32::from(x));
    }
}

/// [`matvec_i8`] for each of several points: the specification of
/// [`super::MatmatI8`]. With `(P, O) =` [`super::matmat_dims`], point `p` (`x[p·K..][..K]`,
/// `K = k`) goes to `out[p·out_stride..][..O]`; `K = 0` gives `bias` (where [`matvec_i8`] would
/// panic). Nothing else in `out` is written.
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
    for p in 0..points {
        let y = &mut out[p * out_stride..][..rows];
        if k == 0 {
            y.copy_from_slice(&bias[..rows]);
        } else {
            matvec(w, &x[p * k..][..k], bias, y);
        }
    }
}

/// The same for the i16 first layer (|w| ≤ 1023, |x| ≤ 2047 keep every sum below 2^24).
pub fn matvec_i16(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row
            .iter()
            .zip(x)
            .fold(b, |acc, (&w, &x)| acc + i32::from(w) * i32::from(x));
    }
}

/// f32 version: the dot product summed in index order, then the bias added.
pub fn matvec_f32(w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]) {
    let k = x.len();
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row.iter().zip(x).fold(0.0, |acc, (&w, &x)| acc + w * x) + b;
    }
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
