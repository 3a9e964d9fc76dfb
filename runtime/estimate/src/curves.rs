//! The fitted parametric error curves and their confidence bands.
//!
//! Each parametric error (a frame's `tx` … `rz`) is linear in its own coefficients:
//! `e(x) = fixed(x) + Σ_j g_j(x) β_j`. Its fitted part `g(x)ᵀ β̂` is drawn along each variable
//! it depends on, the other variables held at a reference state, with the band
//! `± 2 u(x)`, `u` the standard uncertainty of that fitted part (eq. 4.12 restricted to one
//! parametric error, with the fitted non-linear parameters' share: [`PredictionCovariance`];
//! ≈ 95 %).
//! `g_j(x)` is taken from the interpreter as the change of the error when β_j goes from 0 to 1,
//! which is exact because the model is linear in β. Known fixed terms (e.g. a declared scale
//! expansion) are left out: they were not fitted and would hide the fitted shape.

use std::collections::HashMap;

use crate::fit::report::FitReport;
use crate::uncertainty::{self, PredictionCovariance};
use kin_compiler::basis::Basis;
use kin_compiler::ir::{Component, FrameRef, Machine, Scalar, Var};
use kin_compiler::units::{Dim, Unit};
use kin_model::interp::{var_name, EvalError, Interpreter, State};
use kin_model::kinematics::FrameErrors;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum CurveError {
    #[error("FIT.json has {fit} coefficients but the model has {model}: it was fitted with another model")]
    Count { fit: usize, model: usize },
    #[error("coefficient {index} is `{fit}` in FIT.json but `{model}` in the model: it was fitted with another model")]
    Name {
        index: usize,
        fit: String,
        model: String,
    },
    #[error("evaluating the model: {0}")]
    Eval(#[from] EvalError),
}

/// One plotted curve: a parametric error along one variable.
pub struct Curve {
    /// `Y.ty`.
    pub target: String,
    pub variable: String,
    pub x_unit: String,
    pub y_unit: String,
    pub x: Vec<f64>,
    /// One line, or two (`dir +1`, `dir −1`) when the error depends on a direction of motion.
    pub lines: Vec<Line>,
}

pub struct Line {
    pub label: Option<String>,
    pub value: Vec<f64>,
    /// Half-width of the ≈ 95 % band: 2 standard errors.
    pub band: Vec<f64>,
}

/// A parametric error that depends on no variable (a squareness, an offset).
pub struct Constant {
    pub target: String,
    pub unit: String,
    pub value: f64,
    pub band: f64,
}

pub struct Curves {
    pub curves: Vec<Curve>,
    pub constants: Vec<Constant>,
    /// The reference state, e.g. `X = 300 mm`: where the variables not plotted are held.
    pub reference: Vec<String>,
}

/// Where a variable's values lie: SI bounds per variable, from the data when available.
pub type Ranges = HashMap<Var, (f64, f64)>;

/// How a frame is called in a `.kin` file: its axis, tool or `workpiece`.
pub fn frame_name(m: &Machine, f: FrameRef) -> String {
    let axis = |chain: &[kin_compiler::ir::Element], k: usize| {
        chain
            .get(k)
            .and_then(|e| m.axes.get(e.axis))
            .map(|a| a.name.clone())
    };
    let name = match f {
        FrameRef::Tool(k) => axis(&m.tool_chain, k),
        FrameRef::Workpiece(k) => axis(&m.workpiece_chain, k),
        FrameRef::ToolEnd(None) => Some("tool".into()),
        FrameRef::ToolEnd(Some(i)) => m.tools.get(i).map(|t| t.name.clone()),
        FrameRef::WorkpieceEnd => Some("workpiece".into()),
    };
    name.unwrap_or_else(|| "?".into())
}

/// The display unit of a state variable.
pub fn var_unit(m: &Machine, v: Var) -> Unit {
    match v {
        Var::Axis(a) => match m.axes.get(a).map(|a| a.kind) {
            Some(kin_compiler::ir::JointKind::Revolute) => m.units.angle.clone(),
            _ => m.units.length.clone(),
        },
        Var::Input(i) => m
            .inputs
            .get(i)
            .map(|i| i.unit.clone())
            .unwrap_or_else(Unit::dimensionless),
        // A lag of the input itself is in the input's unit; of a heat-source relation, in the
        // relation's: a power of the input, or a ratio to a reference value (dimensionless).
        Var::Lag(l) => m
            .lags
            .get(l)
            .and_then(|l| {
                if l.warmup {
                    // A warm-up's share of its end: a number from 0 to 1.
                    return Some(Unit::dimensionless());
                }
                let unit = &m.inputs.get(l.input)?.unit;
                Some(
                    if l.source.reference != 1.0 || l.source.power.fract() != 0.0 {
                        Unit::dimensionless()
                    } else if l.source.power == 1.0 {
                        unit.clone()
                    } else {
                        unit.powi(l.source.power as i32)
                    },
                )
            })
            .unwrap_or_else(Unit::dimensionless),
        Var::Time => m.units.time.clone(),
        Var::Direction(_) => Unit::dimensionless(),
    }
}

/// The variables a known scalar reads (with repeats).
pub(crate) fn scalar_vars(s: &Scalar, out: &mut Vec<Var>) {
    match s {
        Scalar::Num(_) => {}
        Scalar::Var(v) => out.push(*v),
        Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => scalar_vars(a, out),
        Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
            scalar_vars(a, out);
            scalar_vars(b, out);
        }
    }
}

