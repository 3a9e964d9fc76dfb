//! Identifiability (thesis §4.3, appendix B): which combinations of coefficients the
//! observations cannot see.
//!
//! A combination λᵀβ is estimable iff λ lies in the row space of the design matrix X (§4.3). We
//! scale every column of X to unit length (so that units and ranges do not decide), take the
//! singular values of the scaled matrix for the rank, and name the invisible directions by an
//! incremental QR in declaration order: a column that the earlier columns already explain is
//! reported together with the earlier columns it is a combination of. Nuisance columns
//! (alignment of an artifact) come first, so a model term they absorb is named as absorbed.

use faer::Mat;
use kin_compiler::diagnostic::{Diagnostic, Span};
use kin_compiler::ir::Machine;
use kin_compiler::SourceMap;
use thiserror::Error;

use crate::interp::{EvalError, State};
use crate::states::States;

#[derive(Debug, Error)]
pub enum IdentifyError {
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Engine(#[from] crate::engine::EngineError),
    #[error("the singular value decomposition did not converge")]
    Svd,
    #[error("no observations to analyse")]
    Empty,
}

/// What is observed at each sampled state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Observe {
    /// Position errors ex, ey, ez (the usual point measurement).
    Position,
    /// Position and rotation errors.
    Pose,
    /// Lengths between pairs of poses (ball bar, step gauge, laser): eq. 4.5.
    Length,
    /// The rows of measurement files (the fit's own data).
    Data,
}

/// A column of the design matrix: a model coefficient or a nuisance parameter.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    Coefficient(usize),
    /// Alignment of the artifact: translation along or rotation about axis 0..3 of wr.
    Alignment {
        rotation: bool,
        axis: usize,
    },
    /// Another nuisance parameter of a fit, by name (an artifact's placement or length).
    Nuisance(String),
}

/// One invisible direction: `column` is (numerically) the combination `Σ w·c` of earlier ones.
#[derive(Debug, Clone, PartialEq)]
pub struct Dependency {
    pub column: Column,
    /// The earlier columns and weights, in unit-scaled units; empty when the column has no
    /// effect at all on the observations.
    pub combination: Vec<(Column, f64)>,
}

#[derive(Debug, Clone)]
pub struct Report {
    pub rows: usize,
    pub columns: usize,
    pub rank: usize,
    /// Relative singular-value threshold used for the rank.
    pub tolerance: f64,
    /// Largest over smallest kept singular value of the scaled matrix.
    pub condition: f64,
    pub dependencies: Vec<Dependency>,
}

/// Relative tolerance below which a direction counts as invisible. Structural dependencies
/// sit at rounding level (1e-13 and below); anything an experiment can resolve is far above.
pub const TOLERANCE: f64 = 1e-8;

/// Builds the design matrix of `observe` at `states` (row-major, columns = coefficients, then
/// six alignment columns when `aligned`).
/// As [`design_with`], evaluated by the interpreter.
pub fn design(
    m: &Machine,
    states: &States,
    observe: Observe,
    aligned: bool,
) -> Result<(Vec<f64>, Vec<Column>), IdentifyError> {
    design_with(m, states, observe, aligned, crate::engine::Engine::Interp)
}

/// Builds the design matrix of `observe` at `states` with the chosen engine.
pub fn design_with(
    m: &Machine,
    states: &States,
    observe: Observe,
    aligned: bool,
    engine: crate::engine::Engine,
) -> Result<(Vec<f64>, Vec<Column>), IdentifyError> {
    let n = m.coefficients.len();
    let mut columns: Vec<Column> = Vec::new();
    if aligned && observe != Observe::Length {
        for rotation in [false, true] {
            for axis in 0..3 {
                columns.push(Column::Alignment { rotation, axis });
            }
        }
    }
    let offset = columns.len();
    columns.extend((0..n).map(Column::Coefficient));
    let width = columns.len();
    let mut it = crate::engine::make(m, engine)?;
    let beta = vec![0.0; n];
    let mut jac = vec![0.0; 6 * n];
    let mut err = [0.0; 6];
    let mut out = Vec::new();
    match observe {
        Observe::Position | Observe::Pose | Observe::Data => {
            let comps = if observe == Observe::Position { 3 } else { 6 };
            for r in 0..states.len() {
                let s = states.get(r);
                it.error_and_jacobian(&s, &beta, &mut err, &mut jac)?;
                let p = if aligned {
                    nalgebra::Vector3::from(it.nominal_position(&s)?)
                } else {
                    nalgebra::Vector3::zeros()
                };
                for c in 0..comps {
                    let mut row = vec![0.0; width];
                    if aligned {
                        // A rigid displacement (t, ω) of the artifact moves a point p by t + ω × p.
                        if c < 3 {
                            row[c] = 1.0;
                            let e = nalgebra::Vector3::ith(c, 1.0);
                            for k in 0..3 {
                                row[3 + k] = nalgebra::Vector3::ith(k, 1.0).cross(&p).dot(&e);
                            }
                        } else {
                            row[3 + c - 3] = 1.0;
                        }
                    }
                    row[offset..].copy_from_slice(jac.get(c * n..(c + 1) * n).unwrap_or(&[]));
                    out.extend(row);
                }
            }
        }
        Observe::Length => {
            let mut row = vec![0.0; n];
            // Pairs of consecutive sampled states with the same tool: random lengths and
            // directions throughout the range.
            for r in 0..states.len().saturating_sub(1) {
                let (a, mut b) = (states.get(r), states.get(r + 1));
                b.tool = a.tool;
                let b: State = b;
                match it.length_and_row(&a, &b, &beta, &mut row) {
                    Ok(_) => out.extend_from_slice(&row),
                    Err(EvalError::Kinematics(_)) => continue,
                    Err(e) => return Err(e.into()),
                }
            }
        }
    }
    Ok((out, columns))
}

