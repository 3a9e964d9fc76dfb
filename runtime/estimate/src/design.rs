//! Planning a calibration: how well a set of observations determines a model, and which small
//! subset of candidate observations determines it best (Soons §4.3–4.4).
//!
//! The unit of choice is a *unit*: one observation row, or a group of rows measured together
//! (one ball-bar setup, one placement of an artifact). A unit's unknown nuisance parameters (an
//! artifact's placement, a bar's unknown length) belong to it alone, so they are eliminated
//! inside the unit: its rows are projected onto the complement of its nuisance columns. What
//! remains is the information the unit carries about the machine's coefficients, and the
//! determinant of the sum of those is the Ds-criterion (D-optimality for the coefficients with
//! the nuisance parameters profiled out).
//!
//! Figures follow the thesis' Table 4.1: the covariance and the prediction variances are those
//! of `n · (XᵀX)⁻¹` (unit noise, scaled by the number of observations `n`), so that designs of
//! different sizes compare.

use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use thiserror::Error;

#[derive(Debug, Error, PartialEq)]
pub enum DesignError {
    #[error("no candidate observations")]
    Empty,
    #[error("the candidates hold values that are not finite numbers")]
    NotFinite,
    #[error("a design of {0} units was asked for; at least one is needed")]
    Size(usize),
    #[error(
        "a design of {asked} units was asked for from {candidates} candidates: at most as many \
         as there are candidates are chosen (a plan measured twice repeats its units; more \
         candidates give the choice room)"
    )]
    MoreThanCandidates { asked: usize, candidates: usize },
    #[error(
        "no subset of the candidates determines any coefficient: every candidate row is zero \
         after its artifact's placement is taken out"
    )]
    Blind,
    #[error("the plan does not determine the terms the candidates can determine ({missing} of {rank} directions are missing)")]
    Deficient { missing: usize, rank: usize },
}

/// A coefficient column reduced by its unit's nuisance elimination to this fraction of its
/// length or less is zero up to rounding.
const CANCELLED: f64 = 1e-10;

/// One candidate unit: `rows × p` values (row-major) after its nuisance parameters were
/// eliminated, `p` the number of coefficients.
#[derive(Debug, Clone, PartialEq)]
pub struct Unit {
    pub rows: Vec<f64>,
    /// The number of observations of the unit (its rows before elimination).
    pub observations: usize,
}

impl Unit {
    /// A unit of `x` (`rows × (p + q)` row-major: `p` coefficient columns then `q` nuisance
    /// columns of this unit alone), with the nuisance columns eliminated.
    pub(crate) fn eliminated(x: &[f64], p: usize, q: usize) -> Unit {
        let width = p + q;
        let rows = x.len().checked_div(width).unwrap_or(0);
        let mut b = DMatrix::from_row_slice(rows, p, &take_columns(x, width, 0, p));
        if q > 0 && rows > 0 {
            let before: Vec<f64> = b.column_iter().map(|c| c.norm()).collect();
            let z = DMatrix::from_row_slice(rows, q, &take_columns(x, width, p, q));
            // An orthonormal basis of the nuisance columns' span (dropping dependent ones: a
            // length error and a shift may coincide on a single row), then B − Q Qᵀ B.
            let svd = z.svd(true, false);
            if let Some(u) = svd.u {
                let largest = svd.singular_values.max();
                for (k, s) in svd.singular_values.iter().enumerate() {
                    if *s > largest * 1e-10 && *s > 0.0 {
                        let qk = u.column(k).into_owned();
                        let proj = qk.transpose() * &b;
                        b -= &qk * proj;
                    }
                }
            }
            // A column the placement explains entirely leaves only rounding (~1e-16 of its
            // length); scaled to unit length that residue would look like information, so it
            // is taken as the zero it is (a constant offset seen by one artifact, say).
            for (j, was) in before.iter().enumerate() {
                let mut col = b.column_mut(j);
                if col.norm() <= CANCELLED * was {
                    col.fill(0.0);
                }
            }
        }
        let mut out = Vec::with_capacity(rows * p);
        for r in 0..rows {
            out.extend(b.row(r).iter());
        }
        Unit {
            rows: out,
            observations: rows,
        }
    }

    fn matrix(&self, p: usize) -> DMatrix<f64> {
        let rows = self.rows.len().checked_div(p).unwrap_or(0);
        DMatrix::from_row_slice(rows, p, &self.rows)
    }
}

fn take_columns(x: &[f64], width: usize, from: usize, count: usize) -> Vec<f64> {
    x.chunks_exact(width.max(1))
        .flat_map(|r| r.get(from..from + count).unwrap_or(&[]).iter().copied())
        .collect()
}

/// The information `Σ UᵀU` of `units` chosen by index (repeats count twice).
pub fn information(units: &[Unit], chosen: &[usize], p: usize) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(p, p);
    for &i in chosen {
        if let Some(u) = units.get(i) {
            let a = u.matrix(p);
            m += a.transpose() * a;
        }
    }
    m
}

