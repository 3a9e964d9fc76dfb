//! Stepwise selection of regressors by partial F-tests (thesis §3.2.2: "a stepwise regression
//! procedure is implemented to remove statistically insignificant parameters").
//!
//! The triangle `R` of `[X | y]` holds everything least squares needs about any subset S of
//! columns: `X_Sᵀ X_S` and `X_Sᵀ y` are the Gram products of R's columns. So the sub-model's
//! residual sum of squares is the last diagonal element, squared, of the QR of `R[:, S ∪ y]`,
//! and selection never goes back to the data.

use faer::Mat;
use serde::Serialize;

use super::qr::Reduced;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    Removed,
    Added,
}

/// One step of the selection: which column, and the partial F statistic and p-value that
/// decided it.
#[derive(Debug, Clone, Serialize)]
pub struct Step {
    pub column: usize,
    pub action: Action,
    pub f: f64,
    pub p: f64,
}

#[derive(Debug, Clone)]
pub struct Selection {
    /// Per column: kept in the final model.
    pub kept: Vec<bool>,
    pub steps: Vec<Step>,
}

/// The sub-problem of the columns in `kept` (y stays last): re-triangularised from R.
pub fn restrict(red: &Reduced, kept: &[bool]) -> Reduced {
    let p = red.norms.len();
    let cols: Vec<usize> = (0..p)
        .filter(|&j| kept.get(j).copied().unwrap_or(true))
        .chain([p])
        .collect();
    let k = red.r.nrows();
    let sub = Mat::from_fn(k, cols.len(), |i, j| red.r[(i, cols[j])]);
    let q = cols.len();
    let r = if k >= q {
        let qr = sub.qr();
        let t = qr.thin_R();
        Mat::from_fn(q, q, |i, j| if j >= i { t[(i, j)] } else { 0.0 })
    } else {
        Mat::zeros(q, q)
    };
    Reduced {
        r,
        rows: red.rows,
        norms: cols.iter().take(q - 1).map(|&j| red.norms[j]).collect(),
        y_sum: red.y_sum,
        y_sumsq: red.y_sumsq,
    }
}

/// Residual sum of squares of the sub-model `kept`.
fn rss(red: &Reduced, kept: &[bool]) -> f64 {
    let sub = restrict(red, kept);
    let q = sub.r.nrows();
    if q == 0 {
        return red.y_sumsq;
    }
    sub.r[(q - 1, q - 1)].powi(2)
}

