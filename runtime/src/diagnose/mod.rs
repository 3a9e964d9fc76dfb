//! Where the model fails and which physical effect is missing.
//!
//! Two questions asked of a fitted model and its data. *Where*: the residuals, binned along
//! every axis and input, against what the noise estimate and the model's own uncertainty allow
//! (thesis eq. 4.12, appendix A). *What*: a library of candidate physical effects, each a term
//! that could be added to the `.kin` model, tested against the residuals with a partial F-test
//! (Holm–Bonferroni over all candidates) and ranked by the residual variance it would explain.

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
}

/// A term that could be added to the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    pub family: Family,
    /// The error component it adds to, e.g. `Y.ty`.
    pub target: String,
    /// The exact line to add inside `errors { … }`, e.g. `Y.ty += linear(X) * spline(Y, knots 3)`.
    pub text: String,
    /// What it would mean physically, in plain words.
    pub explanation: String,
}

/// A tested candidate.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Finding {
    pub candidate: Candidate,
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
}

/// A region of the workspace where residuals exceed what the noise allows.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Region {
    /// `ex`, …, `dL`.
    pub component: String,
    /// The conditions, e.g. `["Y > 420 mm", "X < 150 mm"]`.
    pub conditions: Vec<String>,
    /// Residual RMS in the region over σ̂.
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
    pub sigma: f64,
    pub rms: f64,
    pub error_unit: String,
    /// Family-wise significance level of the candidate tests.
    pub alpha: f64,
    pub regions: Vec<Region>,
    pub bins: Vec<Bin>,
    pub spectra: Vec<Spectrum>,
    /// Ranked: significant first, by explained variance.
    pub findings: Vec<Finding>,
}

mod analyse;
pub mod library;

pub use analyse::{diagnose, DiagnoseError, Settings};
