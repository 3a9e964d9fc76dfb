//! Coefficients that cancel each other: large estimates whose effects on the data are nearly
//! opposite, so that only their small sum is what the data show (spec/cli.md, "Coefficients
//! that cancel").
//!
//! With `C = σ̂²(XᵀX)⁻¹` the coefficients' covariance (nuisance parameters profiled out),
//! `M = C⁻¹ = (XᵀX)/σ̂²` holds the columns' inner products in units of the noise: the effect of
//! coefficient k alone on the fitted values has length `|β_k|·√M_kk` noise units, and the
//! effect of a set S together `√(β_Sᵀ M_SS β_S)`. A set whose joint effect is below a tenth of
//! its largest member's, each member with a variance inflation `C_kk·M_kk` of 10 or more (or
//! below a third, each inflated a hundredfold or more) and an estimate of three standard errors
//! or more, and the set's estimates jointly far from zero
//! (Wald's `β_Sᵀ C_SS⁻¹ β_S` beyond χ²'s 0.1 % point: noise of a sound fit does not produce
//! it), is a set of terms trading off against each other:
//! typically an effect the model lacks that several nearly alike columns imitate together
//! (three constants moving by millimetres to explain micrometres). The values are then an
//! artefact of the missing term, not the machine's geometry, and say so before anyone
//! compensates with them.

use nalgebra::DMatrix;

use crate::design::root;
use serde::{Deserialize, Serialize};

/// Beyond this many determined coefficients the check (an inverse of their covariance) is
/// left out: its cost grows with their cube.
const MAX_COEFFICIENTS: usize = 1500;
/// A member's variance inflation at least this (its standard error at least √10 times what
/// it would be were its column alone).
const INFLATED: f64 = 10.0;
/// A member's estimate at least this many standard errors: not noise around zero.
const SIGNIFICANT: f64 = 3.0;
/// The set's joint Wald test below this p-value.
const JOINTLY: f64 = 1e-3;
/// Two members' columns at least this alike (cosine) to join one set.
const ALIKE: f64 = 0.5;
/// The set's joint effect at most this fraction of its largest member's effect.
const CANCELS: f64 = 0.1;
/// Or at most this fraction, when every member is inflated [`DEEPLY`] or more: a member whose
/// standard error is ten times its own column's is almost wholly a combination of the others'
/// columns, and two thirds of its effect undone by them makes its value an artefact of the
/// trade-off as surely (a cosine that is nearly constant over a short arc beside a constant:
/// the two move by millimetres to draw a small curve).
const CANCELS_DEEPLY: f64 = 1.0 / 3.0;
const DEEPLY: f64 = 100.0;

/// A set of coefficients whose effects cancel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Cancelling {
    /// Indices of the coefficients, in declaration order.
    pub members: Vec<usize>,
    /// The largest member's effect alone, and the set's joint effect: lengths over the fitted
    /// rows in units of σ̂.
    pub largest: f64,
    pub joint: f64,
}

/// The determined coefficients' covariance scaled to unit diagonal, and its inverse.
struct Scaled {
    /// Indices of the coefficients with a finite, positive variance.
    determined: Vec<usize>,
    /// Their standard errors.
    s: Vec<f64>,
    /// Their correlation matrix.
    r: DMatrix<f64>,
    /// `M̃ = R⁻¹`: M in the scaled coordinates (`M = S⁻¹ M̃ S⁻¹`); its diagonal is each
    /// coefficient's variance inflation, its off-diagonal the cosines of the columns (scaled).
    m: DMatrix<f64>,
}

