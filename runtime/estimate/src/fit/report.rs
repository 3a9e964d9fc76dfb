//! What a fit reports: `FIT.json` (every coefficient with its unit, value and standard error,
//! the noise estimate, the rank, residuals and outliers) and the bound parameters as `.kin`
//! text that `kin eval`, `kin simulate` and compensation load back.

use kin_compiler::ir::Machine;
use serde::{Deserialize, Serialize};

use super::design::{NuisanceKind, Weights, LENGTH};
use super::tally::{FileTally, Tally};
use super::{solve, FitResult, Options, ResidualRow};
use crate::fit::DataSet;
use kin_data::data::OBSERVED;

/// JSON has no NaN or infinity: serde_json writes them as `null`. Read `null` back as NaN so a
/// report with an undetermined quantity (an unbounded standard error) still loads.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// As [`nan_if_null`], for every element of an array.
pub(crate) fn nans_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
    Ok(Vec::<Option<f64>>::deserialize(d)?
        .into_iter()
        .map(|x| x.unwrap_or(f64::NAN))
        .collect())
}

/// Format version of `FIT.json`.
pub const VERSION: u32 = 1;

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitReport {
    pub version: u32,
    pub machine: String,
    /// FNV-1a hash of the model's source text: which revision of the model this fit belongs to.
    pub model_hash: String,
    pub engine: String,
    pub solver: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub tolerance: f64,
    pub columns: usize,
    pub rank: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub condition: f64,
    pub rows: usize,
    pub dof: usize,
    /// Noise estimate σ̂, residual RMS and largest |residual|, in `error_unit` (rotation rows
    /// count a tilt unit as an error unit).
    #[serde(deserialize_with = "nan_if_null")]
    pub sigma: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rms: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub max: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub r2: f64,
    pub error_unit: String,
    pub tilt_unit: String,
    pub files: Vec<FileSummary>,
    pub coefficients: Vec<Estimate>,
    pub nonlinear: Vec<Estimate>,
    pub nuisance: Vec<Estimate>,
    /// Covariance of the coefficients (eq. 4.11), SI, row-major `n × n`.
    #[serde(deserialize_with = "nans_if_null")]
    pub covariance: Vec<f64>,
    /// Covariance `S` of the non-linear parameters, SI, row-major `K × K` over every one of
    /// the model's non-linear parameters (zero for fixed ones); empty when none was fitted.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nonlinear_covariance: Vec<f64>,
    /// `A = (XᵀX)⁻¹XᵀD_θ`, row-major `n × K`: how the coefficients' estimates move with the
    /// non-linear parameters, so that `Cov(β, θ) = −A·S` ([`super::nonlinear::Joint`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nonlinear_sensitivity: Vec<f64>,
    #[serde(deserialize_with = "nan_if_null")]
    pub outlier_threshold: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub cook_threshold: f64,
    pub outliers: Vec<Residual>,
    /// Every row's residual, unless there were more than `MAX_RESIDUALS`.
    pub residuals: Vec<Residual>,
    pub residuals_omitted: usize,
    pub validation: Vec<FileSummary>,
    pub validation_residuals: Vec<Residual>,
    /// Messages naming what a minimum-norm fit of a deficient problem constrained.
    pub constrained: Vec<String>,
    /// What the data determine (spec/design.md): absent in reports of earlier versions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub estimability: Option<FitEstimability>,
    /// The stepwise selection: its steps, and which regressors of each term survived.
    pub stepwise: Option<StepwiseReport>,
    /// The fitted values as a `params { … }` block.
    pub params: String,
    /// The stated instrument noise the rows were weighted by, and the χ² test of σ̂ against it.
    /// When present, `sigma`, `rms` and `max` are ratios to that noise (dimensionless); the
    /// residuals and the per-file and per-component summaries stay in display units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<StatedWeights>,
    /// With a σ per file (`--noise FILE=…`, a file's `# noise:` header, `--noise-per-file`):
    /// each file's σ per kind of row, stated or estimated, and σ̂ against it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_per_file: Option<NoisePerFile>,
    /// Every error component that varies along one axis, as values at stations along it with
    /// their standard uncertainties (spec/json.md); absent in reports of earlier versions.
    #[serde(default)]
    pub stations: Vec<super::stations::StationTable>,
    /// Sets of coefficients whose large estimates cancel each other ([`super::cancel`]);
    /// absent in reports of earlier versions.
    #[serde(default)]
    pub cancelling: Vec<CancellingSet>,
    /// Coefficients the data barely separate ([`super::cancel::weak`]); absent in reports of
    /// earlier versions.
    #[serde(default)]
    pub weak: Vec<WeakSet>,
    /// Files of absolute positions: where their instrument and targets were found
    /// ([`crate::register`]); absent otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub registration: Vec<crate::register::PlacementReport>,
}

