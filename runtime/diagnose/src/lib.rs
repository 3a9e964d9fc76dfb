//! Where the model fails and which physical effect is missing.
//!
//! Two questions asked of a fitted model and its data. *Where*: the residuals, binned along
//! every axis and input, against what the noise estimate and the model's own uncertainty allow
//! (thesis eq. 4.12, appendix A). *What*: a library of candidate physical effects, each a term
//! that could be added to the `.kin` model, tested against the residuals with a partial F-test
//! (Holm–Bonferroni over all candidates) and ranked by an information criterion (BIC), so that
//! a candidate pays for every column it adds. Candidates the data cannot tell apart are one
//! finding; the residual level is judged against a stated instrument noise when there is one.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use serde::{Deserialize, Serialize};

/// The kinds of physical effect the library proposes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Family {
    /// An error that also depends on another axis or an input (carriage weight, load): eq. 3.19.
    CrossCoupling,
    /// A spline too stiff for what the data show: more knots.
    MoreKnots,
    /// A periodic error along an axis (leadscrew, scale): eq. 3.11–3.15.
    Periodic,
    /// A step with the direction of motion (backlash, hysteresis): §3.2.5.
    Backlash,
    /// A thermal drift following an input through a lag: eq. 3.41–3.48.
    Thermal,
    /// A slow drift in time.
    Drift,
    /// Error motion of a revolute axis at 2, 3, … per revolution.
    RevoluteHarmonics,
    /// An angular error seen through the tool's Abbe offset.
    AbbeAngular,
    /// A missing squareness or axis-location constant.
    Constant,
    /// An error motion of an axis along its own travel: a prismatic axis' positioning (scale)
    /// or straightness error, a limited rotary axis' angular positioning error (§3.2.2–3.2.3).
    ErrorMotion,
}

/// A term that could be added to the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    pub family: Family,
    /// The error component it adds to, e.g. `Y.ty`.
    pub target: String,
    /// Further components the line adds the same terms to, sharing its non-linear parameters
    /// (`X.tx, X.ry += …`: one effect seen in several components); usually empty.
    #[serde(default)]
    pub also: Vec<String>,
    /// The exact line to add inside `errors { … }`, e.g. `Y.ty += linear(X) * spline(Y, knots 3)`.
    pub text: String,
    /// What it would mean physically, in plain words.
    pub explanation: String,
    /// Why no load or motion path links the axes the line couples (they sit on different
    /// chains); ranked after the candidates that have one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_path: Option<String>,
}

/// A tested candidate: the canonical line of a group of lines the data cannot tell apart.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Finding {
    pub candidate: Candidate,
    /// Other lines whose added columns span the same space on these data (the same effect
    /// seen through another element or Abbe arm): the data cannot decide between them.
    #[serde(default)]
    pub alternatives: Vec<Candidate>,
    /// With alternatives: what measurement would tell them apart.
    #[serde(default)]
    pub separation: Option<String>,
    /// Independent columns it adds to the design.
    pub columns: usize,
    /// Fraction of the residual sum of squares it explains.
    pub explained: f64,
    /// Partial F statistic, its p-value, and the Holm–Bonferroni adjusted p-value.
    pub f: f64,
    pub p: f64,
    pub p_adjusted: f64,
    pub significant: bool,
    /// Residual RMS (error unit) if it were added.
    pub rms_after: f64,
    /// Change of the Bayesian information criterion, `n ln(RSS/RSS₀) + k ln n`: the ranking
    /// (lower first), which charges `ln n` for every column added.
    #[serde(default)]
    pub bic: f64,
    /// How the model looks with the line added (significant findings only).
    #[serde(default)]
    pub plausibility: Option<Plausibility>,
    /// The non-linear parameters the line adds, as the refit with it gives them (significant
    /// findings only); `rms_after` is then that refit's too.
    #[serde(default)]
    pub fitted: Vec<Fitted>,
    /// The measured components the refit with the line makes worse beyond their noise
    /// (checked for the findings ranked first): a contradicted line is ranked after every
    /// one that is not, and `--apply` refuses it without `--force`.
    #[serde(default)]
    pub contradicted: Vec<Worse>,
    /// Earlier findings (lower ΔBIC) whose line leaves this one nothing significant to add: it
    /// is another reading of the effect they explain (checked among the first significant
    /// findings).
    #[serde(default)]
    pub same_effect_as: Vec<String>,
}

impl Finding {
    /// What the finding's contradicted components say, when there are any.
    pub fn contradiction(&self) -> Option<String> {
        (!self.contradicted.is_empty()).then(|| evidence::said(&self.contradicted))
    }
}

/// A measured component a candidate's refit makes worse beyond its noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Worse {
    /// The observed component (`ex` … `erz`, `dL`).
    pub component: String,
    /// Its RMS in the base fit and in the refit with the line (`unit`).
    pub rms_before: f64,
    pub rms_after: f64,
    pub unit: String,
    /// The probability of growth this large by chance (χ² of the columns added).
    pub p: f64,
}

/// A non-linear parameter (wavelength, time constant) of a refit, in its display unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fitted {
    pub name: String,
    pub value: f64,
    /// Standard error (Gauss–Newton, with the linear coefficients' correlation).
    pub se: f64,
    pub unit: String,
}

/// Whether a refit with the candidate would still be a believable model of the machine.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Plausibility {
    /// Condition number of the unit-scaled design without and with the candidate's columns.
    pub condition_before: f64,
    pub condition_after: f64,
    /// The largest fitted length coefficient of the refit (length unit), and the machine's
    /// size (the sum of its travels and nominal offsets, length unit).
    pub largest_length: f64,
    pub machine_size: f64,
    /// Why the refit is implausible; empty when it is not.
    pub warnings: Vec<String>,
}

