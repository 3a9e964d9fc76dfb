//! Least-squares fitting of a model to measurement files (thesis §3.2.2, §4.2–4.3).
//!
//! Two passes over the data. The first streams the weighted rows of `[X | y]` through a QR
//! accumulator (memory ∝ columns², not rows); the solve, the rank decision and the covariance
//! (eq. 4.11) work on the small triangle. The second pass recomputes each row for its residual,
//! leverage (eq. 4.12's quadratic form), studentized residual and Cook's distance.

pub mod cancel;
pub mod components;
mod design;
pub mod merge;
pub mod nonlinear;
mod projection;
mod qr;
pub mod report;
mod solve;
pub mod stations;
pub mod stepwise;
pub mod stream;
pub mod tally;
mod team;
mod tpqr;

use faer::Mat;
use kin_compiler::{Compiled, Diagnostic};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor, Normal};
use thiserror::Error;

pub(crate) use design::declared_offset;
use design::kinds_observed;
pub use design::{
    count_rows, for_each_row, holdout, rotation_weight, states, states_with, DataSet, DesignError,
    FileStates, Layout, Noise, Nuisance, NuisanceKind, RowMeta, Weights, HELD_OUT, LENGTH,
};
pub use qr::{Reduced, StreamingQr};
pub use solve::{Solution, Solver};

use crate::identify::{self, Column, Observe};
use kin_model::engine::Evaluator;
use team::{Batches, Team};

#[derive(Debug, Error)]
pub enum FitError {
    #[error(transparent)]
    Design(#[from] DesignError),
    #[error("the files hold no observed value")]
    NoRows,
    #[error(
        "{rows} observed values cannot determine {rank} parameters with a noise estimate left over"
    )]
    TooFewRows { rows: usize, rank: usize },
    #[error(
        "the sums of squares of the data overflow double precision: values in the data or the \
         model are too large to fit"
    )]
    Overflow,
    #[error(
        "the data hold {kind} but no noise is stated for them: with a stated noise every kind of \
         row needs its own standard deviation (--noise for positions and lengths, --noise-tilt \
         for rotations)"
    )]
    NoNoiseFor { kind: &'static str },
    #[error(transparent)]
    Read(#[from] kin_data::data::ReadError),
    #[error(transparent)]
    Merge(#[from] merge::MergeError),
    #[error("the design is rank-deficient: rank {rank} of {columns} columns")]
    RankDeficient {
        rank: usize,
        columns: usize,
        diagnostics: Vec<Diagnostic>,
    },
}

#[derive(Debug, Clone)]
pub struct Options {
    pub solver: Solver,
    /// Relative tolerance of the rank decision on the unit-scaled problem.
    pub tolerance: f64,
    /// Fit the visible part of a rank-deficient problem (minimum norm) instead of stopping.
    pub min_norm: bool,
    /// Rows per block streamed through the QR.
    pub block: usize,
    /// Family-wise significance level for flagging outliers (Bonferroni over all rows).
    pub outlier_alpha: f64,
    /// Stepwise selection of the coefficients (§3.2.2), if asked.
    pub stepwise: Option<Stepwise>,
    /// The instrument's stated noise: rows are weighted by it (see [`Weights`]).
    pub noise: Option<Noise>,
    /// Per fitted file (in order), the σs stated for it; a kind it leaves `None` takes
    /// `noise`'s or, without one, is estimated ([`components`]). Empty: every file as `noise`.
    pub file_noise: Vec<Noise>,
    /// Estimate a σ per file and kind of row wherever none is stated, even when no file has
    /// one of its own (variance components, [`components`]).
    pub components: bool,
    /// Threads factoring the blocks of rows and computing the residual pass's leverages
    /// (default: the cores this process may use). A given count gives the same bits on every
    /// run; another count differs only by rounding ([`StreamingQr`]).
    pub threads: usize,
}

/// Significance levels of the partial F-tests: a coefficient whose p-value exceeds `remove`
/// is dropped; a dropped one whose p-value falls below `enter` comes back.
#[derive(Debug, Clone, Copy)]
pub struct Stepwise {
    pub remove: f64,
    pub enter: Option<f64>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            solver: Solver::Qr,
            tolerance: 1e-10,
            min_norm: false,
            block: 4096,
            outlier_alpha: 0.05,
            stepwise: None,
            noise: None,
            file_noise: Vec::new(),
            components: false,
            threads: crate::rank_update::threads(),
        }
    }
}

