//! The HardFault handler, on a stack it can trust.
//!
//! `memory.x` puts the stack at the bottom of RAM, so an overflow runs off RAM and faults instead
//! of overwriting the statics. The core then enters HardFault with the stack pointer below RAM:
//! it tries to push the exception frame there, fails, and enters the handler anyway. A handler
//! running on that stack faults again at its first push, and a fault inside HardFault locks the
//! core up: QEMU 7.2 aborts with "Lockup: can't escalate 3 to HardFault (current priority -1)",
//! a board hangs until its watchdog fires, and neither says why.
//!
//! So the `HardFault` vector is eight instructions of assembly that move the main stack pointer
//! back to the top of the stack region before any Rust runs, and pass the stack pointer of the
//! fault on to [`hard_fault`]. The interrupted code never resumes (the handler exits), so
//! overwriting its frames is harmless. What [`hard_fault`] prints:
//! - `hard fault: stack overflow sp=… bottom=… reserved=…` where the stack pointer is below the
//!   stack region,
//! - `hard fault: pc=… lr=…` where the exception frame lies inside the stack region (any other
//!   fault of this image), and `hard fault: sp=… outside the stack region` otherwise,
//!
//! each with the fault status registers (`cfsr`, `hfsr`),
//!
//! and the image exits with code 3. `tests/firmware_qemu.rs` builds the image with the
//! `overflow-test` feature ([`overflow`] at boot) and checks both under QEMU.

use cortex_m_rt::ExceptionFrame;

use crate::{exit, stack};

// The vector. Bit 2 of EXC_RETURN (in `lr`) says which stack held the frame: the firmware runs
// on the main stack (MSP) alone, a port to an RTOS may run its threads on PSP. `_stack_start`
// (memory.x) is the top of the stack region, 8-byte aligned as the AAPCS wants.
core::arch::global_asm!(
    ".section .HardFault.user, \"ax\"",
    ".global HardFault",
    ".type HardFault,%function",
    ".thumb_func",
    "HardFault:",
    "tst lr, #4",
    "ite eq",
    "mrseq r0, MSP",
    "mrsne r0, PSP",
    "movw r1, :lower16:_stack_start",
    "movt r1, :upper16:_stack_start",
    "msr MSP, r1",
    "b {handler}",
    ".size HardFault, . - HardFault",
    handler = sym hard_fault,
);

/// The Rust half of the HardFault handler, entered from the vector on a fresh stack with `sp`,
/// the stack pointer at the fault (where the exception frame was pushed, if pushing worked).
extern "C" fn hard_fault(sp: u32) -> ! {
    // SAFETY: the System Control Block's fault status registers, read-only here.
    let (cfsr, hfsr) = unsafe {
        let scb = &*cortex_m::peripheral::SCB::PTR;
        (scb.cfsr.read(), scb.hfsr.read())
    };
    let (bottom, top) = stack::bounds();
    let at = sp as usize;
    let in_stack = at >= bottom
        && at
            .checked_add(core::mem::size_of::<ExceptionFrame>())
            .is_some_and(|end| end <= top);
    if at < bottom {
        defmt::error!(
            "hard fault: stack overflow sp={=u32:#010x} bottom={=u32:#010x} reserved={=usize} cfsr={=u32:#010x} hfsr={=u32:#010x}",
            sp,
            bottom as u32,
            top - bottom,
            cfsr,
            hfsr
        );
    } else if in_stack {
        // SAFETY: the frame lies inside the stack region (checked above): RAM the core pushed
        // the exception frame to, 4-byte aligned by the architecture.
        let frame = unsafe { &*(at as *const ExceptionFrame) };
        defmt::error!(
            "hard fault: pc={=u32:#010x} lr={=u32:#010x} cfsr={=u32:#010x} hfsr={=u32:#010x}",
            frame.pc(),
            frame.lr(),
            cfsr,
            hfsr
        );
    } else {
        // A frame outside the stack region (another stack, or a corrupted pointer): not read.
        defmt::error!(
            "hard fault: sp={=u32:#010x} outside the stack region cfsr={=u32:#010x} hfsr={=u32:#010x}",
            sp,
            cfsr,
            hfsr
        );
    }
    exit(3)
}

/// Overflows the stack on purpose (the `overflow-test` feature's image calls it at boot): a
/// recursion whose frames the optimizer cannot fold, deeper than any stack this image reserves.
#[cfg(feature = "overflow-test")]
pub fn overflow() {
    #[inline(never)]
    fn deep(n: u32) -> u32 {
        let mut frame = [0u8; 256];
        frame[(n % 256) as usize] = n as u8;
        let frame = core::hint::black_box(&mut frame);
        match n {
            0 => u32::from(frame[0]),
            _ => deep(n - 1).wrapping_add(u32::from(frame[3])),
        }
    }
    let depth = core::hint::black_box(1 << 20);
    defmt::error!("overflow-test: returned {=u32}", deep(depth));
    exit(1)
}
