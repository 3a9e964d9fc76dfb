//! A fitted error that is a function of one axis' position, as values at stations along that
//! axis with their standard uncertainties: what a laser run along the axis shows, instead of
//! the basis coefficients (a truncated-power spline's coefficients mean nothing on their own).

use kin_compiler::basis::Basis;
use kin_compiler::ir::{FrameRef, JointKind, Machine, Scalar, Var};
use serde::{Deserialize, Serialize};

use super::report::FitReport;
use crate::uncertainty::PredictionCovariance;

/// One error component at stations along one axis (FIT.json `stations[]`, spec/json.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StationTable {
    /// kin's name of the component, e.g. `X.tx`.
    pub error: String,
    /// Its ISO 230-1 name when it is a component error of the axis it varies along (`EXX`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iso: Option<String>,
    /// The axis whose position the values are a function of.
    pub axis: String,
    /// Unit of `positions` (the axis' length or angle unit).
    pub position_unit: String,
    /// Unit of `values` and `u` (the error or tilt unit).
    pub unit: String,
    pub positions: Vec<f64>,
    /// `null` where a coefficient it depends on is undetermined.
    #[serde(deserialize_with = "super::report::nans_if_null")]
    pub values: Vec<f64>,
    /// Standard uncertainty of each value (eq. 4.12); `null` where a coefficient it depends on
    /// is undetermined.
    #[serde(deserialize_with = "super::report::nans_if_null")]
    pub u: Vec<f64>,
    /// True when the component also has terms that are not functions of this axis alone
    /// (backlash, inputs, time, another axis): those are left out of `values`.
    pub partial: bool,
}

/// Station positions along `[lo, hi]` (display units): the ends and the multiples of a round
/// step (1, 2, 2.5 or 5 × 10ⁿ) giving about ten intervals, like the targets of a laser run.
pub fn stations(lo: f64, hi: f64) -> Vec<f64> {
    // The ends come from the range in SI: −120° is −119.99999999999999° after the round trip
    // through radians. Thirteen significant digits give a user's number back.
    let tidy = |x: f64| format!("{x:.12e}").parse::<f64>().unwrap_or(x);
    let (lo, hi) = (tidy(lo), tidy(hi));
    let span = hi - lo;
    if !(span > 0.0) || !span.is_finite() {
        return vec![lo];
    }
    let raw = span / 10.0;
    let decade = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * decade)
        .find(|s| *s >= raw * (1.0 - 1e-12))
        .unwrap_or(10.0 * decade);
    let mut out = vec![lo];
    let mut k = (lo / step).floor() + 1.0;
    while k * step < hi - step * 1e-9 {
        if k * step > lo + step * 1e-9 {
            out.push(k * step);
        }
        k += 1.0;
    }
    out.push(hi);
    out
}