/// The SI range a variable is plotted over: an axis's travel, an input's declared range, else
/// what the data span, else a plausible spread (the same defaults as sampled states use).
pub fn range_of(m: &Machine, v: Var, data: &Ranges) -> Option<(f64, f64)> {
    match v {
        Var::Axis(a) => m.axes.get(a).map(|a| (a.range[0], a.range[1])),
        Var::Input(i) => {
            let input = m.inputs.get(i)?;
            if let Some(r) = input.range {
                return Some((r[0], r[1]));
            }
            if let Some(r) = data.get(&v) {
                return Some(*r);
            }
            Some(match input.unit.dim {
                d if d == Dim::TEMPERATURE && input.absolute => (291.15, 295.15),
                d if d == Dim::TEMPERATURE => (0.0, 4.0),
                d if d == Dim::FORCE => (0.0, 1000.0),
                _ => (0.0, 1.0),
            })
        }
        Var::Lag(l) => match m.lags.get(l)? {
            lag if lag.warmup => Some((0.0, 1.0)),
            lag => range_of(m, Var::Input(lag.input), data),
        },
        // A time axis only means something over the measurements' own span.
        Var::Time => data.get(&v).copied(),
        Var::Direction(_) => Some((-1.0, 1.0)),
    }
}

/// The state the variables not plotted are held at: mid-range, lags in steady state with
/// their input, every direction +1.
struct Reference {
    q: Vec<f64>,
    inputs: Vec<f64>,
    lags: Vec<f64>,
    time: f64,
    dirs: Vec<f64>,
}

impl Reference {
    fn new(m: &Machine, data: &Ranges) -> Reference {
        let mid = |v: Var| {
            range_of(m, v, data)
                .map(|(lo, hi)| 0.5 * (lo + hi))
                .unwrap_or(0.0)
        };
        let inputs: Vec<f64> = (0..m.inputs.len()).map(|i| mid(Var::Input(i))).collect();
        Reference {
            q: (0..m.axes.len()).map(|a| mid(Var::Axis(a))).collect(),
            lags: m
                .lags
                .iter()
                .map(|l| {
                    if l.warmup {
                        l.steady(0.0)
                    } else {
                        inputs.get(l.input).copied().unwrap_or(0.0)
                    }
                })
                .collect(),
            inputs,
            time: mid(Var::Time),
            dirs: vec![1.0; m.axes.len()],
        }
    }

    fn set(&mut self, v: Var, x: f64) {
        let slot = match v {
            Var::Axis(a) => self.q.get_mut(a),
            Var::Input(i) => self.inputs.get_mut(i),
            Var::Lag(l) => self.lags.get_mut(l),
            Var::Time => Some(&mut self.time),
            Var::Direction(a) => self.dirs.get_mut(a),
        };
        if let Some(s) = slot {
            *s = x;
        }
    }

    fn state(&self, tool: usize) -> State<'_> {
        State {
            q: &self.q,
            inputs: &self.inputs,
            lags: &self.lags,
            time: self.time,
            dirs: &self.dirs,
            tool,
            tool_offset: None,
        }
    }

    fn describe(&self, m: &Machine, data: &Ranges) -> Vec<String> {
        let mut out = Vec::new();
        let show = |v: Var, si: f64| {
            let u = var_unit(m, v);
            format!("{} = {} {}", var_name(v, m), num(u.from_si(si), 4), u.name)
        };
        for (a, q) in self.q.iter().enumerate() {
            out.push(show(Var::Axis(a), *q));
        }
        for (i, x) in self.inputs.iter().enumerate() {
            out.push(show(Var::Input(i), *x));
        }
        if range_of(m, Var::Time, data).is_some() {
            out.push(show(Var::Time, self.time));
        }
        if !self.dirs.is_empty() {
            out.push("directions of motion +1".into());
        }
        out
    }
}

