//! Every kernel this CPU runs against [`reference`], bit for bit (`assert_eq!`, no tolerance).
//!
//! Kernels whose instructions the CPU lacks are skipped and named (`--nocapture` shows them).

use evpose_core::kernels::{self, reference, Isa, Kernels};
use proptest::prelude::*;

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

/// Checks every kernel against the reference on one case, with a sentinel-filled `out`.
fn check_i8(w: &[i8], x: &[i8], bias: &[i32], out_len: usize) {
    let out = vec![0x5A5A_5A5A; out_len];
    let want = expected_i8(w, x, bias, &out);
    for k in with_reference_table() {
        let got = run(|w, x, b, o| k.matvec_i8(w, x, b, o), w, x, bias, &out);
        assert_eq!(got, want, "{} (K = {}, out = {out_len})", k.name(), x.len());
    }
    assert_eq!(
        run(kernels::matvec_i8, w, x, bias, &out),
        want,
        "kernels::matvec_i8"
    );
}

/// Checks every kernel against the exact value modulo 2^32, and against the reference where
/// the reference cannot overflow.
fn check_i16(w: &[i16], x: &[i16], bias: &[i32], out_len: usize) {
    let out = vec![0x5A5A_5A5A; out_len];
    let mut want = out.clone();
    for (o, e) in want.iter_mut().zip(exact(w, x, bias, out_len)) {
        *o = e as i32; // the residue modulo 2^32
    }
    let no_overflow = reference_cannot_overflow(w, x, bias, out_len);
    if !x.is_empty() && no_overflow {
        assert_eq!(
            run(reference::matvec_i16, w, x, bias, &out),
            want,
            "reference"
        );
    }
    for k in candidates() {
        let got = run(|w, x, b, o| k.matvec_i16(w, x, b, o), w, x, bias, &out);
        assert_eq!(got, want, "{} (K = {}, out = {out_len})", k.name(), x.len());
    }
    if no_overflow || Kernels::best().isa() != Isa::Reference {
        // (A debug build of the reference panics on overflow; the SIMD kernels wrap.)
        assert_eq!(
            run(kernels::matvec_i16, w, x, bias, &out),
            want,
            "kernels::matvec_i16"
        );
    }
}

/// An int8 value, with the extremes over-represented.
fn any_i8() -> impl Strategy<Value = i8> + Clone {
    prop_oneof![6 => any::<i8>(), 1 => Just(i8::MIN), 1 => Just(i8::MAX), 1 => Just(0)]
}

/// An i16 value over the whole range, extremes over-represented.
fn any_i16() -> impl Strategy<Value = i16> + Clone {
    prop_oneof![6 => any::<i16>(), 1 => Just(i16::MIN), 1 => Just(i16::MAX), 1 => Just(0)]
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
                prop::collection::vec(-(1i32 << 30)..(1 << 30), bl),
                Just(n),
            )
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

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
        // The first layer's range (|w| <= 1023 below, |x| <= 2047): never overflows.
        let w: Vec<i16> = w.iter().map(|&v| v / 2).collect();
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
fn i8_all_products_k1() {
    sweep_products(1);
}

#[test]
fn i8_all_products_k64() {
    sweep_products(64);
}

#[test]
fn i8_all_products_k67() {
    // A full 64-lane chunk plus a 3-lane tail.
    sweep_products(67);
}

#[test]
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

#[cfg(target_arch = "x86_64")]
#[test]
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
    let c = Features::compile_time();
    for isa in Isa::ALL {
        // What the build assumes, the CPU must have.
        assert!(!c.supports(isa) || f.supports(isa), "{}", isa.name());
    }
}
