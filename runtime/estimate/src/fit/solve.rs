//! Solving the reduced problem `min ‖R_X β − z‖` with unit-length column scaling (thesis
//! §3.2.2), a rank decision with a stated tolerance, and the covariance of eq. 4.11.
//!
//! With `D = diag(1/‖xⱼ‖)` the scaled triangle is `R_s = R_X D`; `R_sᵀR_s = (XD)ᵀ(XD)`, so every
//! statement about the scaled design matrix can be made on the small `p × p` triangle.

use faer::Mat;
use serde::Serialize;

use super::qr::Reduced;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Solver {
    /// Column-pivoted QR of the scaled triangle: rank from its diagonal.
    Qr,
    /// Singular value decomposition of the scaled triangle: rank from the singular values.
    Svd,
}

/// The estimate and what is needed for its statistics.
#[derive(Debug, Clone)]
pub struct Solution {
    /// All columns (coefficients, then nuisance), SI.
    pub beta: Vec<f64>,
    pub rank: usize,
    /// Residual sum of squares.
    pub rss: f64,
    /// `G` (rank × p) with `(XᵀX)⁺ = GᵀG`: covariance `σ̂²GᵀG` (eq. 4.11) and leverage
    /// `h = ‖G x‖²` of a row x (the quadratic form of eq. 4.12).
    pub g: Mat<f64>,
    /// Directions the data cannot see, in unit-scaled coordinates (rank-deficient fits).
    pub null: Mat<f64>,
    /// Largest over smallest retained singular value (or pivot) of the scaled problem.
    pub condition: f64,
    /// Column scale factors `1/‖xⱼ‖` (0 for a column with no effect at all).
    pub scale: Vec<f64>,
}

/// The scaled triangle `R_s`, row-major, for naming dependencies with the identifiability code.
pub(crate) fn scaled_triangle(red: &Reduced) -> (Vec<f64>, Vec<f64>) {
    let p = red.norms.len();
    let biggest = red.norms.iter().copied().fold(0.0, f64::max);
    let scale: Vec<f64> = red
        .norms
        .iter()
        .map(|&n| {
            if n > 1e-14 * biggest && n > 0.0 {
                1.0 / n
            } else {
                0.0
            }
        })
        .collect();
    let mut rs = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..p {
            rs[i * p + j] = red.r[(i, j)] * scale[j];
        }
    }
    (rs, scale)
}

/// The rank decision of the thesis' procedure on a unit-scaled triangle `rs` (see
/// [`scaled_triangle`]): a column-pivoted QR, and the columns whose pivot exceeds `tol` times
/// the first. Returns the rank, the ratio of the first to the last retained pivot, and the
/// columns in pivot order (the first `rank` of them independent).
pub(crate) fn pivoted_rank(rs: &Mat<f64>, tol: f64) -> (usize, f64, Vec<usize>) {
    let p = rs.ncols();
    if p == 0 {
        return (0, f64::INFINITY, Vec::new());
    }
    let piv = rs.col_piv_qr();
    let r2 = piv.R();
    let d0 = r2[(0, 0)].abs();
    let rank = (0..p.min(rs.nrows()))
        .take_while(|&i| r2[(i, i)].abs() > tol * d0)
        .count();
    let cond = if rank > 0 {
        d0 / r2[(rank - 1, rank - 1)].abs()
    } else {
        f64::INFINITY
    };
    (rank, cond, piv.P().arrays().0.to_vec())
}

