//! Every kernel this CPU runs against [`reference`], bit for bit (`assert_eq!`, no tolerance).
//!
//! Kernels whose instructions the CPU lacks are skipped and named (`--nocapture` shows them).

use evpose_core::kernels::{self, packed, reference, Isa, Kernels, PackedI16, PackedI8};
use proptest::prelude::*;

/// `n` property cases, or 2 under Miri (`scripts/miri.sh`), which interprets about a thousand
/// times slower.
fn cases(n: u32) -> ProptestConfig {
    ProptestConfig::with_cases(if cfg!(miri) { 2 } else { n })
}

/// The kernels to test: every one this CPU runs except the reference itself.
fn candidates() -> Vec<Kernels> {
    Isa::ALL
        .iter()
        .filter(|&&isa| isa != Isa::Reference)
        .filter_map(|isa| isa.kernels())
        .collect()
}

/// The reference table (the raw reference plus `K = 0` handling), checked like the others.
fn with_reference_table() -> Vec<Kernels> {
    let mut v = candidates();
    v.push(Kernels::reference());
    v
}

#[test]
fn report_tested_kernels() {
    let (here, absent): (Vec<Isa>, Vec<Isa>) =
        Isa::ALL.iter().partition(|isa| isa.is_supported_here());
    let names = |v: &[Isa]| v.iter().map(|i| i.name()).collect::<Vec<_>>().join(", ");
    eprintln!("kernels tested: {}", names(&here));
    eprintln!("kernels skipped (not on this CPU): {}", names(&absent));
    eprintln!(
        "best: compile time {}, run time {}",
        Kernels::best().name(),
        Kernels::detect().name()
    );
    assert!(here.contains(&Isa::Reference));
    assert!(Kernels::best().isa().is_supported_here());
    assert!(Kernels::detect().isa().is_supported_here());
}

/// `Σ w·x + bias` per row in i64, over the rows the reference visits: the exact value.
fn exact<T: Copy + Into<i64>>(w: &[T], x: &[T], bias: &[i32], out_len: usize) -> Vec<i64> {
    let k = x.len();
    (0..kernels::rows(k, w.len(), bias.len(), out_len))
        .map(|o| {
            let row = &w[o * k..(o + 1) * k];
            let dot: i64 = row.iter().zip(x).map(|(&a, &b)| a.into() * b.into()).sum();
            i64::from(bias[o]) + dot
        })
        .collect()
}

/// Whether the reference's left-to-right i32 fold (from the bias) never overflows.
fn reference_cannot_overflow<T: Copy + Into<i64>>(
    w: &[T],
    x: &[T],
    bias: &[i32],
    n: usize,
) -> bool {
    let k = x.len();
    (0..kernels::rows(k, w.len(), bias.len(), n)).all(|o| {
        let mut acc = i64::from(bias[o]);
        w[o * k..(o + 1) * k].iter().zip(x).all(|(&a, &b)| {
            acc += a.into() * b.into();
            i32::try_from(acc).is_ok()
        })
    })
}

/// Runs `f` on a copy of `out` and returns it (the untouched rows must stay as they were).
fn run<T>(
    f: impl Fn(&[T], &[T], &[i32], &mut [i32]),
    w: &[T],
    x: &[T],
    b: &[i32],
    out: &[i32],
) -> Vec<i32> {
    let mut o = out.to_vec();
    f(w, x, b, &mut o);
    o
}

/// The reference's answer; `K = 0` (where `chunks_exact(0)` panics) is defined as `out = bias`.
fn expected_i8(w: &[i8], x: &[i8], bias: &[i32], out: &[i32]) -> Vec<i32> {
    if x.is_empty() {
        let mut o = out.to_vec();
        let n = o.len().min(bias.len());
        o[..n].copy_from_slice(&bias[..n]);
        return o;
    }
    run(reference::matvec_i8, w, x, bias, out)
}

/// The exact sums modulo 2^32 in a copy of `out` (rows the reference does not visit keep
/// their values): what every kernel, the reference included, must give, since all of them
/// wrap.
fn wrapped<T: Copy + Into<i64>>(w: &[T], x: &[T], bias: &[i32], out: &[i32]) -> Vec<i32> {
    let mut want = out.to_vec();
    for (o, e) in want.iter_mut().zip(exact(w, x, bias, out.len())) {
        *o = e as i32; // the residue modulo 2^32
    }
    want
}

/// Checks every kernel against the reference and the exact sums modulo 2^32 on one case, with
/// a sentinel-filled `out`.
fn check_i8(w: &[i8], x: &[i8], bias: &[i32], out_len: usize) {
    let out = vec![0x5A5A_5A5A; out_len];
    let want = expected_i8(w, x, bias, &out);
    assert_eq!(want, wrapped(w, x, bias, &out), "reference");
    for k in with_reference_table() {
        let got = run(|w, x, b, o| k.matvec_i8(w, x, b, o), w, x, bias, &out);
        assert_eq!(got, want, "{} (K = {}, out = {out_len})", k.name(), x.len());
    }
    assert_eq!(
        run(kernels::matvec_i8, w, x, bias, &out),
        want,
        "kernels::matvec_i8"
    );
    // The Cortex-M DSP kernel, on emulated SXTB16/SMLAD here (the real ones run under QEMU).
    assert_eq!(
        run(kernels::arm::matvec_i8, w, x, bias, &out),
        want,
        "arm::matvec_i8 (emulated)"
    );
}

/// Checks every kernel against the exact sums modulo 2^32 (the reference's wrapping sums).
fn check_i16(w: &[i16], x: &[i16], bias: &[i32], out_len: usize) {
    let out = vec![0x5A5A_5A5A; out_len];
    let want = wrapped(w, x, bias, &out);
    if !x.is_empty() {
        assert_eq!(
            run(reference::matvec_i16, w, x, bias, &out),
            want,
            "reference"
        );
    }
    for k in with_reference_table() {
        let got = run(|w, x, b, o| k.matvec_i16(w, x, b, o), w, x, bias, &out);
        assert_eq!(got, want, "{} (K = {}, out = {out_len})", k.name(), x.len());
    }
    // The Cortex-M DSP kernel, on emulated SMLAD here (the real one runs under QEMU).
    assert_eq!(
        run(kernels::arm::matvec_i16, w, x, bias, &out),
        want,
        "arm::matvec_i16 (emulated, K = {}, out = {out_len})",
        x.len()
    );
    assert_eq!(
        run(kernels::matvec_i16, w, x, bias, &out),
        want,
        "kernels::matvec_i16"
    );
}

/// An int8 value, with the extremes over-represented.
fn any_i8() -> impl Strategy<Value = i8> + Clone {
    prop_oneof![6 => any::<i8>(), 1 => Just(i8::MIN), 1 => Just(i8::MAX), 1 => Just(0)]
}

/// An i16 value over the whole range, extremes over-represented.
fn any_i16() -> impl Strategy<Value = i16> + Clone {
    prop_oneof![6 => any::<i16>(), 1 => Just(i16::MIN), 1 => Just(i16::MAX), 1 => Just(0)]
}

/// A bias, mostly within ±2^30, sometimes at or near the i32 limits, where the sums wrap.
fn any_bias() -> impl Strategy<Value = i32> + Clone {
    prop_oneof![
        8 => -(1i32 << 30)..(1 << 30),
        1 => Just(i32::MAX),
        1 => Just(i32::MIN),
        1 => (i32::MAX - (1 << 22))..=i32::MAX,
        1 => i32::MIN..=(i32::MIN + (1 << 22)),
    ]
}

/// `(w, x, bias, out_len)` with `w.len() = out·K + dw`, `bias.len() = out + db`, `dw`/`db` in
/// `-3..=3` (clamped at 0), so lengths that disagree are covered too.
fn shape<T: std::fmt::Debug + Clone>(
    val: impl Strategy<Value = T> + Clone,
    k: std::ops::Range<usize>,
) -> impl Strategy<Value = (Vec<T>, Vec<T>, Vec<i32>, usize)> {
    (
        k,
        0usize..40,
        -3i64..=3,
        -3i64..=3,
        prop::bool::weighted(0.7),
    )
        .prop_flat_map(move |(k, n, dw, db, exact_lengths)| {
            let (dw, db) = if exact_lengths { (0, 0) } else { (dw, db) };
            let wl = ((n * k) as i64 + dw).max(0) as usize;
            let bl = (n as i64 + db).max(0) as usize;
            (
                prop::collection::vec(val.clone(), wl),
                prop::collection::vec(val.clone(), k),
                prop::collection::vec(any_bias(), bl),
                Just(n),
            )
        })
}

