//! Stack high-water mark: paint the free stack at boot, find the deepest overwritten word later.
//!
//! The stack is the `STACK` region of `memory.x`, `_stack_end.._stack_start`, below the statics.

/// The paint pattern.
const PAINT: u32 = 0xC0FF_EE11;
/// Bytes left unpainted below the stack pointer when painting (the painting function's own
/// frame, and the exception frame an interrupt would push).
const MARGIN: usize = 128;

extern "C" {
    // Defined in memory.x.
    static _stack_start: u32;
    static _stack_end: u32;
}

/// The stack region, `(bottom, top)`: `_stack_end` and `_stack_start` of memory.x.
pub fn bounds() -> (usize, usize) {
    // Only the addresses of the linker symbols are used, never their contents.
    (
        core::ptr::addr_of!(_stack_end) as usize,
        core::ptr::addr_of!(_stack_start) as usize,
    )
}

/// The stack reservation in bytes.
pub fn size() -> usize {
    let (bottom, top) = bounds();
    top - bottom
}

/// Fills the unused stack below the current stack pointer with the pattern.
pub fn paint() {
    let (bottom, _) = bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let mut a = bottom;
    while a + 4 <= sp - MARGIN {
        // SAFETY: `a` lies in the stack region below the live stack (the stack pointer minus a
        // margin), which no Rust object occupies; an interrupt that pushes a frame there
        // restores nothing from it after returning.
        unsafe { (a as *mut u32).write_volatile(PAINT) };
        a += 4;
    }
}

/// Deepest stack use since [`paint`], in bytes.
pub fn high_water() -> usize {
    let (bottom, top) = bounds();
    let mut a = bottom;
    // SAFETY: reads of the stack region, aligned, below the live stack or part of it.
    while a < top && unsafe { (a as *const u32).read_volatile() } == PAINT {
        a += 4;
    }
    top - a
}
