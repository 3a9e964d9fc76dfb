//! Writing the batch path's Jacobian blocks out with streaming (non-temporal) stores.
//!
//! A batch of design-matrix rows is written once and read much later (by the fit's QR, a
//! block at a time), and at 6 × n values per pose it is far larger than any cache. An ordinary
//! store to a line not in the cache first reads the line from memory ("read for ownership"),
//! then writes it back when it is evicted: two transfers per line written, and the evicted
//! lines push the code's own working set out. A streaming store goes to a write-combining
//! buffer and on to memory as whole lines, never reading them: one transfer.
//!
//! Cranelift 0.135 has no non-temporal store (its `MemFlags` carry no such hint and its x64
//! back end emits `movnt*` for nothing), so the generated code keeps writing a pose's block
//! into a scratch buffer that stays in the first-level cache, and this module copies the
//! block out with `movntpd`, which SSE2 — part of every x86-64 CPU — provides. Elsewhere the
//! copy is an ordinary one.

/// Destinations smaller than this are written directly: they fit in the last-level cache of
/// a common CPU (up to 32 MiB), from which the caller reads them back and where an ordinary
/// store is cheap. Measured with `kin bench` on the 5-axis example, JIT batch ÷ the
/// hand-written evaluator's batch with ordinary stores, in the same run: with streaming from
/// 1 MiB on, 0.78 (six rows) and 0.59 (position rows) at 1000 poses (8 and 4 MB, inside this
/// computer's 32 MiB cache), 1.56 and 1.18 at 20 000 poses (166 and 83 MB).
const STREAM_BYTES: usize = 32 << 20;

/// Below this a destination is taken to stay in a core's second-level cache (256 KiB to
/// 2 MiB on current x86-64 CPUs): a consumer reusing one block of rows (the blocks of
/// `kin bench`, 256 KiB) finds its lines there already, and requesting them again for writing
/// only costs the requests.
const CACHED_BYTES: usize = 1 << 20;

/// Whether a destination of `values` f64s is larger than a core's second-level cache, where
/// requesting the next pose's lines for writing ([`prefetch_for_writing`]) pays.
pub(crate) fn beyond_cache(values: usize) -> bool {
    values.saturating_mul(8) > CACHED_BYTES
}

/// Whether a destination of `values` f64s is large enough for streaming stores to pay.
pub(crate) fn worth_it(values: usize) -> bool {
    cfg!(target_arch = "x86_64") && values.saturating_mul(8) >= STREAM_BYTES
}

/// Copies `src` to `dst` (the shorter length) with streaming stores where the destination is
/// 16-byte aligned, ordinary ones for an unaligned first and a last value.
pub fn copy(dst: &mut [f64], src: &[f64]) {
    let len = dst.len().min(src.len());
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_loadu_pd, _mm_stream_pd};
        let mut i = 0;
        if !(dst.as_ptr() as usize).is_multiple_of(16) && len > 0 {
            if let (Some(d), Some(s)) = (dst.first_mut(), src.first()) {
                *d = *s;
            }
            i = 1;
        }
        while i + 2 <= len {
            // SAFETY: `i + 2 <= len` keeps both reads inside `src` and both writes inside `dst`;
            // `dst + i` is 16-byte aligned (an f64 slice is 8-byte aligned, and `i` was made
            // odd exactly when the start was not 16-byte aligned), as `movntpd` requires;
            // `_mm_loadu_pd` needs no alignment. SSE2 is part of the x86-64 base.
            unsafe {
                let v = _mm_loadu_pd(src.as_ptr().add(i));
                _mm_stream_pd(dst.as_mut_ptr().add(i), v);
            }
            i += 2;
        }
        if let (Some(d), Some(s)) = (dst.get_mut(i..len), src.get(i..len)) {
            d.copy_from_slice(s);
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    if let (Some(d), Some(s)) = (dst.get_mut(..len), src.get(..len)) {
        d.copy_from_slice(s);
    }
}

/// Asks for the `len` f64s from `start` to be brought into the cache for writing
/// (`prefetchw`), a line at a time: a hint, which reads and changes no memory. The batch path
/// requests the next pose's block before evaluating a pose, so that the reads for ownership
/// of its lines overlap with the evaluation instead of stalling its stores (`kin bench`,
/// 5-axis example, 1000 poses into 8 MB: the generated code storing straight into the output
/// at 0.68 × the rate per pose without, 0.81 × with; no change past the last-level cache,
/// where the memory's rate bounds either).
pub fn prefetch_for_writing(start: *const f64, len: usize) {
    #[cfg(target_arch = "x86_64")]
    for i in (0..len).step_by(8) {
        // SAFETY: a prefetch never faults and changes no memory; the address is only computed
        // (`wrapping_add`), never dereferenced.
        unsafe {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_ET0};
            _mm_prefetch::<_MM_HINT_ET0>(start.wrapping_add(i).cast::<i8>());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (start, len);
}

/// Orders the streaming stores before every later store, so that whoever reads the
/// destination next (another thread included, once it is handed over) sees them.
pub fn fence() {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `sfence` has no operands and SSE is part of the x86-64 base.
    unsafe {
        std::arch::x86_64::_mm_sfence();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_every_value_at_any_alignment_and_length() {
        let src: Vec<f64> = (0..37).map(|i| i as f64 * 1.5 - 7.0).collect();
        let mut big = vec![0.0; 64];
        for (start, len) in (0..5).flat_map(|s| [0, 1, 2, 3, 5, 8, 33, 37].map(|l| (s, l))) {
            big.fill(f64::NAN);
            let dst = &mut big[start..start + len];
            copy(dst, &src[..len]);
            fence();
            assert_eq!(&big[start..start + len], &src[..len], "at {start}, {len}");
            assert!(big[start + len].is_nan(), "wrote past the end");
            if start > 0 {
                assert!(big[start - 1].is_nan(), "wrote before the start");
            }
        }
    }
}