// Both outcomes carry a whole solution, once per fit: boxing it would buy nothing.
#[allow(clippy::result_large_err)]
/// Solves with the rank decided at relative tolerance `tol`. `min_norm` gives the minimum-norm
/// solution of a rank-deficient problem (on the unit-scaled columns); without it a deficient
/// problem returns `Err(solution-with-null-space)` so the caller can name what is invisible.
pub fn solve(
    red: &Reduced,
    solver: Solver,
    tol: f64,
    min_norm: bool,
) -> Result<Solution, Solution> {
    let p = red.norms.len();
    let (rs_flat, scale) = scaled_triangle(red);
    let rs = Mat::from_fn(p, p, |i, j| rs_flat[i * p + j]);
    let z: Vec<f64> = (0..p).map(|i| red.r[(i, p)]).collect();
    let rss_full = red.r[(p, p)].powi(2);

    let qr_rank = |tol: f64| -> (usize, f64) {
        let (rank, cond, _) = pivoted_rank(&rs, tol);
        (rank, cond)
    };

    // The SVD of the small triangle gives both the pseudo-inverse and the null space; the
    // pivoted QR decides the rank by default, as the thesis' procedure does.
    let svd = rs.thin_svd();
    let (u, s, v) = match &svd {
        Ok(d) => (
            d.U().to_owned(),
            d.S().column_vector().iter().copied().collect::<Vec<f64>>(),
            d.V().to_owned(),
        ),
        Err(_) => (Mat::zeros(p, 0), Vec::new(), Mat::zeros(p, 0)),
    };
    let s_max = s.first().copied().unwrap_or(0.0);
    let (rank, condition) = match solver {
        Solver::Qr if p > 0 => qr_rank(tol),
        _ => {
            let r = s.iter().take_while(|&&x| x > tol * s_max).count();
            (
                r,
                if r > 0 {
                    s_max / s[r - 1]
                } else {
                    f64::INFINITY
                },
            )
        }
    };
    // The retained singular directions: as many as the rank.
    let keep = rank.min(s.len());
    let g_scaled = Mat::from_fn(keep, p, |k, j| v[(j, k)] / s[k]);
    let mut b = vec![0.0; p];
    for k in 0..keep {
        let uz: f64 = (0..p).map(|i| u[(i, k)] * z[i]).sum();
        for j in 0..p {
            b[j] += v[(j, k)] * uz / s[k];
        }
    }
    // What the dropped directions would have explained stays in the residual.
    let dropped: f64 = (keep..s.len())
        .map(|k| (0..p).map(|i| u[(i, k)] * z[i]).sum::<f64>().powi(2))
        .sum();
    let g = Mat::from_fn(keep, p, |k, j| g_scaled[(k, j)] * scale[j]);
    // A failed SVD (only possible on non-finite input, which the callers stop before) leaves
    // `v` without columns: the null space is then left empty rather than indexed out of bounds.
    let null = Mat::from_fn(p, p - keep, |j, k| {
        if keep + k < v.ncols() && j < v.nrows() {
            v[(j, keep + k)]
        } else {
            0.0
        }
    });
    let solution = Solution {
        beta: b.iter().zip(&scale).map(|(b, s)| b * s).collect(),
        rank,
        rss: rss_full + dropped,
        g,
        null,
        condition,
        scale,
    };
    if rank < p && !min_norm {
        return Err(solution);
    }
    Ok(solution)
}

/// A solution of the sub-problem of the `kept` columns, widened back to all columns: dropped
/// coefficients are zero and carry no variance.
pub fn expand(s: Solution, kept: &[bool]) -> Solution {
    let p = kept.len();
    let index: Vec<usize> = (0..p).filter(|&j| kept[j]).collect();
    let mut beta = vec![0.0; p];
    let mut scale = vec![0.0; p];
    for (k, &j) in index.iter().enumerate() {
        beta[j] = s.beta.get(k).copied().unwrap_or(0.0);
        scale[j] = s.scale.get(k).copied().unwrap_or(0.0);
    }
    let g = Mat::from_fn(s.g.nrows(), p, |r, j| {
        match index.iter().position(|&i| i == j) {
            Some(k) => s.g[(r, k)],
            None => 0.0,
        }
    });
    let null = Mat::from_fn(p, s.null.ncols(), |j, c| {
        match index.iter().position(|&i| i == j) {
            Some(k) => s.null[(k, c)],
            None => 0.0,
        }
    });
    Solution {
        beta,
        rank: s.rank,
        rss: s.rss,
        g,
        null,
        condition: s.condition,
        scale,
    }
}

/// `σ̂² GᵀG` restricted to the diagonal: variances of every column.
pub fn variances(g: &Mat<f64>, sigma2: f64) -> Vec<f64> {
    (0..g.ncols())
        .map(|j| sigma2 * (0..g.nrows()).map(|k| g[(k, j)].powi(2)).sum::<f64>())
        .collect()
}

/// The full covariance `σ̂² GᵀG` (eq. 4.11).
pub fn covariance(g: &Mat<f64>, sigma2: f64) -> Mat<f64> {
    let p = g.ncols();
    Mat::from_fn(p, p, |a, b| {
        sigma2 * (0..g.nrows()).map(|k| g[(k, a)] * g[(k, b)]).sum::<f64>()
    })
}
