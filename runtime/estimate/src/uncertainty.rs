//! The uncertainty of a prediction (thesis eq. 4.12): the one implementation every command
//! uses (`kin eval --uncertainty`, `predict`, `correct`, `compensate`, the report's map and the
//! confidence ellipsoids).
//!
//! A prediction of the fitted model is linear in the coefficients β and, through wavelengths
//! and time constants, non-linear in the fitted parameters θ. To first order in both,
//! `ê = e(β̂, θ̂) + g·(β − β̂) + h·(θ − θ̂)` with `g = ∂e/∂β` (a row of the β-Jacobian) and
//! `h = ∂e/∂θ`. A fit with fitted θ reports `C₀`, the coefficients' covariance at fixed θ,
//! the joint covariance `S` of θ̂ and the sensitivity `A = ∂β̂/∂θ` of the coefficients to θ
//! ([`crate::fit::nonlinear::Joint`]). Then `β̂ − β ≈ δβ₀ + A (θ̂ − θ)` with `δβ₀` independent
//! of `θ̂`, and the covariance of two predictions a and b is
//!
//! ```text
//! Cov(êₐ, ê_b) = gₐᵀ C₀ g_b + dₐᵀ S d_b,    d = h − Aᵀ g,
//! ```
//!
//! which for a = b and no fitted θ is eq. 4.12, `Var(ê) = gᵀ Cov(β̂) g`. The nuisance
//! parameters (an artifact's placement) do not enter: a prediction is of the machine.
//!
//! `h` depends on the history of the inputs when θ is a time constant (the lag states are
//! integrated over a run), so it is computed for a whole set of rows at once, by central
//! differences (`PredictionCovariance::nonlinear_gradients`).

use kin_compiler::ir::Machine;
use kin_data::data::Rows;
use kin_model::engine::Evaluator;
use kin_model::interp::EvalError;
use kin_model::states::States;

use crate::fit::report::FitReport;

/// Whether the uncertainty includes the non-linear parameters' (the fit holds their joint
/// covariance), and which of them it includes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Coverage {
    /// Names of the fitted non-linear parameters whose uncertainty is included.
    pub included: Vec<String>,
    /// Names of fitted non-linear parameters the fit report carries no joint covariance for
    /// (a report written before it did): their uncertainty is left out.
    pub missing: Vec<String>,
}

/// The covariance of a fit's predictions (eq. 4.12 with the fitted non-linear parameters).
#[derive(Debug)]
pub struct PredictionCovariance<'f> {
    fit: &'f FitReport,
    /// The model's coefficients.
    n: usize,
    /// The model's non-linear parameters, fitted or not (the layout of `S` and `A`).
    k: usize,
    /// Indices (in `Machine::nonlinear`) of the fitted parameters whose share is included.
    included: Vec<usize>,
    coverage: Coverage,
}

/// A row whose gradient could not be evaluated: its 0-based index and why.
#[derive(Debug)]
pub struct RowError {
    pub row: usize,
    pub source: EvalError,
}

impl<'f> PredictionCovariance<'f> {
    /// The covariance of `fit`'s predictions for the model `m` it was fitted to; `Err` says why
    /// the fit does not belong to `m` ([`FitReport::covariance_mismatch`]). The methods that
    /// evaluate a prediction's θ-gradients take `m` with the fitted values bound (`m.beta` and
    /// the non-linear parameters' values): the gradients are taken there.
    pub fn new(m: &Machine, fit: &'f FitReport) -> Result<Self, String> {
        if let Some(why) = fit.covariance_mismatch(m) {
            return Err(why);
        }
        let n = m.coefficients.len();
        let k = m.nonlinear.len();
        let joint =
            fit.nonlinear_covariance.len() == k * k && fit.nonlinear_sensitivity.len() == n * k;
        let mut coverage = Coverage::default();
        let mut included = Vec::new();
        for (i, p) in m.nonlinear.iter().enumerate() {
            if !p.fitted {
                continue;
            }
            if !joint {
                coverage.missing.push(p.name.clone());
            } else if fit
                .nonlinear_covariance
                .get(i * k + i)
                .is_some_and(|v| *v > 0.0)
            {
                coverage.included.push(p.name.clone());
                included.push(i);
            }
        }
        Ok(PredictionCovariance {
            fit,
            n,
            k,
            included,
            coverage,
        })
    }

    /// Which fitted non-linear parameters the uncertainty includes.
    pub fn coverage(&self) -> &Coverage {
        &self.coverage
    }

    /// The included parameters (indices in `Machine::nonlinear`), in the order of a
    /// prediction's θ-gradients `h`.
    pub fn nonlinear(&self) -> &[usize] {
        &self.included
    }

