//! A σ per instrument: variance components per file, estimated by reweighting (Helmert's
//! variance component estimation in Förstner's iterative form; Koch, *Parameter Estimation and
//! Hypothesis Testing in Linear Models*, §3.6; spec/cli.md, "Noise per file").
//!
//! The rows of a fit fall into groups: per file, its positions and lengths, and its rotations.
//! A group's σ is stated (for the file, or for every file by `--noise`/`--noise-tilt`) or it is
//! estimated: with rows weighted by the current σs, a group `g` has the estimate
//!
//! ```text
//! σ̂_g² = σ_g² · Σ_{i∈g} r_i² / Σ_{i∈g} (1 − h_ii)
//! ```
//!
//! where `r_i` are the weighted residuals and `h_ii` the leverages: `Σ_{i∈g} h_ii` is the share
//! of the parameters the group's rows determine, so the denominator is the group's redundancy
//! (the degrees of freedom it contributes; the redundancies of all groups add up to `n − rank`).
//! Each estimated group is reweighted by its σ̂ and the problem refitted until no ratio
//! `σ̂_g/σ_g` moves by more than [`TOLERANCE`] (at most [`ITERATIONS`] fits). Rows flagged as
//! outliers (against their own group's σ) are left out of the sums, so a gross error does not
//! inflate its instrument's σ and hide itself.

use serde::{Deserialize, Serialize};

use super::{FitError, FitResult, Noise, Options, ResidualRow};

/// Largest change of any ratio σ̂_g/σ_g at which the estimates are stable.
pub const TOLERANCE: f64 = 1e-3;
/// Most fits the reweighting makes.
pub const ITERATIONS: usize = 20;

/// The kind of rows a component weighs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RowKind {
    /// Positions and lengths (error unit).
    Position,
    /// Rotations (tilt unit).
    Rotation,
}

/// One file's σ of one kind of row after the fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Component {
    pub file: usize,
    pub kind: RowKind,
    /// The σ the rows were weighted by, SI: the stated one, or the converged estimate.
    pub sigma: f64,
    pub stated: bool,
    /// σ̂/σ over the group's rows that are not outliers (1 for a converged estimate).
    pub ratio: f64,
    pub rows: usize,
    /// Σ (1 − h_ii) over those rows: the degrees of freedom the group contributes.
    pub redundancy: f64,
    pub outliers: usize,
}

/// The components of a fit with a σ per file.
#[derive(Debug, Clone, PartialEq)]
pub struct Components {
    pub groups: Vec<Component>,
    /// Fits made (1 when every σ was stated).
    pub iterations: usize,
    /// Whether the ratios settled within [`TOLERANCE`].
    pub converged: bool,
}

/// Whether `options` ask for a σ per file.
pub(crate) fn per_file(options: &Options) -> bool {
    options.components || !options.file_noise.is_empty()
}

/// The sums of a group over the rows of one fit.
#[derive(Clone, Copy, Default)]
struct Sums {
    rss: f64,
    redundancy: f64,
    rows: usize,
    outliers: usize,
}

fn group_of(component: u8) -> usize {
    usize::from((3..6).contains(&component))
}

fn sums(files: usize, residuals: &[ResidualRow], threshold: f64) -> Vec<[Sums; 2]> {
    let mut out = vec![[Sums::default(); 2]; files];
    for r in residuals {
        let Some(slot) = out
            .get_mut(r.meta.file as usize)
            .and_then(|g| g.get_mut(group_of(r.meta.component)))
        else {
            continue;
        };
        slot.rows += 1;
        if r.studentized.abs() > threshold {
            slot.outliers += 1;
            continue;
        }
        slot.rss += r.residual * r.residual;
        slot.redundancy += (1.0 - r.leverage).max(0.0);
    }
    out
}

/// A group's σ̂/σ from its sums: the weighted rows have unit variance when σ is right, and a
/// weighted residual is `r · scale/σ`.
fn ratio(s: &Sums, scale: f64) -> Option<f64> {
    (s.redundancy >= 1.0 && s.rss > 0.0).then(|| (s.rss / s.redundancy).sqrt() / scale)
}

/// Fits with a σ per file and kind of row: the stated ones fixed, the others estimated by
/// reweighting until stable. `once` is one weighted fit with the options given.
pub(crate) fn fit(
    m: &kin_compiler::ir::Machine,
    files: usize,
    options: &Options,
    mut once: impl FnMut(&Options) -> Result<FitResult, FitError>,
) -> Result<FitResult, FitError> {
    let scale = m.units.error.scale;
    // What unit weights assume (1 error unit; a tilt unit as an error unit): the start.
    let start = [scale, scale / super::rotation_weight(m)];
    let given = |f: usize, g: usize| -> Option<f64> {
        let own = options.file_noise.get(f).copied().unwrap_or(Noise {
            position: None,
            rotation: None,
        });
        let all = options.noise;
        match g {
            0 => own.position.or(all.and_then(|n| n.position)),
            _ => own.rotation.or(all.and_then(|n| n.rotation)),
        }
    };
    let stated: Vec<[Option<f64>; 2]> = (0..files).map(|f| [given(f, 0), given(f, 1)]).collect();
    let mut sigma: Vec<[f64; 2]> = stated
        .iter()
        .map(|s| [s[0].unwrap_or(start[0]), s[1].unwrap_or(start[1])])
        .collect();
    let mut current = options.clone();
    current.components = false;
    let mut iterations = 0;
    loop {
        current.file_noise = sigma
            .iter()
            .map(|s| Noise {
                position: Some(s[0]),
                rotation: Some(s[1]),
            })
            .collect();
        let mut result = once(&current)?;
        iterations += 1;
        let sums = sums(files, &result.residuals, result.outlier_threshold);
        let mut moved = 0.0f64;
        let mut next = sigma.clone();
        for (f, groups) in sums.iter().enumerate() {
            for (g, s) in groups.iter().enumerate() {
                let fixed = stated.get(f).and_then(|x| x[g]).is_some();
                if fixed || s.rows == 0 {
                    continue;
                }
                if let (Some(rho), Some(slot)) =
                    (ratio(s, scale), next.get_mut(f).and_then(|x| x.get_mut(g)))
                {
                    moved = moved.max((rho - 1.0).abs());
                    *slot *= rho;
                }
            }
        }
        if moved < TOLERANCE || iterations >= ITERATIONS {
            result.components = Some(Components {
                groups: components(&sums, &sigma, &stated, scale),
                iterations,
                converged: moved < TOLERANCE,
            });
            return Ok(result);
        }
        sigma = next;
    }
}

fn components(
    sums: &[[Sums; 2]],
    sigma: &[[f64; 2]],
    stated: &[[Option<f64>; 2]],
    scale: f64,
) -> Vec<Component> {
    let mut out = Vec::new();
    for (f, groups) in sums.iter().enumerate() {
        for (g, s) in groups.iter().enumerate() {
            if s.rows == 0 {
                continue;
            }
            out.push(Component {
                file: f,
                kind: if g == 0 {
                    RowKind::Position
                } else {
                    RowKind::Rotation
                },
                sigma: sigma
                    .get(f)
                    .and_then(|x| x.get(g))
                    .copied()
                    .unwrap_or(f64::NAN),
                stated: stated.get(f).and_then(|x| x[g]).is_some(),
                ratio: ratio(s, scale).unwrap_or(f64::NAN),
                rows: s.rows,
                redundancy: s.redundancy,
                outliers: s.outliers,
            });
        }
    }
    out
}
