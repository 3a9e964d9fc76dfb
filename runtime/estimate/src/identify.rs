//! Identifiability (thesis §4.3, appendix B): which combinations of coefficients the
//! observations cannot see.
//!
//! A combination λᵀβ is estimable iff λ lies in the row space of the design matrix X (§4.3). We
//! scale every column of X to unit length (so that units and ranges do not decide) and name the
//! invisible directions in declaration order: a column that the earlier columns already explain
//! is reported together with the earlier columns it is a combination of. The design is streamed
//! into `XᵀX` (memory: columns², whatever the rows), factored in column order. Nuisance columns
//! (alignment of an artifact) come first, so a model term they absorb is named as absorbed.

use faer::linalg::matmul::triangular::BlockStructure;
use faer::{Accum, Mat, Par};
use kin_compiler::diagnostic::{Diagnostic, Span};
use kin_compiler::ir::Machine;
use kin_compiler::SourceMap;
use thiserror::Error;

use kin_model::interp::{EvalError, State};
use kin_model::states::States;

#[derive(Debug, Error)]
pub enum IdentifyError {
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Engine(#[from] kin_model::engine::EngineError),
    /// A column whose values (or whose products with another column) overflow: a term scaled
    /// beyond what a double holds (`1e308 * const`).
    #[error("the design holds values that are not finite numbers")]
    Factor {
        /// The column that overflows, when one alone does.
        column: Option<Column>,
    },
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

/// Whether a dependency's first partner is a registration's parameter (the instrument's
/// placement or a target's offset of a file of absolute positions).
fn registration(d: &Dependency) -> bool {
    matches!(d.combination.first(), Some((Column::Nuisance(name), _))
        if name.starts_with("instrument ") || name.starts_with("target "))
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
    /// Largest over smallest kept singular value of the scaled matrix (NaN when not
    /// estimated, see [`Condition`]).
    pub condition: f64,
    pub dependencies: Vec<Dependency>,
}

/// Relative tolerance below which a direction counts as invisible. Structural dependencies
/// sit at rounding level (1e-13 and below); anything an experiment can resolve is far above.
pub const TOLERANCE: f64 = 1e-8;

/// A unit-scaled column whose part not explained by the earlier columns is at most this
/// fraction of its length is named as a combination of them.
const DEPENDENT: f64 = 1e-6;

/// Rows of the design held at a time while the Gram matrix is accumulated: the design itself
/// (up to 12 × coefficients² values, 9.6 GB at 10 000 coefficients) is never held.
const BLOCK_ROWS: usize = 256;

/// Builds the design matrix of `observe` at `states` (row-major, columns = coefficients, then
/// six alignment columns when `aligned`).
/// As `design_with`, evaluated by the interpreter.
pub fn design(
    m: &Machine,
    states: &States,
    observe: Observe,
    aligned: bool,
) -> Result<(Vec<f64>, Vec<Column>), IdentifyError> {
    design_with(
        m,
        states,
        observe,
        aligned,
        kin_model::engine::Engine::Interp,
    )
}

/// Builds the design matrix of `observe` at `states` with the chosen engine.
pub(crate) fn design_with(
    m: &Machine,
    states: &States,
    observe: Observe,
    aligned: bool,
    engine: kin_model::engine::Engine,
) -> Result<(Vec<f64>, Vec<Column>), IdentifyError> {
    let mut out = Vec::new();
    let columns = for_each_row(m, states, observe, aligned, engine, |row| {
        out.extend_from_slice(row)
    })?;
    Ok((out, columns))
}

/// The columns of the design of `observe` at `states`, each row handed to `sink` in turn.
fn for_each_row(
    m: &Machine,
    states: &States,
    observe: Observe,
    aligned: bool,
    engine: kin_model::engine::Engine,
    mut sink: impl FnMut(&[f64]),
) -> Result<Vec<Column>, IdentifyError> {
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
    let mut it = kin_model::engine::make(m, engine)?;
    let beta = vec![0.0; n];
    let mut jac = vec![0.0; 6 * n];
    let mut err = [0.0; 6];
    match observe {
        Observe::Position | Observe::Pose | Observe::Data => {
            let comps = if observe == Observe::Position { 3 } else { 6 };
            let mut row = vec![0.0; width];
            for r in 0..states.len() {
                let s = states.get(r);
                it.error_and_jacobian(&s, &beta, &mut err, &mut jac)?;
                let p = if aligned {
                    nalgebra::Vector3::from(it.nominal_position(&s)?)
                } else {
                    nalgebra::Vector3::zeros()
                };
                for c in 0..comps {
                    if aligned {
                        row[..offset].fill(0.0);
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
                    if let (Some(dst), Some(src)) =
                        (row.get_mut(offset..), jac.get(c * n..(c + 1) * n))
                    {
                        dst.copy_from_slice(src);
                    }
                    sink(&row);
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
                    Ok(_) => sink(&row),
                    Err(EvalError::Kinematics(_)) => continue,
                    Err(e) => return Err(e.into()),
                }
            }
        }
    }
    Ok(columns)
}

/// `XᵀX` of a design fed one row at a time (lower triangle only), `BLOCK_ROWS` rows buffered:
/// memory is `columns²` plus one block, whatever the number of rows.
struct Gram {
    g: Mat<f64>,
    /// `BLOCK_ROWS` design rows as columns (column-major, so each row is copied contiguously).
    block: Mat<f64>,
    filled: usize,
    rows: usize,
}

impl Gram {
    fn new(columns: usize) -> Gram {
        Gram {
            g: Mat::zeros(columns, columns),
            block: Mat::zeros(columns, BLOCK_ROWS),
            filled: 0,
            rows: 0,
        }
    }

    fn push(&mut self, row: &[f64]) {
        for (j, v) in row.iter().enumerate().take(self.block.nrows()) {
            self.block[(j, self.filled)] = *v;
        }
        self.filled += 1;
        self.rows += 1;
        if self.filled == self.block.ncols() {
            self.flush();
        }
    }

    fn flush(&mut self) {
        if self.filled == 0 {
            return;
        }
        let b = self.block.as_ref().subcols(0, self.filled);
        crate::rank_update::lower(self.g.as_mut(), b, 1.0);
        self.filled = 0;
    }

    fn finish(mut self) -> (Mat<f64>, usize) {
        self.flush();
        (self.g, self.rows)
    }
}

/// Poses buffered by [`PoseGram`] before they are added to the Gram matrix.
const BLOCK_POSES: usize = 256;

/// `XᵀX` of a design observed pose by pose (`comps` rows per pose), using its structure: every
/// coefficient belongs to one error model, so at one pose its column is the model's F-matrix
/// column times a scalar (`F·v_j`, eq. 2.24), and within a term all columns share that
/// direction. The `comps` rows of a pose then add `(F_a·F_b) v_j v_k` to entry (j, k) — one
/// product per entry and pose instead of one per entry and row, a sixth of the work of
/// [`Gram`] for pose observations. The directions and values are read off the design rows
/// themselves (the largest entry of a group fixes its scale); a pose whose rows do not have
/// this shape to rounding goes to the plain row-by-row accumulation instead, so the result
/// is `XᵀX` either way.
struct PoseGram {
    comps: usize,
    width: usize,
    /// Column ranges (start, length) sharing a direction at every pose, in column order,
    /// covering every column.
    groups: Vec<(usize, usize)>,
    /// The current pose's rows, `comps × width` row-major.
    pose: Vec<f64>,
    pose_rows: usize,
    /// `v_j` of the buffered poses, one column per pose.
    v: Mat<f64>,
    /// Each buffered pose's unit-pivot direction per group: `comps` values per (pose, group).
    dirs: Vec<f64>,
    poses: usize,
    /// Scratch: one group's values times the weights of a pair of groups.
    scaled: Mat<f64>,
    weights: Vec<f64>,
    /// Row-by-row fallback; also holds the Gram matrix both add to.
    rows: Gram,
}

impl PoseGram {
    fn new(width: usize, comps: usize, groups: Vec<(usize, usize)>) -> PoseGram {
        let widest = groups.iter().map(|g| g.1).max().unwrap_or(0);
        let dirs = vec![0.0; BLOCK_POSES * groups.len() * comps];
        PoseGram {
            comps,
            width,
            pose: vec![0.0; comps * width],
            pose_rows: 0,
            v: Mat::zeros(width, BLOCK_POSES),
            dirs,
            poses: 0,
            scaled: Mat::zeros(widest, BLOCK_POSES),
            weights: vec![0.0; BLOCK_POSES],
            rows: Gram::new(width),
            groups,
        }
    }

    fn push(&mut self, row: &[f64]) {
        let w = self.width;
        if let Some(dst) = self
            .pose
            .get_mut(self.pose_rows * w..(self.pose_rows + 1) * w)
        {
            for (d, s) in dst.iter_mut().zip(row) {
                *d = *s;
            }
        }
        self.pose_rows += 1;
        if self.pose_rows == self.comps {
            self.pose_rows = 0;
            self.end_pose();
        }
    }

    /// Splits the pose into directions and values, or hands its rows to the fallback.
    fn end_pose(&mut self) {
        let (w, comps, ng, p) = (self.width, self.comps, self.groups.len(), self.poses);
        let at = |r: usize, j: usize| r * w + j;
        let mut shaped = self.pose.iter().all(|x| x.is_finite());
        for (gi, &(start, len)) in self.groups.iter().enumerate() {
            if !shaped {
                break;
            }
            let mut best = (0, start, 0.0f64);
            for r in 0..comps {
                for j in start..start + len {
                    let a = self.pose[at(r, j)].abs();
                    if a > best.2 {
                        best = (r, j, a);
                    }
                }
            }
            let dir = &mut self.dirs[(p * ng + gi) * comps..(p * ng + gi + 1) * comps];
            if best.2 == 0.0 {
                dir.fill(0.0);
                for j in start..start + len {
                    self.v[(j, p)] = 0.0;
                }
                continue;
            }
            let pivot = self.pose[at(best.0, best.1)];
            for (r, d) in dir.iter_mut().enumerate() {
                *d = self.pose[at(r, best.1)] / pivot;
            }
            // Each entry is one product F[r]·v_j, so the reconstruction is exact to a few
            // roundings of the group's largest entry.
            let tolerance = 1e-12 * best.2;
            for j in start..start + len {
                let vj = self.pose[at(best.0, j)];
                self.v[(j, p)] = vj;
                for (r, d) in dir.iter().enumerate() {
                    if (self.pose[at(r, j)] - d * vj).abs() > tolerance {
                        shaped = false;
                    }
                }
            }
        }
        if shaped {
            self.poses += 1;
            if self.poses == BLOCK_POSES {
                self.flush();
            }
        } else {
            for r in 0..comps {
                self.rows.push(&self.pose[r * w..(r + 1) * w]);
            }
        }
    }

    fn flush(&mut self) {
        let n = self.poses;
        if n == 0 {
            return;
        }
        let bands = bands(&self.groups, crate::rank_update::threads());
        let shared = Buffered {
            groups: &self.groups,
            v: self.v.as_ref(),
            dirs: &self.dirs,
            comps: self.comps,
            poses: n,
        };
        // Each band of groups owns the rows of `g` its groups cover (every column left of the
        // diagonal): bands write disjoint entries, so they run on their own threads.
        std::thread::scope(|scope| {
            let mut rest = self.rows.g.as_mut();
            let mut first_row = 0usize;
            let mut scratch = Some((&mut self.scaled, &mut self.weights));
            for (k, &(a0, a1)) in bands.iter().enumerate() {
                let end = self
                    .groups
                    .get(a1.wrapping_sub(1))
                    .map_or(first_row, |g| g.0 + g.1);
                let (band, next) = rest.split_at_row_mut(end.saturating_sub(first_row));
                rest = next;
                let offset = first_row;
                first_row = end;
                let shared = &shared;
                if k + 1 == bands.len() {
                    // The last band runs here, with the accumulator's own scratch.
                    if let Some((scaled, weights)) = scratch.take() {
                        shared.add(band, offset, a0..a1, scaled, weights);
                    }
                } else {
                    scope.spawn(move || {
                        let mut scaled = Mat::zeros(shared.widest(), shared.poses);
                        let mut weights = vec![0.0; shared.poses];
                        shared.add(band, offset, a0..a1, &mut scaled, &mut weights);
                    });
                }
            }
        });
        self.rows.rows += n * self.comps;
        self.poses = 0;
    }

    fn finish(mut self) -> (Mat<f64>, usize) {
        self.flush();
        self.rows.finish()
    }
}

/// What [`PoseGram`] holds of its buffered poses, shared read-only by the threads of a flush.
struct Buffered<'a> {
    groups: &'a [(usize, usize)],
    v: faer::MatRef<'a, f64>,
    dirs: &'a [f64],
    comps: usize,
    poses: usize,
}

impl Buffered<'_> {
    fn widest(&self) -> usize {
        self.groups.iter().map(|g| g.1).max().unwrap_or(0)
    }

    /// Adds the buffered poses' products of groups `a ∈ groups` with every group `b ≤ a` to
    /// `band`, the rows `offset..` of the Gram matrix the groups cover.
    fn add(
        &self,
        mut band: faer::MatMut<'_, f64>,
        offset: usize,
        groups: std::ops::Range<usize>,
        scaled: &mut Mat<f64>,
        weights: &mut [f64],
    ) {
        let (n, comps, ng) = (self.poses, self.comps, self.groups.len());
        let dir = |p: usize, g: usize| {
            self.dirs
                .get((p * ng + g) * comps..(p * ng + g + 1) * comps)
                .unwrap_or(&[])
        };
        for a in groups {
            let (sa, la) = self.groups[a];
            for b in 0..=a {
                let (sb, lb) = self.groups[b];
                let mut any = false;
                for (p, wt) in weights.iter_mut().enumerate().take(n) {
                    *wt = dir(p, a).iter().zip(dir(p, b)).map(|(x, y)| x * y).sum();
                    any |= *wt != 0.0;
                }
                if !any {
                    continue;
                }
                for (p, &wt) in weights.iter().enumerate().take(n) {
                    for j in 0..lb {
                        scaled[(j, p)] = self.v[(sb + j, p)] * wt;
                    }
                }
                let va = self.v.submatrix(sa, 0, la, n);
                let sc = scaled.as_ref().submatrix(0, 0, lb, n);
                let target = band.as_mut().submatrix_mut(sa - offset, sb, la, lb);
                // Groups are in column order, so block (a, b ≤ a) is in the lower triangle;
                // a diagonal block needs only its own lower triangle.
                let structure = if a == b {
                    BlockStructure::TriangularLower
                } else {
                    BlockStructure::Rectangular
                };
                faer::linalg::matmul::triangular::matmul(
                    target,
                    structure,
                    Accum::Add,
                    va,
                    BlockStructure::Rectangular,
                    sc.transpose(),
                    BlockStructure::Rectangular,
                    1.0,
                    Par::Seq,
                );
            }
        }
    }
}

/// Splits the groups into at most `threads` consecutive bands of about equal work (a group's
/// products reach every column left of its end: its width times its last column).
fn bands(groups: &[(usize, usize)], threads: usize) -> Vec<(usize, usize)> {
    let work: Vec<f64> = groups
        .iter()
        .map(|&(s, l)| l as f64 * (s + l) as f64)
        .collect();
    let total: f64 = work.iter().sum();
    let threads = threads.max(1);
    let mut out = Vec::with_capacity(threads);
    let (mut start, mut done) = (0usize, 0.0);
    for (i, w) in work.iter().enumerate() {
        done += w;
        let share = total * (out.len() + 1) as f64 / threads as f64;
        if done >= share && out.len() + 1 < threads {
            out.push((start, i + 1));
            start = i + 1;
        }
    }
    if start < groups.len() || out.is_empty() {
        out.push((start, groups.len()));
    }
    out
}

/// Column groups of the design that share one direction at every pose: each term's
/// coefficients (shifted past the alignment columns), every other column alone.
fn groups(m: &Machine, offset: usize, width: usize) -> Vec<(usize, usize)> {
    let mut group = vec![usize::MAX; width];
    let mut out = Vec::new();
    for term in m.errors.iter().flat_map(|e| &e.terms) {
        let start = offset.saturating_add(term.first);
        let end = start.saturating_add(term.coefficients);
        // A term the IR got wrong (overlapping, out of range) is left to the singletons.
        if term.coefficients == 0
            || end > width
            || group[start..end].iter().any(|&g| g != usize::MAX)
        {
            continue;
        }
        group[start..end].fill(out.len());
        out.push((start, term.coefficients));
    }
    for (j, g) in group.iter().enumerate() {
        if *g == usize::MAX {
            out.push((j, 1));
        }
    }
    out.sort_unstable();
    out
}

/// Analyses a row-major `rows × columns.len()` design matrix.
pub fn analyse(x: &[f64], columns: &[Column]) -> Result<Report, IdentifyError> {
    let n = columns.len();
    let mut gram = Gram::new(n);
    if n > 0 {
        for row in x.chunks_exact(n) {
            gram.push(row);
        }
    }
    let (g, rows) = gram.finish();
    analyse_gram(g, rows, columns, Condition::Estimate)
}

/// The analysis of an information matrix `XᵀX` given whole (`p × p`, symmetric; only its lower
/// triangle is read): the decision [`analyse`] makes on the design itself, for the callers that
/// hold the information of a plan rather than its rows (`design::estimability`), so that
/// `kin check`, `kin check --plan` and `kin design` call the same columns dependent.
pub(crate) fn analyse_information(
    p: usize,
    information: impl Fn(usize, usize) -> f64,
) -> Result<Report, IdentifyError> {
    let g = Mat::from_fn(p, p, |i, j| if i >= j { information(i, j) } else { 0.0 });
    let columns: Vec<Column> = (0..p).map(Column::Coefficient).collect();
    // The information of a plan no longer knows its rows; one stands for "some".
    analyse_gram(g, 1, &columns, Condition::Skip)
}

/// The analysis from the lower triangle of `XᵀX` (what [`analyse`] does after accumulating it).
///
/// The Gram matrix of the unit-scaled columns is factored `LLᵀ` in declaration order; a pivot at
/// most `DEPENDENT²` is the squared length of the part of that column the earlier independent
/// columns do not explain (what Gram–Schmidt in column order measures), so the column is named
/// as their combination and replaced by a huge pivot, which takes it out of every later column's
/// elimination. Cost: `rows × columns²` to accumulate, `columns³ / 3` to factor; memory
/// `columns²`. Forming `XᵀX` squares the condition: a residual is resolved to about
/// `√(columns · ε)` of the column's length, below `DEPENDENT` up to 10⁴ columns.
fn analyse_gram(
    mut g: Mat<f64>,
    rows: usize,
    columns: &[Column],
    estimate: Condition,
) -> Result<Report, IdentifyError> {
    let n = columns.len();
    if rows == 0 || n == 0 {
        return Err(IdentifyError::Empty);
    }
    // A column that overflows is named, so the error can point at its term.
    if let Some(j) = (0..n).find(|&j| !g[(j, j)].is_finite()) {
        return Err(IdentifyError::Factor {
            column: columns.get(j).cloned(),
        });
    }
    let norms: Vec<f64> = (0..n).map(|j| g[(j, j)].max(0.0).sqrt()).collect();
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
    for j in 0..n {
        for i in j..n {
            g[(i, j)] *= scale[i] * scale[j];
        }
    }
    if (0..n).any(|j| !(j..n).all(|i| g[(i, j)].is_finite())) {
        return Err(IdentifyError::Factor { column: None });
    }
    let independent = factor_in_order(&mut g, &scale);
    let l = g;
    let mut dependencies = Vec::new();
    let mut w = vec![0.0; n];
    for j in 0..n {
        if independent[j] {
            continue;
        }
        let column = columns.get(j).cloned().unwrap_or(Column::Coefficient(j));
        if scale[j] == 0.0 {
            dependencies.push(Dependency {
                column,
                combination: Vec::new(),
            });
            continue;
        }
        // Row j of L holds the column's coordinates on the earlier independent directions;
        // back-substitute Rw = c over those (R = Lᵀ restricted to independent columns).
        w[..j].fill(0.0);
        for i in (0..j).rev() {
            if !independent[i] {
                continue;
            }
            let col = l.col(i);
            let mut s = l[(j, i)];
            for k in i + 1..j {
                s -= col[k] * w[k];
            }
            w[i] = s / l[(i, i)];
        }
        let mut combination: Vec<(Column, f64)> = (0..j)
            .filter(|&i| independent[i] && w[i].abs() > 1e-6)
            .map(|i| {
                (
                    columns.get(i).cloned().unwrap_or(Column::Coefficient(i)),
                    w[i],
                )
            })
            .collect();
        combination.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
        dependencies.push(Dependency {
            column,
            combination,
        });
    }
    let rank = independent.iter().filter(|&&b| b).count();
    Ok(Report {
        rows,
        columns: n,
        rank,
        tolerance: TOLERANCE,
        condition: if estimate == Condition::Estimate {
            condition(&l, &independent)
        } else {
            f64::NAN
        },
        dependencies,
    })
}

/// Cholesky factor `L` of the scaled Gram matrix in place (lower triangle), in column order,
/// blocked so the trailing update is a matrix product. A pivot at most `DEPENDENT²` marks its
/// column dependent: the column of `L` below it is zeroed, which takes it out of every later
/// elimination, and its row keeps the coordinates on the earlier independent columns.
fn factor_in_order(g: &mut Mat<f64>, scale: &[f64]) -> Vec<bool> {
    const PANEL: usize = 64;
    let n = g.nrows();
    let mut independent = vec![false; n];
    let mut j0 = 0;
    while j0 < n {
        let j1 = (j0 + PANEL).min(n);
        for j in j0..j1 {
            // Left-looking within the panel: the earlier panels are already applied.
            {
                // Columns j0..j on the left, column j on the right: both as contiguous slices.
                let (left, right) = g.as_mut().split_at_col_mut(j);
                let target = right
                    .col_mut(0)
                    .try_as_col_major_mut()
                    .map(|c| c.as_slice_mut());
                if let Some(target) = target {
                    let target = target.get_mut(j..).unwrap_or(&mut []);
                    for i in j0..j {
                        let source = left
                            .as_ref()
                            .col(i)
                            .try_as_col_major()
                            .map(|c| c.as_slice());
                        let Some(source) = source else { continue };
                        let lji = source.get(j).copied().unwrap_or(0.0);
                        if lji != 0.0 {
                            for (t, v) in target.iter_mut().zip(source.get(j..).unwrap_or(&[])) {
                                *t -= v * lji;
                            }
                        }
                    }
                }
            }
            let d = g[(j, j)];
            if scale.get(j).copied().unwrap_or(0.0) > 0.0 && d > DEPENDENT * DEPENDENT {
                let root = d.sqrt();
                g[(j, j)] = root;
                for k in j + 1..n {
                    g[(k, j)] /= root;
                }
                independent[j] = true;
            } else {
                for k in j..n {
                    g[(k, j)] = 0.0;
                }
            }
        }
        if j1 < n {
            let panel = g.as_ref().submatrix(j1, j0, n - j1, j1 - j0).to_owned();
            crate::rank_update::lower(
                g.as_mut().submatrix_mut(j1, j1, n - j1, n - j1),
                panel.as_ref(),
                -1.0,
            );
        }
        j0 = j1;
    }
    independent
}

/// Largest over smallest singular value of the independent columns (unit-scaled), estimated
/// from their triangular factor `R = Lᵀ` by power iteration on `RᵀR` and on its inverse: a few
/// matrix-vector products and triangular solves, `O(columns²)` each, where a singular value
/// decomposition would cost `O(rows × columns²)`.
fn condition(l: &Mat<f64>, independent: &[bool]) -> f64 {
    const ITERATIONS: usize = 30;
    let n = independent.len();
    if !independent.iter().any(|&b| b) {
        return f64::INFINITY;
    }
    let normalise = |x: &mut [f64]| {
        let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 {
            x.iter_mut().for_each(|v| *v /= norm);
        }
        norm
    };
    let start = |x: &mut Vec<f64>| {
        // A fixed, non-special start vector: reproducible and not orthogonal to anything likely.
        *x = (0..n)
            .map(|i| {
                if independent[i] {
                    1.0 + (i as f64 * 0.618_033_988_75).fract()
                } else {
                    0.0
                }
            })
            .collect();
    };
    let mut x = Vec::new();
    let mut y = vec![0.0; n];
    // λmax(RᵀR): y = Rx (y_i = Σ_{k≥i} L[k,i] x_k), x = Rᵀy.
    start(&mut x);
    normalise(&mut x);
    let mut top = 0.0;
    for _ in 0..ITERATIONS {
        for i in 0..n {
            y[i] = if independent[i] {
                dot(tail(l, i, i), &x[i..])
            } else {
                0.0
            };
        }
        x.fill(0.0);
        for i in 0..n {
            if independent[i] {
                let yi = y[i];
                for (xk, c) in x[i..].iter_mut().zip(tail(l, i, i)) {
                    *xk += c * yi;
                }
            }
        }
        for (k, v) in x.iter_mut().enumerate() {
            if !independent[k] {
                *v = 0.0;
            }
        }
        top = normalise(&mut x);
    }
    // λmax((RᵀR)⁻¹): solve Rᵀy = x forward, then Rx' = y backward.
    start(&mut x);
    normalise(&mut x);
    let mut inv = 0.0;
    for _ in 0..ITERATIONS {
        for i in 0..n {
            if !independent[i] {
                y[i] = 0.0;
                continue;
            }
            y[i] = x[i] / l[(i, i)];
            let yi = y[i];
            for (xk, c) in x[i + 1..].iter_mut().zip(tail(l, i, i + 1)) {
                *xk -= c * yi;
            }
        }
        for i in (0..n).rev() {
            if !independent[i] {
                x[i] = 0.0;
                continue;
            }
            let s = dot(tail(l, i, i + 1), &x[i + 1..]);
            x[i] = (y[i] - s) / l[(i, i)];
        }
        inv = normalise(&mut x);
    }
    if top > 0.0 && inv > 0.0 && (top * inv).is_finite() {
        (top * inv).sqrt()
    } else {
        f64::INFINITY
    }
}

/// Entries `from..` of column `j` of `l` as a slice (a `Mat` is column-major and contiguous;
/// empty otherwise, which no caller meets).
fn tail(l: &Mat<f64>, j: usize, from: usize) -> &[f64] {
    l.col(j)
        .try_as_col_major()
        .map_or(&[][..], |c| c.as_slice())
        .get(from..)
        .unwrap_or(&[])
}

/// `Σ a_k b_k` in four running sums (the condition estimate's inner product; independent sums
/// let the compiler keep four multiplications in flight instead of one chain).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut s = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (p, q) in ca.zip(cb) {
        for k in 0..4 {
            s[k] += p[k] * q[k];
        }
    }
    let rest: f64 = ra.iter().zip(rb).map(|(p, q)| p * q).sum();
    (s[0] + s[1]) + (s[2] + s[3]) + rest
}