/// An observation whose studentized residual the fit flags (Bonferroni): named as an outlier,
/// not counted in the region tests.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Outlier {
    pub file: String,
    pub line: usize,
    pub component: String,
    /// Residual (error unit; tilt unit for rotations) and studentized residual.
    pub residual: f64,
    pub studentized: f64,
}

/// The residual level against an absolute reference: the stated instrument noise, and the
/// pure error of repeated poses.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct NoiseCheck {
    /// Stated standard deviation of positions and lengths (error unit) and of rotations (tilt
    /// unit), when given.
    pub stated: Option<f64>,
    pub stated_tilt: Option<f64>,
    /// Σ r²/σ² over the rows with a stated σ against χ²(dof): is σ̂ larger than stated?
    pub chi2: Option<ChiSquare>,
    /// Lack of fit against the scatter of repeated poses.
    pub lack_of_fit: Option<LackOfFit>,
    /// With a σ per file: each file's σ̂ per kind of row against its noise (stated, or
    /// estimated by the base fit). Every fit of the diagnosis weighs the file's rows by it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub per_file: Vec<FileSigma>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ChiSquare {
    pub rows: usize,
    pub dof: f64,
    pub statistic: f64,
    /// σ̂ over the stated σ: √(statistic/dof).
    pub ratio: f64,
    /// Upper-tail p-value.
    pub p: f64,
    /// p ≥ α: the residuals are what the stated noise gives.
    pub consistent: bool,
}

/// A region of the workspace where residuals exceed what the noise allows.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Region {
    /// `ex`, …, `dL`.
    pub component: String,
    /// The conditions, e.g. `["Y > 420 mm", "X < 150 mm"]`.
    pub conditions: Vec<String>,
    /// Residual RMS in the region over what the reference σ (stated, else σ̂) allows.
    pub ratio: f64,
    pub rows: usize,
    pub p: f64,
    /// The sentence: "ez residuals exceed 3σ for Y > 420 mm and X < 150 mm".
    pub text: String,
}

/// Residual statistics of one component in one bin of one variable, for plots and tables.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Bin {
    pub component: String,
    pub variable: String,
    pub unit: String,
    pub lo: f64,
    pub hi: f64,
    pub rows: usize,
    pub mean: f64,
    pub rms: f64,
    /// What the noise and the model's uncertainty allow here (RMS), error unit.
    pub allowed: f64,
}

/// A peak of the residual spectrum along an axis (Lomb–Scargle, non-uniform sampling).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Spectrum {
    pub component: String,
    pub variable: String,
    pub unit: String,
    /// Wavelengths (variable's unit) and normalised power.
    pub wavelengths: Vec<f64>,
    pub power: Vec<f64>,
    /// The false-alarm probability of the highest peak.
    pub peak_false_alarm: f64,
}

/// Everything `kin diagnose` found, as written to `DIAGNOSE.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Diagnosis {
    pub machine: String,
    pub model_hash: String,
    /// σ̂ and the residual RMS of the fit diagnosed, error unit; with `weighted`, ratios to
    /// the stated noise (every row divided by its kind's σ), as are the findings' `rms_after`.
    pub sigma: f64,
    pub rms: f64,
    pub error_unit: String,
    /// Family-wise significance level of the candidate tests.
    pub alpha: f64,
    pub regions: Vec<Region>,
    pub bins: Vec<Bin>,
    pub spectra: Vec<Spectrum>,
    /// Ranked: significant and plausible first, then by BIC; equal ones by their text.
    pub findings: Vec<Finding>,
    #[serde(default)]
    pub noise: NoiseCheck,
    #[serde(default)]
    pub outliers: Vec<Outlier>,
    /// Whether every fit of the diagnosis (the base fit, the candidate tests, the refits) was
    /// weighted by the stated noise (`--noise`, `--noise-tilt`).
    #[serde(default)]
    pub weighted: bool,
    /// How many candidate lines the library proposed: each is a finding, another reading of
    /// one (`alternatives`) or `dropped`.
    #[serde(default)]
    pub proposed: usize,
    /// Every candidate the library proposed that is not among the findings, with the reason
    /// (`kin diagnose --explain` prints them).
    #[serde(default)]
    pub dropped: Vec<Dropped>,
}

/// A proposed candidate that is not a finding, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dropped {
    /// The line as proposed.
    pub text: String,
    pub reason: String,
}

/// One file's scatter of one kind of row against its noise.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FileSigma {
    pub file: String,
    /// `position` (positions and lengths) or `rotation`.
    pub kind: kin_estimate::fit::components::RowKind,
    pub unit: String,
    /// The σ the rows were weighted by: stated, or the base fit's estimate.
    pub sigma: f64,
    pub stated: bool,
    /// σ̂ of the file's rows, outliers left out, in `unit`.
    pub sigma_hat: f64,
    /// σ̂/σ, and for a stated σ the χ² test of it (an estimated σ is its own σ̂).
    pub ratio: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p: Option<f64>,
    pub rows: usize,
    pub outliers: usize,
}

mod analyse;
mod beam;
// The coverage table the library is audited against (its tests; spec/diagnosis.md for users).
#[cfg(test)]
mod coverage;
mod evidence;
mod gravity;
mod heat;
pub mod library;
mod motions;
mod pass;
mod periodic;
mod refit;
mod spectrum;
mod trend;

pub use analyse::{diagnose, DiagnoseError, Progress, Settings, Step};
// The lack-of-fit test is the estimation layer's (the standard tests use it too).
pub use kin_estimate::statistics::{lack_of_fit, LackOfFit};