/// Coefficients whose effects on the data cancel (see [`super::cancel`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CancellingSet {
    /// The coefficients' names, in declaration order.
    pub members: Vec<String>,
    /// The largest member's effect alone and the set's joint effect on the fitted values:
    /// lengths over the rows in units of σ̂.
    #[serde(deserialize_with = "nan_if_null")]
    pub largest: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub joint: f64,
}

/// Coefficients the data barely separate (see [`super::cancel::weak`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WeakSet {
    /// The coefficients' names, in declaration order.
    pub members: Vec<String>,
    /// Each one's variance inflation: its variance over what its column alone would give.
    pub inflation: Vec<f64>,
}

/// The weights of a fit by a stated noise (`kin fit --noise`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StatedWeights {
    /// The stated standard deviation of positions and lengths, error unit (`null` if none).
    #[serde(default)]
    pub position: Option<f64>,
    /// The stated standard deviation of rotations, tilt unit (`null` if none).
    #[serde(default)]
    pub rotation: Option<f64>,
    pub error_unit: String,
    pub tilt_unit: String,
    /// Σ (residual / σ)² over the fitted rows, on `dof` degrees of freedom.
    #[serde(deserialize_with = "nan_if_null")]
    pub chi2: f64,
    pub dof: usize,
    /// P(χ²_dof ≥ chi2): small when the residuals exceed what the stated noise gives.
    #[serde(deserialize_with = "nan_if_null")]
    pub p: f64,
}

/// The σs of a fit with a σ per file ([`super::components`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NoisePerFile {
    /// Weighted fits made (1 when every σ was stated).
    pub iterations: usize,
    /// Whether the estimated σs settled (every σ̂/σ within 1e-3 of 1).
    pub converged: bool,
    pub files: Vec<FileNoise>,
}