/// [`Scaled`] of `covariance` (row-major `n × n`, SI), over the coefficients with a finite,
/// positive variance and a finite estimate; `None` for fewer than two or more than
/// [`MAX_COEFFICIENTS`] of them, or a covariance that is not positive definite.
fn scaled(beta: &[f64], covariance: &[f64]) -> Option<Scaled> {
    let n = beta.len();
    if covariance.len() != n * n {
        return None;
    }
    let var = |k: usize| covariance.get(k * n + k).copied().unwrap_or(f64::NAN);
    let determined: Vec<usize> = (0..n)
        .filter(|&k| var(k).is_finite() && var(k) > 0.0 && beta[k].is_finite())
        .collect();
    let d = determined.len();
    if !(2..=MAX_COEFFICIENTS).contains(&d) {
        return None;
    }
    let c = DMatrix::from_fn(d, d, |a, b| {
        covariance
            .get(determined[a] * n + determined[b])
            .copied()
            .unwrap_or(f64::NAN)
    });
    // Scaled to unit diagonal first: the coefficients' units span many decades.
    let s: Vec<f64> = (0..d).map(|a| c[(a, a)].sqrt()).collect();
    let r = DMatrix::from_fn(d, d, |a, b| c[(a, b)] / (s[a] * s[b]));
    let m = r.clone().cholesky()?.inverse();
    Some(Scaled {
        determined,
        s,
        r,
        m,
    })
}

/// A member's variance inflation at least this makes it weakly determined: its standard error
/// some thirty times what its column alone would give, whatever its estimate. (A hundred,
/// tenfold, is common for a squareness beside detrended splines known to 0.2 µrad; a plan that
/// leaves a link length at millimetres inflates it by tens of thousands.)
const WEAK: f64 = 1000.0;

/// Coefficients the data barely determine (see [`weak`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Weak {
    /// Indices of the coefficients, in declaration order.
    pub members: Vec<usize>,
    /// Each member's variance inflation: its variance over what its column alone would give.
    pub inflation: Vec<f64>,
}

/// The sets of weakly determined coefficients: each member's variance in `covariance`
/// (row-major `n × n`, SI) at least 1 000 times `alone` — the variance it would have were
/// its column the only one (`σ̂²/‖x‖²`; `None`: not asked about) — grouped with those whose
/// columns are alike. Whatever a coefficient trades off against, other coefficients or the
/// fit's nuisance parameters (an instrument's placement), shows in that ratio. The fit asks
/// about constants only (locations, offsets, lengths): the functions of a spline or a
/// polynomial are alike by construction, and what their values leave uncertain is the curve's
/// uncertainty along its axis (the station tables), not a plan that fails to separate them.
pub fn weak(beta: &[f64], covariance: &[f64], alone: &[Option<f64>]) -> Vec<Weak> {
    let Some(Scaled {
        determined, s, m, ..
    }) = scaled(beta, covariance)
    else {
        return Vec::new();
    };
    let d = determined.len();
    let inflation: Vec<f64> = (0..d)
        .map(|a| match alone.get(determined[a]).copied().flatten() {
            Some(v) if v > 0.0 => s[a] * s[a] / v,
            _ => 0.0,
        })
        .collect();
    let inflated: Vec<bool> = inflation.iter().map(|&v| v >= WEAK).collect();
    let mut parent: Vec<usize> = (0..d).collect();
    for a in 0..d {
        for b in a + 1..d {
            if inflated[a] && inflated[b] {
                let cosine = m[(a, b)] / (m[(a, a)] * m[(b, b)]).sqrt();
                if cosine.abs() >= ALIKE {
                    let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                    parent[ra] = rb;
                }
            }
        }
    }
    let mut out = Vec::new();
    let mut seen = vec![false; d];
    for a in 0..d {
        if !inflated[a] || seen[a] {
            continue;
        }
        let ra = root(&mut parent, a);
        let set: Vec<usize> = (0..d)
            .filter(|&b| inflated[b] && root(&mut parent, b) == ra)
            .collect();
        for &b in &set {
            seen[b] = true;
        }
        out.push(Weak {
            members: set.iter().map(|&i| determined[i]).collect(),
            inflation: set.iter().map(|&i| inflation[i]).collect(),
        });
    }
    out
}