/// Poses `kin check` samples for a machine of `coefficients` coefficients observed as
/// `observe`: enough for about two rows per coefficient, at least 200.
///
/// Two are enough: a random m × p design with m = 2p has full rank wherever the model is
/// identifiable, and its smallest singular value is about (√2 − 1)√p (Marchenko–Pastur for
/// independent rows), so an identifiable column keeps a residual of order 0.1–0.4 of its length
/// after the earlier ones, five orders of magnitude above the `DEPENDENT` threshold; four rows
/// per coefficient only doubled the accumulation, which costs rows × coefficients² and is
/// most of the analysis at 10 000 coefficients.
pub fn poses_for(coefficients: usize, observe: Observe) -> usize {
    let per_pose = match observe {
        Observe::Position => 3,
        Observe::Pose | Observe::Data => 6,
        // One length per pair of consecutive poses.
        Observe::Length => 1,
    };
    coefficients
        .saturating_mul(2)
        .div_ceil(per_pose)
        .saturating_add(1)
        .max(200)
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
    sampled_with(
        m,
        observe,
        aligned,
        n,
        seed,
        kin_model::engine::Engine::Interp,
    )
}

/// As [`sampled`], with the chosen engine. The design is streamed into its Gram matrix, never
/// held whole.
pub(crate) fn sampled_with(
    m: &Machine,
    observe: Observe,
    aligned: bool,
    n: usize,
    seed: u64,
    engine: kin_model::engine::Engine,
) -> Result<Report, IdentifyError> {
    sampled_verdicts(m, observe, aligned, n, seed, engine, Condition::Estimate)
}