/// One file's σ of one kind of row.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FileNoise {
    pub file: String,
    /// `position` (positions and lengths, error unit) or `rotation` (tilt unit).
    pub kind: super::components::RowKind,
    pub unit: String,
    /// The σ the rows were weighted by: the stated one, or the converged estimate.
    #[serde(deserialize_with = "nan_if_null")]
    pub sigma: f64,
    pub stated: bool,
    /// σ̂ of the file's rows (outliers left out), in `unit`.
    #[serde(deserialize_with = "nan_if_null")]
    pub sigma_hat: f64,
    /// σ̂/σ: 1 for an estimated σ; for a stated one, how the file's scatter compares with it.
    #[serde(deserialize_with = "nan_if_null")]
    pub ratio: f64,
    pub rows: usize,
    /// Σ (1 − leverage) over the rows used: the degrees of freedom the file contributes.
    #[serde(deserialize_with = "nan_if_null")]
    pub redundancy: f64,
    pub outliers: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StepwiseReport {
    #[serde(deserialize_with = "nan_if_null")]
    pub alpha_remove: f64,
    pub alpha_enter: Option<f64>,
    pub steps: Vec<StepReport>,
    /// Per error component: the labels of the regressors kept and removed.
    pub components: Vec<Survivors>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StepReport {
    pub name: String,
    pub label: String,
    pub action: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub f: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub p: f64,
}

/// The estimability of a fit's unknowns (coefficients, then nuisance parameters).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitEstimability {
    pub rank: usize,
    pub columns: usize,
    /// Per coefficient: its standard error per unit of σ̂ (coefficient unit per error unit);
    /// null when the data do not determine it.
    #[serde(deserialize_with = "nans_if_null")]
    pub se_per_sigma: Vec<f64>,
    /// Groups of unknowns the data cannot separate, with the combinations they determine.
    pub groups: Vec<FitGroup>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitGroup {
    pub members: Vec<String>,
    pub determined: Vec<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Survivors {
    pub component: String,
    pub kept: Vec<String>,
    pub removed: Vec<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Estimate {
    pub name: String,
    pub label: String,
    pub unit: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub value: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub se: f64,
    /// False for a coefficient stepwise selection removed (its value is 0 by decision).
    #[serde(default = "yes")]
    pub kept: bool,
    /// For a fitted non-linear parameter the data do not determine, or do not tell apart from
    /// its start value: why, with the test's p-value (`label` is then `undetermined` or
    /// `not significant`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The coefficient's ISO 230-1 name (`EXX`, or `-EC0Y` for a constant that is minus that
    /// squareness), when its frame is an axis'; absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iso: Option<String>,
    /// The robot engineer's name of a constant (`joint offset`, `link length δa`, …) on a
    /// chain of joints about their own z ([`Machine::robot_names`]); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot: Option<String>,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FileSummary {
    pub path: String,
    pub kind: String,
    pub rows: usize,
    /// Per observed quantity (`ex`, …, `dL`): rows, RMS and max |residual|, display units.
    pub components: Vec<ComponentSummary>,
    #[serde(deserialize_with = "nan_if_null")]
    pub rms: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub max: f64,
    pub outliers: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ComponentSummary {
    pub name: String,
    pub unit: String,
    pub rows: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub rms: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub max: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Residual {
    pub file: u32,
    pub line: u32,
    pub component: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub observed: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub residual: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub studentized: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub leverage: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub cook: f64,
}

/// Beyond this many rows the per-row residuals are left out of `FIT.json` (summaries and
/// outliers stay).
pub(crate) const MAX_RESIDUALS: usize = 200_000;

pub fn component_name(c: u8) -> &'static str {
    if c == LENGTH {
        "dL"
    } else {
        OBSERVED.get(c as usize).copied().unwrap_or("?")
    }
}

/// FNV-1a, 64 bit: stable across runs and platforms, enough to tell model revisions apart.
pub fn model_hash(source: &str) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in source.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x100000001b3);
    }
    format!("{h:016x}")
}

/// What turns a weighted value of a row of `component` into its display unit: undo the row's
/// weight, then express the SI value in the error or tilt unit.
fn display_factor(m: &Machine, w: &Weights, component: u8) -> f64 {
    let unit = if (3..6).contains(&component) {
        &m.units.tilt
    } else {
        &m.units.error
    };
    1.0 / (w.of(component) * unit.scale)
}

/// Each component's [`display_factor`], for a [`Tally`].
pub(super) fn display_factors(m: &Machine, w: &Weights) -> [f64; LENGTH as usize + 1] {
    std::array::from_fn(|c| display_factor(m, w, c as u8))
}

fn residual(m: &Machine, w: &Weights, r: &ResidualRow) -> Residual {
    let s = display_factor(m, w, r.meta.component);
    Residual {
        file: r.meta.file,
        line: r.meta.line,
        component: component_name(r.meta.component).to_string(),
        observed: r.observed * s,
        residual: r.residual * s,
        studentized: r.studentized,
        leverage: r.leverage,
        cook: r.cook,
    }
}

fn summaries(m: &Machine, files: &[DataSet], tally: &Tally) -> Vec<FileSummary> {
    files
        .iter()
        .enumerate()
        .map(|(f, file)| {
            let empty = FileTally::default();
            let mine = tally.file(f).unwrap_or(&empty);
            let components = (0..=LENGTH)
                .filter_map(|c| {
                    let sum = mine.components.get(c as usize)?;
                    if sum.rows == 0 {
                        return None;
                    }
                    let unit = if (3..6).contains(&c) {
                        &m.units.tilt
                    } else {
                        &m.units.error
                    };
                    Some(ComponentSummary {
                        name: component_name(c).to_string(),
                        unit: unit.name.clone(),
                        rows: sum.rows,
                        rms: sum.rms(),
                        max: sum.max(),
                    })
                })
                .collect();
            FileSummary {
                path: file.path.display().to_string(),
                kind: match file.observations {
                    kin_data::data::Observations::Points(_) => "points".into(),
                    kin_data::data::Observations::Lengths(_) => "lengths".into(),
                },
                rows: mine.all.rows,
                components,
                rms: mine.all.rms(),
                max: mine.all.max(),
                outliers: mine.outliers,
            }
        })
        .collect()
}

pub fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// Builds the report of a fit.
#[allow(clippy::too_many_arguments)]
/// A null-space weight (unit vectors in scaled coordinates) above this makes its coefficient
/// undetermined; rounding leaves weights near 1e-16.
const UNDETERMINED: f64 = 1e-6;

pub fn build(
    m: &Machine,
    source: &str,
    engine: &str,
    files: &[DataSet],
    validate: &[DataSet],
    result: &FitResult,
    options: &Options,
) -> FitReport {
    let nonlinear: Vec<Estimate> = m
        .nonlinear
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let (value, se, verdict) = match &result.nonlinear {
                Some(n) => (
                    n.values.get(i).copied().unwrap_or(p.value),
                    n.se.get(i).copied().flatten().unwrap_or(0.0),
                    n.verdicts.get(i).copied().flatten(),
                ),
                None => (p.value, 0.0, None),
            };
            let start = format!("{} {}", p.unit.from_si(p.value), p.unit.name);
            let (label, note) = match verdict {
                _ if !p.fitted => ("fixed", None),
                Some(v) if !v.determined => (
                    "undetermined",
                    Some(format!(
                        "the data do not determine it: the term it shapes explains no more than noise (p = {:.2e}) or its standard error is unbounded; start value {start}",
                        v.term_p
                    )),
                ),
                Some(v) if !v.significant() => (
                    "not significant",
                    Some(format!(
                        "no better than its start value {start} (p = {:.2e})",
                        v.start_p
                    )),
                ),
                _ => ("fitted", None),
            };
            Estimate {
                name: p.name.clone(),
                label: label.into(),
                unit: p.unit.name.clone(),
                value: p.unit.from_si(value),
                se: se / p.unit.scale,
                kept: true,
                note,
                iso: None,
                robot: None,
            }
        })
        .collect();
    let sol = &result.solution;
    let sigma2 = result.sigma * result.sigma;
    let var = solve::variances(&sol.g, sigma2);
    let n = m.coefficients.len();
    // A minimum-norm fit of a deficient problem: a coefficient that an unobserved direction
    // moves has no estimate (its min-norm value is one choice among infinitely many, and the
    // variance of that choice is not the uncertainty of the coefficient). Its value stays in
    // `value` for predictions (which the null space does not change); `se` is NaN and `note`
    // says why, so no report prints it as a value with a standard error.
    let undetermined =
        |j: usize| (0..sol.null.ncols()).any(|k| sol.null[(j, k)].abs() > UNDETERMINED);
    let iso = m.iso_names();
    let robot = m.robot_names();
    let coefficients: Vec<Estimate> = m
        .coefficients
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let blind = undetermined(j);
            Estimate {
                name: c.name.clone(),
                label: c.label.clone(),
                unit: c.unit.name.clone(),
                value: sol.beta.get(j).copied().unwrap_or(0.0) / c.unit.scale,
                se: if blind {
                    f64::NAN
                } else {
                    var.get(j).copied().unwrap_or(f64::NAN).sqrt() / c.unit.scale
                },
                kept: result
                    .selection
                    .as_ref()
                    .is_none_or(|s| s.kept.get(j).copied().unwrap_or(true)),
                note: blind.then(|| {
                    "undetermined: the data do not separate it from other terms (its value is \
                     the minimum-norm choice)"
                        .to_string()
                }),
                iso: iso.get(j).cloned().flatten(),
                robot: robot.get(j).cloned().flatten(),
            }
        })
        .collect();
    let nuisance: Vec<Estimate> = result
        .layout
        .nuisance
        .iter()
        .enumerate()
        .map(|(k, nu)| {
            let unit = if matches!(
                nu.kind,
                NuisanceKind::Rotation(_) | NuisanceKind::InstrumentRotation(_)
            ) {
                &m.units.tilt
            } else {
                &m.units.error
            };
            let j = n + k;
            Estimate {
                name: nu.name(),
                label: files
                    .get(nu.file)
                    .map(|f| f.path.display().to_string())
                    .unwrap_or_default(),
                unit: unit.name.clone(),
                value: sol.beta.get(j).copied().unwrap_or(0.0) / unit.scale,
                se: var.get(j).copied().unwrap_or(f64::NAN).sqrt() / unit.scale,
                kept: true,
                note: None,
                iso: None,
                robot: None,
            }
        })
        .collect();
    let cov_full = solve::covariance(&sol.g, sigma2);
    let covariance: Vec<f64> = (0..n)
        .flat_map(|a| (0..n).map(move |b| (a, b)))
        .map(|(a, b)| cov_full[(a, b)])
        .collect();
    let s = m.units.error.scale;
    let w = &result.layout.weights;
    // A streamed fit brings its tally; otherwise it is made from the rows held.
    let held;
    let tally = match &result.tally {
        Some(t) => t,
        None => {
            let mut t = Tally::new(
                files.len(),
                display_factors(m, w),
                s,
                result.outlier_threshold,
                result.cook_threshold,
            )
            .with_file_display(
                (0..result.layout.file_weights.len())
                    .map(|f| display_factors(m, &result.layout.weights_of(f)))
                    .collect(),
            );
            for r in &result.residuals {
                t.add(r);
            }
            held = t;
            &held
        }
    };
    // A fit with σs per file weighs each file's rows by its own.
    let own = |r: &ResidualRow| residual(m, &result.layout.weights_of(r.meta.file as usize), r);
    let outliers: Vec<Residual> = tally.outliers().iter().map(own).collect();
    let keep = result.rows <= MAX_RESIDUALS && result.residuals.len() == result.rows;
    let estimability = {
        let names: Vec<String> = coefficients
            .iter()
            .chain(&nuisance)
            .map(|e| e.name.clone())
            .collect();
        let null: Vec<nalgebra::DVector<f64>> = (0..sol.null.ncols())
            .map(|k| nalgebra::DVector::from_fn(sol.null.nrows(), |j, _| sol.null[(j, k)]))
            .collect();
        let ratio = result.sigma / s;
        FitEstimability {
            rank: sol.rank,
            columns: result.layout.columns(),
            se_per_sigma: coefficients
                .iter()
                .map(|e| if ratio > 0.0 { e.se / ratio } else { f64::NAN })
                .collect(),
            groups: crate::design::groups_of(&null, &sol.scale)
                .into_iter()
                .map(|g| {
                    let members: Vec<String> = g
                        .members
                        .iter()
                        .map(|&j| names.get(j).cloned().unwrap_or_default())
                        .collect();
                    FitGroup {
                        determined: g
                            .combinations
                            .iter()
                            .map(|w| crate::design::combination_text(&members, w))
                            .collect(),
                        members,
                    }
                })
                .collect(),
        }
    };
    let cancelling = super::cancel::cancelling(sol.beta.get(..n).unwrap_or(&[]), &covariance)
        .into_iter()
        .map(|c| CancellingSet {
            members: c
                .members
                .iter()
                .filter_map(|&j| coefficients.get(j).map(|e| e.name.clone()))
                .collect(),
            largest: c.largest,
            joint: c.joint,
        })
        .collect();
    // What each constant's variance would be were its column alone: σ̂²/‖x‖².
    let mut alone = vec![None; n];
    for term in m.errors.iter().flat_map(|e| &e.terms) {
        if term.is_constant() {
            for j in term.first..term.first + term.coefficients {
                let scale = sol.scale.get(j).copied().unwrap_or(0.0);
                if let Some(slot) = alone.get_mut(j) {
                    *slot = (scale > 0.0).then_some(sigma2 * scale * scale);
                }
            }
        }
    }
    let weak = super::cancel::weak(sol.beta.get(..n).unwrap_or(&[]), &covariance, &alone)
        .into_iter()
        .map(|w| WeakSet {
            members: w
                .members
                .iter()
                .filter_map(|&j| coefficients.get(j).map(|e| e.name.clone()))
                .collect(),
            inflation: w.inflation,
        })
        .collect();
    let mut report = FitReport {
        stations: Vec::new(),
        registration: Vec::new(),
        weak,
        cancelling,
        estimability: Some(estimability),
        version: VERSION,
        machine: m.name.clone(),
        model_hash: model_hash(source),
        engine: engine.to_string(),
        solver: format!("{:?}", options.solver).to_lowercase(),
        tolerance: options.tolerance,
        columns: result.layout.columns(),
        rank: sol.rank,
        condition: sol.condition,
        rows: result.rows,
        dof: result.rows.saturating_sub(sol.rank),
        sigma: result.sigma / s,
        rms: tally.all().rms(),
        max: tally.all().max(),
        r2: result.r2,
        error_unit: m.units.error.name.clone(),
        tilt_unit: m.units.tilt.name.clone(),
        files: summaries(m, files, tally),
        weights: stated_weights(m, options, result),
        noise_per_file: noise_per_file(m, files, result),
        params: params_text(m, &sol.beta, &nonlinear),
        stepwise: result
            .selection
            .as_ref()
            .map(|sel| stepwise_report(m, sel, options)),
        coefficients,
        nonlinear,
        nuisance,
        covariance,
        nonlinear_covariance: result
            .nonlinear
            .as_ref()
            .map(|n| n.joint.s.clone())
            .unwrap_or_default(),
        nonlinear_sensitivity: result
            .nonlinear
            .as_ref()
            .map(|n| n.joint.a.clone())
            .unwrap_or_default(),
        outlier_threshold: result.outlier_threshold,
        cook_threshold: result.cook_threshold,
        outliers,
        residuals: if keep {
            result.residuals.iter().map(own).collect()
        } else {
            Vec::new()
        },
        residuals_omitted: if keep { 0 } else { result.rows },
        validation: summaries(
            m,
            validate,
            &Tally::of(
                &result.validation,
                validate.len(),
                display_factors(m, w),
                s,
                f64::INFINITY,
                f64::INFINITY,
            ),
        ),
        validation_residuals: result
            .validation
            .iter()
            .map(|r| residual(m, w, r))
            .collect(),
        constrained: result
            .constrained
            .iter()
            .map(|d| d.message.clone())
            .collect(),
    };
    let nonlinear_si: Vec<f64> = m
        .nonlinear
        .iter()
        .enumerate()
        .map(|(i, p)| {
            result
                .nonlinear
                .as_ref()
                .and_then(|n| n.values.get(i).copied())
                .unwrap_or(p.value)
        })
        .collect();
    report.stations = super::stations::tables(m, &sol.beta, &nonlinear_si, &report);
    report
}

