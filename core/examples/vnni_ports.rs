//! What each instruction of the pooled epilogue costs the `vpdpbusd` stream on this CPU, one
//! thread: a loop of 12 independent 512-bit `vpdpbusd` (the packed int8 kernel's work, at the
//! CPU's multiply rate) is timed alone and with four more instructions of one kind on other
//! registers, which depend on nothing in the loop. An instruction that runs on other execution
//! ports than `vpdpbusd` adds nothing; one that shares its ports adds up to a `vpdpbusd` slot.
//! The table prints the added time as `vpdpbusd` slots per instruction (0: free, 1: as costly as
//! a product). `core/src/kernels/x86/packed.rs`'s pooled epilogue (per output register and
//! point: `vpaddd`, `vpsubd`, `vcvtdq2ps`, `vmulps`, `vcmpps`, a masked `vmulps`, `vmaxps`,
//! `vminps`, `vmaxps`, `vcvtps2dq`, `vpaddd`) runs beside the next tile's products, so its
//! price is what this table says, not its instruction count.
//!
//! `cargo run --release -p evpose-core --example vnni_ports` (x86_64 with AVX-512 VNNI; prints
//! why not elsewhere).
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
fn main() {
    use core::arch::asm;
    use evpose_core::kernels::Isa;
    use std::time::Instant;

    if !Isa::X86Avx512Vnni.is_supported_here() {
        println!("no AVX-512 VNNI here");
        return;
    }
    /// 64-byte aligned scratch for the loads and stores.
    #[repr(C, align(64))]
    struct Scratch([u8; 256]);
    let mut scratch = Scratch([0; 256]);
    let p = scratch.0.as_mut_ptr();
    const ROUNDS: u64 = 20_000_000;

    // One timed loop: 12 `vpdpbusd` on accumulators zmm0–zmm11 plus `$extra` (four instructions
    // writing zmm20–zmm23 or k1 from zmm28/zmm29, or touching `[p]`), best of five runs, in ns
    // per iteration.
    macro_rules! time {
        ($extra:literal) => {{
            let mut best = f64::MAX;
            for _ in 0..5 {
                let t = Instant::now();
                // SAFETY: AVX-512 VNNI is present (checked above); the loop touches only the
                // registers it declares as clobbered and the 256 bytes of `scratch` at `p`.
                unsafe {
                    asm!(
                        "/* scratch at {p} */",
                        "vpxord zmm28, zmm28, zmm28",
                        "vpxord zmm29, zmm29, zmm29",
                        "vpxord zmm30, zmm30, zmm30",
                        "vpxord zmm31, zmm31, zmm31",
                        "2:",
                        "vpdpbusd zmm0, zmm30, zmm31",
                        "vpdpbusd zmm1, zmm30, zmm31",
                        "vpdpbusd zmm2, zmm30, zmm31",
                        "vpdpbusd zmm3, zmm30, zmm31",
                        "vpdpbusd zmm4, zmm30, zmm31",
                        "vpdpbusd zmm5, zmm30, zmm31",
                        "vpdpbusd zmm6, zmm30, zmm31",
                        "vpdpbusd zmm7, zmm30, zmm31",
                        "vpdpbusd zmm8, zmm30, zmm31",
                        "vpdpbusd zmm9, zmm30, zmm31",
                        "vpdpbusd zmm10, zmm30, zmm31",
                        "vpdpbusd zmm11, zmm30, zmm31",
                        $extra,
                        "dec {n}",
                        "jnz 2b",
                        n = inout(reg) ROUNDS => _,
                        p = in(reg) p,
                        out("zmm0") _, out("zmm1") _, out("zmm2") _, out("zmm3") _,
                        out("zmm4") _, out("zmm5") _, out("zmm6") _, out("zmm7") _,
                        out("zmm8") _, out("zmm9") _, out("zmm10") _, out("zmm11") _,
                        out("zmm20") _, out("zmm21") _, out("zmm22") _, out("zmm23") _,
                        out("zmm28") _, out("zmm29") _, out("zmm30") _, out("zmm31") _,
                        out("k1") _,
                        options(nostack),
                    );
                }
                best = best.min(t.elapsed().as_secs_f64() * 1e9 / ROUNDS as f64);
            }
            best
        }};
    }

    let base = time!("");
    let rows: [(&str, f64); 15] = [
        ("vcvtdq2ps", time!("vcvtdq2ps zmm20, zmm28\nvcvtdq2ps zmm21, zmm28\nvcvtdq2ps zmm22, zmm28\nvcvtdq2ps zmm23, zmm28")),
        ("vmulps", time!("vmulps zmm20, zmm28, zmm29\nvmulps zmm21, zmm28, zmm29\nvmulps zmm22, zmm28, zmm29\nvmulps zmm23, zmm28, zmm29")),
        ("vcmpltps (to a mask)", time!("vcmpltps k1, zmm28, zmm29\nvcmpltps k1, zmm29, zmm28\nvcmpltps k1, zmm28, zmm29\nvcmpltps k1, zmm29, zmm28")),
        ("vmulps, masked", time!("vmulps zmm20{{k1}}, zmm28, zmm29\nvmulps zmm21{{k1}}, zmm28, zmm29\nvmulps zmm22{{k1}}, zmm28, zmm29\nvmulps zmm23{{k1}}, zmm28, zmm29")),
        ("vmaxps", time!("vmaxps zmm20, zmm28, zmm29\nvmaxps zmm21, zmm28, zmm29\nvmaxps zmm22, zmm28, zmm29\nvmaxps zmm23, zmm28, zmm29")),
        ("vminps", time!("vminps zmm20, zmm28, zmm29\nvminps zmm21, zmm28, zmm29\nvminps zmm22, zmm28, zmm29\nvminps zmm23, zmm28, zmm29")),
        ("vcvtps2dq {rn-sae}", time!("vcvtps2dq zmm20, zmm28, {{rn-sae}}\nvcvtps2dq zmm21, zmm28, {{rn-sae}}\nvcvtps2dq zmm22, zmm28, {{rn-sae}}\nvcvtps2dq zmm23, zmm28, {{rn-sae}}")),
        ("vpaddd", time!("vpaddd zmm20, zmm28, zmm29\nvpaddd zmm21, zmm28, zmm29\nvpaddd zmm22, zmm28, zmm29\nvpaddd zmm23, zmm28, zmm29")),
        ("vpmaxsd", time!("vpmaxsd zmm20, zmm28, zmm29\nvpmaxsd zmm21, zmm28, zmm29\nvpmaxsd zmm22, zmm28, zmm29\nvpmaxsd zmm23, zmm28, zmm29")),
        ("vpcmpgtd (to a mask)", time!("vpcmpgtd k1, zmm28, zmm29\nvpcmpgtd k1, zmm29, zmm28\nvpcmpgtd k1, zmm28, zmm29\nvpcmpgtd k1, zmm29, zmm28")),
        ("vpmovsdb (to 16 bytes)", time!("vpmovsdb xmm20, zmm28\nvpmovsdb xmm21, zmm28\nvpmovsdb xmm22, zmm28\nvpmovsdb xmm23, zmm28")),
        ("vpbroadcastd (from memory)", time!("vpbroadcastd zmm20, [{p}]\nvpbroadcastd zmm21, [{p} + 64]\nvpbroadcastd zmm22, [{p} + 128]\nvpbroadcastd zmm23, [{p} + 192]")),
        ("vmovdqu32 load (64 B)", time!("vmovdqu32 zmm20, [{p}]\nvmovdqu32 zmm21, [{p} + 64]\nvmovdqu32 zmm22, [{p} + 128]\nvmovdqu32 zmm23, [{p} + 192]")),
        ("vmovdqu32 store (32 B)", time!("vmovdqu32 [{p}], ymm28\nvmovdqu32 [{p} + 64], ymm28\nvmovdqu32 [{p} + 128], ymm28\nvmovdqu32 [{p} + 192], ymm28")),
        ("vmovdqu32 store (64 B)", time!("vmovdqu32 [{p}], zmm28\nvmovdqu32 [{p} + 64], zmm28\nvmovdqu32 [{p} + 128], zmm28\nvmovdqu32 [{p} + 192], zmm28")),
    ];
    let again = time!("");
    let slot = base.min(again) / 12.0;
    println!(
        "12 x vpdpbusd zmm: {base:.3} ns per iteration ({:.3} at the end), {:.1} GMAC/s",
        again,
        12.0 * 64.0 / base.min(again)
    );
    println!(
        "{:<28} {:>9} {:>22}",
        "plus 4 x", "ns/iter", "vpdpbusd slots each"
    );
    for (name, t) in rows {
        let cost = (t - base.min(again)) / slot / 4.0;
        println!("{name:<28} {t:9.3} {:>22.2}", cost.max(0.0));
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn main() {
    println!("x86_64 only");
}