    /// `Cov(êₐ, ê_b) = gₐᵀ C₀ g_b + dₐᵀ S d_b`, `d = h − Aᵀg`: `g` the β-gradients (length n;
    /// missing entries count as 0), `h` the θ-gradients over the included parameters (empty
    /// when none is included). SI².
    pub fn covariance(&self, ga: &[f64], ha: &[f64], gb: &[f64], hb: &[f64]) -> f64 {
        let n = self.n;
        let cov = &self.fit.covariance;
        let mut v = 0.0;
        for (a, x) in ga.iter().enumerate().take(n) {
            // Most of a Jacobian row is structurally zero.
            if *x == 0.0 {
                continue;
            }
            let row = cov.get(a * n..(a + 1) * n).unwrap_or(&[]);
            v += x * row.iter().zip(gb).map(|(c, y)| c * y).sum::<f64>();
        }
        if self.included.is_empty() {
            return v;
        }
        let (da, db) = (self.d(ga, ha), self.d(gb, hb));
        for (a, &i) in self.included.iter().enumerate() {
            for (b, &j) in self.included.iter().enumerate() {
                let s = self
                    .fit
                    .nonlinear_covariance
                    .get(i * self.k + j)
                    .copied()
                    .unwrap_or(0.0);
                v += da[a] * s * db[b];
            }
        }
        v
    }

    /// `Var(ê) = gᵀ C₀ g + dᵀ S d`: [`covariance`](Self::covariance) of a prediction with itself.
    pub fn variance(&self, g: &[f64], h: &[f64]) -> f64 {
        self.covariance(g, h, g, h)
    }

    /// `d = h − Aᵀ g` over the included parameters.
    fn d(&self, g: &[f64], h: &[f64]) -> Vec<f64> {
        let a = &self.fit.nonlinear_sensitivity;
        self.included
            .iter()
            .enumerate()
            .map(|(slot, &i)| {
                let atg: f64 = g
                    .iter()
                    .enumerate()
                    .take(self.n)
                    .map(|(b, gb)| gb * a.get(b * self.k + i).copied().unwrap_or(0.0))
                    .sum();
                h.get(slot).copied().unwrap_or(0.0) - atg
            })
            .collect()
    }

    /// `∂y/∂θᵢ` at every row for each included parameter i, by central differences: `h[i][r]`.
    /// `value(ev, states, r)` is the predicted quantity of row r (`E` values: the six error
    /// components, or one length); every `states` is integrated again at `θ ± δ` over `rows`
    /// and the engine told the new values, then both are restored to `m`'s values.
    pub(crate) fn nonlinear_gradients<const E: usize>(
        &self,
        m: &Machine,
        ev: &mut dyn Evaluator,
        states: &mut [&mut States],
        rows: &Rows,
        mut value: impl FnMut(&mut dyn Evaluator, &[&mut States], usize) -> Result<[f64; E], EvalError>,
    ) -> Result<Vec<Vec<[f64; E]>>, RowError> {
        if self.included.is_empty() {
            return Ok(Vec::new());
        }
        let values: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let len = states.first().map_or(0, |s| s.len());
        let set = |ev: &mut dyn Evaluator, states: &mut [&mut States], v: &[f64]| {
            for s in states.iter_mut() {
                s.integrate_lags(m, rows, v);
            }
            ev.set_nonlinear(v)
                .map_err(|source| RowError { row: 0, source })
        };
        let mut out = Vec::with_capacity(self.included.len());
        let mut pass = |ev: &mut dyn Evaluator, states: &mut [&mut States], i: usize, sign: f64| {
            let d = step(values.get(i).copied().unwrap_or(1.0));
            let mut v = values.clone();
            if let Some(x) = v.get_mut(i) {
                *x += sign * d;
            }
            set(ev, states, &v)?;
            (0..len)
                .map(|r| value(ev, states, r).map_err(|source| RowError { row: r, source }))
                .collect::<Result<Vec<[f64; E]>, RowError>>()
                .map(|col| (col, d))
        };
        let mut result = Ok(());
        for &i in &self.included {
            let up = pass(ev, states, i, 1.0);
            let dn = pass(ev, states, i, -1.0);
            match (up, dn) {
                (Ok((up, step)), Ok((dn, _))) => out.push(
                    up.iter()
                        .zip(&dn)
                        .map(|(a, b)| std::array::from_fn(|c| (a[c] - b[c]) / (2.0 * step)))
                        .collect(),
                ),
                (Err(e), _) | (_, Err(e)) => {
                    result = Err(e);
                    break;
                }
            }
        }
        // Restore the model's own values whatever happened above.
        set(ev, states, &values)?;
        result.map(|()| out)
    }
}