/// The stated noise and the χ² test of the fit against it: with rows divided by their σ, the
/// residual sum of squares is χ²-distributed on the residual degrees of freedom when the model
/// is complete and the noise is what was stated.
fn stated_weights(m: &Machine, options: &Options, result: &FitResult) -> Option<StatedWeights> {
    // With σs per file every row is a multiple of its own σ, as with a stated noise.
    let n = match (options.noise, &result.components) {
        (Some(n), _) => n,
        (None, Some(_)) => super::Noise {
            position: None,
            rotation: None,
        },
        (None, None) => return None,
    };
    let dof = result.rows.saturating_sub(result.solution.rank);
    let ratio = result.sigma / m.units.error.scale;
    let chi2 = ratio * ratio * dof as f64;
    let p = crate::statistics::chi_squared_p(chi2, dof.max(1) as f64).unwrap_or(f64::NAN);
    Some(StatedWeights {
        position: n.position.map(|v| v / m.units.error.scale),
        rotation: n.rotation.map(|v| v / m.units.tilt.scale),
        error_unit: m.units.error.name.clone(),
        tilt_unit: m.units.tilt.name.clone(),
        chi2,
        dof,
        p,
    })
}

fn noise_per_file(m: &Machine, files: &[DataSet], result: &FitResult) -> Option<NoisePerFile> {
    let c = result.components.as_ref()?;
    let files = c
        .groups
        .iter()
        .map(|g| {
            let unit = match g.kind {
                super::components::RowKind::Position => &m.units.error,
                super::components::RowKind::Rotation => &m.units.tilt,
            };
            let sigma = g.sigma / unit.scale;
            FileNoise {
                file: files
                    .get(g.file)
                    .map(|f| f.path.display().to_string())
                    .unwrap_or_default(),
                kind: g.kind,
                unit: unit.name.clone(),
                sigma,
                stated: g.stated,
                sigma_hat: sigma * g.ratio,
                ratio: g.ratio,
                rows: g.rows,
                redundancy: g.redundancy,
                outliers: g.outliers,
            }
        })
        .collect();
    Some(NoisePerFile {
        iterations: c.iterations,
        converged: c.converged,
        files,
    })
}