/// Analyses a row-major `rows × columns.len()` design matrix.
pub fn analyse(x: &[f64], columns: &[Column]) -> Result<Report, IdentifyError> {
    let n = columns.len();
    let rows = x.len().checked_div(n).unwrap_or(0);
    if rows == 0 {
        return Err(IdentifyError::Empty);
    }
    let at = |i: usize, j: usize| x.get(i * n + j).copied().unwrap_or(0.0);
    let norms: Vec<f64> = (0..n)
        .map(|j| (0..rows).map(|i| at(i, j).powi(2)).sum::<f64>().sqrt())
        .collect();
    let biggest = norms.iter().copied().fold(0.0, f64::max);
    // A column far below the others has no effect worth the name: scale it to zero rather than
    // blow rounding noise up to unit length.
    let scale: Vec<f64> = norms
        .iter()
        .map(|&v| {
            if v > 1e-14 * biggest && v > 0.0 {
                1.0 / v
            } else {
                0.0
            }
        })
        .collect();
    let a = Mat::<f64>::from_fn(rows, n, |i, j| {
        at(i, j) * scale.get(j).copied().unwrap_or(0.0)
    });

    let sv: Vec<f64> = a.singular_values().map_err(|_| IdentifyError::Svd)?;
    let top = sv.first().copied().unwrap_or(0.0);
    let kept: Vec<f64> = sv
        .iter()
        .copied()
        .filter(|s| *s > TOLERANCE * top)
        .collect();
    let rank = kept.len();
    let condition = match kept.last() {
        Some(s) if *s > 0.0 => top / s,
        _ => f64::INFINITY,
    };

    // Incremental QR in column order with one re-orthogonalisation (classical Gram–Schmidt
    // twice is as stable as Householder for this purpose).
    let mut q: Vec<Vec<f64>> = Vec::new();
    let mut r_cols: Vec<Vec<f64>> = Vec::new();
    let mut independent: Vec<usize> = Vec::new();
    let mut dependencies = Vec::new();
    for j in 0..n {
        let col: Vec<f64> = (0..rows).map(|i| a[(i, j)]).collect();
        let norm = col.iter().map(|v| v * v).sum::<f64>().sqrt();
        let column = columns.get(j).cloned().unwrap_or(Column::Coefficient(j));
        if norm == 0.0 {
            dependencies.push(Dependency {
                column,
                combination: Vec::new(),
            });
            continue;
        }
        let mut resid = col.clone();
        let mut coef = vec![0.0; q.len()];
        for _ in 0..2 {
            for (k, qk) in q.iter().enumerate() {
                let c: f64 = qk.iter().zip(&resid).map(|(a, b)| a * b).sum();
                coef[k] += c;
                for (v, qv) in resid.iter_mut().zip(qk) {
                    *v -= c * qv;
                }
            }
        }
        let rn = resid.iter().map(|v| v * v).sum::<f64>().sqrt();
        if rn <= 1e-6 * norm {
            // Back-substitute R x = coef for the weights on the independent columns.
            let k = independent.len();
            let mut w = vec![0.0; k];
            for i in (0..k).rev() {
                let mut s = coef.get(i).copied().unwrap_or(0.0);
                for (jj, wj) in w.iter().enumerate().skip(i + 1) {
                    s -= r_cols
                        .get(jj)
                        .and_then(|c| c.get(i))
                        .copied()
                        .unwrap_or(0.0)
                        * wj;
                }
                let d = r_cols.get(i).and_then(|c| c.get(i)).copied().unwrap_or(1.0);
                w[i] = s / d;
            }
            let mut combination: Vec<(Column, f64)> = independent
                .iter()
                .zip(&w)
                .filter(|(_, wi)| wi.abs() > 1e-6)
                .map(|(&c, &wi)| {
                    (
                        columns.get(c).cloned().unwrap_or(Column::Coefficient(c)),
                        wi,
                    )
                })
                .collect();
            combination.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            dependencies.push(Dependency {
                column,
                combination,
            });
        } else {
            for v in &mut resid {
                *v /= rn;
            }
            let mut rc = coef;
            rc.push(rn);
            q.push(resid);
            r_cols.push(rc);
            independent.push(j);
        }
    }
    Ok(Report {
        rows,
        columns: n,
        rank,
        tolerance: TOLERANCE,
        condition,
        dependencies,
    })
}