/// Whether the analysis estimates the condition number of the independent columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Condition {
    Estimate,
    /// Left out (`Report::condition` is NaN): the dependencies alone are wanted, as by
    /// `kin check`. At 10 000 coefficients the estimate reads the 400 MB factor sixty times,
    /// about a quarter of the analysis.
    Skip,
}

/// As `sampled_with`, estimating the condition number only when asked.
pub fn sampled_verdicts(
    m: &Machine,
    observe: Observe,
    aligned: bool,
    n: usize,
    seed: u64,
    engine: kin_model::engine::Engine,
    estimate: Condition,
) -> Result<Report, IdentifyError> {
    let states = States::sample(m, n, seed);
    let width = m.coefficients.len()
        + if aligned && observe != Observe::Length {
            6
        } else {
            0
        };
    let (g, rows, columns) = if observe == Observe::Length {
        let mut gram = Gram::new(width);
        let columns = for_each_row(m, &states, observe, aligned, engine, |row| gram.push(row))?;
        let (g, rows) = gram.finish();
        (g, rows, columns)
    } else {
        let offset = width.saturating_sub(m.coefficients.len());
        let comps = if observe == Observe::Position { 3 } else { 6 };
        let mut gram = PoseGram::new(width, comps, groups(m, offset, width));
        let columns = for_each_row(m, &states, observe, aligned, engine, |row| gram.push(row))?;
        let (g, rows) = gram.finish();
        (g, rows, columns)
    };
    analyse_gram(g, rows, &columns, estimate)
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

/// The identifiability warnings of a compiled model, as `kin check` and the editor show them:
/// [`poses_for`] states sampled over the ranges with a fixed seed (reproducible), the
/// dependencies only (the condition number is not estimated), located at the terms.
pub fn checked(
    c: &kin_compiler::Compiled,
    observe: Observe,
    aligned: bool,
    engine: kin_model::engine::Engine,
) -> Vec<Diagnostic> {
    if c.machine.coefficients.is_empty() {
        return Vec::new();
    }
    let n = poses_for(c.machine.coefficients.len(), observe);
    let report = sampled_verdicts(
        &c.machine,
        observe,
        aligned,
        n,
        0x6b696e,
        engine,
        Condition::Skip,
    );
    match report {
        Ok(report) => diagnostics(&c.machine, &c.map, &report, observe, aligned),
        Err(IdentifyError::Factor {
            column: Some(column),
        }) => {
            let span = column_span(&c.map, &column).unwrap_or_default();
            vec![Diagnostic::error(
                "E0601",
                "identifiability could not be analysed: this term's values overflow a number",
                span,
            )
            .with_label("beyond ±1.8e308 at some pose")
            .with_help("check the term's scale and units: a factor like `1e308` is a typo")]
        }
        Err(e) => vec![Diagnostic::error(
            "E0601",
            format!("identifiability could not be analysed: {e}"),
            Default::default(),
        )],
    }
}

/// Where a column's coefficient is written; none for nuisance columns.
pub fn column_span(map: &SourceMap, c: &Column) -> Option<Span> {
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
            .with_help(if let Some((Column::Nuisance(name), _)) = d.combination.first().filter(|_| registration(d)) {
                format!("the unknown placement of the instrument or target ({name}, spec/robots.md) absorbs it: remove the term")
            } else if matches!(d.combination.first(), Some((Column::Alignment { .. } | Column::Nuisance(_), _))) {
                "the artifact's alignment absorbs it: remove the term or fix the placement".to_string()
            } else {
                "remove one of them, or use a family without this component (straightness, no_once_per_rev)".to_string()
            })
        };
        out.push(diag);
    }
    out
}
