//! The AMX tile unit's instruction rates on this CPU, one thread: nanoseconds per `tdpbsud`
//! (independent products on resident tiles), per `tileloadd` and per `tilestored` (1 KiB tiles,
//! rows 64 bytes apart, data in L1), and per group of the int8 kernel's pattern (two input and
//! two weight tile loads, four products: `core/src/kernels/x86/amx.rs`). What bounds the tile
//! kernel where loads are slower than products: the pattern's 65,536 MACs per group cannot run
//! faster than its four loads.
//!
//! `cargo run --release -p evpose-core --example amx_rates` (x86_64 Linux with AMX-INT8; prints
//! why not elsewhere).
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
fn main() {
    use core::arch::asm;
    use evpose_core::kernels::{x86::request_tile_data, Isa};
    use std::time::Instant;

    if !Isa::X86Amx.is_supported_here() || !request_tile_data() {
        println!("no AMX-INT8 here (or the OS did not grant the tile state)");
        return;
    }
    #[repr(C, align(64))]
    struct Config([u8; 64]);
    let mut c = [0u8; 64];
    c[0] = 1; // palette 1: eight tiles of 16 rows × 64 bytes
    for t in 0..8 {
        c[16 + 2 * t] = 64;
        c[48 + t] = 16;
    }
    let config = Config(c);
    // 32 KiB of data (L1) and 4 KiB to store into.
    #[repr(C, align(64))]
    struct Data([u8; 36 * 1024]);
    let mut data = Box::new(Data([0; 36 * 1024]));
    for (i, b) in data.0.iter_mut().enumerate() {
        *b = (i * 7 % 251) as u8;
    }
    let p = data.0.as_mut_ptr();
    const ROUNDS: u64 = 200_000;
    let names = [
        "4 x tdpbsud (resident tiles)",
        "4 x tileloadd (1 KiB, L1)",
        "4 x tilestored (1 KiB)",
        "kernel group: 4 loads + 4 products",
        "4 x tileloadd, rows 16 bytes off a line",
        "kernel group, rows 16 bytes off a line",
    ];
    for (which, name) in names.iter().enumerate() {
        let mut best = f64::MAX;
        for _ in 0..7 {
            let t = Instant::now();
            for i in 0..ROUNDS {
                // SAFETY: AMX is present and granted (checked above); `ldtilecfg` reads the
                // 64-byte palette-1 configuration; every load reads 16 rows of 64 bytes inside
                // `data`'s first 32 KiB (from offsets below 24 KiB + 16 bytes, 4 KiB each),
                // every store writes the 4 KiB from 32 KiB on; nothing else is touched.
                unsafe {
                    if i == 0 {
                        asm!("ldtilecfg [{}]", in(reg) config.0.as_ptr(),
                            out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
                            out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _);
                    }
                    // The last two rows: every load 16 bytes past a line, so that each 64-byte
                    // row straddles two (as rows of an unaligned buffer do).
                    let a = p.add((i as usize % 7) * 4096 + if which >= 4 { 16 } else { 0 });
                    match which {
                        0 => asm!("tdpbsud tmm0, tmm4, tmm6", "tdpbsud tmm1, tmm4, tmm7",
                            "tdpbsud tmm2, tmm5, tmm6", "tdpbsud tmm3, tmm5, tmm7",
                            out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _),
                        1 | 4 => asm!("tileloadd tmm4, [{a} + {s}*1]",
                            "tileloadd tmm5, [{a} + {s}*1 + 1024]",
                            "tileloadd tmm6, [{a} + {s}*1 + 2048]",
                            "tileloadd tmm7, [{a} + {s}*1 + 3072]",
                            a = in(reg) a, s = in(reg) 64usize,
                            out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _),
                        2 => asm!("tilestored [{a} + {s}*1], tmm0",
                            "tilestored [{a} + {s}*1 + 1024], tmm1",
                            "tilestored [{a} + {s}*1 + 2048], tmm2",
                            "tilestored [{a} + {s}*1 + 3072], tmm3",
                            a = in(reg) p.add(32 * 1024), s = in(reg) 64usize),
                        _ => asm!("tileloadd tmm4, [{a} + {s}*1]",
                            "tileloadd tmm6, [{a} + {s}*1 + 1024]",
                            "tdpbsud tmm0, tmm4, tmm6",
                            "tileloadd tmm7, [{a} + {s}*1 + 2048]",
                            "tdpbsud tmm1, tmm4, tmm7",
                            "tileloadd tmm5, [{a} + {s}*1 + 3072]",
                            "tdpbsud tmm2, tmm5, tmm6",
                            "tdpbsud tmm3, tmm5, tmm7",
                            a = in(reg) a, s = in(reg) 64usize,
                            out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
                            out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _),
                    }
                }
            }
            // SAFETY: AMX is present and granted; `tilerelease` touches no memory.
            unsafe { asm!("tilerelease") };
            best = best.min(t.elapsed().as_secs_f64());
        }
        let ns = best / ROUNDS as f64 * 1e9;
        let gmacs = if matches!(which, 1 | 2 | 4) {
            String::new()
        } else {
            format!("  ({:.0} GMAC/s)", 4.0 * 16384.0 / ns)
        };
        println!("{name:36} {ns:7.2} ns per group of four{gmacs}");
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn main() {
    println!("AMX is x86_64 only");
}