/// The kept candidate with the smallest partial F, `F_j = β_j² / Var(β_j)` with
/// `Var(β_j) = s²‖row j of R⁻¹‖²` on the sub-model's triangle.
fn weakest(
    red: &Reduced,
    kept: &[bool],
    candidates: usize,
    rss: f64,
    dof: f64,
) -> Option<(usize, f64)> {
    let sub = restrict(red, kept);
    let q = sub.r.nrows().saturating_sub(1);
    let cols: Vec<usize> = (0..kept.len()).filter(|&j| kept[j]).collect();
    // R⁻¹ by back substitution, column by column of the identity.
    let mut inv = Mat::<f64>::zeros(q, q);
    for c in 0..q {
        for i in (0..=c).rev() {
            let mut v = if i == c { 1.0 } else { 0.0 };
            for k in i + 1..=c {
                v -= sub.r[(i, k)] * inv[(k, c)];
            }
            let d = sub.r[(i, i)];
            inv[(i, c)] = if d != 0.0 { v / d } else { f64::INFINITY };
        }
    }
    let s2 = rss / dof;
    (0..q)
        .filter(|&i| cols.get(i).is_some_and(|&j| j < candidates))
        .map(|i| {
            let beta: f64 = (i..q).map(|k| inv[(i, k)] * sub.r[(k, q)]).sum();
            let var: f64 = s2 * (i..q).map(|k| inv[(i, k)].powi(2)).sum::<f64>();
            let f = if var.is_finite() && var > 0.0 {
                beta * beta / var
            } else {
                0.0
            };
            (cols[i], if f.is_finite() { f } else { 0.0 })
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// Backward elimination of the model's coefficients (`0..candidates`; nuisance columns after
/// them are always kept) at significance `alpha_remove`, re-admitting removed ones whose
/// F-to-enter is significant at `alpha_enter` when given (`alpha_enter < alpha_remove`
/// prevents cycling).
pub fn select(
    red: &Reduced,
    candidates: usize,
    alpha_remove: f64,
    alpha_enter: Option<f64>,
) -> Selection {
    let p = red.norms.len();
    let m = red.rows as f64;
    let mut kept = vec![true; p];
    // A column with no effect at all cannot be tested; leave it to the rank analysis.
    let mut steps = Vec::new();
    let p_value = |f: f64, dof: f64| -> f64 {
        if dof > 0.0 {
            crate::statistics::f_p(f, 1.0, dof).unwrap_or(0.0)
        } else {
            0.0
        }
    };
    for _ in 0..(4 * p + 8) {
        let active = kept.iter().filter(|&&k| k).count() as f64;
        let base = rss(red, &kept);
        let dof = m - active;
        if dof <= 0.0 {
            break;
        }
        // Weakest kept coefficient: the partial F of dropping one regressor is its t², read
        // off one factorisation of the current sub-model instead of one per candidate.
        if let Some((j, f)) = weakest(red, &kept, candidates, base, dof) {
            let pv = p_value(f, dof);
            if pv > alpha_remove {
                kept[j] = false;
                steps.push(Step {
                    column: j,
                    action: Action::Removed,
                    f,
                    p: pv,
                });
                continue;
            }
        }
        let Some(alpha_enter) = alpha_enter else {
            break;
        };
        // Strongest removed coefficient: largest decrease of RSS when re-admitted.
        let outside: Vec<usize> = (0..candidates).filter(|&j| !kept[j]).collect();
        let strongest = outside
            .into_iter()
            .map(|j| {
                kept[j] = true;
                let with = rss(red, &kept);
                kept[j] = false;
                let dof_with = dof - 1.0;
                (j, (base - with) / (with / dof_with.max(1.0)), dof_with)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match strongest {
            Some((j, f, d)) if p_value(f, d) < alpha_enter => {
                kept[j] = true;
                steps.push(Step {
                    column: j,
                    action: Action::Added,
                    f,
                    p: p_value(f, d),
                });
            }
            _ => break,
        }
    }
    Selection { kept, steps }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::qr::StreamingQr;
    use rand::{Rng, SeedableRng};

    fn problem(beta: &[f64], m: usize, seed: u64) -> Reduced {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut acc = StreamingQr::new(beta.len(), 64);
        for _ in 0..m {
            let x: Vec<f64> = beta.iter().map(|_| rng.random_range(-1.0..1.0)).collect();
            let noise: f64 = rng.random_range(-1.0..1.0) * 0.1;
            let y = x.iter().zip(beta).map(|(a, b)| a * b).sum::<f64>() + noise;
            acc.push(&x, y);
        }
        acc.finish()
    }

    #[test]
    fn removes_exactly_the_absent_regressors() {
        let beta = [1.0, 0.0, 0.5, 0.0, 0.0, -0.8];
        let red = problem(&beta, 2000, 1);
        let s = select(&red, beta.len(), 1e-4, None);
        assert_eq!(s.kept, vec![true, false, true, false, false, true]);
        assert_eq!(s.steps.len(), 3);
        assert!(s
            .steps
            .iter()
            .all(|st| st.action == Action::Removed && st.p > 1e-4));
    }

    #[test]
    fn restricted_rss_matches_a_direct_fit_of_the_subset() {
        let beta = [1.0, 0.3, -0.5];
        let red = problem(&beta, 500, 2);
        let full = rss(&red, &[true, true, true]);
        let without = rss(&red, &[true, false, true]);
        assert!(without > full, "dropping a real regressor costs");
        // Against an independent accumulation of the subset only.
        let mut rng = rand::rngs::StdRng::seed_from_u64(2);
        let mut acc = StreamingQr::new(2, 64);
        for _ in 0..500 {
            let x: Vec<f64> = beta.iter().map(|_| rng.random_range(-1.0..1.0)).collect();
            let noise: f64 = rng.random_range(-1.0..1.0) * 0.1;
            let y = x.iter().zip(&beta).map(|(a, b)| a * b).sum::<f64>() + noise;
            acc.push(&[x[0], x[2]], y);
        }
        let sub = acc.finish();
        let direct = sub.r[(2, 2)].powi(2);
        assert!(
            (direct - without).abs() < 1e-9 * direct,
            "{direct} vs {without}"
        );
    }
}