/// One observed value after the fit. Values are weighted (by `layout.weights`: a tilt unit
/// weighs as an error unit, or every row is divided by its stated noise); `report` converts to
/// display units.
#[derive(Debug, Clone, Copy)]
pub struct ResidualRow {
    pub meta: RowMeta,
    pub observed: f64,
    pub residual: f64,
    pub leverage: f64,
    pub studentized: f64,
    pub cook: f64,
}

/// Everything a fit found.
#[derive(Debug, Clone)]
pub struct FitResult {
    pub layout: Layout,
    pub solution: Solution,
    pub rows: usize,
    pub sigma: f64,
    pub r2: f64,
    pub residuals: Vec<ResidualRow>,
    /// |studentized| above this is flagged (Bonferroni at `outlier_alpha`).
    pub outlier_threshold: f64,
    /// Cook's distance above this (median of F(rank, dof)) is flagged as influential.
    pub cook_threshold: f64,
    /// When `min_norm` fitted a deficient problem: what was constrained, as diagnostics.
    pub constrained: Vec<Diagnostic>,
    pub validation: Vec<ResidualRow>,
    /// The stepwise selection, when asked for.
    pub selection: Option<stepwise::Selection>,
    /// The fitted non-linear parameters, when the model has any.
    pub nonlinear: Option<nonlinear::NonlinearFit>,
    /// Set by a streamed fit ([`stream::fit`]), which keeps `residuals` only up to
    /// `report::MAX_RESIDUALS` rows: the per-file statistics and the outliers of every row.
    pub tally: Option<tally::Tally>,
    /// With a σ per file: each file's σs, stated or estimated, and σ̂/σ.
    pub components: Option<components::Components>,
}

impl FitResult {
    /// The variance of every column's estimate (coefficients, then nuisance), SI².
    pub fn variances(&self) -> Vec<f64> {
        solve::variances(&self.solution.g, self.sigma * self.sigma)
    }
}

