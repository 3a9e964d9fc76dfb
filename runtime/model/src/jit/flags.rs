//! The processor's sticky floating-point exception flags (per thread), read after a call of
//! generated code to learn, without looking at its outputs, that none of them is infinite or NaN.
//!
//! Every operation of the generated code and of the routines it calls (`sincos`, `fmod`) is an
//! IEEE operation on the processor's vector unit, which raises a flag when it produces an
//! infinity or a NaN from operands that were neither: *overflow* (a finite result too large),
//! *division by zero*, or *invalid operation* (`0·∞`, `∞ − ∞`, …). An infinity or a NaN among
//! the outputs can therefore come only from an input that was one or from an operation that
//! raised one of these three flags — the flags stay set until cleared ("sticky"). So when the
//! values a call reads are finite and none of the three flags went up during the call, every
//! output is finite: the test costs one read of the status register after the call (the flags
//! are cleared whenever found up, so up after a call means raised since the last look), where a
//! pass over a Jacobian's outputs reads every entry again (issue 36: a tenth of a C ABI call).
//!
//! The converse does not hold — an intermediate may overflow and still give a finite output
//! (`1/∞ = 0`), or other code of the thread may have raised a flag since the last read — so a
//! raised flag means only "look at the values", never "a value is bad".
//!
//! Where the flags cannot be read (an architecture other than x86-64 and AArch64), [`quiet`]
//! answers `false` and the caller looks at every value, as before.

/// The flags of invalid operation, division by zero and overflow in the status register:
/// MXCSR's IE (bit 0), ZE (bit 2), OE (bit 3) on x86-64; FPSR's IOC (bit 0), DZC (bit 1), OFC
/// (bit 2) on AArch64.
#[cfg(target_arch = "x86_64")]
const RAISED: u64 = 0b1101;
#[cfg(target_arch = "aarch64")]
const RAISED: u64 = 0b111;

/// The status register's value.
#[cfg(target_arch = "x86_64")]
fn status() -> u64 {
    let mut csr: u32 = 0;
    // SAFETY: `stmxcsr` writes the 4 bytes of `csr`, a live local, and nothing else.
    unsafe {
        std::arch::asm!(
            "stmxcsr [{p}]",
            p = in(reg) &mut csr,
            options(nostack, preserves_flags)
        );
    }
    u64::from(csr)
}

/// Sets the status register (only its sticky flags change: `value` is what [`status`] read,
/// with some flags cleared).
#[cfg(target_arch = "x86_64")]
fn set_status(value: u64) {
    // MXCSR is 32 bits wide: `value` came from it.
    let csr = value as u32;
    // SAFETY: `ldmxcsr` reads the 4 bytes of `csr`; the control bits (rounding, masks) are the
    // ones just read, so only the cleared status flags change.
    unsafe {
        std::arch::asm!(
            "ldmxcsr [{p}]",
            p = in(reg) &csr,
            options(nostack, preserves_flags, readonly)
        );
    }
}

#[cfg(target_arch = "aarch64")]
fn status() -> u64 {
    let fpsr: u64;
    // SAFETY: reads FPSR into a register, nothing else.
    unsafe {
        std::arch::asm!("mrs {x}, fpsr", x = out(reg) fpsr, options(nomem, nostack, preserves_flags));
    }
    fpsr
}

#[cfg(target_arch = "aarch64")]
fn set_status(value: u64) {
    // SAFETY: FPSR holds only status flags: writing back what was read, with some cleared.
    unsafe {
        std::arch::asm!("msr fpsr, {x}", x = in(reg) value, options(nomem, nostack, preserves_flags));
    }
}

/// Whether none of the three flags is up, clearing them if any is: after a call, `true`
/// says that no operation since the last time a flag was found up (and cleared) raised one —
/// in particular none of the call's. One read of the status register per call, the cheap
/// case: the register is written only when a flag is found up (the register's read waits for
/// the operations before it to finish; a write is slower still). `false` where the flags
/// cannot be read.
pub(super) fn quiet() -> bool {
    #[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
    {
        let s = status();
        if s & RAISED == 0 {
            return true;
        }
        set_status(s & !RAISED);
        false
    }
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    false
}

#[cfg(test)]
mod tests {
    use super::quiet;
    use std::hint::black_box;

    #[test]
    #[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
    fn an_overflow_an_invalid_operation_and_a_division_by_zero_are_seen() {
        let big: f64 = black_box(1e300);
        quiet();
        assert!(black_box(big * 2.0).is_finite());
        assert!(quiet(), "finite arithmetic raises none of the three");
        assert!(black_box(big * big).is_infinite());
        assert!(!quiet(), "overflow");
        assert!(quiet(), "the flags were cleared when found up");
        let inf = black_box(f64::INFINITY);
        assert!(black_box(inf - inf).is_nan());
        assert!(!quiet(), "invalid operation");
        assert!(black_box(1.0 / black_box(0.0f64)).is_infinite());
        assert!(!quiet(), "division by zero");
        // A NaN or an infinity passed along raises nothing: the inputs' finiteness is the
        // caller's to check.
        assert!(black_box(black_box(f64::NAN) + 1.0).is_nan());
        assert!(black_box(inf * 2.0).is_infinite());
        assert!(quiet());
        // An underflow and an inexact result are not among the three.
        assert!(black_box(black_box(1e-300) * 1e-300) == 0.0);
        assert!(black_box(black_box(1.0) / 3.0) > 0.0);
        assert!(quiet());
    }
}