impl Target {
    /// The first variable sharing a term with `v` (directions aside: they get lines of their
    /// own).
    fn coupled(&self, v: Var) -> Option<Var> {
        let mut with: Vec<Var> = self
            .terms
            .iter()
            .filter(|t| t.contains(&v))
            .flatten()
            .copied()
            .filter(|w| *w != v && !matches!(w, Var::Direction(_)))
            .collect();
        with.sort_by_key(|w| order(*w));
        with.first().copied()
    }
}

/// One parametric error with fitted coefficients: which coefficients, over which variables.
struct Target {
    frame: FrameRef,
    component: Component,
    columns: Vec<usize>,
    vars: Vec<Var>,
    /// The variables of each fitted term: a variable coupled with another in one term is
    /// drawn at several values of the other, since at one reference value the coupling may
    /// vanish (a centred `linear(Y)` is zero mid-travel).
    terms: Vec<Vec<Var>>,
    /// Samples per curve: more where a periodic or harmonic basis oscillates along the variable.
    dense: Vec<Var>,
}

fn targets(m: &Machine) -> Vec<Target> {
    let mut out: Vec<Target> = Vec::new();
    for model in &m.errors {
        let k = match out
            .iter()
            .position(|t| t.frame == model.frame && t.component == model.component)
        {
            Some(k) => k,
            None => {
                out.push(Target {
                    frame: model.frame,
                    component: model.component,
                    columns: Vec::new(),
                    vars: Vec::new(),
                    terms: Vec::new(),
                    dense: Vec::new(),
                });
                out.len() - 1
            }
        };
        let Some(t) = out.get_mut(k) else { continue };
        for term in model.terms.iter().filter(|t| t.coefficients > 0) {
            t.columns.extend(term.first..term.first + term.coefficients);
            let mut vars = Vec::new();
            scalar_vars(&term.scale, &mut vars);
            for f in &term.factors {
                vars.push(f.var);
                if matches!(f.basis, Basis::Periodic { .. } | Basis::Fourier { .. }) {
                    t.dense.push(f.var);
                }
            }
            t.vars.extend(&vars);
            t.terms.push(vars);
        }
    }
    for t in &mut out {
        t.columns.sort_unstable();
        t.columns.dedup();
        t.vars.sort_by_key(|v| order(*v));
        t.vars.dedup();
    }
    out.retain(|t| !t.columns.is_empty());
    out
}

fn order(v: Var) -> (u8, usize) {
    match v {
        Var::Axis(a) => (0, a),
        Var::Input(i) => (1, i),
        Var::Lag(l) => (2, l),
        Var::Time => (3, 0),
        Var::Direction(a) => (4, a),
    }
}

/// β̂ (SI) from a fit report, checked against the model.
fn estimates(m: &Machine, fit: &FitReport) -> Result<Vec<f64>, CurveError> {
    let n = m.coefficients.len();
    if fit.coefficients.len() != n {
        return Err(CurveError::Count {
            fit: fit.coefficients.len(),
            model: n,
        });
    }
    let mut beta = Vec::with_capacity(n);
    for (j, (e, c)) in fit.coefficients.iter().zip(&m.coefficients).enumerate() {
        if e.name != c.name {
            return Err(CurveError::Name {
                index: j,
                fit: e.name.clone(),
                model: c.name.clone(),
            });
        }
        beta.push(e.value * c.unit.scale);
    }
    Ok(beta)
}

