//! Estimating a model's parameters from measurements (thesis ch. 3–4).
//!
//! [`fit`] is the least-squares fit and its report; [`curves`] draws its fitted parametric
//! errors along their variables with their confidence bands; [`identify`] says which parameters the
//! data cannot separate; [`design`] and [`plan`] judge a measurement plan before it is
//! measured, [`generate`] writes the candidate measurements a plan is chosen from;
//! [`simulate`] makes measurements of a model with known truth; [`predict`] gives the error and
//! its uncertainty at new poses over a duty cycle; [`uncertainty`] is the one implementation of
//! a prediction's uncertainty (eq. 4.12) they all use, [`statistics`] of the significance tests.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod curves;
pub mod design;
pub mod fit;
pub mod generate;
pub mod identify;
pub mod plan;
pub mod predict;
mod rank_update;
pub mod register;
pub mod simulate;
pub mod statistics;
pub mod uncertainty;