/// Progress callback: rows done in the current pass, and the pass name (`optimising` for the
/// fitted non-linear parameters' search, reported once with 0 rows, then `factorising` and
/// `residuals`).
pub type Progress<'a> = &'a mut dyn FnMut(&'static str, usize);

/// Observations a fit that holds its rows evaluates between two settlements of its parts
/// (see [`Team::batched`]): a batch's residuals are what the residual pass holds besides the
/// result's.
const BATCH: usize = stream::CHUNK_ROWS;

/// Pass 1 of a fit: the triangle of [X | y] over every row of `batches`, reporting the pass's
/// progress. Each part of the team folds its rows into a triangle of its own and the parts'
/// triangles are merged in part order (TSQR, [`merge`]): for a given number of threads the
/// same bits every time. A team of one (one thread, or an engine that cannot be forked) keeps
/// the factorisation's own worker threads, which overlap the evaluation on the calling thread.
fn triangle(
    team: &mut Team,
    layout: &Layout,
    options: &Options,
    progress: Progress,
    batches: &mut Batches,
) -> Result<Reduced, FitError> {
    let threads = if team.parts() > 1 { 1 } else { options.threads };
    let mut parts: Vec<StreamingQr> = (0..team.parts())
        .map(|_| StreamingQr::with_threads(layout.columns(), options.block, threads))
        .collect();
    team.batched(
        layout,
        batches,
        &mut parts,
        |qr, _, x, y| qr.push(x, y),
        |_| {},
        &mut |done| progress("factorising", done),
    )?;
    let mut red: Option<Reduced> = None;
    for qr in parts {
        let r = qr.finish();
        red = Some(match red {
            None => r,
            Some(a) => merge::merge(&a, &r)?,
        });
    }
    let red = red.ok_or(FitError::NoRows)?;
    if red.rows == 0 {
        return Err(FitError::NoRows);
    }
    if !red.is_finite() {
        return Err(FitError::Overflow);
    }
    Ok(red)
}

/// Pass 2 of a fit: every row's residual and leverage (eq. 4.12's quadratic form) in blocks,
/// one matrix product per block, handed to `settle` in row order a batch at a time (their
/// studentized residuals and Cook's distances still to be set).
fn residual_pass(
    team: &mut Team,
    layout: &Layout,
    options: &Options,
    solution: &Solution,
    progress: Progress,
    batches: &mut Batches,
    mut settle: impl FnMut(&mut Vec<ResidualRow>),
) -> Result<(), FitError> {
    let threads = if team.parts() > 1 { 1 } else { options.threads };
    let block = Block::new(options.block, layout.columns(), threads, solution);
    let mut parts: Vec<(Block, Vec<ResidualRow>)> = (0..team.parts())
        .map(|_| (block.clone(), Vec::new()))
        .collect();
    team.batched(
        layout,
        batches,
        &mut parts,
        |(block, rows), meta, x, y| {
            block.push(meta, x, y);
            if block.full() {
                block.drain(rows);
            }
        },
        |parts| {
            // Rows in order: several parts' blocks are emptied before the next batch, one
            // part's block goes on into it. Where a block is cut changes the rounding of its
            // products (a one-row block takes another path), so one thread cuts every
            // `options.block` rows whatever the batches, as a fit read in blocks does.
            let several = parts.len() > 1;
            for (block, rows) in parts {
                if several {
                    block.drain(rows);
                }
                settle(rows);
                rows.clear();
            }
        },
        &mut |done| progress("residuals", done),
    )?;
    for (block, rows) in &mut parts {
        block.drain(rows);
        settle(rows);
    }
    Ok(())
}

/// Fits `files` (and checks against `validate`). With a σ per file (`file_noise`, or
/// `components`), the estimated ones by reweighted fits ([`components`]).
pub fn fit(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    validate: &[DataSet],
    options: &Options,
    progress: Progress,
) -> Result<FitResult, FitError> {
    if !components::per_file(options) {
        return fit_once(compiled, engine, files, validate, options, progress);
    }
    design::check_artifacts(files)?;
    components::fit(&compiled.machine, files.len(), options, |o| {
        fit_once(compiled, engine, files, validate, o, &mut *progress)
    })
}

/// One weighted fit: the weights as `options` state them.
fn fit_once(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    validate: &[DataSet],
    options: &Options,
    progress: Progress,
) -> Result<FitResult, FitError> {
    let m = &compiled.machine;
    design::check_artifacts(files)?;
    // With σs per file every group of rows has one (stated or being estimated).
    if options.file_noise.is_empty() {
        check_noise(files, options.noise)?;
    }
    let layout = Layout::new(m, files).weighted(m, options.noise, &options.file_noise);
    // Fitted wavelengths and time constants first: the linear problem below is the one at
    // their optimum. Its passes report no rows: the pass name says what the time goes to.
    if m.nonlinear.iter().any(|p| p.fitted) {
        progress("optimising", 0);
    }
    let nonlinear = nonlinear::optimise(compiled, engine, files, options)?;
    let values: Vec<f64> = match &nonlinear {
        Some(n) => n.values.clone(),
        None => m.nonlinear.iter().map(|p| p.value).collect(),
    };
    let states = design::states_with(m, files, &values)?;

    let mut rows = team::held(files, &states, BATCH);
    let (red, solved, mut residuals) = Team::with(engine, options.threads, |team| {
        let red = triangle(team, &layout, options, &mut *progress, &mut rows)?;
        let solved = solve_reduced(compiled, &layout, &red, options)?;
        let mut residuals = Vec::with_capacity(red.rows);
        residual_pass(
            team,
            &layout,
            options,
            &solved.solution,
            &mut *progress,
            &mut rows,
            |batch| residuals.append(batch),
        )?;
        Ok::<_, FitError>((red, solved, residuals))
    })?;
    let Solved {
        solution,
        selection,
        constrained,
        dof,
        sigma,
        r2,
    } = solved;
    for r in &mut residuals {
        influence(r, sigma, solution.rank);
    }
    let (outlier_threshold, cook_threshold) =
        thresholds(red.rows, solution.rank, dof, options.outlier_alpha);

    let validation = if validate.is_empty() {
        Vec::new()
    } else {
        validation_residuals(compiled, engine, validate, &solution, &values, options)?
    };

    Ok(FitResult {
        layout,
        solution,
        rows: red.rows,
        sigma,
        r2,
        residuals,
        outlier_threshold,
        cook_threshold,
        constrained,
        validation,
        selection,
        nonlinear,
        tally: None,
        components: None,
    })
}

/// A row's studentized residual and Cook's distance, from its residual and leverage.
fn influence(r: &mut ResidualRow, sigma: f64, rank: usize) {
    let rank = rank.max(1) as f64;
    let room = (1.0 - r.leverage).max(1e-15);
    r.studentized = r.residual / (sigma * room.sqrt());
    r.cook = r.studentized.powi(2) * r.leverage / (rank * room);
}

/// The outlier threshold of |studentized| (Bonferroni at `alpha` over `rows`) and the
/// Cook's-distance threshold (median of F(rank, dof)).
fn thresholds(rows: usize, rank: usize, dof: usize, alpha: f64) -> (f64, f64) {
    let n = rows as f64;
    let outlier = Normal::new(0.0, 1.0)
        .map(|d| d.inverse_cdf(1.0 - alpha / (2.0 * n)))
        .unwrap_or(4.0);
    (outlier, f_median(rank.max(1) as f64, dof as f64))
}

/// What the triangle of pass 1 gives, before the residual pass.
struct Solved {
    solution: Solution,
    selection: Option<stepwise::Selection>,
    constrained: Vec<Diagnostic>,
    dof: usize,
    sigma: f64,
    r2: f64,
}

/// The solve, the rank decision, the selection and σ̂ from the accumulated triangle: the part
/// of a fit between its two passes over the rows (the same for a fit that holds its rows and
/// for a streamed one).
fn solve_reduced(
    compiled: &Compiled,
    layout: &Layout,
    red: &Reduced,
    options: &Options,
) -> Result<Solved, FitError> {
    let p = layout.columns();
    // Selection reads sub-models off the triangle, which needs independent columns: a
    // deficient model is reported (or fitted by minimum norm) before anything is selected.
    if options.stepwise.is_some() && !options.min_norm {
        if let Err(s) = solve::solve(red, options.solver, options.tolerance, false) {
            return Err(FitError::RankDeficient {
                rank: s.rank,
                columns: p,
                diagnostics: name_invisible(compiled, layout, red),
            });
        }
    }
    let selection = options
        .stepwise
        .map(|sw| stepwise::select(red, layout.coefficients, sw.remove, sw.enter));
    let solved = match &selection {
        Some(sel) => solve::solve(
            &stepwise::restrict(red, &sel.kept),
            options.solver,
            options.tolerance,
            options.min_norm,
        )
        .map(|s| solve::expand(s, &sel.kept))
        .map_err(|s| solve::expand(s, &sel.kept)),
        None => solve::solve(red, options.solver, options.tolerance, options.min_norm),
    };
    let solution = match solved {
        Ok(s) => s,
        Err(s) => {
            return Err(FitError::RankDeficient {
                rank: s.rank,
                columns: p,
                diagnostics: name_invisible(compiled, layout, red),
            });
        }
    };
    let active = selection
        .as_ref()
        .map(|s| s.kept.iter().filter(|&&k| k).count())
        .unwrap_or(p);
    let constrained = if solution.rank < active {
        name_invisible(compiled, layout, red)
    } else {
        Vec::new()
    };
    let dof = red.rows.saturating_sub(solution.rank);
    if dof == 0 {
        return Err(FitError::TooFewRows {
            rows: red.rows,
            rank: solution.rank,
        });
    }
    let sigma2 = solution.rss / dof as f64;
    let sigma = sigma2.sqrt();
    let sst = red.y_sumsq - red.y_sum * red.y_sum / red.rows as f64;
    let r2 = if sst > 0.0 {
        1.0 - solution.rss / sst
    } else {
        f64::NAN
    };

    Ok(Solved {
        solution,
        selection,
        constrained,
        dof,
        sigma,
        r2,
    })
}

/// With a stated noise, every kind of row the files hold needs its own σ: a row without one
/// would get an arbitrary weight against the others.
fn check_noise(files: &[DataSet], noise: Option<Noise>) -> Result<(), FitError> {
    let Some(n) = noise else {
        return Ok(());
    };
    let (positions, rotations) = kinds_observed(files);
    if positions && n.position.is_none() {
        return Err(FitError::NoNoiseFor {
            kind: "positions or lengths",
        });
    }
    if rotations && n.rotation.is_none() {
        return Err(FitError::NoNoiseFor { kind: "rotations" });
    }
    Ok(())
}

/// Rows buffered for the residual pass, one per column (`p × rows`): a row is copied in as
/// one contiguous run, and `G' xᵢ` is column `i` of one product.
#[derive(Clone)]
struct Block {
    x: Mat<f64>,
    y: Vec<f64>,
    meta: Vec<RowMeta>,
    threads: usize,
    /// β as a row.
    beta: Mat<f64>,
    /// `G` of the solution brought to upper-trapezoidal form (see [`trapezoid`]).
    g: Mat<f64>,
    /// Per thread: room for its rows' `G' x` (reused, so no block allocates it again).
    gx: Vec<Mat<f64>>,
}

/// Rows of a block each thread of the residual pass takes at least: below it a thread costs
/// more than the product it would share.
const ROWS_PER_THREAD: usize = 512;

/// Rows of `G'` one product of the residual pass takes (see [`Block::drain`]).
const BAND: usize = 32;

/// `G'` (rank × p, zero below its diagonal) with `G'ᵀG' = GᵀG`: the triangular factor of
/// `G = Q G'` (Householder, so `G'` is `G` turned by an orthogonal `Qᵀ`). A leverage
/// `h = ‖G x‖² = ‖G' x‖²` then skips the zeros below the diagonal (products by bands of
/// rows, [`BAND`]): about half the flops of the dense one, for the same number up to rounding.
fn trapezoid(g: &Mat<f64>) -> Mat<f64> {
    let (r, p) = (g.nrows(), g.ncols());
    if r == 0 {
        return Mat::zeros(0, p);
    }
    let qr = g.qr();
    let t = qr.thin_R();
    Mat::from_fn(r, p, |i, j| if j >= i { t[(i, j)] } else { 0.0 })
}

impl Block {
    fn new(rows: usize, p: usize, threads: usize, s: &Solution) -> Self {
        let rows = rows.max(1);
        let threads = threads.max(1);
        let g = trapezoid(&s.g);
        // As wide as the block: a short block is cut into fewer, wider slices.
        Block {
            x: Mat::zeros(p, rows),
            y: Vec::with_capacity(rows),
            meta: Vec::with_capacity(rows),
            threads,
            beta: Mat::from_fn(1, s.beta.len(), |_, j| s.beta[j]),
            gx: (0..threads).map(|_| Mat::zeros(g.nrows(), rows)).collect(),
            g,
        }
    }
    fn full(&self) -> bool {
        self.y.len() == self.x.ncols()
    }
    fn push(&mut self, meta: RowMeta, x: &[f64], y: f64) {
        let i = self.y.len();
        let column = self.x.col_mut(i);
        for (cell, v) in column.iter_mut().zip(x) {
            *cell = *v;
        }
        self.y.push(y);
        self.meta.push(meta);
    }
    fn drain(&mut self, out: &mut Vec<ResidualRow>) {
        use faer::reborrow::{Reborrow, ReborrowMut};
        let b = self.y.len();
        if b == 0 {
            return;
        }
        // Fitted value and leverage of every row, the rows cut into one slice per thread (the
        // cut depends only on the block and the thread count, so the bits do too).
        let mut fitted = vec![0.0; b];
        let mut leverage = vec![0.0; b];
        let threads = self.threads.min(b / ROWS_PER_THREAD).max(1);
        let per = b.div_ceil(threads);
        let x = self.x.get(.., ..b);
        let (beta, g) = (&self.beta, &self.g);
        let rank = g.nrows();
        let work = |from: usize, f: &mut [f64], h: &mut [f64], gx: &mut Mat<f64>| {
            let n = f.len();
            let rows = x.subcols(from, n);
            let fit = beta * rows;
            // G'x by bands of G''s rows: band `r0..r1` is zero left of column `r0`, so it is
            // one rectangular product with `x[r0.., ..]`. The zeros of each band's corner are
            // multiplied too (≈ BAND / p more flops), but faer's GEMM runs at twice the rate
            // of its triangular product on these shapes.
            let mut gx = gx.get_mut(.., ..n);
            let mut r0 = 0;
            while r0 < rank {
                let r1 = (r0 + BAND).min(rank);
                faer::linalg::matmul::matmul(
                    gx.rb_mut().subrows_mut(r0, r1 - r0),
                    faer::Accum::Replace,
                    g.get(r0..r1, r0..),
                    rows.get(r0.., ..),
                    1.0,
                    faer::Par::Seq,
                );
                r0 = r1;
            }
            for (i, (f, h)) in f.iter_mut().zip(h.iter_mut()).enumerate() {
                *f = fit[(0, i)];
                *h = gx.rb().col(i).squared_norm_l2();
            }
        };
        let mut bufs = self.gx.iter_mut();
        if threads == 1 {
            if let Some(gx) = bufs.next() {
                work(0, &mut fitted, &mut leverage, gx);
            }
        } else {
            std::thread::scope(|scope| {
                let mut parts = fitted
                    .chunks_mut(per)
                    .zip(leverage.chunks_mut(per))
                    .zip(bufs);
                let first = parts.next();
                for (t, ((f, h), gx)) in parts.enumerate() {
                    let work = &work;
                    scope.spawn(move || work((t + 1) * per, f, h, gx));
                }
                // The first slice on the calling thread.
                if let Some(((f, h), gx)) = first {
                    work(0, f, h, gx);
                }
            });
        }
        for i in 0..b {
            out.push(ResidualRow {
                meta: self.meta[i],
                observed: self.y[i],
                residual: self.y[i] - fitted[i],
                leverage: leverage[i],
                studentized: 0.0,
                cook: 0.0,
            });
        }
        self.y.clear();
        self.meta.clear();
    }
}

/// Residuals of validation files with β fixed; their own artifacts' placements are fitted.
fn validation_residuals(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    solution: &Solution,
    values: &[f64],
    options: &Options,
) -> Result<Vec<ResidualRow>, FitError> {
    let m = &compiled.machine;
    check_noise(files, options.noise)?;
    // Validation files are other files: they weigh by the σs stated for every file.
    let layout = Layout::new(m, files).weighted(m, options.noise, &[]);
    let n = layout.coefficients;
    let states = design::states_with(m, files, values)?;
    let beta = solution.beta.get(..n).unwrap_or(&[]);
    let extra = layout.nuisance.len();
    // First the nuisance (placements) by least squares on y − Xβ, then the residuals.
    let mut acc = StreamingQr::new(extra, options.block);
    design::for_each_row(engine, files, &states, &layout, |_, x, y| {
        let pred: f64 = x.iter().zip(beta).map(|(a, b)| a * b).sum();
        acc.push(x.get(n..).unwrap_or(&[]), y - pred);
    })?;
    let nuisance = if extra > 0 {
        let red = acc.finish();
        match solve::solve(&red, Solver::Svd, options.tolerance, true) {
            Ok(s) | Err(s) => s.beta,
        }
    } else {
        Vec::new()
    };
    let mut out = Vec::new();
    design::for_each_row(engine, files, &states, &layout, |meta, x, y| {
        let pred: f64 = x
            .iter()
            .zip(beta.iter().chain(&nuisance))
            .map(|(a, b)| a * b)
            .sum();
        out.push(ResidualRow {
            meta,
            observed: y,
            residual: y - pred,
            leverage: f64::NAN,
            studentized: f64::NAN,
            cook: f64::NAN,
        });
    })?;
    Ok(out)
}

/// Names the invisible combinations of a deficient problem with the identifiability analysis
/// run on the data's own scaled triangle (it has the same column dependencies as X).
fn name_invisible(compiled: &Compiled, layout: &Layout, red: &Reduced) -> Vec<Diagnostic> {
    let (rs, _) = solve::scaled_triangle(red);
    let columns: Vec<Column> = (0..layout.coefficients)
        .map(Column::Coefficient)
        .chain(layout.nuisance.iter().map(|n| Column::Nuisance(n.name())))
        .collect();
    // Nuisance first, so a model term they absorb is reported as absorbed.
    let order: Vec<usize> = (layout.coefficients..layout.columns())
        .chain(0..layout.coefficients)
        .collect();
    let p = layout.columns();
    let reordered: Vec<f64> = (0..p)
        .flat_map(|i| order.iter().map(move |&j| (i, j)))
        .map(|(i, j)| rs[i * p + j])
        .collect();
    let cols: Vec<Column> = order.iter().map(|&j| columns[j].clone()).collect();
    match identify::analyse(&reordered, &cols) {
        Ok(report) => identify::diagnostics(
            &compiled.machine,
            &compiled.map,
            &report,
            Observe::Data,
            false,
        ),
        Err(e) => vec![Diagnostic::error(
            "E0601",
            format!("the invisible combinations could not be named: {e}"),
            Default::default(),
        )],
    }
}

/// Median of F(d1, d2), the Cook's-distance threshold. statrs inverts the F distribution through
/// the incomplete beta function, whose work grows with d2: above 2·10⁷ residual degrees of
/// freedom it ran for many minutes. There F(d1, d2) is χ²(d1)/d1 to within O(1/d2), far below
/// what a threshold needs, and the χ² quantile costs the same at any size.
fn f_median(d1: f64, d2: f64) -> f64 {
    const LARGE: f64 = 1e5;
    if d2 > LARGE {
        ChiSquared::new(d1)
            .map(|d| d.inverse_cdf(0.5) / d1)
            .unwrap_or(1.0)
    } else {
        FisherSnedecor::new(d1, d2)
            .map(|d| d.inverse_cdf(0.5))
            .unwrap_or(1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The residual pass's leverages through the trapezoidal `G'` are `‖G x‖²` of the dense
    /// `G`, full rank or not, on one thread and on three.
    #[test]
    fn leverages_through_the_trapezoid_are_those_of_g() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        for (rank, p) in [(6, 6), (4, 7), (1, 3)] {
            let g = Mat::from_fn(rank, p, |_, _| rng.random_range(-1.0..1.0));
            let s = Solution {
                beta: (0..p).map(|j| j as f64 - 1.5).collect(),
                rank,
                rss: 0.0,
                g: g.clone(),
                null: Mat::zeros(p, p - rank),
                condition: 1.0,
                scale: vec![1.0; p],
            };
            for threads in [1, 3] {
                let rows = 1600;
                let mut block = Block::new(rows, p, threads, &s);
                let xs: Vec<Vec<f64>> = (0..rows)
                    .map(|_| (0..p).map(|_| rng.random_range(-1.0..1.0)).collect())
                    .collect();
                let meta = RowMeta {
                    file: 0,
                    line: 0,
                    component: 0,
                };
                for x in &xs {
                    block.push(meta, x, 1.0);
                }
                let mut out = Vec::new();
                block.drain(&mut out);
                assert_eq!(out.len(), rows);
                for (x, r) in xs.iter().zip(&out) {
                    let h: f64 = (0..rank)
                        .map(|k| (0..p).map(|j| g[(k, j)] * x[j]).sum::<f64>().powi(2))
                        .sum();
                    let fitted: f64 = x.iter().zip(&s.beta).map(|(a, b)| a * b).sum();
                    assert!(
                        (r.leverage - h).abs() <= 1e-12 * h.max(1.0),
                        "{} vs {h}",
                        r.leverage
                    );
                    assert!((r.residual - (1.0 - fitted)).abs() <= 1e-12 * fitted.abs().max(1.0));
                }
            }
        }
    }

    #[test]
    fn the_f_median_is_continuous_where_it_switches_to_chi_squared() {
        for d1 in [1.0, 7.0, 200.0] {
            let exact = FisherSnedecor::new(d1, 1e5).map(|d| d.inverse_cdf(0.5));
            let exact = exact.unwrap_or(f64::NAN);
            let limit = f_median(d1, 1e5 + 1.0);
            assert!(
                (exact - limit).abs() < 1e-3 * exact,
                "{d1}: {exact} vs {limit}"
            );
        }
        // 10⁸ observations: answered at once (statrs alone did not finish in 20 minutes).
        let m = f_median(30.0, 1e8);
        assert!(m > 0.9 && m < 1.0, "{m}");
    }
}