proptest! {
    #![proptest_config(cases(512))]

    #[test]
    fn i8_kernels_match_reference((w, x, b, n) in shape(any_i8(), 0..600)) {
        check_i8(&w, &x, &b, n);
    }

    #[test]
    fn i16_kernels_match_reference_full_range((w, x, b, n) in shape(any_i16(), 0..600)) {
        check_i16(&w, &x, &b, n);
    }

    #[test]
    fn i16_kernels_match_reference_model_range(
        (w, x, b, n) in shape(-2047i16..=2047, 0..600)
    ) {
        // The first layer's range (|w| <= 1023 below, |x| <= 2047, biases within ±2^30):
        // never overflows.
        let w: Vec<i16> = w.iter().map(|&v| v / 2).collect();
        let b: Vec<i32> = b.iter().map(|&v| v.clamp(-(1 << 30), 1 << 30)).collect();
        prop_assert!(x.is_empty() || reference_cannot_overflow(&w, &x, &b, n));
        check_i16(&w, &x, &b, n);
    }

    #[test]
    fn i16_kernels_match_reference_small_k((w, x, b, n) in shape(any_i16(), 0..12)) {
        // The engines' first layer has K = 5: all-tail shapes.
        check_i16(&w, &x, &b, n);
    }
}

/// All 256 × 256 int8 products, as `K` equal terms: `w` holds one row per weight value.
fn sweep_products(k: usize) {
    let wv: Vec<i8> = (i8::MIN..=i8::MAX)
        .flat_map(|a| std::iter::repeat_n(a, k))
        .collect();
    let bias: Vec<i32> = (0..256).map(|i| i * 7 - 900).collect();
    for xv in i8::MIN..=i8::MAX {
        let x = vec![xv; k];
        let want: Vec<i32> = (i8::MIN..=i8::MAX)
            .zip(&bias)
            .map(|(a, &b)| b + k as i32 * i32::from(a) * i32::from(xv))
            .collect();
        assert_eq!(
            expected_i8(&wv, &x, &bias, &[0; 256]),
            want,
            "reference, x = {xv}"
        );
        check_i8(&wv, &x, &bias, 256);
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i8_all_products_k1() {
    sweep_products(1);
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i8_all_products_k64() {
    sweep_products(64);
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i8_all_products_k67() {
    // A full 64-lane chunk plus a 3-lane tail.
    sweep_products(67);
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i16_all_extreme_pairs() {
    // (−32768)² · 2 = 2^31 leaves i32 inside `vpmaddwd`; the result must still be the residue.
    let ext = [i16::MIN, i16::MIN + 1, -1, 0, 1, i16::MAX];
    for &a in &ext {
        for &b in &ext {
            for k in [1, 2, 3, 16, 31, 32, 33, 64] {
                check_i16(
                    &vec![a; 5 * k],
                    &vec![b; k],
                    &[0, 1, -1, i32::MAX, i32::MIN],
                    5,
                );
            }
        }
    }
}

#[test]
fn k_zero_gives_bias() {
    let bias = [3, -4, i32::MAX, i32::MIN];
    for out_len in 0..6 {
        for w_len in [0, 5] {
            check_i8(&vec![1; w_len], &[], &bias, out_len);
            check_i16(&vec![1; w_len], &[], &bias, out_len);
            let mut out = vec![9; out_len];
            kernels::matvec_i8(&vec![1; w_len], &[], &bias, &mut out);
            let n = out_len.min(4);
            assert_eq!(out[..n], bias[..n]);
            assert!(out[n..].iter().all(|&v| v == 9));
        }
    }
}

#[test]
fn mismatched_lengths_touch_the_reference_rows_only() {
    let x: Vec<i8> = (0..70).map(|i| (i * 37 % 256) as u8 as i8).collect();
    let w: Vec<i8> = (0..70 * 9 + 13)
        .map(|i| (i * 101 % 256) as u8 as i8)
        .collect();
    for out_len in 0..12 {
        for bias_len in 0..12i32 {
            let bias: Vec<i32> = (0..bias_len).collect();
            for w_len in [0, 69, 70, 71, 70 * 5, 70 * 9, w.len()] {
                check_i8(&w[..w_len], &x, &bias, out_len);
                let w16: Vec<i16> = w[..w_len].iter().map(|&v| i16::from(v) * 200).collect();
                let x16: Vec<i16> = x.iter().map(|&v| i16::from(v) * 13).collect();
                check_i16(&w16, &x16, &bias, out_len);
            }
        }
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn model_shapes() {
    // The PointNet layers (K → out) the int8 engine runs, with pseudo-random values.
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    for (k, n) in [
        (64, 64),
        (64, 128),
        (128, 256),
        (512, 1024),
        (2048, 64),
        (128, 346),
    ] {
        let w: Vec<i8> = (0..k * n).map(|_| next() as i8).collect();
        let x: Vec<i8> = (0..k).map(|_| next() as i8).collect();
        let b: Vec<i32> = (0..n).map(|_| (next() as i32) >> 8).collect();
        check_i8(&w, &x, &b, n);
    }
    let w: Vec<i16> = (0..5 * 64).map(|_| (next() % 2047) as i16 - 1023).collect();
    let x: Vec<i16> = (0..5).map(|_| (next() % 4095) as i16 - 2047).collect();
    check_i16(&w, &x, &[7; 64], 64);
}

// The blocked int8 matrix-matrix kernel.

/// The expected `out` of a matmat call, from the reference matvec (`expected_i8`) per point,
/// with the shape rules written out independently of `kernels::matmat_dims`: `O` rows as a
/// matvec into a row of `stride`, then every point `p` of `x` whose row
/// `out[p·stride..][..O]` fits.
fn expected_mm(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &[i32], stride: usize) -> Vec<i32> {
    let mut o = out.to_vec();
    let rows = match w.len().checked_div(k) {
        Some(r) => r.min(bias.len()).min(stride),
        None => bias.len().min(stride),
    };
    if rows == 0 {
        return o;
    }
    for p in 0usize.. {
        let fits = |v: Option<usize>, len: usize| v.is_some_and(|v| v <= len);
        if !fits((p + 1).checked_mul(k), x.len())
            || !fits(
                p.checked_mul(stride).and_then(|o| o.checked_add(rows)),
                o.len(),
            )
        {
            break;
        }
        let y = &mut o[p * stride..][..rows];
        let want = expected_i8(w, &x[p * k..][..k], bias, y);
        y.copy_from_slice(&want);
    }
    o
}

/// Checks every matmat kernel (and the raw reference, and `kernels::matmat_i8`) against
/// [`expected_mm`], with a sentinel-filled `out` of `out_len`.
fn check_mm(w: &[i8], k: usize, x: &[i8], bias: &[i32], out_len: usize, stride: usize) {
    let out = vec![0x5A5A_5A5A; out_len];
    let want = expected_mm(w, k, x, bias, &out, stride);
    let run = |f: &dyn Fn(&mut [i32])| {
        let mut o = out.clone();
        f(&mut o);
        o
    };
    let ctx = format!(
        "K = {k}, x = {}, w = {}, bias = {}, out = {out_len}, stride = {stride}",
        x.len(),
        w.len(),
        bias.len()
    );
    assert_eq!(
        run(&|o| reference::matmat_i8(w, k, x, bias, o, stride)),
        want,
        "reference::matmat_i8, {ctx}"
    );
    for kern in with_reference_table() {
        let got = run(&|o| kern.matmat_i8(w, k, x, bias, o, stride));
        assert_eq!(got, want, "{}, {ctx}", kern.name());
    }
    assert_eq!(
        run(&|o| kernels::matmat_i8(w, k, x, bias, o, stride)),
        want,
        "kernels::matmat_i8, {ctx}"
    );
    assert_eq!(
        run(&|o| kernels::arm::matmat_i8(w, k, x, bias, o, stride)),
        want,
        "arm::matmat_i8 (emulated), {ctx}"
    );
    // The widened layout of the Cortex-M DSP kernel, widened from the rows computed; a
    // widening one word short falls back to the row-major weights.
    let (np, no) = kernels::matmat_dims(k, w.len(), x.len(), bias.len(), out_len, stride);
    let mut ww = vec![0u32; no * kernels::arm::widened_row_words(k)];
    assert_eq!(
        kernels::arm::widen_i8(w, no, k, &mut ww),
        Some(ww.len()),
        "{ctx}"
    );
    assert_eq!(
        run(&|o| kernels::arm::matmat_widened_i8(&ww, w, k, x, bias, o, stride)),
        want,
        "arm::matmat_widened_i8 (emulated), {ctx}"
    );
    if let Some(short) = ww.len().checked_sub(1) {
        assert_eq!(
            run(&|o| kernels::arm::matmat_widened_i8(&ww[..short], w, k, x, bias, o, stride)),
            want,
            "arm::matmat_widened_i8 (emulated, one word short), {ctx}"
        );
    }
    // The written rectangle is the one `matmat_dims` announces.
    let mut probe = vec![i32::MIN; out_len];
    let marker = vec![i32::MAX; bias.len()];
    kernels::matmat_i8(
        &vec![0; w.len()],
        k,
        &vec![0; x.len()],
        &marker,
        &mut probe,
        stride,
    );
    let written: Vec<usize> = (0..out_len).filter(|&i| probe[i] == i32::MAX).collect();
    let announced: Vec<usize> = (0..np)
        .flat_map(|p| (0..no).map(move |o| p * stride + o))
        .collect();
    assert_eq!(written, announced, "matmat_dims, {ctx}");
}

/// `(w, k, x, bias, out_len, stride)`: `P` points in `0..=17`, `O` rows in `0..40`, `K` in `k`,
/// `stride = O + 0..5` (below `O` one time in ten), `out_len = P·stride + 0..=3` or cut short
/// by up to a row, `x` of `P·K` plus a partial point or minus a point, and `w`/`bias` lengths
/// that disagree by up to 3 (as in [`shape`]) three times in ten.
#[allow(clippy::type_complexity)]
fn mm_shape(
    k: std::ops::Range<usize>,
) -> impl Strategy<Value = (Vec<i8>, usize, Vec<i8>, Vec<i32>, usize, usize)> {
    (
        k,
        0usize..40,
        0usize..=17,
        (prop::bool::weighted(0.9), 0usize..5),
        (prop::bool::weighted(0.7), 0usize..=3, 0usize..=100),
        (prop::bool::weighted(0.8), 0usize..=100),
        (prop::bool::weighted(0.7), -3i64..=3, -3i64..=3),
    )
        .prop_flat_map(
            |(k, n, p, (wide, ds), (pad, dpad, cut), (whole_x, dx), (exact, dw, db))| {
                let stride = if wide {
                    n + ds
                } else {
                    n.saturating_sub(ds + 1)
                };
                let full = p * stride;
                let out_len = if pad {
                    full + dpad
                } else {
                    full.saturating_sub(cut % (stride + 1))
                };
                let x_len = if whole_x {
                    p * k
                } else if dx % 2 == 0 {
                    p * k + dx % k.max(1)
                } else {
                    (p * k).saturating_sub(1 + dx % k.max(1))
                };
                let (dw, db) = if exact { (0, 0) } else { (dw, db) };
                let wl = ((n * k) as i64 + dw).max(0) as usize;
                let bl = (n as i64 + db).max(0) as usize;
                (
                    prop::collection::vec(any_i8(), wl),
                    Just(k),
                    prop::collection::vec(any_i8(), x_len),
                    prop::collection::vec(-(1i32 << 30)..(1 << 30), bl),
                    Just(out_len),
                    Just(stride),
                )
            },
        )
}

proptest! {
    #![proptest_config(cases(512))]

    #[test]
    fn i8_matmat_kernels_match_reference((w, k, x, b, n, s) in mm_shape(0..600)) {
        check_mm(&w, k, &x, &b, n, s);
    }

    #[test]
    fn i8_matmat_kernels_match_reference_small_k((w, k, x, b, n, s) in mm_shape(0..80)) {
        // Every tail length of the 16-, 32- and 64-lane kernels, and K below one chunk.
        check_mm(&w, k, &x, &b, n, s);
    }
}

/// All 256 × 256 int8 products, as `K` equal terms, through the matmat kernels: `w` holds one
/// row per weight value, the points one value each, 17 points per call (a full group of 16 and
/// a 1-point remainder; the last call 1 point).
fn sweep_products_mm(k: usize, stride: usize) {
    let wv: Vec<i8> = (i8::MIN..=i8::MAX)
        .flat_map(|a| std::iter::repeat_n(a, k))
        .collect();
    let bias: Vec<i32> = (0..256).map(|i| i * 7 - 900).collect();
    let xs: Vec<i8> = (i8::MIN..=i8::MAX).collect();
    for vals in xs.chunks(17) {
        let x: Vec<i8> = vals
            .iter()
            .flat_map(|&v| std::iter::repeat_n(v, k))
            .collect();
        let out_len = vals.len() * stride;
        let mut want = vec![0x5A5A_5A5A; out_len];
        for (p, &xv) in vals.iter().enumerate() {
            for (o, a) in (i8::MIN..=i8::MAX).enumerate() {
                want[p * stride + o] = bias[o] + k as i32 * i32::from(a) * i32::from(xv);
            }
        }
        assert_eq!(
            expected_mm(&wv, k, &x, &bias, &vec![0x5A5A_5A5A; out_len], stride),
            want,
            "reference, x = {vals:?}"
        );
        check_mm(&wv, k, &x, &bias, out_len, stride);
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i8_matmat_all_products() {
    for k in [1, 16, 31, 32, 33, 64, 67, 128, 131] {
        sweep_products_mm(k, 256);
    }
    sweep_products_mm(67, 261);
}

#[test]
fn i8_matmat_extremes() {
    // Sums at the edge of the i32 range: `bias` near ±2^31 and K · 128 · 128 large. The
    // reference's `+` would overflow only past what the shapes here reach (K ≤ 2^17 / 2).
    for (wv, xv) in [
        (-128i8, -128i8),
        (-128, 127),
        (127, -128),
        (127, 127),
        (-128, 0),
    ] {
        for k in [1, 63, 64, 65, 127, 128, 129, 1000] {
            let big = 1i32 << 30;
            let bias = [
                0,
                1,
                -1,
                big,
                -big,
                i32::MAX - 16384 * k as i32,
                i32::MIN + 16384 * k as i32,
            ];
            let bias: Vec<i32> = bias.iter().cycle().take(9).copied().collect();
            for p in [1, 4, 5, 16, 17] {
                let w = vec![wv; 9 * k];
                let x = vec![xv; p * k];
                check_mm(&w, k, &x, &bias, p * 11, 11);
            }
        }
    }
}

#[test]
fn i8_matmat_k_zero_p_zero_and_degenerate_strides() {
    let bias = [3, -4, i32::MAX - 3, i32::MIN + 3, 5]; // (K = 3 below: no overflow)
    for out_len in 0..14 {
        for stride in 0..7 {
            for w_len in [0, 5] {
                for x_len in [0, 3] {
                    check_mm(&vec![1; w_len], 0, &vec![1; x_len], &bias, out_len, stride);
                    // K = 3: x holds 0 or 1 points.
                    check_mm(
                        &vec![1; w_len * 3],
                        3,
                        &vec![1; x_len],
                        &bias,
                        out_len,
                        stride,
                    );
                }
            }
        }
    }
    // K = 0: as many points as rows of `out` fit, each `bias`.
    let mut out = [9; 11];
    kernels::matmat_i8(&[], 0, &[], &bias[..2], &mut out, 3);
    assert_eq!(out, [3, -4, 9, 3, -4, 9, 3, -4, 9, 3, -4]);
    assert_eq!(kernels::matmat_dims(0, 0, 0, 2, 11, 3), (4, 2));
    // O limited by the stride, P by x, then by out.
    assert_eq!(kernels::matmat_dims(2, 10, 6, 5, 100, 4), (3, 4));
    assert_eq!(kernels::matmat_dims(2, 10, 6, 5, 9, 4), (2, 4));
    assert_eq!(kernels::matmat_dims(2, 10, 6, 5, 7, 4), (1, 4));
    assert_eq!(kernels::matmat_dims(2, 10, 6, 5, 3, 4), (0, 0));
    assert_eq!(kernels::matmat_dims(2, 10, 6, 5, 100, 0), (0, 0));
    // Strides whose multiple by four (the Cortex-M kernel's block of points) overflows: one
    // point, computed like any other (the Arm kernel wrote nothing before), and with x for
    // five points still one, as out holds one row.
    for stride in [usize::MAX / 4 + 1, usize::MAX / 2, usize::MAX] {
        for x_len in [3, 15] {
            check_mm(
                &[1, 2, 3, 4, 5, 6],
                3,
                &vec![1; x_len],
                &[10, 20],
                2,
                stride,
            );
        }
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i8_matmat_model_shapes() {
    // The PointNet point layers (K → O) at the block sizes the engine uses, into rows wider
    // than O; and P = 1 and 33 (two groups and a remainder) on conv5 and fc1.
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    for (k, n, points) in [
        (64, 64, &[1, 2, 3, 4, 7, 8, 15, 16][..]),
        (64, 128, &[5, 16]),
        (128, 256, &[16]),
        (512, 1024, &[1, 4, 8, 16, 17, 33]),
        (2048, 1024, &[1, 3]),
        (2048, 64, &[16]),
        (128, 346, &[6, 16]),
    ] {
        let w: Vec<i8> = (0..k * n).map(|_| next() as i8).collect();
        let b: Vec<i32> = (0..n).map(|_| (next() as i32) >> 8).collect();
        for &p in points {
            let x: Vec<i8> = (0..p * k).map(|_| next() as i8).collect();
            check_mm(&w, k, &x, &b, p * (n + 3), n + 3);
            check_mm(&w, k, &x, &b, p * n, n);
        }
    }
}

#[test]
fn i8_matmat_equals_matvec_per_point() {
    // The same table's matvec, point by point (what the engine did before blocking).
    let mut s = 0x1234_5678_9ABC_DEF1u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let (k, n, p) = (200, 37, 13);
    let w: Vec<i8> = (0..k * n).map(|_| next() as i8).collect();
    let x: Vec<i8> = (0..k * p).map(|_| next() as i8).collect();
    let b: Vec<i32> = (0..n).map(|_| (next() as i32) >> 4).collect();
    for kern in with_reference_table() {
        let mut mm = vec![0; p * n];
        kern.matmat_i8(&w, k, &x, &b, &mut mm, n);
        let mut mv = vec![0; p * n];
        for (xp, y) in x.chunks_exact(k).zip(mv.chunks_exact_mut(n)) {
            kern.matvec_i8(&w, xp, &b, y);
        }
        assert_eq!(mm, mv, "{}", kern.name());
    }
}

// The kernels over pre-packed weights.

/// The expected `out` of a packed call, from the reference matvec per point on the row-major
/// weights, with the shape rules written out independently of `packed::packed_dims`.
#[allow(clippy::too_many_arguments)]
fn expected_packed<T: Copy + Into<i64>>(
    w: &[T],
    rows: usize,
    k: usize,
    x: &[T],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &[i32],
    out_stride: usize,
) -> Vec<i32> {
    let mut o = out.to_vec();
    let n = rows.min(bias.len()).min(out_stride);
    if n == 0 {
        return o;
    }
    for p in 0..points {
        if p * x_stride + k > x.len() || p * out_stride + n > o.len() {
            break;
        }
        let y = &mut o[p * out_stride..][..n];
        // The exact sum's residue modulo 2^32: bias near the i32 limits wraps.
        for (y, e) in y
            .iter_mut()
            .zip(exact(&w[..n * k], &x[p * x_stride..][..k], bias, n))
        {
            *y = e as i32;
        }
    }
    o
}

/// A weight type with packed kernels: packing and the calls, for [`check_packed`].
trait PackedKernel: packed::Lane + Into<i64> {
    fn reference(w: &[Self], rows: usize, k: usize, io: PackedIo<'_, Self>, buf: &mut [u8]);
    fn table(kern: &Kernels, w: &[Self], rows: usize, k: usize, io: PackedIo<'_, Self>);
}

/// `(x, x_stride, points, bias, out, out_stride)` of a packed call.
type PackedIo<'a, T> = (&'a [T], usize, usize, &'a [i32], &'a mut [i32], usize);

/// Packs `w` for one call, into a buffer 5 bytes longer than needed (which must stay unused).
fn pack_for<T: packed::Lane>(w: &[T], rows: usize, k: usize) -> Vec<u8> {
    let mut buf = vec![0u8; packed::packed_len_of::<T>(rows, k).expect("fits") + 5];
    let (_, rest) = packed::Packed::pack(w, rows, k, &mut buf).expect("pack");
    assert_eq!(rest.len(), 5);
    buf
}

macro_rules! packed_kernel {
    ($($t:ty => $packed:ident, $reference:path, $method:ident;)*) => {$(
        impl PackedKernel for $t {
            fn reference(
                w: &[$t],
                rows: usize,
                k: usize,
                (x, xs, p, b, o, os): PackedIo<'_, $t>,
                buf: &mut [u8],
            ) {
                let (pw, _) = $packed::pack(w, rows, k, buf).expect("pack");
                $reference(&pw, x, xs, p, b, o, os);
            }
            fn table(kern: &Kernels, w: &[$t], rows: usize, k: usize, io: PackedIo<'_, $t>) {
                let mut buf = pack_for(w, rows, k);
                let (pw, _) = $packed::pack(w, rows, k, &mut buf).expect("pack");
                let (x, xs, p, b, o, os) = io;
                kern.$method(&pw, x, xs, p, b, o, os);
            }
        }
    )*};
}

packed_kernel! {
    i8 => PackedI8, packed::matmat_packed_i8, matmat_packed_i8;
    i16 => PackedI16, packed::matmat_packed_i16, matmat_packed_i16;
}

/// Packs `w` and checks every table's packed kernel (native or the reference fallback) and the
/// raw reference against [`expected_packed`], with a sentinel-filled `out` of `out_len`.
#[allow(clippy::too_many_arguments)]
fn check_packed<T: PackedKernel>(
    w: &[T],
    rows: usize,
    k: usize,
    x: &[T],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out_len: usize,
    out_stride: usize,
) {
    let mut buf = pack_for(w, rows, k);
    let out = vec![0x5A5A_5A5A; out_len];
    let want = expected_packed(w, rows, k, x, x_stride, points, bias, &out, out_stride);
    let ctx = format!(
        "rows {rows}, K {k}, x {} stride {x_stride}, points {points}, bias {}, out {out_len} \
         stride {out_stride}",
        x.len(),
        bias.len()
    );
    let mut got = out.clone();
    T::reference(
        w,
        rows,
        k,
        (x, x_stride, points, bias, &mut got, out_stride),
        &mut buf,
    );
    assert_eq!(got, want, "packed reference, {ctx}");
    for kern in with_reference_table() {
        let mut got = out.clone();
        T::table(
            &kern,
            w,
            rows,
            k,
            (x, x_stride, points, bias, &mut got, out_stride),
        );
        assert_eq!(got, want, "{} packed, {ctx}", kern.name());
    }
}

/// Checks the specification of the pooled kernel ([`packed::matmat_packed_pool_i8`]) and
/// every table's native one ([`Kernels::packed_pool_i8`]) against the exact sums, each
/// requantized by `quant::requantize` and pooled one at a time, from a running max and sum
/// that are not at their initial values. Scales, slope and the pooled state come from `seed`;
/// `pooled` is the length of `scales`, `max` and `sum` (one of them a row short one time in
/// four).
#[allow(clippy::too_many_arguments)]
fn check_pooled(
    w: &[i8],
    rows: usize,
    k: usize,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    pooled: usize,
    seed: u64,
) {
    use evpose_core::quant::{requantize, Requant, LEAKY_ALPHA};
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let short = |n: usize, which: u64| {
        if seed % 4 == which {
            n.saturating_sub(1)
        } else {
            n
        }
    };
    // Scales that put the sums anywhere from saturated to zero, a few negative.
    let scales: Vec<f32> = (0..short(pooled, 1))
        .map(|_| {
            let r = next();
            let m = 2f32.powi(-((r % 24) as i32) - 4);
            if r % 16 == 0 {
                -m
            } else {
                m
            }
        })
        .collect();
    let leaky = [None, Some(LEAKY_ALPHA), Some(0.25)][(seed % 3) as usize];
    let max0: Vec<i8> = (0..short(pooled, 2)).map(|_| next() as i8).collect();
    let sum0: Vec<i32> = (0..short(pooled, 3)).map(|_| next() as i32).collect();
    let o = rows
        .min(bias.len())
        .min(scales.len())
        .min(max0.len())
        .min(sum0.len());
    let (mut want_max, mut want_sum) = (max0.clone(), sum0.clone());
    if o > 0 {
        for p in 0..points {
            if p * x_stride + k > x.len() {
                break;
            }
            let e = exact(&w[..o * k], &x[p * x_stride..][..k], bias, o);
            for (j, &e) in e.iter().enumerate() {
                let v = requantize(e as i32, scales[j], leaky);
                want_max[j] = want_max[j].max(v);
                want_sum[j] = want_sum[j].wrapping_add(i32::from(v));
            }
        }
    }
    let requant = Requant {
        scales: &scales,
        leaky,
    };
    let mut buf = pack_for(w, rows, k);
    let (pw, _) = PackedI8::pack(w, rows, k, &mut buf).expect("pack");
    let ctx = format!(
        "rows {rows}, K {k}, x {} stride {x_stride}, points {points}, bias {}, scales {}, \
         max {}, sum {}, leaky {leaky:?}",
        x.len(),
        bias.len(),
        scales.len(),
        max0.len(),
        sum0.len()
    );
    let (mut max, mut sum) = (max0.clone(), sum0.clone());
    packed::matmat_packed_pool_i8(&pw, x, x_stride, points, bias, requant, &mut max, &mut sum);
    assert_eq!(
        (&max, &sum),
        (&want_max, &want_sum),
        "pooled specification, {ctx}"
    );
    for kern in with_reference_table() {
        let native = kern.packed_pool_i8(&pw);
        // The VNNI tables (and AMX, on tiles or on AVX-512 VNNI) pool every shape, AVX2 and
        // AVX-512BW layers of up to 512 inputs.
        let offered = match kern.isa() {
            Isa::X86Amx | Isa::X86Avx512Vnni | Isa::X86AvxVnni => Some(true),
            Isa::X86Avx2 | Isa::X86Avx512Bw => Some(k <= 512),
            _ => None,
        };
        if let Some(offered) = offered {
            assert_eq!(
                native.is_some(),
                offered,
                "{} pooled kernel offered, {ctx}",
                kern.name()
            );
        }
        if let Some(f) = native {
            let (mut max, mut sum) = (max0.clone(), sum0.clone());
            f(&pw, x, x_stride, points, bias, requant, &mut max, &mut sum);
            assert_eq!(
                (&max, &sum),
                (&want_max, &want_sum),
                "{} pooled, {ctx}",
                kern.name()
            );
        }
    }
    // The AVX2 and AVX-512BW kernels called directly, on every shape: natively up to 512
    // inputs, past that (where the table does not offer them) through their fallback to the
    // specification.
    #[cfg(target_arch = "x86_64")]
    {
        type Direct = unsafe fn(
            &PackedI8<'_>,
            &[i8],
            usize,
            usize,
            &[i32],
            Requant<'_>,
            &mut [i8],
            &mut [i32],
        );
        let direct: [(Isa, Direct); 2] = [
            (Isa::X86Avx2, kernels::x86::matmat_packed_pool_i8_avx2),
            (
                Isa::X86Avx512Bw,
                kernels::x86::matmat_packed_pool_i8_avx512bw,
            ),
        ];
        for (isa, f) in direct {
            if !isa.is_supported_here() {
                continue;
            }
            let (mut max, mut sum) = (max0.clone(), sum0.clone());
            // SAFETY: the CPU supports the kernel's features (checked above).
            unsafe { f(&pw, x, x_stride, points, bias, requant, &mut max, &mut sum) };
            assert_eq!(
                (&max, &sum),
                (&want_max, &want_sum),
                "{} pooled (called directly), {ctx}",
                isa.name()
            );
        }
    }
}

/// `(w, rows, k, x, x_stride, points, bias, out_len, out_stride)`: up to 140 rows (partial and
/// several row groups), `points` (up to 30 is past one 24-point pass), point rows that overlap,
/// touch or leave gaps, and `x`, `bias` and `out` that may be short.
#[allow(clippy::type_complexity)]
fn packed_shape<T: std::fmt::Debug, S: Strategy<Value = T> + Clone>(
    values: S,
    k: impl Strategy<Value = usize>,
    points: std::ops::RangeInclusive<usize>,
) -> impl Strategy<
    Value = (
        Vec<T>,
        usize,
        usize,
        Vec<T>,
        usize,
        usize,
        Vec<i32>,
        usize,
        usize,
    ),
> {
    (
        k,
        1usize..140,
        points,
        (0usize..3, 0usize..8),
        (prop::bool::weighted(0.8), 0usize..=40),
        (prop::bool::weighted(0.8), 0usize..4),
        (prop::bool::weighted(0.8), 0usize..5, 0usize..=200),
    )
        .prop_flat_map(
            move |(
                k,
                rows,
                points,
                (xs_kind, dxs),
                (whole_x, dx),
                (whole_b, db),
                (wide, ds, cut),
            )| {
                let x_stride = match xs_kind {
                    0 => k,
                    1 => k + dxs,
                    _ => k.saturating_sub(dxs),
                };
                let x_full = if points == 0 {
                    0
                } else {
                    (points - 1) * x_stride + k
                };
                let x_len = if whole_x {
                    x_full
                } else {
                    x_full.saturating_sub(dx)
                };
                let b_len = if whole_b {
                    rows
                } else {
                    rows.saturating_sub(db)
                };
                let out_stride = if wide {
                    rows + ds
                } else {
                    rows.saturating_sub(ds)
                };
                let out_full = points * out_stride;
                let out_len = if wide {
                    out_full
                } else {
                    out_full.saturating_sub(cut)
                };
                (
                    prop::collection::vec(values.clone(), rows * k),
                    Just(rows),
                    Just(k),
                    prop::collection::vec(values.clone(), x_len),
                    Just(x_stride),
                    Just(points),
                    prop::collection::vec(near_limits_or_any(), b_len),
                    Just(out_len),
                    Just(out_stride),
                )
            },
        )
}

/// Biases anywhere, or within 10^6 of `i32::MAX` or `i32::MIN`, so that sums wrap.
fn near_limits_or_any() -> impl Strategy<Value = i32> + Clone {
    prop_oneof![
        any::<i32>(),
        (i32::MAX - 1_000_000)..=i32::MAX,
        i32::MIN..=(i32::MIN + 1_000_000),
    ]
}

proptest! {
    #![proptest_config(cases(256))]

    /// Sums that leave the i32 range wrap to the exact sum's residue modulo 2^32 in every
    /// native int8 kernel and in the (emulated) Cortex-M DSP kernel: the reference's release
    /// semantics (a debug build of the reference panics there instead, so it is not run).
    #[test]
    fn i8_kernels_wrap_modulo_2_32(
        (k, n) in (1usize..300, 1usize..40),
        seed in any::<u64>(),
        bias in prop::collection::vec(near_limits_or_any(), 40),
    ) {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            // Mostly extremes, so that the dot products are large.
            match s % 4 { 0 => i8::MIN, 1 => i8::MAX, _ => (s >> 8) as i8 }
        };
        let w: Vec<i8> = (0..k * n).map(|_| next()).collect();
        let x: Vec<i8> = (0..2 * k).map(|_| next()).collect();
        let bias = &bias[..n];
        for p in 0..2 {
            let xp = &x[p * k..][..k];
            let want: Vec<i32> = exact(&w, xp, bias, n).iter().map(|&e| e as i32).collect();
            let mut got = vec![0; n];
            kernels::arm::matvec_i8(&w, xp, bias, &mut got);
            prop_assert_eq!(&got, &want, "arm (emulated)");
            for kern in candidates() {
                kern.matvec_i8(&w, xp, bias, &mut got);
                prop_assert_eq!(&got, &want, "{} matvec", kern.name());
            }
        }
        let want: Vec<i32> = x
            .chunks_exact(k)
            .flat_map(|xp| exact(&w, xp, bias, n))
            .map(|e| e as i32)
            .collect();
        for kern in candidates() {
            let mut got = vec![0; 2 * n];
            kern.matmat_i8(&w, k, &x, bias, &mut got, n);
            prop_assert_eq!(&got, &want, "{} matmat", kern.name());
        }
        // (The packed kernels get near-limit biases in `packed_shape`.)
    }

    #[test]
    fn i8_packed_kernels_match_reference(
        (w, r, k, x, xs, p, b, n, s) in packed_shape(any_i8(), 1usize..600, 0..=30)
    ) {
        check_packed(&w, r, k, &x, xs, p, &b, n, s);
    }

    #[test]
    fn i8_packed_kernels_match_reference_small_k(
        (w, r, k, x, xs, p, b, n, s) in packed_shape(any_i8(), 1usize..20, 0..=30)
    ) {
        // Every tail of the four-input step, and K below one step.
        check_packed(&w, r, k, &x, xs, p, &b, n, s);
    }

    #[test]
    fn i8_packed_kernels_match_reference_whole_tiles(
        (w, r, k, x, xs, p, b, n, s) in
            packed_shape(any_i8(), (1usize..10).prop_map(|c| 64 * c), 0..=70)
    ) {
        // `K` a multiple of 64 from 64 (AVX-512 VNNI on an AMX CPU) to 576 (on tiles from
        // 128: `kernels::x86::AMX_MIN_K`), and blocks of points past one (32) and two tile
        // pairs, every remainder of 16.
        check_packed(&w, r, k, &x, xs, p, &b, n, s);
    }

    #[test]
    fn i8_pooled_kernels_match_reference(
        (w, r, k, x, xs, p, b, _, _) in
            packed_shape(any_i8(), prop_oneof![1usize..80, (1usize..10).prop_map(|c| 64 * c)], 0..=70),
        extra in 0usize..3,
        seed in any::<u64>(),
    ) {
        // The tiles' shapes (K a multiple of 64 from 128, blocks of points past one and two
        // tile pairs) and the others (the VNNI tables' register tiles and their tails).
        check_pooled(&w, r, k, &x, xs, p, &b, r + extra, seed);
    }

    #[test]
    fn i16_packed_kernels_match_reference(
        (w, r, k, x, xs, p, b, n, s) in packed_shape(any_i16(), 1usize..40, 0..=30)
    ) {
        // The first layer's shapes (K = 5) and both tails of the two-input step; full-range
        // values, so that pairs of (-32768)·(-32768) wrap.
        check_packed(&w, r, k, &x, xs, p, &b, n, s);
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn i8_packed_all_products_and_model_shapes() {
    // Every int8 product: 256 rows, one per weight value, times points holding every value.
    let k = 67;
    let w: Vec<i8> = (i8::MIN..=i8::MAX)
        .flat_map(|a| std::iter::repeat_n(a, k))
        .collect();
    let x: Vec<i8> = (i8::MIN..=i8::MAX)
        .flat_map(|a| std::iter::repeat_n(a, k))
        .collect();
    let b: Vec<i32> = (0..256).map(|i| i * 7 - 900).collect();
    check_packed(&w, 256, k, &x, k, 256, &b, 256 * 256, 256);
    // The PointNet point layers as the engine calls them: rows of a 1536-wide activation
    // buffer, sources at its start, blocks of 16 points and fewer.
    let mut s = 0x0DDB_1A5E_5BAD_5EEDu64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    for (k, n) in [(64, 64), (64, 128), (128, 256), (256, 1024), (512, 1024)] {
        let w: Vec<i8> = (0..k * n).map(|_| next() as i8).collect();
        let b: Vec<i32> = (0..n).map(|_| (next() as i32) >> 8).collect();
        let x: Vec<i8> = (0..16 * 1536).map(|_| next() as i8).collect();
        for p in [1, 5, 16] {
            check_packed(&w, n, k, &x, 1536, p, &b, p * n, n);
        }
    }
    // Rows longer than the AVX2 kernel's 1,024-input chunk of widened inputs: two and three
    // chunks, the last one short and (for K = 2_053) ending in a partial step.
    for (k, n) in [(1_027, 70), (2_053, 9)] {
        let w: Vec<i8> = (0..k * n).map(|_| next() as i8).collect();
        let b: Vec<i32> = (0..n).map(|_| (next() as i32) >> 8).collect();
        let x: Vec<i8> = (0..7 * k + 3).map(|_| next() as i8).collect();
        for p in [1, 6, 7] {
            check_packed(&w, n, k, &x, k, p, &b, p * n, n);
        }
    }
}

#[test]
fn i16_packed_first_layer_shape_and_extremes() {
    // The engine's first layer: 5 coded inputs, 8 apart, 64 rows, blocks of up to 30 points;
    // every extreme pair.
    let ext = [i16::MIN, i16::MIN + 1, -1, 0, 1, i16::MAX];
    let w: Vec<i16> = (0..64 * 5).map(|i| ext[i * 7 % 6]).collect();
    let x: Vec<i16> = (0..30 * 8).map(|i| ext[i * 5 % 6]).collect();
    let b: Vec<i32> = (0..64).map(|i| i * 1001 - 30_000).collect();
    for p in [1, 6, 7, 24, 30] {
        check_packed(&w, 64, 5, &x, 8, p, &b, p * 64, 64);
    }
}

#[test]
fn every_x86_table_has_a_native_packed_kernel() {
    for kern in with_reference_table() {
        assert_eq!(
            kern.has_packed(),
            matches!(
                kern.isa(),
                Isa::X86Amx
                    | Isa::X86Avx512Vnni
                    | Isa::X86AvxVnni
                    | Isa::X86Avx2
                    | Isa::X86Avx512Bw
            ),
            "{}",
            kern.name()
        );
    }
}

// The f32 kernel: partial sums in a fixed order, so every table gives the same bits.

/// `(w, x, bias, out_len)` like [`shape`], in f32.
fn shape_f32(
    k: std::ops::Range<usize>,
) -> impl Strategy<Value = (Vec<f32>, Vec<f32>, Vec<f32>, usize)> {
    let val = prop_oneof![8 => -4.0f32..4.0, 1 => Just(0.0f32), 1 => -1e3f32..1e3];
    shape(val, k).prop_map(|(w, x, b, n)| {
        let b = b.iter().map(|&v| v as f32 / (1 << 26) as f32).collect();
        (w, x, b, n)
    })
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|f| f.to_bits()).collect()
}

/// Checks the reference against the f64 sum (within the worst-case rounding of any summation
/// order), each row alone against the rows together, and every table against the reference,
/// bit for bit; elements past the computed rows stay untouched.
fn check_f32(w: &[f32], x: &[f32], bias: &[f32], out_len: usize) {
    const UNTOUCHED: f32 = 7.5;
    let k = x.len();
    let rows = kernels::rows(k, w.len(), bias.len(), out_len);
    let mut want = vec![UNTOUCHED; out_len];
    reference::matvec_f32(w, x, bias, &mut want);
    assert!(want[rows..].iter().all(|&v| v == UNTOUCHED));
    let u = 2f64.powi(-24); // f32 unit roundoff
    let gamma = (k + 2) as f64 * u / (1.0 - (k + 2) as f64 * u);
    for o in 0..rows {
        let row = &w[o * k..(o + 1) * k];
        let exact: f64 = row
            .iter()
            .zip(x)
            .map(|(&a, &b)| a as f64 * b as f64)
            .sum::<f64>()
            + bias[o] as f64;
        let magnitude: f64 = row
            .iter()
            .zip(x)
            .map(|(&a, &b)| (a as f64 * b as f64).abs())
            .sum::<f64>()
            + (bias[o] as f64).abs();
        let err = (want[o] as f64 - exact).abs();
        assert!(
            err <= gamma * magnitude,
            "row {o}: error {err} over {}",
            gamma * magnitude
        );
        let mut alone = [UNTOUCHED];
        reference::matvec_f32(row, x, &bias[o..=o], &mut alone);
        assert_eq!(alone[0].to_bits(), want[o].to_bits(), "row {o} alone");
    }
    for kern in with_reference_table() {
        let mut got = vec![UNTOUCHED; out_len];
        kern.matvec_f32(w, x, bias, &mut got);
        assert_eq!(bits(&got), bits(&want), "{}", kern.name());
    }
    let mut got = vec![UNTOUCHED; out_len];
    kernels::matvec_f32(w, x, bias, &mut got);
    assert_eq!(bits(&got), bits(&want), "kernels::matvec_f32");
}

proptest! {
    #![proptest_config(cases(512))]

    #[test]
    fn f32_kernels_match_reference_bits((w, x, b, n) in shape_f32(0..300)) {
        check_f32(&w, &x, &b, n);
    }

    #[test]
    fn f32_kernels_match_reference_bits_small_k((w, x, b, n) in shape_f32(0..40)) {
        check_f32(&w, &x, &b, n);
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn f32_model_shapes() {
    // The paper model's point layers and heads (K, rows), and its FC layers' K with a few rows
    // (odd counts, for the rows past the last group of four).
    for (k, rows) in [
        (5, 64),
        (64, 64),
        (64, 128),
        (128, 256),
        (512, 1024),
        (2048, 8),
        (1024, 7),
        (128, 346),
        (128, 260),
    ] {
        let w: Vec<f32> = (0..k * rows)
            .map(|i| ((i * 7919 % 2001) as f32 - 1000.0) / 997.0)
            .collect();
        let x: Vec<f32> = (0..k)
            .map(|i| ((i * 104_729 % 401) as f32 - 200.0) / 50.0)
            .collect();
        let b: Vec<f32> = (0..rows).map(|i| i as f32 * 0.25 - 3.0).collect();
        check_f32(&w, &x, &b, rows);
        check_f32(&w, &x, &b, rows + 3);
    }
}

/// Rows of `stride` values for [`kernels::PointRows`]: a block of `points` points and `extra`
/// rows after it that are not the block's, the inputs at `x0..x0 + k`, the outputs `gap` values
/// after them, marker values everywhere else.
fn f32_block(
    vals: &[f32],
    (points, extra): (usize, usize),
    stride: usize,
    (x0, k, gap): (usize, usize, usize),
) -> (Vec<f32>, kernels::PointRows) {
    const MARK: f32 = -7.25;
    let mut rows = vec![MARK; (points + extra) * stride];
    for (p, row) in rows.chunks_mut(stride.max(1)).enumerate() {
        for (j, v) in row.iter_mut().enumerate().skip(x0).take(k) {
            *v = vals[(p * 31 + j) % vals.len()];
        }
    }
    let at = kernels::PointRows {
        stride,
        points,
        x: x0..x0 + k,
        out: x0 + k + gap,
    };
    (rows, at)
}

/// Every table's `matmat_f32` against the reference's, bit for bit over the whole block
/// (outputs and everything it must leave alone), and the reference against `matvec_f32`
/// point by point.
fn check_matmat_f32(w: &[f32], bias: &[f32], rows: &[f32], at: &kernels::PointRows) {
    let mut want = rows.to_vec();
    reference::matmat_f32(w, bias, &mut want, at);
    let (k, o, points) = at.dims(w.len(), bias.len(), rows.len());
    let stride = at.stride.max(1);
    for (p, (row, got)) in rows.chunks(stride).zip(want.chunks(stride)).enumerate() {
        let mut alone = row.to_vec();
        if p < points && o > 0 {
            let x = &row[at.x.clone()];
            reference::matvec_f32(&w[..o * k], x, &bias[..o], &mut alone[at.out..][..o]);
        }
        assert_eq!(bits(got), bits(&alone), "point {p}");
    }
    for kern in with_reference_table() {
        let mut got = rows.to_vec();
        kern.matmat_f32(w, bias, &mut got, at);
        assert_eq!(bits(&got), bits(&want), "{}: {at:?}", kern.name());
    }
}

proptest! {
    #![proptest_config(cases(256))]

    #[test]
    fn f32_matmat_matches_reference_bits(
        (w, mut x, b, n) in shape_f32(0..150),
        whole in proptest::bool::ANY,
        (points, extra) in (0usize..11, 0usize..3),
        (x0, gap, pad) in (0usize..3, 0usize..3, 0usize..3),
        short in 0usize..2,
    ) {
        // The weights as `shape_f32` made them, read as rows of K (at most `n` outputs per
        // point); half the cases with K cut to a multiple of 16 (no tails: the AVX-512 tiles'
        // own finish). The inputs' values spread over the block's points.
        if whole && x.len() >= 16 {
            x.truncate(x.len() / 16 * 16);
        }
        let k = x.len();
        let o = kernels::rows(k, w.len(), b.len(), n);
        let stride = x0 + k + gap + o + pad;
        let vals = if x.is_empty() { vec![1.5] } else { x };
        let (mut rows, at) = f32_block(&vals, (points, extra), stride, (x0, k, gap));
        // A last row cut short: that point is skipped when its outputs do not fit.
        let cut = rows.len().saturating_sub(short * (pad + 1));
        rows.truncate(cut);
        check_matmat_f32(&w, &b, &rows, &at);
    }
}

#[test]
fn f32_matmat_model_shapes_and_refusals() {
    // The paper model's point layers that read earlier layers (K, rows), with point counts
    // around the four-point tiles, and blocks the kernels must leave alone.
    for (k, o) in [
        (64, 64),
        (64, 128),
        (128, 256),
        (512, 24),
        (48, 6),
        (17, 5),
        (0, 3),
    ] {
        let w: Vec<f32> = (0..k * o)
            .map(|i| ((i * 7919 % 2001) as f32 - 1000.0) / 997.0)
            .collect();
        let mut b: Vec<f32> = (0..o).map(|i| i as f32 * 0.25 - 3.0).collect();
        b[0] = -0.0;
        let vals: Vec<f32> = (0..401).map(|i| (i as f32 - 200.0) / 50.0).collect();
        for points in [1, 3, 4, 5, 8, 9] {
            // Inputs from 1, outputs one value after them, a row after the block.
            let (rows, at) = f32_block(&vals, (points, 1), 2 + k + o, (1, k, 1));
            check_matmat_f32(&w, &b, &rows, &at);
            // Outputs overlapping the inputs, past the stride, or a reversed input range:
            // nothing written.
            for bad in [
                kernels::PointRows {
                    out: at.x.end.saturating_sub(1),
                    ..at.clone()
                },
                kernels::PointRows {
                    stride: at.stride - 1,
                    ..at.clone()
                },
                kernels::PointRows {
                    x: at.x.end + 1..at.x.start,
                    ..at.clone()
                },
            ] {
                assert_eq!(bad.dims(w.len(), b.len(), rows.len()), (0, 0, 0), "{bad:?}");
                check_matmat_f32(&w, &b, &rows, &bad);
            }
        }
    }
}

// Requantization and pooling, the engine's loops between kernels.

proptest! {
    #![proptest_config(cases(512))]

    #[test]
    fn requantize_matches_reference_in_every_table(
        acc in prop::collection::vec(
            prop_oneof![any::<i32>(), -100_000i32..100_000, -300i32..300], 0..200),
        scales in prop::collection::vec(
            prop_oneof![
                4 => 1e-6f32..1e-2, 4 => 1e-2f32..2.0, 1 => Just(1.0f32), 1 => Just(0.5f32),
                // Negative, zero and huge scales (the products overflow to ±inf).
                1 => -2.0f32..0.0, 1 => Just(0.0f32), 1 => Just(f32::MAX)],
            0..200),
        leaky in prop_oneof![
            Just(None), Just(Some(0.01f32)), (0.0f32..1.0).prop_map(Some),
            // The edges of the Cortex-M kernel's max form, and slopes outside it (reference).
            Just(Some(0.0f32)), Just(Some(1.0f32)), Just(Some(1.5f32)), Just(Some(-0.2f32))],
    ) {
        let mut want = vec![7i8; acc.len().max(scales.len())];
        reference::requantize_i8(&acc, &scales, leaky, &mut want);
        // Independently: the scalar definition element by element, untouched past the shorter.
        for (i, w) in want.iter().enumerate() {
            let expect = match (acc.get(i), scales.get(i)) {
                (Some(&a), Some(&s)) => evpose_core::quant::requantize(a, s, leaky),
                _ => 7,
            };
            prop_assert_eq!(*w, expect);
        }
        for kern in with_reference_table() {
            let mut got = vec![7i8; want.len()];
            kern.requantize_i8(&acc, &scales, leaky, &mut got);
            prop_assert_eq!(&got, &want, "{}", kern.name());
        }
        // The Cortex-M7 kernel's arithmetic (VMAXNM, VCVTN), emulated here.
        let mut got = vec![7i8; want.len()];
        kernels::arm::requantize_i8(&acc, &scales, leaky, &mut got);
        prop_assert_eq!(&got, &want, "arm::requantize_i8 (emulated)");
    }

    #[test]
    fn pooling_matches_reference_in_every_table(
        max in prop::collection::vec(any::<i8>(), 0..300),
        sum in prop::collection::vec(any::<i32>(), 0..300),
        y in prop::collection::vec(any::<i8>(), 0..300),
    ) {
        let n = max.len().min(sum.len()).min(y.len());
        let (mut wm, mut ws) = (max.clone(), sum.clone());
        for i in 0..n {
            wm[i] = wm[i].max(y[i]);
            ws[i] = ws[i].wrapping_add(i32::from(y[i]));
        }
        for kern in with_reference_table() {
            let (mut m, mut s) = (max.clone(), sum.clone());
            kern.pool_i8(&mut m, &mut s, &y);
            prop_assert_eq!((&m, &s), (&wm, &ws), "{}", kern.name());
        }
        let (mut m, mut s) = (max.clone(), sum.clone());
        kernels::arm::pool_i8(&mut m, &mut s, &y);
        prop_assert_eq!((&m, &s), (&wm, &ws), "arm::pool_i8 (emulated)");
    }
}

#[test]
#[cfg_attr(
    miri,
    ignore = "too slow interpreted; the property tests run the same kernels under Miri"
)]
fn peak_loop_runs_every_family_this_cpu_has() {
    assert_eq!(kernels::peak_loop(Isa::Reference, 10), None);
    for isa in Isa::ALL.into_iter().filter(|&i| i != Isa::Reference) {
        let macs = kernels::peak_loop(isa, 1000);
        assert_eq!(macs.is_some(), isa.is_supported_here(), "{}", isa.name());
        if let Some(m) = macs {
            if isa == Isa::X86Amx {
                // 1000 rounds of six `tdpbssd`, 16 × 16 × 64 MACs each.
                assert_eq!(m, 1000 * 6 * 16 * 16 * 64);
            } else {
                // 1000 rounds of 12 instructions of 16 to 64 MACs each.
                assert!(m % 12_000 == 0 && (16..=64).contains(&(m / 12_000)), "{m}");
            }
            // A MAC count past u64 is refused before anything runs.
            assert_eq!(kernels::peak_loop(isa, u64::MAX), None);
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[test]
#[cfg_attr(miri, ignore = "Miri runs no cpuid")]
fn cpuid_detection_matches_std() {
    use evpose_core::kernels::x86::Features;
    let f = Features::detect();
    let avx512 = is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx512bw")
        && is_x86_feature_detected!("avx512vl");
    assert_eq!(f.avx2(), is_x86_feature_detected!("avx2"), "avx2");
    assert_eq!(
        f.avxvnni(),
        f.avx2() && is_x86_feature_detected!("avxvnni"),
        "avxvnni"
    );
    assert_eq!(f.avx512bw(), avx512, "avx512bw");
    assert_eq!(
        f.avx512vnni(),
        avx512 && is_x86_feature_detected!("avx512vnni"),
        "avx512vnni"
    );
    // std's AMX detection is unstable; Linux lists the CPU's flags, and grants the tile state
    // (what the core also asks for) wherever it lists them.
    #[cfg(target_os = "linux")]
    {
        let info = std::fs::read_to_string("/proc/cpuinfo").expect("/proc/cpuinfo");
        let flags: Vec<&str> = info
            .lines()
            .find(|l| l.starts_with("flags"))
            .map_or(vec![], |l| l.split_whitespace().collect());
        let amx = flags.contains(&"amx_tile") && flags.contains(&"amx_int8");
        assert_eq!(f.amx(), f.avx512vnni() && amx, "amx");
    }
    let c = Features::compile_time();
    for isa in Isa::ALL {
        // What the build assumes, the CPU must have.
        assert!(!c.supports(isa) || f.supports(isa), "{}", isa.name());
    }
}

/// The Cortex-M7 requantization (emulated here; the real `VMAXNM`/`VCVTN` run in the
/// firmware's self-test) on every accumulator in ±2^17 and the i32 extremes, at scales where
/// ties (x.5) occur, for every slope form it takes: none, PyTorch's 0.01, the edges 0 and 1,
/// and a slope it leaves to the reference. Lengths not a multiple of four reach its tail.
#[test]
fn arm_requantization_matches_reference_on_every_accumulator_in_range() {
    let acc: Vec<i32> = (-(1 << 17)..(1 << 17))
        .chain([i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX - 1, i32::MAX])
        .collect();
    for scale in [0.003_137_254_9f32, 0.5, 1.0, 0.25, 1e-3, 3.0e-5, -0.5] {
        let scales = vec![scale; acc.len()];
        for leaky in [None, Some(0.01f32), Some(0.0), Some(1.0), Some(1.25)] {
            let mut want = vec![0i8; acc.len()];
            reference::requantize_i8(&acc, &scales, leaky, &mut want);
            let mut got = vec![0i8; acc.len()];
            kernels::arm::requantize_i8(&acc, &scales, leaky, &mut got);
            assert!(got == want, "scale {scale}, leaky {leaky:?}");
        }
    }
}

/// `widen_i8` writes per row and step of four weights the two words `SXTB16` makes (bytes 0, 2
/// and 1, 3 as sign-extended halfwords), skips the last `K mod 4` of each row, and refuses
/// short buffers without writing.
#[test]
fn widened_weights_are_the_sxtb16_halfword_pairs() {
    use kernels::arm::{widen_i8, widened_row_words};
    let half = |v: i8| u32::from(v as i16 as u16);
    for k in 0..=13 {
        let rows = 3;
        let w: Vec<i8> = (0..rows * k).map(|i| (i as i32 * 37 - 128) as i8).collect();
        let per = widened_row_words(k);
        assert_eq!(per, k / 4 * 2);
        let mut out = vec![0xDEAD_BEEF; rows * per + 2];
        assert_eq!(widen_i8(&w, rows, k, &mut out), Some(rows * per), "K = {k}");
        for r in 0..rows {
            for s in 0..k / 4 {
                let v = &w[r * k + 4 * s..][..4];
                assert_eq!(
                    out[r * per + 2 * s..][..2],
                    [half(v[0]) | half(v[2]) << 16, half(v[1]) | half(v[3]) << 16],
                    "K = {k}, row {r}, step {s}"
                );
            }
        }
        assert_eq!(out[rows * per..], [0xDEAD_BEEF; 2], "K = {k}: past the end");
        if per > 0 {
            let mut short = vec![7u32; rows * per - 1];
            assert_eq!(widen_i8(&w, rows, k, &mut short), None);
            assert!(short.iter().all(|&v| v == 7), "K = {k}: nothing written");
            assert_eq!(
                widen_i8(&w[1..], rows, k, &mut out),
                None,
                "K = {k}: w short"
            );
        }
    }
}