/// Evaluates every fitted parametric error of `m` along its variables.
pub fn curves(m: &Machine, fit: &FitReport, data: &Ranges) -> Result<Curves, CurveError> {
    let beta = estimates(m, fit)?;
    let n = beta.len();
    // Without a usable covariance the curves are still drawn, without bands.
    let cov = PredictionCovariance::new(m, fit).ok();
    let mut engine = Interpreter::new(m)?;
    // The fitted non-linear parameters (wavelengths, time constants) shape the curves too.
    let nonlinear = fit.nonlinear_values(m);
    engine.set_nonlinear(&nonlinear)?;
    let mut reference = Reference::new(m, data);
    let described = reference.describe(m, data);
    let mut probe = Probe {
        engine,
        errors: FrameErrors::zeros(m),
        unit: vec![0.0; n],
    };
    let mut out = Curves {
        curves: Vec::new(),
        constants: Vec::new(),
        reference: described,
    };
    for t in targets(m) {
        let tool = match t.frame {
            FrameRef::ToolEnd(Some(i)) => i,
            _ => 0,
        };
        let name = format!("{}.{}", frame_name(m, t.frame), t.component.name());
        let y_unit = if t.component.is_rotation() {
            &m.units.tilt
        } else {
            &m.units.error
        };
        let directions: Vec<usize> = t
            .vars
            .iter()
            .filter_map(|v| {
                if let Var::Direction(a) = v {
                    Some(*a)
                } else {
                    None
                }
            })
            .collect();
        let mut plotted: Vec<Var> = t
            .vars
            .iter()
            .copied()
            .filter(|v| !matches!(v, Var::Direction(_)))
            .collect();
        if plotted.is_empty() {
            if let Some(&a) = directions.first() {
                // Only a direction (pure backlash): show it along its axis, one line per direction.
                plotted.push(Var::Axis(a));
            }
        }
        if plotted.is_empty() {
            let state = reference.state(tool);
            let (v, s) = probe.at(&state, &t, &beta, cov.as_ref(), &nonlinear)?;
            out.constants.push(Constant {
                target: name,
                unit: y_unit.name.clone(),
                value: y_unit.from_si(v),
                band: 2.0 * s / y_unit.scale,
            });
            continue;
        }
        let signs: Vec<Option<f64>> = if directions.is_empty() {
            vec![None]
        } else {
            vec![Some(1.0), Some(-1.0)]
        };
        for v in plotted {
            let Some((lo, hi)) = range_of(m, v, data) else {
                continue;
            };
            let samples = if t.dense.contains(&v) { 1201 } else { 241 };
            let xu = var_unit(m, v);
            let xs: Vec<f64> = (0..samples)
                .map(|i| lo + (hi - lo) * i as f64 / (samples - 1) as f64)
                .collect();
            // Lines: one per direction of motion and per level of a coupled variable.
            let levels: Vec<Option<(Var, f64)>> =
                match t.coupled(v).and_then(|w| Some((w, range_of(m, w, data)?))) {
                    Some((w, (wlo, whi))) => [wlo, 0.5 * (wlo + whi), whi]
                        .into_iter()
                        .map(|x| Some((w, x)))
                        .collect(),
                    None => vec![None],
                };
            let mut lines = Vec::new();
            for sign in &signs {
                for &a in &directions {
                    reference.set(Var::Direction(a), sign.unwrap_or(1.0));
                }
                for level in &levels {
                    let held = level.map(|(w, _)| (w, reference_value(&reference, w)));
                    if let Some((w, x)) = level {
                        set_with_lags(&mut reference, m, *w, *x);
                    }
                    let mut parts = Vec::new();
                    if let Some(s) = sign {
                        parts.push(if *s > 0.0 {
                            "moving +".to_string()
                        } else {
                            "moving −".to_string()
                        });
                    }
                    if let Some((w, x)) = level {
                        let wu = var_unit(m, *w);
                        parts.push(format!(
                            "{} = {} {}",
                            var_name(*w, m),
                            num(wu.from_si(*x), 3),
                            wu.name
                        ));
                    }
                    let mut line = Line {
                        label: (!parts.is_empty()).then(|| parts.join(", ")),
                        value: Vec::with_capacity(samples),
                        band: Vec::with_capacity(samples),
                    };
                    let saved = reference_value(&reference, v);
                    for &x in &xs {
                        set_with_lags(&mut reference, m, v, x);
                        let (value, se) = probe.at(
                            &reference.state(tool),
                            &t,
                            &beta,
                            cov.as_ref(),
                            &nonlinear,
                        )?;
                        line.value.push(y_unit.from_si(value));
                        line.band.push(2.0 * se / y_unit.scale);
                    }
                    set_with_lags(&mut reference, m, v, saved);
                    if let Some((w, x)) = held {
                        set_with_lags(&mut reference, m, w, x);
                    }
                    lines.push(line);
                }
            }
            for &a in &directions {
                reference.set(Var::Direction(a), 1.0);
            }
            out.curves.push(Curve {
                target: name.clone(),
                variable: var_name(v, m),
                x_unit: xu.name.clone(),
                y_unit: y_unit.name.clone(),
                x: xs.iter().map(|x| xu.from_si(*x)).collect(),
                lines,
            });
        }
    }
    Ok(out)
}

