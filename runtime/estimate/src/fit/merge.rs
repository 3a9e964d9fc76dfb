//! Triangles from different row sets merged into one (TSQR), and the solve of a triangle, for
//! fits whose rows are spread over processes or machines (the Python package's `StreamingFit`).
//!
//! Each worker streams its rows through a [`StreamingQr`](super::StreamingQr) and keeps only its
//! `k × k` triangle `Rᵢ` of `[Xᵢ | yᵢ]`. Stacking two triangles and refactoring,
//! `QR([R₁; R₂]) = Q R`, gives `RᵀR = R₁ᵀR₁ + R₂ᵀR₂ = [X y]ᵀ[X y]` of all the rows: the triangle
//! one stream over every row would have reached (up to the signs of its rows, which no
//! solution depends on). Merging is associative, so partitions can be merged pairwise in a
//! tree, in any grouping.

use faer::Mat;
use thiserror::Error;

use super::qr::Reduced;
use super::solve::{self, Solution, Solver};

#[derive(Debug, Error, PartialEq, Eq)]
pub enum MergeError {
    #[error("cannot merge a triangle of {got} columns into one of {expected}")]
    Columns { expected: usize, got: usize },
}

/// The triangle of the rows of both `a` and `b` (QR of the stacked triangles), with the row
/// counts, column norms and sums of `y` added.
pub fn merge(a: &Reduced, b: &Reduced) -> Result<Reduced, MergeError> {
    let k = a.r.ncols();
    if b.r.ncols() != k || b.norms.len() != a.norms.len() {
        return Err(MergeError::Columns {
            expected: k,
            got: b.r.ncols(),
        });
    }
    let stacked = Mat::from_fn(
        2 * k,
        k,
        |i, j| {
            if i < k {
                a.r[(i, j)]
            } else {
                b.r[(i - k, j)]
            }
        },
    );
    let qr = stacked.qr();
    let thin = qr.thin_R();
    let r = Mat::from_fn(k, k, |i, j| if j >= i { thin[(i, j)] } else { 0.0 });
    // ‖y‖² is the squared norm of R's last column, as `StreamingQr::finish` states it.
    let y_sumsq = (0..k).map(|i| r[(i, k - 1)].powi(2)).sum();
    Ok(Reduced {
        r,
        rows: a.rows + b.rows,
        norms: a
            .norms
            .iter()
            .zip(&b.norms)
            .map(|(x, y)| x.hypot(*y))
            .collect(),
        y_sum: a.y_sum + b.y_sum,
        y_sumsq,
    })
}

/// A triangle given row-major (`k × k`, as a worker sent it) with its row count, the column
/// norms of X and the sum of y: the [`Reduced`] [`merge`] and [`solve_triangle`] take. Entries
/// below the diagonal are ignored; `‖y‖²` is that of R's last column.
pub fn from_triangle(
    k: usize,
    r: &[f64],
    rows: usize,
    norms: Vec<f64>,
    y_sum: f64,
) -> Result<Reduced, MergeError> {
    if k == 0 || r.len() != k * k || norms.len() + 1 != k {
        return Err(MergeError::Columns {
            expected: k,
            got: norms.len() + 1,
        });
    }
    let r = Mat::from_fn(k, k, |i, j| if j >= i { r[i * k + j] } else { 0.0 });
    let y_sumsq = (0..k).map(|i| r[(i, k - 1)].powi(2)).sum();
    Ok(Reduced {
        r,
        rows,
        norms,
        y_sum,
        y_sumsq,
    })
}

/// The least-squares solution of a triangle, by the fit's own solver (unit-scaled columns, the
/// rank decided at relative tolerance `tolerance`, the covariance factor of eq. 4.11). A
/// rank-deficient problem comes back as `Err` with its rank and null space, or, with
/// `min_norm`, as the minimum-norm solution.
// As `solve::solve`: both outcomes carry a whole solution.
#[allow(clippy::result_large_err)]
pub fn solve_triangle(
    red: &Reduced,
    solver: Solver,
    tolerance: f64,
    min_norm: bool,
) -> Result<Solution, Solution> {
    solve::solve(red, solver, tolerance, min_norm)
}

#[cfg(test)]
mod tests {
    use super::super::StreamingQr;
    use super::*;
    use rand::{Rng, SeedableRng};

    fn rows(seed: u64, m: usize, p: usize) -> Vec<(Vec<f64>, f64)> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let truth: Vec<f64> = (0..p).map(|j| 1.0 + j as f64).collect();
        (0..m)
            .map(|_| {
                let x: Vec<f64> = (0..p).map(|_| rng.random_range(-1.0..1.0)).collect();
                let y = x.iter().zip(&truth).map(|(a, b)| a * b).sum::<f64>()
                    + 1e-3 * rng.random_range(-1.0..1.0);
                (x, y)
            })
            .collect()
    }

    fn stream(rows: &[(Vec<f64>, f64)], p: usize) -> Reduced {
        let mut acc = StreamingQr::new(p, 37);
        for (x, y) in rows {
            acc.push(x, *y);
        }
        acc.finish()
    }

    #[test]
    fn four_merged_partitions_give_the_single_stream_solution() {
        let p = 6;
        let all = rows(7, 2000, p);
        let whole = stream(&all, p);
        let parts: Vec<Reduced> = all.chunks(500).map(|c| stream(c, p)).collect();
        // A tree, not a chain: ((0 1) (2 3)).
        let left = merge(&parts[0], &parts[1]).expect("same columns");
        let right = merge(&parts[2], &parts[3]).expect("same columns");
        let merged = merge(&left, &right).expect("same columns");
        assert_eq!(merged.rows, 2000);
        let a = solve_triangle(&whole, Solver::Qr, 1e-10, false).expect("full rank");
        let b = solve_triangle(&merged, Solver::Qr, 1e-10, false).expect("full rank");
        for (x, y) in a.beta.iter().zip(&b.beta) {
            assert!((x - y).abs() <= 1e-12 * x.abs().max(1.0), "{x} vs {y}");
        }
        assert!((a.rss - b.rss).abs() <= 1e-9 * a.rss);
        assert!((whole.y_sumsq - merged.y_sumsq).abs() <= 1e-12 * whole.y_sumsq);
        // Sent as numbers and rebuilt, a triangle is the same triangle.
        let k = p + 1;
        let flat: Vec<f64> = (0..k * k).map(|i| merged.r[(i / k, i % k)]).collect();
        let back = from_triangle(k, &flat, merged.rows, merged.norms.clone(), merged.y_sum)
            .expect("k × k");
        let c = solve_triangle(&back, Solver::Qr, 1e-10, false).expect("full rank");
        assert_eq!(b.beta, c.beta);
        for (x, y) in whole.norms.iter().zip(&merged.norms) {
            assert!((x - y).abs() <= 1e-12 * x);
        }
    }

    #[test]
    fn triangles_of_different_sizes_do_not_merge() {
        let a = stream(&rows(1, 20, 3), 3);
        let b = stream(&rows(2, 20, 4), 4);
        assert_eq!(
            merge(&a, &b).map(|_| ()),
            Err(MergeError::Columns {
                expected: 4,
                got: 5
            })
        );
    }
}