/// The sets of `beta` (SI) that cancel under the covariance `covariance` (row-major `n × n`,
/// SI); coefficients with a non-finite or zero variance (undetermined, removed) take no part.
pub fn cancelling(beta: &[f64], covariance: &[f64]) -> Vec<Cancelling> {
    let Some(Scaled {
        determined,
        s,
        r,
        m,
    }) = scaled(beta, covariance)
    else {
        return Vec::new();
    };
    let d = determined.len();
    let z: Vec<f64> = (0..d).map(|a| beta[determined[a]] / s[a]).collect();
    let effect = |a: usize| z[a].abs() * m[(a, a)].max(0.0).sqrt();
    let candidate: Vec<bool> = (0..d)
        .map(|a| m[(a, a)] >= INFLATED && z[a].abs() >= SIGNIFICANT)
        .collect();
    // Candidates whose columns are alike and whose effects oppose join one set.
    let mut parent: Vec<usize> = (0..d).collect();
    for a in 0..d {
        for b in a + 1..d {
            if !(candidate[a] && candidate[b]) {
                continue;
            }
            let cosine = m[(a, b)] / (m[(a, a)] * m[(b, b)]).sqrt();
            if cosine.abs() >= ALIKE && z[a] * z[b] * cosine < 0.0 {
                let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                parent[ra] = rb;
            }
        }
    }
    let mut out = Vec::new();
    let mut seen = vec![false; d];
    for a in 0..d {
        if !candidate[a] || seen[a] {
            continue;
        }
        let ra = root(&mut parent, a);
        let set: Vec<usize> = (0..d)
            .filter(|&b| candidate[b] && root(&mut parent, b) == ra)
            .collect();
        for &b in &set {
            seen[b] = true;
        }
        if set.len() < 2 {
            continue;
        }
        let mut joint = 0.0;
        for &i in &set {
            for &j in &set {
                joint += z[i] * m[(i, j)] * z[j];
            }
        }
        let joint = joint.max(0.0).sqrt();
        let largest = set.iter().map(|&i| effect(i)).fold(0.0, f64::max);
        // Wald's statistic from the scaled covariance of the set (r restricted to it).
        let rs = DMatrix::from_fn(set.len(), set.len(), |a, b| r[(set[a], set[b])]);
        let zs = nalgebra::DVector::from_iterator(set.len(), set.iter().map(|&i| z[i]));
        let wald = rs
            .cholesky()
            .map(|ch| zs.dot(&ch.solve(&zs)))
            .unwrap_or(f64::NAN);
        let p = crate::statistics::chi_squared_p(wald, set.len() as f64).unwrap_or(f64::NAN);
        let deeply = set.iter().all(|&i| m[(i, i)] >= DEEPLY);
        let cancels = if deeply { CANCELS_DEEPLY } else { CANCELS };
        if joint <= cancels * largest && p < JOINTLY {
            out.push(Cancelling {
                members: set.iter().map(|&i| determined[i]).collect(),
                largest,
                joint,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The covariance σ²(XᵀX)⁻¹ and least-squares estimate of `y` on the columns of `x`.
    fn fit(x: &DMatrix<f64>, y: &[f64], sigma: f64) -> (Vec<f64>, Vec<f64>) {
        let xtx = x.transpose() * x;
        let inv = xtx.clone().try_inverse().expect("invertible");
        let beta = &inv * x.transpose() * nalgebra::DVector::from_row_slice(y);
        let cov = inv * (sigma * sigma);
        (
            beta.iter().copied().collect(),
            cov.transpose().iter().copied().collect(),
        )
    }

    #[test]
    fn constants_imitating_a_missing_curve_are_named_and_a_sound_fit_is_not() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let rows = 200;
        let t: Vec<f64> = (0..rows).map(|i| i as f64 / rows as f64).collect();
        // Column 0: an offset; column 1: a lever that barely changes (0.4 to 0.405 m, growing
        // with the square of the position); column 2: a slope.
        let x = DMatrix::from_fn(rows, 3, |i, j| match j {
            0 => 1.0,
            1 => 0.4 + 0.005 * t[i] * t[i],
            _ => t[i] - 0.5,
        });
        let noise = 1e-7;
        // The truth has a small curve along t (a bending) the model lacks: offset and lever
        // trade off to imitate it, by values far beyond the curve's size.
        let y: Vec<f64> = (0..rows)
            .map(|i| 2e-6 * t[i] * t[i] + 1e-5 * (t[i] - 0.5) + noise * rng.random_range(-1.7..1.7))
            .collect();
        let (beta, cov) = fit(&x, &y, noise);
        let found = cancelling(&beta, &cov);
        assert_eq!(found.len(), 1, "{found:?} {beta:?}");
        assert_eq!(found[0].members, vec![0, 1]);
        assert!(found[0].joint < 0.1 * found[0].largest);
        // Without the curve the same model is sound: the estimates are noise around zero.
        let y: Vec<f64> = (0..rows)
            .map(|i| 1e-5 * (t[i] - 0.5) + noise * rng.random_range(-1.7..1.7))
            .collect();
        let (beta, cov) = fit(&x, &y, noise);
        assert!(cancelling(&beta, &cov).is_empty(), "{beta:?}");
    }

    #[test]
    fn nearly_alike_constants_are_weak_and_independent_ones_are_not() {
        let rows = 100;
        let t: Vec<f64> = (0..rows).map(|i| i as f64 / rows as f64).collect();
        // Columns 0 and 1 differ by a hundredth of a slope: alike; column 2 is orthogonal-ish.
        let x = DMatrix::from_fn(rows, 3, |i, j| match j {
            0 => 1.0,
            1 => 1.0 + 0.01 * (t[i] - 0.5),
            _ => (6.0 * t[i]).sin(),
        });
        let y: Vec<f64> = (0..rows).map(|i| 1e-6 * (3.0 * t[i]).cos()).collect();
        let sigma = 1e-7;
        let (beta, cov) = fit(&x, &y, sigma);
        let alone: Vec<Option<f64>> = (0..3)
            .map(|j| {
                let norm2: f64 = (0..rows).map(|i| x[(i, j)] * x[(i, j)]).sum();
                Some(sigma * sigma / norm2)
            })
            .collect();
        let found = weak(&beta, &cov, &alone);
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!(found[0].members, vec![0, 1]);
        assert!(found[0].inflation.iter().all(|&v| v >= WEAK), "{found:?}");
        // Not asked about: nothing.
        assert!(weak(&beta, &cov, &[None, None, None]).is_empty());
    }

    /// A tilting axis over ±30°: its cosine is nearly a constant, so beside a constant the two
    /// columns trade off (inflation in the hundreds). A curve `1 − cos θ` beside an offset
    /// makes the two estimates undo most, but not nine tenths, of each other: named by the
    /// deep tier. Over a whole turn the same data leave both columns their own: nothing.
    #[test]
    fn a_short_arc_cosine_beside_a_constant_is_named() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let rows = 200;
        let noise = 2e-6;
        let run = |half_arc: f64, rng: &mut rand::rngs::StdRng| {
            let theta: Vec<f64> = (0..rows)
                .map(|i| half_arc * (2.0 * i as f64 / (rows - 1) as f64 - 1.0))
                .collect();
            let x = DMatrix::from_fn(rows, 2, |i, j| if j == 0 { 1.0 } else { theta[i].cos() });
            let y: Vec<f64> = theta
                .iter()
                .map(|t| 2e-3 * (1.0 - t.cos()) + 0.4e-3 + noise * rng.random_range(-1.7..1.7))
                .collect();
            let (beta, cov) = fit(&x, &y, noise);
            cancelling(&beta, &cov)
        };
        let short = run(30f64.to_radians(), &mut rng);
        assert_eq!(short.len(), 1, "{short:?}");
        assert_eq!(short[0].members, vec![0, 1]);
        let ratio = short[0].joint / short[0].largest;
        assert!(ratio > CANCELS && ratio <= CANCELS_DEEPLY, "{ratio}");
        assert!(run(std::f64::consts::PI, &mut rng).is_empty());
    }

    #[test]
    fn undetermined_or_mismatched_input_gives_nothing() {
        assert!(cancelling(&[1.0, 2.0], &[1.0]).is_empty());
        assert!(cancelling(&[1.0, 2.0], &[f64::NAN, 0.0, 0.0, f64::NAN]).is_empty());
    }
}