/// `v` with `digits` significant digits; scientific outside 1e-3 .. 1e6; a dash when not a
/// number, so a table never shows `NaN`.
pub fn num(v: f64, digits: usize) -> String {
    if !v.is_finite() {
        return "—".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e6).contains(&a) {
        return format!("{:.*e}", digits.saturating_sub(1).min(3), v);
    }
    let decimals = (digits as i32 - 1 - a.log10().floor() as i32).clamp(0, 9) as usize;
    format!("{v:.decimals$}")
}

fn reference_value(r: &Reference, v: Var) -> f64 {
    match v {
        Var::Axis(a) => r.q.get(a).copied(),
        Var::Input(i) => r.inputs.get(i).copied(),
        Var::Lag(l) => r.lags.get(l).copied(),
        Var::Time => Some(r.time),
        Var::Direction(a) => r.dirs.get(a).copied(),
    }
    .unwrap_or(0.0)
}

/// Sets a variable; a lag in steady state follows its input.
fn set_with_lags(r: &mut Reference, m: &Machine, v: Var, x: f64) {
    r.set(v, x);
    if let Var::Input(i) = v {
        for (l, lag) in m.lags.iter().enumerate() {
            if !lag.warmup && lag.input == i {
                r.set(Var::Lag(l), lag.steady(x));
            }
        }
    }
}

/// Evaluates one parametric error's gradient with respect to its coefficients.
struct Probe<'m> {
    engine: Interpreter<'m>,
    errors: FrameErrors,
    /// All zeros between uses: a unit vector is set and cleared around each evaluation.
    unit: Vec<f64>,
}