/// What a plan determines (thesis §4.3: estimability).
#[derive(Debug, Clone, PartialEq)]
pub struct Estimability {
    pub rank: usize,
    /// Per coefficient: whether the plan determines it on its own.
    pub determined: Vec<bool>,
    /// Groups of coefficients the plan cannot separate, each with the combinations of them it
    /// does determine (weights per member, largest magnitude 1).
    pub groups: Vec<Group>,
    /// Largest over smallest singular value of the column-scaled design restricted to the
    /// independent columns (what the plan determines, whatever it cannot separate).
    pub condition: f64,
    /// Per coefficient: the variance inflation against an orthogonal design with the same
    /// column lengths, `(R⁻¹)ⱼⱼ` with `R` the scaled information (None when undetermined).
    pub vif: Vec<Option<f64>>,
    /// Per coefficient: its standard deviation per unit noise, `√(M⁺)ⱼⱼ` (None when
    /// undetermined).
    pub sigma: Vec<Option<f64>>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    pub members: Vec<usize>,
    /// Each determined combination: one weight per member.
    pub combinations: Vec<Vec<f64>>,
}

/// A weight below this (of the largest) in a null direction is rounding, not membership.
const MEMBER: f64 = 1e-6;

/// Analyses the information matrix `m` (`p × p`) of a plan.
///
/// Which coefficients the plan cannot separate is decided once for all of `kin`: by
/// [`crate::identify`]'s factorisation of the column-scaled information in declaration order (a
/// column whose part unexplained by the earlier independent columns is below a millionth of its
/// length is their combination), the decision `kin check` makes on a model's own sampling. Each
/// dependent column gives one unobserved direction — itself minus that combination — from which
/// the groups follow. The figures of the determined coefficients come from the information of
/// the independent columns alone: a determined coefficient lies in the row space, so its
/// variance is the same from any generalised inverse, this one included.
pub fn estimability(m: &DMatrix<f64>) -> Estimability {
    let p = m.nrows();
    let scale: Vec<f64> = (0..p)
        .map(|j| {
            let d = m[(j, j)];
            if d > 0.0 && d.is_finite() {
                d.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let blind = || Estimability {
        rank: 0,
        determined: vec![false; p],
        groups: Vec::new(),
        condition: f64::INFINITY,
        vif: vec![None; p],
        sigma: vec![None; p],
    };
    // Non-finite information (the callers refuse such candidates first) determines nothing.
    let Ok(report) = crate::identify::analyse_information(p, |i, j| m[(i, j)]) else {
        return blind();
    };
    let mut independent = vec![true; p];
    let mut null: Vec<DVector<f64>> = Vec::with_capacity(report.dependencies.len());
    for d in &report.dependencies {
        let crate::identify::Column::Coefficient(j) = d.column else {
            continue;
        };
        let mut v = DVector::zeros(p);
        v[j] = 1.0;
        for (c, w) in &d.combination {
            if let crate::identify::Column::Coefficient(i) = *c {
                v[i] = -w;
            }
        }
        independent[j] = false;
        null.push(v);
    }
    let kept: Vec<usize> = (0..p).filter(|&j| independent[j]).collect();
    let rank = kept.len();
    if rank == 0 {
        return Estimability {
            groups: groups(&null, &scale, &vec![false; p]),
            ..blind()
        };
    }
    // The scaled information of the independent columns: positive definite by the decision.
    let r = DMatrix::from_fn(rank, rank, |a, b| {
        let (i, j) = (kept[a], kept[b]);
        m[(i, j)] / (scale[i] * scale[j])
    });
    let eig = r.symmetric_eigen();
    let largest = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    let smallest = eig
        .eigenvalues
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    let condition = (largest / smallest).sqrt();
    let mut inverse = DMatrix::zeros(rank, rank);
    for k in 0..rank {
        let v = eig.eigenvectors.column(k);
        inverse += (v * v.transpose()) / eig.eigenvalues[k];
    }
    let mut rplus = DMatrix::zeros(p, p);
    for (a, &i) in kept.iter().enumerate() {
        for (b, &j) in kept.iter().enumerate() {
            rplus[(i, j)] = inverse[(a, b)];
        }
    }
    // A coefficient is determined when no unobserved direction moves it (and it has an effect).
    let determined: Vec<bool> = (0..p)
        .map(|j| scale[j] > 0.0 && null.iter().all(|v| v[j].abs() <= MEMBER))
        .collect();
    let vif = (0..p)
        .map(|j| determined[j].then(|| rplus[(j, j)]))
        .collect();
    let sigma = (0..p)
        .map(|j| determined[j].then(|| rplus[(j, j)].sqrt() / scale[j]))
        .collect();
    Estimability {
        rank,
        groups: groups(&null, &scale, &determined),
        determined,
        condition,
        vif,
        sigma,
    }
}

/// The groups of columns that unobserved directions `null` (unit vectors in coordinates scaled
/// by `scale`) join, with the combinations of each group that are determined (see
/// [`Estimability::groups`]): for a fit's null space.
pub(crate) fn groups_of(null: &[DVector<f64>], scale: &[f64]) -> Vec<Group> {
    let determined: Vec<bool> = (0..scale.len())
        .map(|j| {
            null.iter()
                .all(|v| v.get(j).is_none_or(|w| w.abs() <= MEMBER))
        })
        .collect();
    // The combinations are in the columns' own units: weights in scaled coordinates divided by
    // the scale, which `groups` does by multiplying with the inverse scale.
    let inverse: Vec<f64> = scale
        .iter()
        .map(|s| if *s > 0.0 { 1.0 / s } else { 0.0 })
        .collect();
    groups(null, &inverse, &determined)
}

/// `a + b`, `a - 0.5*b`: a determined combination as text, the first weight positive.
pub fn combination_text(names: &[String], weights: &[f64]) -> String {
    let flip = weights
        .iter()
        .find(|w| **w != 0.0)
        .is_some_and(|w| *w < 0.0);
    let mut out = String::new();
    for (name, &w) in names.iter().zip(weights) {
        let w = if flip { -w } else { w };
        if w == 0.0 {
            continue;
        }
        if out.is_empty() {
            if w < 0.0 {
                out.push('-');
            }
        } else {
            out.push_str(if w < 0.0 { " - " } else { " + " });
        }
        if (w.abs() - 1.0).abs() > 1e-9 {
            out.push_str(&format!("{:.4}*", w.abs()));
        }
        out.push_str(name);
    }
    out
}

/// A basis of the span of `null` in which every vector has a coordinate of its own (1 there, 0
/// in every other vector), each scaled to largest magnitude 1 with rounding noise cleared: the
/// reduced form of Gauss–Jordan elimination, pivoting on the largest remaining coordinate.
///
/// The supports of such a basis are the fundamental circuits of the columns (the smallest sets
/// of coefficients whose combination the data cannot see), and joining coefficients that share
/// a circuit gives the same groups whatever basis of the unseen directions one starts from: an
/// eigen- or singular-vector basis, whose rotation within a repeated zero is arbitrary, would
/// otherwise join coefficients that have nothing to do with each other.
fn circuits(null: &[DVector<f64>]) -> Vec<DVector<f64>> {
    let mut basis: Vec<DVector<f64>> = null.to_vec();
    let mut pivots: Vec<usize> = Vec::new();
    let mut kept = Vec::new();
    for k in 0..basis.len() {
        let Some(v) = basis.get(k) else { break };
        let norm = v.amax();
        let pivot =
            (0..v.len())
                .filter(|r| !pivots.contains(r))
                .fold(None, |best: Option<usize>, r| match best {
                    Some(b) if v[b].abs() >= v[r].abs() => Some(b),
                    _ => Some(r),
                });
        let Some(r) = pivot.filter(|&r| norm > 0.0 && v[r].abs() > 1e-12 * norm) else {
            continue;
        };
        let unit = v / v[r];
        for (c, other) in basis.iter_mut().enumerate() {
            if c != k {
                let f = other[r];
                if f != 0.0 {
                    *other -= &unit * f;
                }
            }
        }
        if let Some(slot) = basis.get_mut(k) {
            *slot = unit;
        }
        pivots.push(r);
        kept.push(k);
    }
    kept.into_iter()
        .filter_map(|k| basis.get(k))
        .map(|v| {
            let big = v.amax();
            v.map(|w| {
                if w.abs() <= MEMBER * big {
                    0.0
                } else {
                    w / big
                }
            })
        })
        .collect()
}

/// The representative of `i`'s set in a union–find forest `parent` (paths halved on the way).
pub(crate) fn root(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// Joins coefficients that share an unobserved direction, and finds per group the combinations
/// the plan determines: the directions within the group orthogonal to every unobserved one.
fn groups(null: &[DVector<f64>], scale: &[f64], determined: &[bool]) -> Vec<Group> {
    let null = &circuits(null)[..];
    let p = determined.len();
    let mut parent: Vec<usize> = (0..p).collect();
    for v in null {
        let members: Vec<usize> = (0..p).filter(|&j| v[j].abs() > MEMBER).collect();
        for w in members.windows(2) {
            let (a, b) = (root(&mut parent, w[0]), root(&mut parent, w[1]));
            parent[a] = b;
        }
    }
    let mut out: Vec<Group> = Vec::new();
    let mut seen = vec![false; p];
    for j in 0..p {
        if determined[j] || seen[j] {
            continue;
        }
        let r = root(&mut parent, j);
        let members: Vec<usize> = (0..p)
            .filter(|&k| !determined[k] && root(&mut parent, k) == r)
            .collect();
        for &k in &members {
            seen[k] = true;
        }
        // Null directions restricted to the group, then the complement of their span. In the
        // scaled coordinates a determined combination is c with c ⊥ every null vector; a
        // combination of the coefficients themselves carries weights c / scale.
        let k = members.len();
        let mut a = DMatrix::zeros(null.len(), k);
        for (i, v) in null.iter().enumerate() {
            for (c, &mbr) in members.iter().enumerate() {
                a[(i, c)] = v[mbr];
            }
        }
        let svd = a.clone().svd(false, true);
        let mut combinations = Vec::new();
        if let Some(vt) = svd.v_t {
            let largest = svd.singular_values.iter().cloned().fold(0.0, f64::max);
            let null_rank = svd
                .singular_values
                .iter()
                .filter(|s| **s > largest * 1e-8)
                .count();
            // The rows of Vᵀ beyond the rank of A span its null space: the determined
            // combinations. Vᵀ has min(rows, k) rows; complete it when A is wide or short.
            let full = complete_basis(&vt, k);
            // An orthonormal basis of the determined combinations mixes every member; the
            // reduced echelon form of the same span gives each combination a member of its own
            // and as few others as the span allows (`EXX[0] + 265 mm × EBX[0]`, not a
            // 24-member blend), whatever basis the decomposition returned.
            let rows: Vec<DVector<f64>> = full
                .iter()
                .skip(null_rank)
                .map(|r| DVector::from_column_slice(r))
                .collect();
            for row in circuits(&rows) {
                let weights: Vec<f64> = members
                    .iter()
                    .zip(row.iter())
                    .map(|(&m, w)| if scale[m] > 0.0 { w * scale[m] } else { 0.0 })
                    .collect();
                let big = weights.iter().fold(0.0f64, |a, w| a.max(w.abs()));
                if big > 0.0 {
                    combinations.push(weights.iter().map(|w| clean(w / big)).collect());
                }
            }
        }
        out.push(Group {
            members,
            combinations,
        });
    }
    out
}

/// Rounds weights that are rounding noise to zero so that `a + b` prints as such.
fn clean(w: f64) -> f64 {
    if w.abs() < 1e-9 {
        0.0
    } else {
        w
    }
}

/// An orthonormal basis of ℝᵏ whose first rows are the rows of `vt`.
fn complete_basis(vt: &DMatrix<f64>, k: usize) -> Vec<Vec<f64>> {
    let mut basis: Vec<DVector<f64>> = (0..vt.nrows())
        .map(|r| vt.row(r).transpose().into_owned())
        .collect();
    for e in 0..k {
        let mut v = DVector::zeros(k);
        v[e] = 1.0;
        for b in &basis {
            let d = b.dot(&v);
            v -= b * d;
        }
        let n = v.norm();
        if n > 1e-8 {
            basis.push(v / n);
        }
        if basis.len() >= k {
            break;
        }
    }
    basis.iter().map(|v| v.iter().copied().collect()).collect()
}

/// The figures of Table 4.1 for one design.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    /// Observations in the design (`n`).
    pub observations: usize,
    /// Directions scored (`p`): the coefficients, or the directions the candidates determine.
    pub directions: usize,
    /// `det(n · (XᵀX)⁻¹)^(1/p)`: the geometric mean variance per unit noise.
    pub det_root: f64,
    /// Mean and maximum of `n · xᵀ(XᵀX)⁻¹x` over the prediction set.
    pub average: f64,
    pub maximum: f64,
}

/// Scores the design `chosen` (indices into `units`, repeats allowed) with the prediction
/// variance taken over every row of `over`.
pub fn score(
    units: &[Unit],
    chosen: &[usize],
    over: &[Unit],
    p: usize,
) -> Result<Score, DesignError> {
    let m = information(units, chosen, p);
    let n: usize = chosen
        .iter()
        .filter_map(|&i| units.get(i))
        .map(|u| u.observations)
        .sum();
    let inv = m.clone().cholesky().ok_or_else(|| {
        let e = estimability(&m);
        DesignError::Deficient {
            missing: p - e.rank,
            rank: p,
        }
    })?;
    let nf = n as f64;
    let det = inv.determinant();
    let det_root = (nf.powi(p as i32) / det).powf(1.0 / p as f64);
    let mi = inv.inverse();
    let (mut sum, mut max, mut count) = (0.0, 0.0f64, 0usize);
    for u in over {
        for row in u.rows.chunks_exact(p.max(1)) {
            let x = DVector::from_row_slice(row);
            let d = nf * (x.transpose() * &mi * &x)[(0, 0)];
            sum += d;
            max = max.max(d);
            count += 1;
        }
    }
    Ok(Score {
        observations: n,
        directions: p,
        det_root,
        average: if count > 0 {
            sum / count as f64
        } else {
            f64::NAN
        },
        maximum: max,
    })
}

/// The outcome of [`select`].
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Chosen units (indices into the candidates, sorted; repeats are replications).
    pub chosen: Vec<usize>,
    /// Exchanges made after the greedy start.
    pub exchanges: usize,
    /// What the whole candidate set determines: the design can do no better.
    pub reach: Estimability,
}

/// Chooses `n` units from `units` (with replacement: a repeat is a replicated measurement) to
/// maximise `det(XᵀX)` over the directions the candidates can determine, by a greedy start
/// followed by DETMAX exchanges (add the best unit, drop the worst, until the one dropped is
/// the one added; Mitchell 1974). `tick` is called once per step for a progress display.
pub fn select(
    units: &[Unit],
    n: usize,
    p: usize,
    mut tick: impl FnMut(),
) -> Result<Selection, DesignError> {
    if units.is_empty() {
        return Err(DesignError::Empty);
    }
    if n == 0 {
        return Err(DesignError::Size(n));
    }
    // Each exchange pass weighs every chosen unit against every candidate: beyond the
    // candidates' count the work grows with nothing left to choose between (5 000 of 2 000
    // candidates ran for minutes).
    if n > units.len() {
        return Err(DesignError::MoreThanCandidates {
            asked: n,
            candidates: units.len(),
        });
    }
    if units.iter().any(|u| u.rows.iter().any(|v| !v.is_finite())) {
        return Err(DesignError::NotFinite);
    }
    let all: Vec<usize> = (0..units.len()).collect();
    let total = information(units, &all, p);
    let reach = estimability(&total);
    if reach.rank == 0 {
        return Err(DesignError::Blind);
    }
    // Work in the coordinates of the directions the candidates determine (scaled by the
    // column lengths so that the greedy start's ridge treats every coefficient alike).
    let scale: Vec<f64> = (0..p).map(|j| total[(j, j)].max(0.0).sqrt()).collect();
    let mut r = total.clone();
    for i in 0..p {
        for j in 0..p {
            let s = scale[i] * scale[j];
            r[(i, j)] = if s > 0.0 { r[(i, j)] / s } else { 0.0 };
        }
    }
    // The directions the candidates determine: as many of the largest eigenvalues' as
    // `estimability` found independent columns (one rank decision).
    let eig = r.symmetric_eigen();
    let mut keep: Vec<usize> = (0..p).collect();
    keep.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    keep.truncate(reach.rank);
    keep.sort_unstable();
    let q = keep.len();
    let mut basis = DMatrix::zeros(p, q);
    for (c, &k) in keep.iter().enumerate() {
        for i in 0..p {
            basis[(i, c)] = if scale[i] > 0.0 {
                eig.eigenvectors[(i, k)] / scale[i]
            } else {
                0.0
            };
        }
    }
    let projected: Vec<DMatrix<f64>> = units.iter().map(|u| u.matrix(p) * &basis).collect();
    // A small ridge lets the greedy start compare units before the design has full rank; it is
    // dropped for the exchanges. The scaled information has trace q over all candidates.
    let stack = Stack::new(&projected, q);
    drop(projected);
    let ridge = 1e-6 * q as f64 / units.len() as f64;
    // DETMAX and Fedorov exchanges stop at local optima; a few starts, the first greedy from
    // nothing and the others from a random seed set, keep the best design found.
    let mut rng = rand::rngs::StdRng::seed_from_u64(SEED);
    let mut best: Option<(f64, Vec<usize>, usize)> = None;
    for start in 0..STARTS {
        let seeded: Vec<usize> = if start == 0 {
            Vec::new()
        } else {
            (0..(q / 2).clamp(1, n))
                .map(|_| rng.random_range(0..units.len()))
                .collect()
        };
        let (chosen, m, exchanges) = run(&stack, seeded, n, q, ridge, &mut tick);
        let logdet = m.cholesky().map_or(f64::NEG_INFINITY, |c| {
            c.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum()
        });
        if best.as_ref().is_none_or(|b| logdet > b.0 + 1e-9) {
            best = Some((logdet, chosen, exchanges));
        }
    }
    let (_, chosen, detmax) = best.ok_or(DesignError::Blind)?;
    // Fedorov swaps polish the best DETMAX design only: they cost `n` passes over the
    // candidates per sweep, and the starts have already spread the search.
    let m = information_of(&stack, &chosen, q);
    let guard = DMatrix::identity(q, q) * (ridge * 1e-6);
    let (mut chosen, _, swaps) = fedorov(&stack, chosen, m, &guard, &mut tick);
    let exchanges = detmax + swaps;
    chosen.sort_unstable();
    Ok(Selection {
        chosen,
        exchanges,
        reach,
    })
}

/// Starts of the exchange algorithm (see [`select`]).
const STARTS: usize = 6;
/// The random starts are drawn from a fixed seed: the same candidates give the same design.
const SEED: u64 = 0x6b69_6e14;

/// Every candidate's rows stacked in one matrix, so that the products with `M⁻¹` that every
/// step needs are one matrix product over all candidates, not one small product per unit.
struct Stack {
    /// `q × rows`: each candidate row is a column, so that the dot products a step takes per
    /// unit run over contiguous memory.
    cols: DMatrix<f64>,
    /// Per unit: its first row and its number of rows.
    at: Vec<(usize, usize)>,
}

impl Stack {
    fn new(projected: &[DMatrix<f64>], q: usize) -> Stack {
        let total: usize = projected.iter().map(|u| u.nrows()).sum();
        let mut cols = DMatrix::zeros(q, total);
        let mut at = Vec::with_capacity(projected.len());
        let mut r = 0;
        for u in projected {
            cols.view_mut((0, r), (q, u.nrows()))
                .copy_from(&u.transpose());
            at.push((r, u.nrows()));
            r += u.nrows();
        }
        Stack { cols, at }
    }

    fn unit(&self, i: usize) -> DMatrix<f64> {
        let (r, k) = self.at.get(i).copied().unwrap_or((0, 0));
        self.cols.columns(r, k).transpose()
    }

    /// `M⁻¹ Xᵀ` for every candidate row (`M⁻¹` is symmetric).
    fn times(&self, inv: &DMatrix<f64>) -> DMatrix<f64> {
        inv * &self.cols
    }

    /// The k×k block `A_i M⁻¹ A_iᵀ` of unit `i`, from `w = M⁻¹ Xᵀ`.
    fn block(&self, w: &DMatrix<f64>, i: usize) -> DMatrix<f64> {
        let (r, k) = self.at.get(i).copied().unwrap_or((0, 0));
        DMatrix::from_fn(k, k, |x, y| self.cols.column(r + x).dot(&w.column(r + y)))
    }

    fn information(&self, i: usize) -> DMatrix<f64> {
        let u = self.unit(i);
        u.transpose() * u
    }
}

/// The information of `chosen` in the search's coordinates.
fn information_of(stack: &Stack, chosen: &[usize], q: usize) -> DMatrix<f64> {
    chosen
        .iter()
        .fold(DMatrix::zeros(q, q), |m, &i| m + stack.information(i))
}

/// `M⁻¹` and `W = M⁻¹ Xᵀ` for the current design, kept up to date by rank-k updates
/// (Woodbury) when a unit comes in or goes out: `k · q · rows` work instead of a new product
/// `q² · rows`, the cost that dominates a step.
struct Current {
    inv: DMatrix<f64>,
    w: DMatrix<f64>,
}

impl Current {
    fn new(stack: &Stack, m: &DMatrix<f64>) -> Current {
        let inv = inverse(m);
        let w = stack.times(&inv);
        Current { inv, w }
    }

    /// Adds (`sign` +1) or removes (−1) unit `i`: `M⁻¹ ∓ M⁻¹Aᵀ (I ± A M⁻¹ Aᵀ)⁻¹ A M⁻¹`.
    fn update(&mut self, stack: &Stack, i: usize, sign: f64) {
        let a = stack.unit(i);
        let ia = &self.inv * a.transpose(); // q × k
        let mut s = &a * &ia * sign;
        for d in 0..s.nrows() {
            s[(d, d)] += 1.0;
        }
        let Some(s_inv) = s.clone().try_inverse() else {
            return;
        };
        let k = &ia * s_inv * sign; // q × k
        let aw = rows_times(&a, &self.w); // k × rows
                                          // W −= K (A W), column by column in place: no q × rows temporary per step.
        for (j, mut col) in self.w.column_iter_mut().enumerate() {
            for (l, kl) in k.column_iter().enumerate() {
                col.axpy(-aw[(l, j)], &kl, 1.0);
            }
        }
        self.inv -= &k * ia.transpose();
    }
}

/// `A W` for a unit's few rows `A` (k × q) and all candidates' `W` (q × rows), as dot products
/// of contiguous columns of `W`: the generic product of a short wide matrix walks `W` in
/// k-long strides, which made it most of a search's time.
fn rows_times(a: &DMatrix<f64>, w: &DMatrix<f64>) -> DMatrix<f64> {
    let at = a.transpose();
    let mut out = DMatrix::zeros(a.nrows(), w.ncols());
    for (j, wc) in w.column_iter().enumerate() {
        for (x, ac) in at.column_iter().enumerate() {
            out[(x, j)] = ac.dot(&wc);
        }
    }
    out
}

/// One start: greedy completion of `seeded` to `n` units, then DETMAX, then Fedorov swaps.
/// Returns the units, their information and the number of exchanges.
fn run(
    stack: &Stack,
    seeded: Vec<usize>,
    n: usize,
    q: usize,
    ridge: f64,
    tick: &mut impl FnMut(),
) -> (Vec<usize>, DMatrix<f64>, usize) {
    let mut m = DMatrix::identity(q, q) * ridge;
    let mut chosen: Vec<usize> = Vec::with_capacity(n + 1);
    for &i in seeded.iter().take(n) {
        m += stack.information(i);
        chosen.push(i);
    }
    let mut cur = Current::new(stack, &m);
    while chosen.len() < n {
        let best = best_addition(stack, &cur.w);
        chosen.push(best);
        m += stack.information(best);
        cur.update(stack, best, 1.0);
        tick();
    }
    m -= DMatrix::identity(q, q) * ridge;
    let guard = DMatrix::identity(q, q) * (ridge * 1e-6);
    // A fresh inverse without the start's ridge (the updates below keep it current).
    let mut cur = Current::new(stack, &(&m + &guard));
    let mut exchanges = 0;
    // Each DETMAX step strictly increases the determinant; the cap only guards rounding loops.
    let cap = 20 * n + 100;
    for _ in 0..cap {
        let add = best_addition(stack, &cur.w);
        chosen.push(add);
        cur.update(stack, add, 1.0);
        let (drop_at, _) = chosen
            .iter()
            .enumerate()
            .map(|(at, &i)| {
                let g = stack.block(&cur.w, i);
                (
                    at,
                    (DMatrix::identity(g.nrows(), g.nrows()) - g).determinant(),
                )
            })
            .fold((0, f64::NEG_INFINITY), |best, c| {
                if c.1 > best.1 + 1e-12 {
                    c
                } else {
                    best
                }
            });
        let dropped = chosen.swap_remove(drop_at);
        cur.update(stack, dropped, -1.0);
        tick();
        if dropped == add {
            break;
        }
        m = m + stack.information(add) - stack.information(dropped);
        exchanges += 1;
    }
    (chosen, m, exchanges)
}

/// Fedorov swaps on a design (`chosen`, information `m`): returns the swapped design, its
/// information and the number of swaps.
fn fedorov(
    stack: &Stack,
    mut chosen: Vec<usize>,
    mut m: DMatrix<f64>,
    guard: &DMatrix<f64>,
    tick: &mut impl FnMut(),
) -> (Vec<usize>, DMatrix<f64>, usize) {
    let units = stack.at.len();
    let cap = 20 * chosen.len() + 100;
    let mut exchanges = 0;
    // DETMAX stops at designs no single add-then-drop improves; Fedorov swaps (each member in
    // turn swapped for the candidate that raises the determinant most, when one does; Cook and
    // Nachtsheim's modified Fedorov) leave it where no single swap improves either.
    let mut cur = Current::new(stack, &(&m + guard));
    let mut own: Vec<DMatrix<f64>> = (0..units).map(|j| stack.block(&cur.w, j)).collect();
    for _ in 0..cap {
        let mut swapped = false;
        for at in 0..chosen.len() {
            let Some(&i) = chosen.get(at) else { break };
            let a = stack.unit(i);
            // A M⁻¹ B_jᵀ for every candidate j at once (k_a × rows).
            let cross = rows_times(&a, &cur.w);
            let aa = own
                .get(i)
                .cloned()
                .unwrap_or_else(|| stack.block(&cur.w, i));
            let mut best = (i, 1.0 + 1e-9);
            for (j, bb) in own.iter().enumerate() {
                if j == i {
                    continue;
                }
                let (r, kb) = stack.at.get(j).copied().unwrap_or((0, 0));
                let ba = cross.columns(r, kb).transpose();
                let ratio = swap_ratio(bb, &aa, &ba);
                if ratio > best.1 {
                    best = (j, ratio);
                }
            }
            if best.0 != i {
                m = &m - stack.information(i) + stack.information(best.0);
                cur.update(stack, best.0, 1.0);
                cur.update(stack, i, -1.0);
                own = (0..units).map(|j| stack.block(&cur.w, j)).collect();
                if let Some(slot) = chosen.get_mut(at) {
                    *slot = best.0;
                }
                exchanges += 1;
                swapped = true;
            }
        }
        tick();
        if !swapped {
            break;
        }
    }
    (chosen, m, exchanges)
}

fn inverse(m: &DMatrix<f64>) -> DMatrix<f64> {
    match m.clone().cholesky() {
        Some(c) => c.inverse(),
        None => m
            .clone()
            .pseudo_inverse(1e-14)
            .unwrap_or_else(|_| DMatrix::zeros(m.nrows(), m.ncols())),
    }
}

/// The unit whose addition multiplies the determinant most: `det(I + A M⁻¹ Aᵀ)` (matrix
/// determinant lemma, a rank-k update of `det M`), with `w = M⁻¹ Xᵀ` for all candidates.
fn best_addition(stack: &Stack, w: &DMatrix<f64>) -> usize {
    let mut best = (0, f64::NEG_INFINITY);
    for i in 0..stack.at.len() {
        let g = stack.block(w, i);
        let gain = (DMatrix::identity(g.nrows(), g.nrows()) + g).determinant();
        // Ties go to the earlier unit, so that the choice does not hang on rounding.
        if i == 0 || gain > best.1 * (1.0 + 1e-12) {
            best = (i, gain);
        }
    }
    best.0
}

/// The factor by which swapping member `a` for candidate `b` multiplies the determinant:
/// `det(I + S U M⁻¹ Uᵀ)` with `U = [b; a]` and `S = diag(+I, −I)`, from the blocks
/// `bb = B M⁻¹ Bᵀ`, `aa = A M⁻¹ Aᵀ` and `ba = B M⁻¹ Aᵀ`.
fn swap_ratio(bb: &DMatrix<f64>, aa: &DMatrix<f64>, ba: &DMatrix<f64>) -> f64 {
    let (kb, ka) = (bb.nrows(), aa.nrows());
    if kb == 1 && ka == 1 {
        // The rank-one case (Fedorov's Δ): (1 + d_b)(1 − d_a) + d_ab².
        let (b, a, x) = (bb[(0, 0)], aa[(0, 0)], ba[(0, 0)]);
        return (1.0 + b) * (1.0 - a) + x * x;
    }
    let mut w = DMatrix::zeros(kb + ka, kb + ka);
    w.view_mut((0, 0), (kb, kb)).copy_from(bb);
    w.view_mut((0, kb), (kb, ka)).copy_from(ba);
    w.view_mut((kb, 0), (ka, kb)).copy_from(&(-ba.transpose()));
    w.view_mut((kb, kb), (ka, ka)).copy_from(&(-aa));
    (DMatrix::identity(kb + ka, kb + ka) + w).determinant()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `kin check` (the rows) and a plan's analysis (their information) call the same columns
    /// dependent, including a near-dependency at a millionth of a column's length that an
    /// eigenvalue line relative to the largest would keep.
    #[test]
    fn a_plan_and_its_rows_have_one_rank_decision() {
        use crate::identify::{analyse, Column};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let (rows, p) = (40, 6);
        let mut x = vec![0.0; rows * p];
        for r in 0..rows {
            for j in 0..4 {
                x[r * p + j] = rng.random_range(-1.0..1.0);
            }
            // Column 4 is 2·c0 − c1 up to a millionth of its length; column 5 is c2 + c3 exactly.
            let wobble = 2e-6 * rng.random_range(-1.0..1.0);
            x[r * p + 4] = 2.0 * x[r * p] - x[r * p + 1] + wobble;
            x[r * p + 5] = x[r * p + 2] + x[r * p + 3];
        }
        let columns: Vec<Column> = (0..p).map(Column::Coefficient).collect();
        let report = analyse(&x, &columns).expect("analyses");
        let m = DMatrix::from_row_slice(rows, p, &x);
        let e = estimability(&(m.transpose() * &m));
        assert_eq!(e.rank, report.rank);
        assert_eq!(e.rank, 4);
        assert_eq!(e.determined, vec![false; 6]);
        let members: Vec<Vec<usize>> = e.groups.iter().map(|g| g.members.clone()).collect();
        assert_eq!(members, vec![vec![0, 1, 4], vec![2, 3, 5]]);
    }

    #[test]
    fn unrelated_unseen_coefficients_are_not_joined_whatever_the_null_basis() {
        // Coefficients 0 and 1 are never seen (one each), 2 and 3 only as their sum, 4 alone:
        // the unseen directions are e0, e1 and e2 − e3. Given them rotated into each other, as
        // an eigensolver may return a repeated zero, the groups are still {0}, {1}, {2, 3}.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let d = DVector::from_vec(vec![0.0, 0.0, s, -s, 0.0]);
        let null = vec![
            DVector::from_vec(vec![0.6, 0.0, 0.0, 0.0, 0.0]) + &d * 0.8,
            DVector::from_vec(vec![0.48, 0.6, 0.0, 0.0, 0.0]) - &d * 0.36,
            DVector::from_vec(vec![0.64, -0.8, 0.0, 0.0, 0.0]) - &d * 0.48,
        ];
        let determined = [false, false, false, false, true];
        let g = groups(&null, &[1.0; 5], &determined);
        let members: Vec<Vec<usize>> = g.iter().map(|g| g.members.clone()).collect();
        assert_eq!(members, vec![vec![0], vec![1], vec![2, 3]]);
        // Within {2, 3} the sum is determined; nothing is within {0} or {1}.
        assert!(g[0].combinations.is_empty() && g[1].combinations.is_empty());
        let [c] = g[2].combinations.as_slice() else {
            panic!("{:?}", g[2].combinations)
        };
        assert!((c[0] - c[1]).abs() < 1e-12 && c[0].abs() == 1.0, "{c:?}");
    }

    /// Thesis eq. 4.21: the row of a length L at angle α for squareness β₁, x scale β₂, y scale β₃.
    fn bar(alpha_deg: f64) -> Unit {
        let a = alpha_deg.to_radians();
        let (s, c) = a.sin_cos();
        let l = 400.0;
        Unit {
            rows: vec![l * c * s, -l * c * c, -l * s * s],
            observations: 1,
        }
    }

    #[test]
    fn identical_columns_form_a_group_with_their_sum_determined() {
        let mut m = DMatrix::zeros(3, 3);
        for row in [[1.0, 1.0, 0.0], [2.0, 2.0, 1.0], [0.0, 0.0, 3.0]] {
            let x = DVector::from_row_slice(&row);
            m += &x * x.transpose();
        }
        let e = estimability(&m);
        assert_eq!(e.rank, 2);
        assert_eq!(e.determined, vec![false, false, true]);
        assert_eq!(e.groups.len(), 1);
        assert_eq!(e.groups[0].members, vec![0, 1]);
        let c = &e.groups[0].combinations;
        assert_eq!(c.len(), 1);
        assert!((c[0][0] - c[0][1]).abs() < 1e-9, "{c:?}");
        assert!(e.sigma[0].is_none() && e.sigma[2].is_some());
    }

    #[test]
    fn an_artifact_length_is_eliminated_inside_its_unit() {
        // Two rows of one bar with an unknown length: only their difference informs β.
        let u = Unit::eliminated(&[1.0, 0.0, 1.0, 3.0, 0.0, 1.0], 2, 1);
        assert!((u.rows[0] + 1.0).abs() < 1e-12 && (u.rows[2] - 1.0).abs() < 1e-12);
        assert!(u.rows[1].abs() < 1e-12 && u.rows[3].abs() < 1e-12);
    }

    #[test]
    fn no_more_units_are_chosen_than_there_are_candidates() {
        let units: Vec<Unit> = (0..4).map(|k| bar(15.0 * k as f64)).collect();
        assert!(matches!(
            select(&units, 5, 3, || {}),
            Err(DesignError::MoreThanCandidates {
                asked: 5,
                candidates: 4
            })
        ));
        assert_eq!(
            select(&units, 4, 3, || {}).expect("selects").chosen.len(),
            4
        );
    }

    #[test]
    fn the_exchange_finds_a_design_as_good_as_any_in_a_small_exhaustive_search() {
        let units: Vec<Unit> = (0..12).map(|k| bar(15.0 * k as f64)).collect();
        let s = select(&units, 6, 3, || {}).expect("selects");
        let best = information(&units, &s.chosen, 3).determinant();
        // Every multiset of 6 of 12 orientations.
        let mut top = 0.0f64;
        let mut idx = [0usize; 6];
        loop {
            top = top.max(information(&units, &idx, 3).determinant());
            let mut k = 5;
            loop {
                if idx[k] < 11 {
                    idx[k] += 1;
                    for j in k + 1..6 {
                        idx[j] = idx[k];
                    }
                    break;
                }
                if k == 0 {
                    return assert!(best >= top * (1.0 - 1e-9), "{best} < {top}");
                }
                k -= 1;
            }
        }
    }
}