/// Identifiability of a machine's coefficients from `observe` at `n` states sampled over its
/// ranges (what `kin check` runs).
pub fn sampled(
    m: &Machine,
    observe: Observe,
    aligned: bool,
    n: usize,
    seed: u64,
) -> Result<Report, IdentifyError> {
    sampled_with(m, observe, aligned, n, seed, crate::engine::Engine::Interp)
}

/// As [`sampled`], with the chosen engine.
pub fn sampled_with(
    m: &Machine,
    observe: Observe,
    aligned: bool,
    n: usize,
    seed: u64,
    engine: crate::engine::Engine,
) -> Result<Report, IdentifyError> {
    let states = States::sample(m, n, seed);
    let (x, columns) = design_with(m, &states, observe, aligned, engine)?;
    analyse(&x, &columns)
}

fn column_name(m: &Machine, c: &Column) -> String {
    match c {
        Column::Coefficient(j) => match m.coefficients.get(*j) {
            Some(coef) => format!("`{}` ({})", coef.name, coef.label),
            None => format!("coefficient {j}"),
        },
        Column::Alignment { rotation, axis } => {
            let a = ["x", "y", "z"].get(*axis).copied().unwrap_or("?");
            if *rotation {
                format!("the artifact's rotation about {a}")
            } else {
                format!("the artifact's shift along {a}")
            }
        }
        Column::Nuisance(name) => name.clone(),
    }
}

fn column_span(map: &SourceMap, c: &Column) -> Option<Span> {
    match c {
        Column::Coefficient(j) => map.coefficients.get(*j).copied(),
        Column::Alignment { .. } | Column::Nuisance(_) => None,
    }
}

/// Turns a report into located diagnostics (E0601), one per invisible direction.
pub fn diagnostics(
    m: &Machine,
    map: &SourceMap,
    report: &Report,
    observe: Observe,
    aligned: bool,
) -> Vec<Diagnostic> {
    let what = match (observe, aligned) {
        (Observe::Position, false) => "position errors at poses spread over the axis ranges",
        (Observe::Position, true) => "position errors on an artifact of unknown placement",
        (Observe::Pose, false) => "position and rotation errors over the axis ranges",
        (Observe::Pose, true) => "position and rotation errors on an artifact of unknown placement",
        (Observe::Length, _) => "lengths between poses spread over the axis ranges",
        (Observe::Data, _) => "the rows of the measurement files",
    };
    let mut out = Vec::new();
    for d in &report.dependencies {
        let name = column_name(m, &d.column);
        let span = column_span(map, &d.column).unwrap_or_default();
        let diag = if d.combination.is_empty() {
            Diagnostic::error("E0601", format!("{name} has no effect on the observations"), span)
                .with_label("invisible to the observations")
                .with_note(format!("observed: {what}"))
                .with_help("remove the term, or observe what it moves (e.g. rotations, or a tool with an offset)")
        } else {
            let parts: Vec<String> = d
                .combination
                .iter()
                .take(4)
                .map(|(c, w)| format!("{:+.3} × {}", w, column_name(m, c)))
                .collect();
            let more = d.combination.len().saturating_sub(4);
            let mut diag = Diagnostic::error(
                "E0601",
                format!(
                    "{name} cannot be told apart from {}",
                    d.combination
                        .first()
                        .map(|(c, _)| column_name(m, c))
                        .unwrap_or_default()
                ),
                span,
            )
            .with_label("this term's effect …");
            let mut labelled = vec![span];
            for (c, _) in d.combination.iter().take(4) {
                if let Some(s) = column_span(map, c) {
                    if !labelled.contains(&s) {
                        diag = diag.with_secondary(s, "… is already produced here");
                        labelled.push(s);
                    }
                }
            }
            diag.with_note(format!(
                "on the observations ({what}), its effect equals {}{} (unit-scaled columns)",
                parts.join(" "),
                if more > 0 { format!(" and {more} more") } else { String::new() }
            ))
            .with_help(if matches!(d.combination.first(), Some((Column::Alignment { .. } | Column::Nuisance(_), _))) {
                "the artifact's alignment absorbs it: remove the term or fix the placement".to_string()
            } else {
                "remove one of them, or use a family without this component (straightness, no_once_per_rev)".to_string()
            })
        };
        out.push(diag);
    }
    out
}