/// The tables of every error component that varies along one axis, from a fit's coefficients
/// (`beta`, SI), its covariance (eq. 4.12 with the fitted non-linear parameters' share:
/// [`PredictionCovariance`]) and the non-linear parameters' values (`nonlinear`, SI).
pub fn tables(
    m: &Machine,
    beta: &[f64],
    nonlinear: &[f64],
    report: &FitReport,
) -> Vec<StationTable> {
    let n = m.coefficients.len();
    let cov = PredictionCovariance::new(m, report).ok();
    let mut out = Vec::new();
    for (e, model) in m.errors.iter().enumerate() {
        // The axis of the first term with a position factor; terms of that axis alone (with a
        // plain number as scale) make the table.
        let axis_of = |t: &kin_compiler::ir::Term| {
            let mut read = Vec::new();
            crate::curves::scalar_vars(&t.scale, &mut read);
            let scaled = (t.coefficients > 0)
                .then(|| match read.as_slice() {
                    [Var::Axis(a), rest @ ..] if rest.iter().all(|v| *v == Var::Axis(*a)) => {
                        Some(*a)
                    }
                    _ => None,
                })
                .flatten();
            t.factors
                .iter()
                .find_map(|f| match f.var {
                    Var::Axis(a) if !matches!(f.basis, Basis::Const) => Some(a),
                    _ => None,
                })
                .or(scaled)
        };
        let Some(a) = model.terms.iter().find_map(axis_of) else {
            continue;
        };
        // A term of this axis alone: its factors of the axis (or `const`), its scale a number
        // or an expression of the axis (a squareness written `(Y + 250 mm) / 1000 mm * const`).
        let alone = |t: &kin_compiler::ir::Term| {
            let mut read = Vec::new();
            crate::curves::scalar_vars(&t.scale, &mut read);
            read.iter().all(|v| *v == Var::Axis(a))
                && t.coefficients > 0
                && t.factors
                    .iter()
                    .all(|f| matches!(f.basis, Basis::Const) || f.var == Var::Axis(a))
        };
        let axes = m.axes.len();
        let none = vec![f64::NAN; axes.max(m.inputs.len()).max(m.lags.len())];
        // The scale of such a term at q (SI): the axis at q, nothing else read.
        let scale_at = |t: &kin_compiler::ir::Term, q: f64| -> Option<f64> {
            if let Scalar::Num(x) = t.scale {
                return Some(x);
            }
            let mut qs = vec![0.0; axes];
            *qs.get_mut(a)? = q;
            let state = kin_model::interp::State {
                q: &qs,
                inputs: &none[..m.inputs.len()],
                lags: &none[..m.lags.len()],
                time: f64::NAN,
                dirs: &none[..axes],
                tool: 0,
                tool_offset: None,
            };
            kin_model::interp::scalar(&t.scale, &state, m).ok()
        };
        let Some(axis) = m.axes.get(a) else {
            continue;
        };
        let (position_unit, range) = match axis.kind {
            JointKind::Prismatic => (&m.units.length, axis.range),
            JointKind::Revolute => (&m.units.angle, axis.range),
        };
        let unit = if model.component.is_rotation() {
            &m.units.tilt
        } else {
            &m.units.error
        };
        let frame_axis = match model.frame {
            FrameRef::Tool(k) => m.tool_chain.get(k).map(|el| el.axis),
            FrameRef::Workpiece(k) => m.workpiece_chain.get(k).map(|el| el.axis),
            _ => None,
        };
        let error = m
            .coefficients
            .iter()
            .find(|c| c.error == e)
            .and_then(|c| c.name.rsplit_once('[').map(|(b, _)| b.to_string()))
            .unwrap_or_default();
        let iso = (frame_axis == Some(a)).then(|| {
            let d = ['X', 'Y', 'Z', 'A', 'B', 'C'][model.component.index()];
            format!("E{d}{}", axis.name)
        });
        let positions = stations(
            position_unit.from_si(range[0]),
            position_unit.from_si(range[1]),
        );
        // The design row of this axis' terms at q (SI) for the non-linear values `nl`.
        let row_at = |q: f64, nl: &[f64], g: &mut Vec<f64>| {
            g.clear();
            g.resize(n, 0.0);
            let mut f = Vec::new();
            for t in model.terms.iter().filter(|t| alone(t)) {
                let Some(scale) = scale_at(t, q) else {
                    continue;
                };
                // Row-major tensor product of the factors (all of this axis or `const`).
                let mut w = vec![scale];
                for factor in &t.factors {
                    f.resize(factor.basis.size(), 0.0);
                    factor.basis.eval(q, nl, &mut f);
                    w = w
                        .iter()
                        .flat_map(|x| f.iter().map(move |b| x * b))
                        .collect();
                }
                for (k, wk) in w.iter().enumerate() {
                    if let Some(slot) = g.get_mut(t.first + k) {
                        *slot = *wk;
                    }
                }
            }
        };
        let value_at = |g: &[f64]| -> f64 { g.iter().zip(beta).map(|(a, b)| a * b).sum() };
        let mut values = Vec::with_capacity(positions.len());
        let mut u = Vec::with_capacity(positions.len());
        let (mut g, mut side) = (Vec::new(), Vec::new());
        for &p in &positions {
            let q = position_unit.to_si(p);
            row_at(q, nonlinear, &mut g);
            let value = value_at(&g);
            let undetermined = g.iter().enumerate().any(|(j, w)| {
                *w != 0.0 && report.coefficients.get(j).is_some_and(|c| c.note.is_some())
            });
            // A value that rests on an undetermined coefficient is whatever the minimum-norm
            // solution put there: not a value of the machine.
            if undetermined {
                values.push(f64::NAN);
                u.push(f64::NAN);
                continue;
            }
            values.push(unit.from_si(value));
            let Some(cov) = cov.as_ref() else {
                u.push(f64::NAN);
                continue;
            };
            // h = ∂value/∂θ over the included parameters, by central differences.
            let h: Vec<f64> = cov
                .nonlinear()
                .iter()
                .map(|&i| {
                    let d = crate::uncertainty::step(nonlinear.get(i).copied().unwrap_or(1.0));
                    let mut nl = nonlinear.to_vec();
                    let mut at = |x: f64| {
                        if let Some(v) = nl.get_mut(i) {
                            *v = x;
                        }
                        row_at(q, &nl, &mut side);
                        value_at(&side)
                    };
                    let x = nonlinear.get(i).copied().unwrap_or(0.0);
                    (at(x + d) - at(x - d)) / (2.0 * d)
                })
                .collect();
            u.push(cov.variance(&g, &h).max(0.0).sqrt() / unit.scale);
        }
        out.push(StationTable {
            error,
            iso,
            axis: axis.name.clone(),
            position_unit: position_unit.name.clone(),
            unit: unit.name.clone(),
            positions,
            values,
            u,
            partial: model.terms.iter().any(|t| !alone(t)),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::stations;

    #[test]
    fn stations_are_the_ends_and_round_steps_between() {
        assert_eq!(
            stations(0.0, 400.0),
            vec![0.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 350.0, 400.0]
        );
        assert_eq!(
            stations(-450.0, 0.0),
            vec![-450.0, -400.0, -350.0, -300.0, -250.0, -200.0, -150.0, -100.0, -50.0, 0.0]
        );
        let s = stations(3.0, 703.0);
        assert_eq!(s.first(), Some(&3.0));
        assert_eq!(s.get(1), Some(&100.0));
        assert_eq!(s.last(), Some(&703.0));
        assert_eq!(stations(0.0, 360.0).len(), 9);
    }

    #[test]
    fn an_end_converted_from_si_is_the_number_the_user_wrote() {
        let deg = std::f64::consts::PI / 180.0;
        let (lo, hi) = (-120.0 * deg / deg, 30.0 * deg / deg);
        // The round trip through radians is not exact: what the tables used to show.
        assert_ne!(lo, -120.0);
        let s = stations(lo, hi);
        assert_eq!(s.first(), Some(&-120.0));
        assert_eq!(s.last(), Some(&30.0));
        assert_eq!(s.get(1), Some(&-100.0));
    }
}