impl Probe<'_> {
    fn component(&mut self, state: &State, t: &Target) -> Result<f64, CurveError> {
        self.engine
            .frame_errors(state, &self.unit, &mut self.errors)?;
        Ok(self
            .errors
            .get(t.frame)
            .and_then(|e| e.get(t.component.index()))
            .copied()
            .unwrap_or(0.0))
    }

    /// `g(x)`: the error's change per unit of each of its coefficients `t.columns` at `state`.
    fn gradient(&mut self, state: &State, t: &Target) -> Result<Vec<f64>, CurveError> {
        let fixed = self.component(state, t)?;
        let mut g = Vec::with_capacity(t.columns.len());
        for &j in &t.columns {
            if let Some(u) = self.unit.get_mut(j) {
                *u = 1.0;
            }
            let e = self.component(state, t);
            if let Some(u) = self.unit.get_mut(j) {
                *u = 0.0;
            }
            g.push(e? - fixed);
        }
        Ok(g)
    }

    /// The fitted value `gᵀβ̂` (SI) at `state` and its standard uncertainty (eq. 4.12 with the
    /// share of the fitted non-linear parameters, whose values are `nonlinear`; 0 without a
    /// covariance).
    fn at(
        &mut self,
        state: &State,
        t: &Target,
        beta: &[f64],
        cov: Option<&PredictionCovariance>,
        nonlinear: &[f64],
    ) -> Result<(f64, f64), CurveError> {
        let fitted = |g: &[f64]| -> f64 {
            t.columns
                .iter()
                .zip(g)
                .map(|(&j, gj)| gj * beta.get(j).copied().unwrap_or(0.0))
                .sum()
        };
        let g = self.gradient(state, t)?;
        let value = fitted(&g);
        let Some(cov) = cov else {
            return Ok((value, 0.0));
        };
        let mut full = vec![0.0; beta.len()];
        for (&j, gj) in t.columns.iter().zip(&g) {
            if let Some(slot) = full.get_mut(j) {
                *slot = *gj;
            }
        }
        // h = ∂(gᵀβ̂)/∂θ for the included parameters, by central differences.
        let mut h = Vec::with_capacity(cov.nonlinear().len());
        for &i in cov.nonlinear() {
            let x = nonlinear.get(i).copied().unwrap_or(0.0);
            let d = uncertainty::step(x);
            let mut side = |v: f64| -> Result<f64, CurveError> {
                let mut values = nonlinear.to_vec();
                if let Some(slot) = values.get_mut(i) {
                    *slot = v;
                }
                self.engine.set_nonlinear(&values)?;
                Ok(fitted(&self.gradient(state, t)?))
            };
            let (up, down) = (side(x + d), side(x - d));
            self.engine.set_nonlinear(nonlinear)?;
            h.push((up? - down?) / (2.0 * d));
        }
        Ok((value, cov.variance(&full, &h).max(0.0).sqrt()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn machine(src: &str) -> Machine {
        let out = kin_compiler::compile(src);
        out.compiled
            .map(|c| c.machine)
            .unwrap_or_else(|| panic!("{:?}", out.diagnostics))
    }

    const SRC: &str = "machine m {
        task position
        units { length mm, angle deg, error um, tilt urad, time min, temperature degC }
        axis X prismatic along x range 0 mm .. 500 mm
        tool chain { X moving  tool t at (0, 0, 0) mm }
        workpiece chain { workpiece at (0, 0, 0) mm }
        errors {
            X.tx = linear(X)
            X.ty = backlash(X)
            X.rz = const
        }
    }";

    fn report(m: &Machine, values: &[f64], cov: Vec<f64>) -> FitReport {
        let json = serde_json::json!({
            "version": 1, "machine": "m", "model_hash": "0", "engine": "interp", "solver": "qr", "tolerance": 1e-10,
            "columns": values.len(), "rank": values.len(), "condition": 1.0, "rows": 10, "dof": 7,
            "sigma": 0.1, "rms": 0.1, "max": 0.2, "r2": 0.9, "error_unit": "um", "tilt_unit": "urad",
            "files": [], "nonlinear": [], "nuisance": [], "covariance": cov,
            "outlier_threshold": 4.0, "cook_threshold": 1.0, "outliers": [], "residuals": [], "residuals_omitted": 0,
            "validation": [], "validation_residuals": [], "constrained": [], "stepwise": null, "params": "",
            "coefficients": m.coefficients.iter().zip(values).map(|(c, v)| serde_json::json!({
                "name": c.name, "label": c.label, "unit": c.unit.name, "value": v, "se": 0.0, "kept": true
            })).collect::<Vec<_>>(),
        });
        serde_json::from_value(json).expect("report")
    }

    #[test]
    fn a_linear_error_is_drawn_with_its_band() {
        let m = machine(SRC);
        assert_eq!(m.coefficients.len(), 3);
        // tx = β₀ (2s − 1): 2 um at the far end; var(β₀) = (0.5 um)² in SI.
        let mut cov = vec![0.0; 9];
        cov[0] = (0.5e-6f64).powi(2);
        let fit = report(&m, &[2.0, 1.0, 3.0], cov);
        let c = curves(&m, &fit, &Ranges::new()).expect("curves");
        let tx = c.curves.iter().find(|c| c.target == "X.tx").expect("X.tx");
        assert_eq!(
            (tx.variable.as_str(), tx.x_unit.as_str(), tx.y_unit.as_str()),
            ("X", "mm", "um")
        );
        let line = &tx.lines[0];
        let last = tx.x.len() - 1;
        assert!((tx.x[last] - 500.0).abs() < 1e-9);
        assert!(
            (line.value[last] - 2.0).abs() < 1e-9 && (line.value[0] + 2.0).abs() < 1e-9,
            "{:?}",
            &line.value[..3]
        );
        assert!(
            (line.band[last] - 1.0).abs() < 1e-9,
            "band {}",
            line.band[last]
        );
        assert!(
            line.band[tx.x.len() / 2].abs() < 1e-9,
            "no uncertainty where the line passes zero"
        );
        // Backlash: two lines, ±1 um.
        let ty = c.curves.iter().find(|c| c.target == "X.ty").expect("X.ty");
        assert_eq!(ty.lines.len(), 2);
        assert!(
            (ty.lines[0].value[0] - 1.0).abs() < 1e-9 && (ty.lines[1].value[0] + 1.0).abs() < 1e-9
        );
        // A constant is a table row, not a plot.
        assert_eq!(c.constants.len(), 1);
        assert_eq!(c.constants[0].target, "X.rz");
        assert!((c.constants[0].value - 3.0).abs() < 1e-9 && c.constants[0].unit == "urad");
    }

    #[test]
    fn a_report_of_another_model_is_refused() {
        let m = machine(SRC);
        let fit = report(&m, &[1.0, 2.0], vec![0.0; 4]);
        assert!(matches!(
            curves(&m, &fit, &Ranges::new()),
            Err(CurveError::Count { fit: 2, model: 3 })
        ));
    }
}