impl PredictionCovariance<'_> {
    /// `Var(ê_c)` of the six predicted error components at every row of `states` (the rows of
    /// `rows`, a point set), SI² (m², rad²).
    pub fn point_variances(
        &self,
        m: &Machine,
        ev: &mut dyn Evaluator,
        states: &mut States,
        rows: &Rows,
    ) -> Result<Vec<[f64; 6]>, RowError> {
        self.per_point(m, ev, states, rows, |cov, jac, h| {
            std::array::from_fn(|c| cov.variance(row(jac, cov.n, c), &h[c]))
        })
    }

    /// The 3×3 covariance of the predicted position error `(ex, ey, ez)` at every row of
    /// `states`, m²: `Cov(ê_i, ê_j)` for the three components together (the confidence
    /// ellipsoid's matrix).
    pub fn position_covariances(
        &self,
        m: &Machine,
        ev: &mut dyn Evaluator,
        states: &mut States,
        rows: &Rows,
    ) -> Result<Vec<[[f64; 3]; 3]>, RowError> {
        self.per_point(m, ev, states, rows, |cov, jac, h| {
            let raw: [[f64; 3]; 3] = std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    cov.covariance(row(jac, cov.n, i), &h[i], row(jac, cov.n, j), &h[j])
                })
            });
            // Symmetric by construction up to rounding; make it exactly so for the eigensolver.
            std::array::from_fn(|i| std::array::from_fn(|j| 0.5 * (raw[i][j] + raw[j][i])))
        })
    }

    /// `Var(dL̂)` of the predicted length error (eq. 4.5) at every row of a length set, whose
    /// two ends are `s1` and `s2`. SI² (m²).
    pub(crate) fn length_variances(
        &self,
        m: &Machine,
        ev: &mut dyn Evaluator,
        s1: &mut States,
        s2: &mut States,
        rows: &Rows,
    ) -> Result<Vec<f64>, RowError> {
        let n = self.n;
        let h = self.nonlinear_gradients::<1>(m, ev, &mut [s1, s2], rows, |ev, s, r| {
            let mut scratch = vec![0.0; n];
            let (a, b) = (s[0].get(r), s[1].get(r));
            ev.length_and_row(&a, &b, &m.beta, &mut scratch)
                .map(|l| [l])
        })?;
        let beta = vec![0.0; n];
        let mut g = vec![0.0; n];
        let mut out = Vec::with_capacity(s1.len());
        for r in 0..s1.len() {
            ev.length_and_row(&s1.get(r), &s2.get(r), &beta, &mut g)
                .map_err(|source| RowError { row: r, source })?;
            out.push(self.variance(&g, &gradient_at(&h, r, 0)));
        }
        Ok(out)
    }

    /// Calls `each(self, jacobian, θ-gradients per component)` at every row of a point set.
    fn per_point<T>(
        &self,
        m: &Machine,
        ev: &mut dyn Evaluator,
        states: &mut States,
        rows: &Rows,
        each: impl Fn(&Self, &[f64], &[Vec<f64>; 6]) -> T,
    ) -> Result<Vec<T>, RowError> {
        let h = self.nonlinear_gradients::<6>(m, ev, &mut [states], rows, |ev, s, r| {
            ev.error(&s[0].get(r), &m.beta)
        })?;
        let n = self.n;
        // The Jacobian does not depend on β (the model is linear in it).
        let beta = vec![0.0; n];
        let mut jac = vec![0.0; 6 * n];
        let mut err = [0.0; 6];
        let mut out = Vec::with_capacity(states.len());
        for r in 0..states.len() {
            ev.error_and_jacobian(&states.get(r), &beta, &mut err, &mut jac)
                .map_err(|source| RowError { row: r, source })?;
            let hr: [Vec<f64>; 6] = std::array::from_fn(|c| gradient_at(&h, r, c));
            out.push(each(self, &jac, &hr));
        }
        Ok(out)
    }
}

/// The central-difference step for a non-linear parameter of value `value`: relative, as the
/// fit's own derivatives take it.
pub(crate) fn step(value: f64) -> f64 {
    1e-5 * value.abs().max(f64::MIN_POSITIVE)
}

/// Row `c` of a `6 × n` row-major Jacobian.
fn row(jac: &[f64], n: usize, c: usize) -> &[f64] {
    jac.get(c * n..(c + 1) * n).unwrap_or(&[])
}

/// The θ-gradients of row `r` for component `c`, from [`PredictionCovariance::nonlinear_gradients`].
fn gradient_at<const E: usize>(h: &[Vec<[f64; E]>], r: usize, c: usize) -> Vec<f64> {
    h.iter()
        .map(|col| col.get(r).and_then(|e| e.get(c)).copied().unwrap_or(0.0))
        .collect()
}
