//! The 32-byte streaming store `kin bench` compares with the 16-byte one the batch calls use
//! ([`kin_model::jit::stream`]): a measurement of whether the wider store writes faster, which
//! the library keeps out of its own code until it does.

/// [`copy`](kin_model::jit::stream::copy) with 32-byte streaming stores (`vmovntpd`), where the
/// CPU has AVX; the 16-byte copy elsewhere. Used by `kin bench` to measure whether the wider store writes faster.
pub(crate) fn copy_wide(dst: &mut [f64], src: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked just above.
        unsafe { copy_avx(dst, src) };
        return;
    }
    kin_model::jit::stream::copy(dst, src);
}

/// The body of [`copy_wide`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn copy_avx(dst: &mut [f64], src: &[f64]) {
    use std::arch::x86_64::{_mm256_loadu_pd, _mm256_stream_pd};
    let len = dst.len().min(src.len());
    let mut i = 0;
    // Ordinary stores up to the first 32-byte boundary.
    while i < len && !(dst.as_ptr().wrapping_add(i) as usize).is_multiple_of(32) {
        if let (Some(d), Some(s)) = (dst.get_mut(i), src.get(i)) {
            *d = *s;
        }
        i += 1;
    }
    while i + 4 <= len {
        // SAFETY: `i + 4 <= len` keeps the reads inside `src` and the writes inside `dst`;
        // `dst + i` is 32-byte aligned (the loop above), as `vmovntpd` requires.
        unsafe {
            let v = _mm256_loadu_pd(src.as_ptr().add(i));
            _mm256_stream_pd(dst.as_mut_ptr().add(i), v);
        }
        i += 4;
    }
    if let (Some(d), Some(s)) = (dst.get_mut(i..len), src.get(i..len)) {
        d.copy_from_slice(s);
    }
}

#[cfg(test)]
mod tests {
    use super::copy_wide;

    #[test]
    fn copies_every_value_at_any_alignment_and_length() {
        let src: Vec<f64> = (0..37).map(|i| i as f64 * 1.5 - 7.0).collect();
        let mut big = vec![0.0; 64];
        for (start, len) in (0..5).flat_map(|s| [0, 1, 2, 3, 5, 8, 33, 37].map(|l| (s, l))) {
            big.fill(f64::NAN);
            copy_wide(&mut big[start..start + len], &src[..len]);
            kin_model::jit::stream::fence();
            assert_eq!(&big[start..start + len], &src[..len], "at {start}, {len}");
            assert!(big[start + len].is_nan(), "wrote past the end");
            if start > 0 {
                assert!(big[start - 1].is_nan(), "wrote before the start");
            }
        }
    }
}
