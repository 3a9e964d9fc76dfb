//! `C += α·A·Aᵀ` on the lower triangle of a square `C`, split over the machine's cores.
//!
//! The identifiability analysis spends nearly all its time in this one shape: accumulating the
//! Gram matrix of blocks of design rows, and the trailing update of its blocked Cholesky
//! factorisation. faer's own parallelism would come with its rayon feature, which also makes
//! every other faer call in the process parallel by default (the fit's QR and SVD, the C ABI's
//! host program): here the threads are scoped to this call instead.
//!
//! The lower triangle is cut into vertical strips of equal work (a strip of columns `a..b` of an
//! `m × m` triangle holds `∫ₐᵇ (m − x) dx` entries), each strip a small triangle on the
//! diagonal and a rectangle below it; every strip goes to its own thread, so no entry is written
//! by two threads and the sums are the same whatever the number of threads.

use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use faer::{Accum, MatMut, MatRef, Par};

/// Below this many rows the whole update runs on the calling thread: a thread costs tens of
/// microseconds, a 256 × 256 × 64 update about a millisecond.
const PARALLEL_FROM: usize = 256;

/// Threads to use: the cores this process may run on (1 when that cannot be told).
pub fn threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `c += alpha · a · aᵀ` on the lower triangle of `c` (`c` square, `a` with as many rows).
/// Entries above the diagonal are neither read nor written.
pub fn lower(c: MatMut<'_, f64>, a: MatRef<'_, f64>, alpha: f64) {
    let m = c.nrows();
    if m == 0 || a.nrows() != m || c.ncols() != m {
        return;
    }
    let threads = threads().min(m / PARALLEL_FROM).max(1);
    if threads == 1 {
        strip(c, a, alpha);
        return;
    }
    // Strip boundaries: the cumulative work m·x − x²/2 reaches i/k of m²/2 at
    // x = m·(1 − √(1 − i/k)).
    let mut cuts: Vec<usize> = (0..=threads)
        .map(|i| {
            let x = m as f64 * (1.0 - (1.0 - i as f64 / threads as f64).max(0.0).sqrt());
            (x.round() as usize).min(m)
        })
        .collect();
    if let Some(last) = cuts.last_mut() {
        *last = m;
    }
    std::thread::scope(|scope| {
        let mut rest = c;
        let mut from = 0usize;
        for &to in cuts.iter().skip(1) {
            let width = to.saturating_sub(from);
            if width == 0 {
                continue;
            }
            // `rest` is the square trailing triangle from row/column `from`.
            let (left, right) = rest.split_at_col_mut(width);
            let (_, next) = right.split_at_row_mut(width);
            let rows = a.subrows(from, m - from);
            if to == m {
                // The last strip runs here: one thread fewer to start.
                strip(left, rows, alpha);
            } else {
                scope.spawn(move || strip(left, rows, alpha));
            }
            rest = next;
            from = to;
        }
    });
}

/// One strip: `c` holds the strip's columns from its diagonal down (`rows × width`, the top
/// `width × width` a triangle), `a` the matching rows of the factor.
fn strip(c: MatMut<'_, f64>, a: MatRef<'_, f64>, alpha: f64) {
    let width = c.ncols();
    let (top, below) = c.split_at_row_mut(width);
    let (a_top, a_below) = a.split_at_row(width);
    matmul(
        top,
        BlockStructure::TriangularLower,
        Accum::Add,
        a_top,
        BlockStructure::Rectangular,
        a_top.transpose(),
        BlockStructure::Rectangular,
        alpha,
        Par::Seq,
    );
    if below.nrows() > 0 {
        faer::linalg::matmul::matmul(
            below,
            Accum::Add,
            a_below,
            a_top.transpose(),
            alpha,
            Par::Seq,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    #[test]
    fn the_split_update_equals_the_plain_product_on_the_lower_triangle() {
        for (m, k) in [(1, 1), (7, 3), (300, 17), (1100, 40)] {
            let a = Mat::from_fn(m, k, |i, j| ((i * 7 + j * 13) % 11) as f64 - 5.0);
            let mut c = Mat::from_fn(m, m, |i, j| (i + 2 * j) as f64);
            let before = c.clone();
            lower(c.as_mut(), a.as_ref(), -0.5);
            for j in 0..m {
                for i in 0..m {
                    let want = if i >= j {
                        before[(i, j)] - 0.5 * (0..k).map(|l| a[(i, l)] * a[(j, l)]).sum::<f64>()
                    } else {
                        before[(i, j)]
                    };
                    assert_eq!(c[(i, j)], want, "({i}, {j}) of {m} × {m}");
                }
            }
        }
    }
}
