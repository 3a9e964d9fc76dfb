//! Physical dimensions and units: parsing unit text, conversion to SI, and dimension algebra.

use serde::{Deserialize, Serialize};

/// Exponents of the base dimensions. Angle is a base dimension on purpose: it lets the checker
/// tell a rotation error from a translation error (a `urad` is not a `um/m` here).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Dim {
    pub length: i8,
    pub angle: i8,
    pub time: i8,
    pub temperature: i8,
    pub force: i8,
}

/// A unit: a dimension, the factor to SI, and (absolute temperatures only) the offset to SI.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unit {
    /// Canonical text, e.g. `um/m/K`.
    pub name: String,
    pub dim: Dim,
    pub scale: f64,
    pub offset: f64,
}