fn stepwise_report(
    m: &Machine,
    sel: &super::stepwise::Selection,
    options: &Options,
) -> StepwiseReport {
    let (alpha_remove, alpha_enter) = options
        .stepwise
        .map(|s| (s.remove, s.enter))
        .unwrap_or((f64::NAN, None));
    let steps = sel
        .steps
        .iter()
        .map(|st| {
            let c = m.coefficients.get(st.column);
            StepReport {
                name: c.map(|c| c.name.clone()).unwrap_or_default(),
                label: c.map(|c| c.label.clone()).unwrap_or_default(),
                action: format!("{:?}", st.action).to_lowercase(),
                f: st.f,
                p: st.p,
            }
        })
        .collect();
    let mut components: Vec<Survivors> = Vec::new();
    for (j, c) in m.coefficients.iter().enumerate() {
        let base = c
            .name
            .rsplit_once('[')
            .map(|(b, _)| b.to_string())
            .unwrap_or_default();
        if components
            .last()
            .map(|s| s.component != base)
            .unwrap_or(true)
        {
            components.push(Survivors {
                component: base,
                kept: Vec::new(),
                removed: Vec::new(),
            });
        }
        if let Some(s) = components.last_mut() {
            if sel.kept.get(j).copied().unwrap_or(true) {
                s.kept.push(c.label.clone());
            } else {
                s.removed.push(c.label.clone());
            }
        }
    }
    StepwiseReport {
        alpha_remove,
        alpha_enter,
        steps,
        components,
    }
}

