//! A 64-bit monotonic counter from SysTick, and its calibration in instructions.
//!
//! SysTick counts down 24 bits at the core clock; the [`SysTick`] exception counts wraps, so
//! [`ticks`] is a 64-bit count of core-clock ticks since [`start`].
//!
//! Under QEMU the core clock is virtual: with `-icount shift=0` every instruction advances
//! virtual time by exactly 1 ns, and the `mps2-an500` board clocks SysTick at 25 MHz, so one
//! tick is 40 instructions, deterministically. [`calibrate`] measures that ratio on a loop of a
//! known number of instructions instead of assuming it, and the firmware reports instructions
//! (ticks × ratio, resolution one tick). On a real part the same ticks are core cycles.
//! (QEMU implements no DWT cycle counter: CYCCNT reads 0.)

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;

/// SysTick reload value: the full 24 bits.
const RELOAD: u32 = 0x00FF_FFFF;

/// SysTick wraps since [`start`].
static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// Starts SysTick at the core clock, free-running, with the wrap interrupt.
pub fn start(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(RELOAD);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    // The counter reads 0 until its first reload: wait for it, so that `ticks` starts at 0.
    while SYST::get_current() == 0 {}
}

/// Core-clock ticks since [`start`].
pub fn ticks() -> u64 {
    critical_section::with(|_| {
        // A wrap not yet counted shows as a pending SysTick exception (it cannot run inside the
        // critical section). Then the second read is after the counter reached 0: still 0 (the
        // last tick of this period) or reloaded (the next period).
        let before = SYST::get_current();
        let wrapped = SCB::is_pendst_pending();
        let after = SYST::get_current();
        let wraps = u64::from(WRAPS.load(Ordering::Relaxed));
        match (wrapped, after) {
            (true, 0) => wraps << 24 | u64::from(RELOAD),
            (true, _) => (wraps + 1) << 24 | u64::from(RELOAD - after),
            (false, _) => wraps << 24 | u64::from(RELOAD - before),
        }
    })
}

/// Instructions per SysTick tick, measured on a loop of a known number of instructions
/// (2 per iteration: `subs`, `bne`); 40 under `qemu-system-arm -icount shift=0` on
/// `mps2-an500`.
pub fn calibrate() -> u32 {
    const ITERATIONS: u32 = 2_000_000;
    let t0 = ticks();
    let mut n = ITERATIONS;
    // SAFETY: a register-only countdown loop; touches no memory and no stack.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, {n}, #1",
            "bne 2b",
            n = inout(reg) n,
            options(nomem, nostack),
        );
    }
    let _ = n;
    let elapsed = ticks() - t0;
    ((2 * u64::from(ITERATIONS) + elapsed / 2) / elapsed.max(1)) as u32
}