/// The fitted values as a `params { … }` block, each coefficient in its own unit, with enough
/// digits to round-trip.
pub(crate) fn params_text(m: &Machine, beta: &[f64], nonlinear: &[Estimate]) -> String {
    let mut out = String::from("params {\n");
    for (j, c) in m.coefficients.iter().enumerate() {
        let v = beta.get(j).copied().unwrap_or(0.0) / c.unit.scale;
        out.push_str(&format!("    {} = {:?} {}\n", c.name, v, c.unit.name));
    }
    for p in nonlinear {
        out.push_str(&format!("    {} = {:?} {}\n", p.name, p.value, p.unit));
    }
    out.push_str("}\n");
    out
}

impl FitReport {
    /// Why this report's covariance cannot serve `m`'s predictions: it was fitted to a model
    /// with other coefficients (the file changed since), or carries no covariance.
    /// The values of `m`'s non-linear parameters (SI) this fit estimated, each parameter it
    /// does not name keeping `m`'s own value: what the fitted model evaluates with.
    pub fn nonlinear_values(&self, m: &kin_compiler::ir::Machine) -> Vec<f64> {
        m.nonlinear
            .iter()
            .map(|p| {
                self.nonlinear
                    .iter()
                    .find(|e| e.name == p.name)
                    .map_or(p.value, |e| p.unit.to_si(e.value))
            })
            .collect()
    }

    pub fn covariance_mismatch(&self, m: &kin_compiler::ir::Machine) -> Option<String> {
        let n = m.coefficients.len();
        if self.coefficients.len() != n
            || self
                .coefficients
                .iter()
                .zip(&m.coefficients)
                .any(|(e, c)| e.name != c.name)
        {
            return Some(format!(
                "the fit was made with {} coefficients, the model now has {n} (or they are named differently): refit the model",
                self.coefficients.len()
            ));
        }
        if self.covariance.len() != n * n {
            return Some(format!(
                "the fit report holds {} covariance entries, {} are needed",
                self.covariance.len(),
                n * n
            ));
        }
        None
    }
}
