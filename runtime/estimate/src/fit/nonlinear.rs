//! Non-linear parameters (fitted wavelengths, thermal time constants) by variable projection:
//! Levenberg–Marquardt over them, with the linear coefficients β solved by least squares inside
//! every evaluation (thesis §3.2.4: "only the various wavelengths enter the regression in a
//! nonlinear fashion").
//!
//! The parameters are positive, so the search runs over their logarithms. The Jacobian of the
//! projected residual `r(θ) = y − X(θ)β̂(θ)` is Kaufman's `−(I − P_X)∂(Xβ̂)/∂θ`, its products
//! taken from the fixed columns' triangle (`projection`); without that triangle, forward
//! differences of the residual vectors. The search stops when the Gauss–Newton model predicts
//! less than a thousandth of one observation's variance from another step, so its last normal
//! equations are those at the optimum, and `σ̂²(JᵀJ)⁻¹` from their triangle is the covariance
//! of the non-linear parameters with β profiled out (Golub & Pereyra), mapped back by the delta
//! method.
//!
//! Passes that only accumulate sums (each evaluation, Kaufman's derivative columns, the
//! factorisation of the fixed columns, the tests at the optimum) run on every core the fit may
//! use: the rows split into contiguous parts, each evaluated by its own fork of the evaluator,
//! the parts' sums added (triangles merged) in part order, so one thread count gives the same
//! bits on every run.

use faer::Mat;
use kin_compiler::ir::{ErrorModel, Machine, Term};
use kin_compiler::Compiled;

use super::design::{self, DataSet, FileStates, Layout};
use super::projection::{self, Split};
use super::qr::{Reduced, StreamingQr};
use super::team::{at_values, Team};
use super::{solve, FitError, Options, Solver};
use kin_model::engine::{Engine, Evaluator};

/// The outcome: every non-linear parameter's value (fixed ones unchanged) and, for fitted
/// ones, its standard error.
#[derive(Debug, Clone)]
pub struct NonlinearFit {
    pub values: Vec<f64>,
    pub se: Vec<Option<f64>>,
    /// The joint covariance of the fitted parameters with the coefficients, for predictions
    /// whose uncertainty includes that of the fitted values ([`Joint`]).
    pub joint: Joint,
    pub iterations: usize,
    pub rss: f64,
    /// For fitted parameters: whether the data determine it at all, and whether it improves
    /// on its declared start value.
    pub verdicts: Vec<Option<Verdict>>,
}

/// Significance level of the tests behind a [`Verdict`].
pub const ALPHA: f64 = 0.01;

/// What the data say about one fitted non-linear parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Verdict {
    /// p-value of the term the parameter shapes: the columns that move with it, and the
    /// parameter itself, against the fit without them (partial F-test). Above [`ALPHA`] the
    /// data show no effect for the parameter to shape: its value is noise.
    pub term_p: f64,
    /// p-value of the fitted value against the declared start value held fixed (partial F-test
    /// of one parameter). Above [`ALPHA`] the data do not tell the two apart.
    pub start_p: f64,
    /// False when the standard error is unbounded or `term_p` is above [`ALPHA`].
    pub determined: bool,
}

impl Verdict {
    /// Determined and a significant improvement on the start value.
    pub fn significant(&self) -> bool {
        self.determined && self.start_p <= ALPHA
    }
}

/// The weighted residual vector of the linear fit at `values`, and its rank.
fn residuals(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    split: Option<&Split>,
) -> Result<(Vec<f64>, usize), FitError> {
    let (r, rank, _) = linear_fit(compiled, engine, files, values, options, split)?;
    Ok((r, rank))
}

/// The linear fit at `values`: residuals, rank and β̂.
fn linear_fit(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    split: Option<&Split>,
) -> Result<(Vec<f64>, usize, Vec<f64>), FitError> {
    match split {
        Some(split) => projected_fit(compiled, engine, files, values, options, split),
        None => masked_fit(compiled, engine, files, values, options, &[]),
    }
}

/// As [`linear_fit`], the fixed columns' triangle reused (see [`projection`]): one pass that
/// evaluates the rows and accumulates the moving columns' products, one for the residuals.
fn projected_fit(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    split: &Split,
) -> Result<(Vec<f64>, usize, Vec<f64>), FitError> {
    let point = projected(
        compiled,
        &mut Team::alone(&mut *engine),
        files,
        values,
        options,
        split,
        false,
    )?;
    let (states, layout) = at_values(compiled, engine, files, values, options)?;
    let mut r = Vec::with_capacity(point.rows);
    design::for_each_row(engine, files, &states, &layout, |_, x, y| {
        r.push(y - x.iter().zip(&point.beta).map(|(a, b)| a * b).sum::<f64>());
    })?;
    Ok((r, point.rank, point.beta))
}

/// The fixed columns' triangle for [`projected_fit`], from one pass over the rows on every
/// core of the team (each part factors its rows, the triangles merged in part order), and the
/// evaluation at `values` through it from the same pass (the moving columns' products, and with
/// `kaufman` each row's moving columns when [`keeps`] allows). The split is `None` when the
/// plain path must be taken (a moving known term, nothing moving, fixed columns too
/// ill-conditioned for the completion). The flag is `true` when the fixed columns are
/// dependent (some left out of the split) or the split was refused for their conditioning.
fn split_for(
    compiled: &Compiled,
    team: &mut Team,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    fitted: &[usize],
    kaufman: bool,
) -> Result<(Option<(Split, Point)>, bool), FitError> {
    let m = &compiled.machine;
    let columns = Layout::new(m, files).columns();
    let Some(moving) = projection::moving_columns(m, fitted, columns) else {
        return Ok((None, false));
    };
    let fixed = moving.iter().filter(|&&b| !b).count();
    if fixed == columns {
        return Ok((None, false));
    }
    let moving_columns: Vec<usize> = (0..columns).filter(|&j| moving[j]).collect();
    let keep = kaufman && keeps(files, moving_columns.len(), fitted.len());
    let (states, layout) = team.at_values(&compiled.machine, files, values, options)?;
    // One part alone keeps the factorisation's own worker threads.
    let threads = if team.parts() > 1 { 1 } else { options.threads };
    struct Part {
        qr: StreamingQr,
        row: Vec<f64>,
        products: projection::Products,
        kept: Vec<f64>,
    }
    let mut parts: Vec<Part> = (0..team.parts())
        .map(|_| Part {
            qr: StreamingQr::with_threads(fixed, options.block, threads),
            row: Vec::with_capacity(fixed),
            products: projection::Products::new(moving_columns.clone(), columns),
            kept: Vec::new(),
        })
        .collect();
    team.pass(files, &states, &layout, &mut parts, |part, _, x, y| {
        part.row.clear();
        part.row
            .extend(x.iter().zip(&moving).filter(|(_, &m)| !m).map(|(v, _)| *v));
        part.qr.push(&part.row, y);
        part.products.push(x, y);
        if keep {
            part.kept.extend(
                moving_columns
                    .iter()
                    .map(|&j| x.get(j).copied().unwrap_or(0.0)),
            );
        }
    })?;
    let mut base: Option<Reduced> = None;
    let mut products = projection::Products::new(moving_columns.clone(), columns);
    let mut kept = Vec::with_capacity(parts.len());
    for part in parts {
        let r = part.qr.finish();
        base = Some(match base {
            None => r,
            Some(b) => super::merge::merge(&b, &r)?,
        });
        products.add(&part.products);
        kept.push(part.kept);
    }
    let Some(base) = base else {
        return Ok((None, false));
    };
    if !base.is_finite() {
        return Err(FitError::Overflow);
    }
    let split = Split::new(&moving, base, options.tolerance);
    let dependent = split.as_ref().is_none_or(|s| s.dropped() > 0);
    let Some(split) = split else {
        return Ok((None, dependent));
    };
    let point = point_from(&split, &products, columns, options)?;
    Ok((
        Some((
            split,
            Point {
                kept,
                products: Some(products),
                ..point
            },
        )),
        dependent,
    ))
}

/// Whether Kaufman's steps may keep each row's `moving` columns for `k` fitted parameters:
/// at most [`KEPT`] values (two evaluations' worth, and the derivative columns).
fn keeps(files: &[DataSet], moving: usize, k: usize) -> bool {
    design::count_rows(files).saturating_mul(2 * moving + k) <= KEPT
}

/// As [`linear_fit`], with the columns flagged in `without` left out (held at zero).
fn masked_fit(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    without: &[bool],
) -> Result<(Vec<f64>, usize, Vec<f64>), FitError> {
    let (red, states, layout) = triangle_at(compiled, engine, files, values, options, without)?;
    // Minimum norm: a deficiency is reported by the linear fit that follows, not here.
    let sol = match solve::solve(&red, Solver::Svd, options.tolerance, true) {
        Ok(s) | Err(s) => s,
    };
    let mut r = Vec::with_capacity(red.rows);
    design::for_each_row(engine, files, &states, &layout, |_, x, y| {
        let fit: f64 = x
            .iter()
            .zip(&sol.beta)
            .enumerate()
            .filter(|(j, _)| !without.get(*j).copied().unwrap_or(false))
            .map(|(_, (a, b))| a * b)
            .sum();
        r.push(y - fit);
    })?;
    Ok((r, sol.rank, sol.beta))
}

/// The triangle of `[X | y]` at `values`, the columns flagged in `without` held at zero, with
/// the states and columns it was built from.
fn triangle_at(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    without: &[bool],
) -> Result<(Reduced, Vec<design::FileStates>, Layout), FitError> {
    let (states, layout) = at_values(compiled, engine, files, values, options)?;
    let mut acc = StreamingQr::with_threads(layout.columns(), options.block, options.threads);
    let mut row = vec![0.0; layout.columns()];
    design::for_each_row(engine, files, &states, &layout, |_, x, y| {
        if without.is_empty() {
            acc.push(x, y)
        } else {
            for (j, (dst, v)) in row.iter_mut().zip(x).enumerate() {
                *dst = if without.get(j).copied().unwrap_or(false) {
                    0.0
                } else {
                    *v
                };
            }
            acc.push(&row, y)
        }
    })?;
    let red = acc.finish();
    if !red.is_finite() {
        return Err(FitError::Overflow);
    }
    Ok((red, states, layout))
}

/// Refuses, at the declared start values, a design the final linear fit would refuse. Moving
/// a wavelength or a time constant changes the values of its columns, not which combinations
/// of coefficients the data cannot see (those follow from the model's structure and where the
/// data were taken), so a deficient design is reported now, located, instead of after the
/// optimisation's dozens of passes over the data (80 s on 20 000 poses of the 5-axis example).
/// Only called when the first evaluation found a lower rank: it costs one more pass.
fn refuse_deficient(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
) -> Result<(), FitError> {
    let (red, _, layout) = triangle_at(compiled, engine, files, values, options, &[])?;
    match solve::solve(&red, options.solver, options.tolerance, false) {
        Ok(_) => Ok(()),
        Err(s) => Err(FitError::RankDeficient {
            rank: s.rank,
            columns: layout.columns(),
            diagnostics: super::name_invisible(compiled, &layout, &red),
        }),
    }
}

/// The predictions `X(values)·β` of every row, β held fixed.
fn predictions(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    beta: &[f64],
    options: &Options,
) -> Result<Vec<f64>, FitError> {
    let (states, layout) = at_values(compiled, engine, files, values, options)?;
    let mut out = Vec::new();
    design::for_each_row(engine, files, &states, &layout, |_, x, _| {
        out.push(x.iter().zip(beta).map(|(a, b)| a * b).sum::<f64>())
    })?;
    Ok(out)
}

/// What the covariance of the coefficients β (eq. 4.11, at the fitted non-linear values) lacks
/// for a prediction that also depends on the fitted non-linear values θ. For `Z = [X | D_θ]`,
/// `Cov(θ) = S`, `Cov(β, θ) = −A·S` and `Cov(β) = C₀ + A·S·Aᵀ`, with `C₀` the coefficients'
/// covariance at fixed θ and `A = (XᵀX)⁻¹XᵀD_θ` the regression of `D_θ` on the columns of X;
/// so a prediction `gᵀβ + hᵀθ` has the variance `gᵀC₀g + (h − Aᵀg)ᵀ S (h − Aᵀg)`.
#[derive(Debug, Clone, Default)]
pub struct Joint {
    /// `S`, `K × K` over every non-linear parameter of the model (rows and columns of fixed
    /// ones are zero), SI, row-major.
    pub s: Vec<f64>,
    /// `A`, `n × K` for the model's `n` coefficients, row-major.
    pub a: Vec<f64>,
}

/// The triangle of `[X | D_θ | y]` at the optimum for [`uncertainty`] when the optimiser's
/// steps did not leave one (differences of residual vectors): `D_θ = ∂(Xβ̂)/∂θ` at fixed β̂
/// by central differences (`beta` is β̂, any solution of a deficient design: `D_θ` moves only
/// with the moving columns, whose coefficients are unique). Two prediction passes per
/// parameter and one for the triangle. `order[i]` is the design column of the triangle's
/// column i, D's columns after the design's.
#[allow(clippy::too_many_arguments)]
fn difference_triangle(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    fitted: &[usize],
    options: &Options,
    split: Option<&Split>,
    beta: &[f64],
) -> Result<(Reduced, Vec<usize>), FitError> {
    let k = fitted.len();
    let mut d: Vec<Vec<f64>> = Vec::with_capacity(k);
    for &i in fitted {
        let h = 1e-5 * values[i].abs().max(f64::MIN_POSITIVE);
        let (mut up, mut dn) = (values.to_vec(), values.to_vec());
        up[i] += h;
        dn[i] -= h;
        let pu = predictions(compiled, engine, files, &up, beta, options)?;
        let pd = predictions(compiled, engine, files, &dn, beta, options)?;
        d.push(
            pu.iter()
                .zip(&pd)
                .map(|(a, b)| (a - b) / (2.0 * h))
                .collect(),
        );
    }
    let (states, layout) = at_values(compiled, engine, files, values, options)?;
    let p = layout.columns();
    let mut row = vec![0.0; p + k];
    let mut i = 0usize;
    let mut fill = |x: &[f64], row: &mut [f64]| {
        row[..p].copy_from_slice(x);
        for (c, col) in d.iter().enumerate() {
            row[p + c] = col.get(i).copied().unwrap_or(0.0);
        }
        i += 1;
    };
    // The derivative columns join the moving ones of the split: the triangle of [X | D | y]
    // without factoring X again. Its trailing block is all the covariance needs, and the
    // trailing block does not depend on the order of the columns before it.
    Ok(match split {
        Some(split) => {
            let ext = split.extended(p, k);
            let mut products = ext.products();
            design::for_each_row(engine, files, &states, &layout, |_, x, y| {
                fill(x, &mut row);
                ext.push(&mut products, &row, y);
            })?;
            (ext.complete(&products), ext.order)
        }
        None => {
            let mut acc = StreamingQr::with_threads(p + k, options.block, options.threads);
            design::for_each_row(engine, files, &states, &layout, |_, x, y| {
                fill(x, &mut row);
                acc.push(&row, y);
            })?;
            (acc.finish(), (0..p + k).collect())
        }
    })
}

/// Kaufman's triangle has `D_φ = ∂(Xβ̂)/∂φ = θ·D_θ` (φ = ln θ): its D columns divided by θ
/// make it the triangle of `[X | D_θ | y]` that [`uncertainty`] reads (R·diag(s) is the
/// triangle of the columns scaled by s).
fn in_values(red: &mut Reduced, order: &[usize], fitted: &[usize], values: &[f64]) {
    let q = order.len().saturating_sub(fitted.len());
    for (c, &i) in fitted.iter().enumerate() {
        let theta = values.get(i).copied().unwrap_or(1.0);
        for row in 0..red.r.nrows() {
            red.r[(row, q + c)] /= theta;
        }
    }
}

/// Standard errors of the fitted non-linear parameters at the optimum and their [`Joint`]
/// covariance with the coefficients, from the triangle of `[X | D_θ | y]` (`order` as
/// [`difference_triangle`] gives it, `D_θ = ∂(Xβ̂)/∂θ` in its last `k` columns before y): the θ
/// block of the Gauss–Newton covariance over all parameters, `σ̂²[D_θᵀ(I − P_X)D_θ]⁻¹`. It
/// is the trailing block of that triangle, so the linear parameters are profiled out exactly.
fn uncertainty(
    m: &kin_compiler::ir::Machine,
    red: &Reduced,
    order: &[usize],
    fitted: &[usize],
    rss: f64,
    rank: usize,
) -> (Vec<Option<f64>>, Joint) {
    let k = fitted.len();
    // Columns of the triangle before D's: the design's, less the dependent fixed columns a
    // split leaves out (which change nothing below: they add nothing to X's span).
    let q = order.len().saturating_sub(k);
    let r22 = Mat::from_fn(k, k, |a, b| red.r[(q + a, q + b)]);
    // A parameter whose D column the design and the parameters before it explain (no effect
    // on the residuals of its own) leaves no pivot: its standard error is unbounded. The
    // others' are those with it held where it is — the triangle of their columns alone —
    // rather than unbounded too: one time constant the data cannot see must not make another,
    // which they determine, look undetermined.
    let determined: Vec<usize> = (0..k)
        .filter(|&c| {
            let column = (0..=q + c)
                .map(|i| red.r[(i, q + c)].powi(2))
                .sum::<f64>()
                .sqrt();
            r22[(c, c)].abs() > PIVOT_THETA * column
        })
        .collect();
    let dof = red.rows.saturating_sub(rank + k).max(1) as f64;
    let sigma2 = rss / dof;
    let mut se = vec![None; m.nonlinear.len()];
    for &i in fitted {
        se[i] = Some(f64::INFINITY);
    }
    // Cov(θ) = σ̂² (R₂₂ᵀR₂₂)⁻¹ = σ̂² R₂₂⁻¹R₂₂⁻ᵀ: from the triangle itself, never its normal
    // matrix, whose entries span the squares of the parameters' very different scales.
    let all = determined.len() == k;
    let r = if all {
        r22
    } else {
        // R₂₂ without the undetermined columns is no longer triangular: factor it again.
        let kept = Mat::from_fn(k, determined.len(), |a, b| r22[(a, determined[b])]);
        let n = determined.len();
        let qr = kept.qr();
        let t = qr.thin_R();
        Mat::from_fn(n, n, |a, b| if b >= a { t[(a, b)] } else { 0.0 })
    };
    let inv = triangular_inverse(&r);
    let n = r.ncols();
    for (c, &d) in determined.iter().enumerate() {
        let var: f64 = sigma2 * (c..n).map(|j| inv[(c, j)].powi(2)).sum::<f64>();
        if let Some(slot) = fitted.get(d).and_then(|&i| se.get_mut(i)) {
            *slot = Some(if var.is_finite() {
                var.sqrt()
            } else {
                f64::INFINITY
            });
        }
    }
    // The joint covariance needs every parameter bounded: a prediction that moves with an
    // undetermined one has no bounded uncertainty to give.
    let joint = if all {
        joint(&red.r, m, &order[..q], fitted, &inv, sigma2)
    } else {
        Joint::default()
    };
    (se, joint)
}

/// Below this share of its column's length a parameter's pivot in `R₂₂` counts as none (see
/// [`uncertainty`]); the completed triangle resolves a column to about √ε of its length.
const PIVOT_THETA: f64 = 1e-8;

/// The inverse of an upper triangular matrix (faer's; what lies below the diagonal is zero).
fn triangular_inverse(r: &Mat<f64>) -> Mat<f64> {
    let k = r.ncols();
    let mut inv = Mat::<f64>::zeros(k, k);
    if r.nrows() == k {
        faer::linalg::triangular_inverse::invert_upper_triangular(
            inv.as_mut(),
            r.as_ref(),
            faer::Par::Seq,
        );
    }
    inv
}

/// [`Joint`] from the triangle of `[X | D_θ]` (X's columns first, `order[i]` the design column
/// of the triangle's column i) and `R₂₂⁻¹`: `S = σ̂²R₂₂⁻¹R₂₂⁻ᵀ`, `A = R₁₁⁻¹R₁₂`. A coefficient
/// whose pivot vanishes or that the triangle leaves out (a column the data cannot see apart
/// from others) gets a zero row of A: it is not estimated from these data, so it cannot carry
/// their θ.
fn joint(
    r: &Mat<f64>,
    m: &kin_compiler::ir::Machine,
    order: &[usize],
    fitted: &[usize],
    inv: &Mat<f64>,
    sigma2: f64,
) -> Joint {
    let kk = m.nonlinear.len();
    let k = fitted.len();
    let p = order.len();
    let n = m.coefficients.len();
    let mut s = vec![0.0; kk * kk];
    for (a, &i) in fitted.iter().enumerate() {
        for (b, &j) in fitted.iter().enumerate() {
            let v: f64 = (a.max(b)..k).map(|c| inv[(a, c)] * inv[(b, c)]).sum();
            if let Some(slot) = s.get_mut(i * kk + j) {
                *slot = sigma2 * v;
            }
        }
    }
    let scale = (0..p).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
    let mut a_full = vec![0.0; p * k];
    for c in 0..k {
        for i in (0..p).rev() {
            let d = r[(i, i)];
            if !(d.abs() > 1e-12 * scale) {
                continue;
            }
            let mut v = r[(i, p + c)];
            for j in i + 1..p {
                v -= r[(i, j)] * a_full[j * k + c];
            }
            a_full[i * k + c] = v / d;
        }
    }
    let mut a = vec![0.0; n * kk];
    for (i, &row) in order.iter().enumerate().filter(|(_, &row)| row < n) {
        for (c, &j) in fitted.iter().enumerate() {
            if let Some(slot) = a.get_mut(row * kk + j) {
                *slot = a_full[i * k + c];
            }
        }
    }
    if s.iter().chain(&a).any(|v| !v.is_finite()) {
        // An unbounded direction: no joint covariance rather than a wrong one.
        return Joint::default();
    }
    Joint { s, a }
}

/// What the columns `moved` buy at `values`: the residual sum of squares without them less
/// the one with them. Through the split when it has them all as moving columns (both sums from
/// the same products: `at`, the products at `values` when the optimiser kept them, else one
/// pass; no factorisation), else by a masked fit against `rss`.
#[allow(clippy::too_many_arguments)]
fn term_gain(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    split: Option<&Split>,
    at: Option<&projection::Products>,
    moved: &[bool],
    rss: f64,
) -> Result<f64, FitError> {
    if let Some(split) = split {
        let passed;
        let products = match at {
            Some(p) => p,
            None => {
                let (states, layout) = at_values(compiled, engine, files, values, options)?;
                let mut products = split.products();
                design::for_each_row(engine, files, &states, &layout, |_, x, y| {
                    split.push(&mut products, x, y)
                })?;
                passed = products;
                &passed
            }
        };
        if let Some(masked) = split.without(products, moved) {
            let rss_of = |p: &projection::Products| -> Result<f64, FitError> {
                let red = split.complete(p);
                if !red.is_finite() {
                    return Err(FitError::Overflow);
                }
                Ok(
                    match solve::solve(&red, Solver::Svd, options.tolerance, true) {
                        Ok(s) | Err(s) => s.rss,
                    },
                )
            };
            return Ok(rss_of(&masked)? - rss_of(products)?);
        }
    }
    let (rw, _, _) = masked_fit(compiled, engine, files, values, options, moved)?;
    Ok(sumsq(&rw) - rss)
}

fn sumsq(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Optimises the fitted non-linear parameters. Returns `None` when the model has none.
pub(crate) fn optimise(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    options: &Options,
) -> Result<Option<NonlinearFit>, FitError> {
    optimise_with(compiled, engine, files, options, Steps::Kaufman)
}

/// How [`optimise_with`] evaluates and steps (the others are the tests' references).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Steps {
    /// Every evaluation a new QR of every column; steps from forward differences of the
    /// residual vectors.
    Plain,
    /// Evaluations through the split; steps from forward differences of the residual vectors.
    #[cfg_attr(not(test), allow(dead_code))]
    Differences,
    /// Evaluations through the split; Kaufman's steps (falls back to differences when the
    /// moving columns are too many to keep).
    Kaufman,
}

/// Values of the moving columns kept per row for the Gauss–Newton step through the split
/// (two evaluations' worth, and the derivative columns): above this many, the step falls back
/// to forward differences of the residual vectors (twice the passes). 2²⁵ values: 256 MB.
const KEPT: usize = 1 << 25;

/// A step of 1e-6 in log space for the forward differences: a relative change of one part per
/// million.
const H: f64 = 1e-6;

/// The step in log space of Kaufman's `D = ∂(Xβ̂)/∂φ`, a difference of evaluated columns (not
/// of refitted residuals). Its error is about `ε/h` from rounding plus `h·g/2` from
/// truncation, `g` the columns' relative curvature: a wavelength with n periods over an axis
/// has `g ≈ 2πn`, 10² and more, so a step of 1e-6 errs by 1e-4 — in the standard errors the
/// optimum's triangle gives too. At 1e-8 both parts stay near 1e-6.
const H_COLUMNS: f64 = 1e-8;

/// `D_c` of one row: `(B(φ + h e_c) − B(φ)) β̂_B / h` from the row's moving columns at
/// `φ + h e_c` (in the split's order), their values `b0` at φ and their coefficients — one sum
/// in one order, whichever model evaluated the columns.
fn difference(moved: impl Iterator<Item = f64>, b0: &[f64], beta: &[f64]) -> f64 {
    moved
        .zip(b0)
        .zip(beta)
        .map(|((x, b), beta)| (x - b) * beta)
        .sum::<f64>()
        / H_COLUMNS
}

/// The terms of a model whose columns move with the fitted parameters, as a machine of their
/// own: a difference of the moving columns evaluates these instead of every column (for the
/// 5-axis example, two lag-scaled constants instead of 173 columns).
struct Moving {
    machine: Machine,
    /// The design column of each of its coefficients.
    columns: Vec<usize>,
}

/// What one difference pass fills: `d[t][i·k + c]` for the rows `i` of part `t`, from the
/// moving columns `moving` (design order of the split), their coefficients `beta` and the
/// values `kept` by the evaluation at φ.
struct Differences<'d> {
    moving: &'d [usize],
    beta: &'d [f64],
    kept: &'d [&'d [f64]],
    d: Vec<&'d mut Vec<f64>>,
    c: usize,
    k: usize,
    /// The parts the evaluation at φ was split into: the pass must split its rows the same way.
    parts: usize,
}

/// The machine of `m`'s terms whose coefficients are the design columns `moving` — all of
/// them and nothing else — or `None` when a term is only partly among them or a moving column
/// is not a coefficient.
fn moving_model(m: &Machine, moving: &[usize]) -> Option<Moving> {
    let wanted: std::collections::HashSet<usize> = moving.iter().copied().collect();
    let mut machine = m.clone();
    machine.errors.clear();
    machine.coefficients.clear();
    machine.beta.clear();
    let mut columns = Vec::with_capacity(moving.len());
    for model in &m.errors {
        let mut terms = Vec::new();
        for t in model.terms.iter().filter(|t| t.coefficients > 0) {
            let range = t.first..t.first + t.coefficients;
            let inside = range.clone().filter(|j| wanted.contains(j)).count();
            if inside == 0 {
                continue;
            }
            if inside != t.coefficients {
                return None;
            }
            let first = machine.coefficients.len();
            for j in range {
                let mut co = m.coefficients.get(j)?.clone();
                co.error = machine.errors.len();
                machine.coefficients.push(co);
                columns.push(j);
            }
            terms.push(Term { first, ..t.clone() });
        }
        if !terms.is_empty() {
            machine.errors.push(ErrorModel {
                terms,
                ..model.clone()
            });
        }
    }
    (columns.len() == wanted.len()).then_some(Moving { machine, columns })
}

impl Moving {
    /// One difference pass on the moving terms alone, at the non-linear `values` (φ + h e_c)
    /// and the full model's `states` there (this model has the same axes, inputs and lags, so
    /// the same states):
    /// `D_c` of every row, summed as the pass over every column sums it (the same columns in
    /// the same order, so the same numbers). `false` when this engine cannot take the pass
    /// as the evaluation at φ split it; the caller then passes over every column.
    fn differences(
        &self,
        kind: Engine,
        files: &[DataSet],
        states: &[FileStates],
        values: &[f64],
        options: &Options,
        mut out: Differences,
    ) -> Result<bool, FitError> {
        let Ok(mut engine) = kin_model::engine::make(&self.machine, kind) else {
            return Ok(false);
        };
        design::set_values(engine.as_mut(), values)?;
        let layout = Layout::new(&self.machine, files).weighted(
            &self.machine,
            options.noise,
            &options.file_noise,
        );
        // Each moving column's place among this model's columns.
        let at: Vec<Option<usize>> = out
            .moving
            .iter()
            .map(|j| self.columns.iter().position(|c| c == j))
            .collect();
        let nb = out.moving.len();
        let (c, k) = (out.c, out.k);
        Team::with(engine.as_mut(), out.parts, |team| {
            if team.parts() != out.parts || out.kept.len() != out.parts {
                return Ok(false);
            }
            let mut parts: Vec<(usize, &[f64], &mut Vec<f64>)> = out
                .kept
                .iter()
                .zip(out.d.iter_mut())
                .map(|(kept, d)| (0usize, *kept, &mut **d))
                .collect();
            team.pass(
                files,
                states,
                &layout,
                &mut parts,
                |(row, kept, d), _, x, _| {
                    let i = *row;
                    *row += 1;
                    let b0 = kept.get(i * nb..(i + 1) * nb).unwrap_or(&[]);
                    let dc = difference(
                        at.iter()
                            .map(|a| a.and_then(|a| x.get(a)).copied().unwrap_or(0.0)),
                        b0,
                        out.beta,
                    );
                    if let Some(slot) = d.get_mut(i * k + c) {
                        *slot = dc;
                    }
                },
            )?;
            Ok(true)
        })
    }
}

/// One evaluation of the linear fit at given non-linear values: what the optimiser compares
/// and what its next step is taken from.
struct Point {
    rss: f64,
    rank: usize,
    rows: usize,
    /// β̂ in design column order (through a split: zero for the dependent fixed columns left
    /// out; the fitted values do not depend on which solution is used).
    beta: Vec<f64>,
    /// Through a split and with Kaufman's steps: each row's moving columns (`Split::moving`
    /// per row), one vector per part of the [`Team`]'s passes.
    kept: Vec<Vec<f64>>,
    /// Without a split or Kaufman's steps: the residual vector.
    residuals: Vec<f64>,
    /// Through a split: the moving columns' products the triangle was completed from (what
    /// the term tests at the optimum take columns out of).
    products: Option<projection::Products>,
}

/// The Gauss–Newton normal equations at a point: `JᵀJ` and `−Jᵀr` of the projected residual.
struct Normal {
    a: Mat<f64>,
    g: Vec<f64>,
    /// Kaufman's steps: the triangle of `[X | D_φ | y]` they came from (`D_φ = ∂(Xβ̂)/∂φ`)
    /// and its column order, `order[i]` the design column of the triangle's column i with D's
    /// `k` columns after the design's. At the optimum it is the covariance's triangle.
    triangle: Option<(Reduced, Vec<usize>)>,
}

/// The objective of the search over the logarithms `φ` of the fitted parameters.
struct Problem<'a> {
    compiled: &'a Compiled,
    files: &'a [DataSet],
    options: &'a Options,
    split: Option<&'a Split>,
    /// Whether steps are taken from the split's stored moving columns (Kaufman).
    kaufman: bool,
    /// The moving terms alone ([`moving_model`]) and the engine to evaluate them with: what
    /// the difference passes of [`Problem::kaufman_normal`] evaluate instead of every column.
    moving: Option<(Moving, Engine)>,
    /// Every non-linear parameter's value; the fitted ones are replaced by `exp(φ)`.
    values: Vec<f64>,
    fitted: &'a [usize],
}

impl Problem<'_> {
    fn values(&self, phi: &[f64]) -> Vec<f64> {
        let mut v = self.values.clone();
        for (&i, f) in self.fitted.iter().zip(phi) {
            v[i] = f.exp();
        }
        v
    }

    /// The linear fit at `φ`: for Kaufman's steps one pass through the split (the residual sum
    /// of squares is the completed triangle's), else the fit and its residual vector.
    fn evaluate(&self, team: &mut Team, phi: &[f64]) -> Result<Point, FitError> {
        let values = self.values(phi);
        match self.split.filter(|_| self.kaufman) {
            Some(split) => projected(
                self.compiled,
                team,
                self.files,
                &values,
                self.options,
                split,
                true,
            ),
            None => {
                let (r, rank, beta) = linear_fit(
                    self.compiled,
                    &mut *team.lead,
                    self.files,
                    &values,
                    self.options,
                    self.split,
                )?;
                Ok(Point {
                    rss: sumsq(&r),
                    rank,
                    rows: r.len(),
                    beta,
                    kept: Vec::new(),
                    residuals: r,
                    products: None,
                })
            }
        }
    }

    /// The Gauss–Newton normal equations at `at` (evaluated at `φ`): `JᵀJ` and `−Jᵀr` of the
    /// projected residual `r(φ) = y − X(φ)β̂(φ)`.
    fn normal(&self, team: &mut Team, phi: &[f64], at: &Point) -> Result<Normal, FitError> {
        match self.split.filter(|_| self.kaufman) {
            Some(split) => self.kaufman_normal(team, phi, at, split),
            None => self.difference_normal(&mut *team.lead, phi, at),
        }
    }

    /// Forward differences of the residual vectors: one linear fit per parameter.
    fn difference_normal(
        &self,
        engine: &mut dyn Evaluator,
        phi: &[f64],
        at: &Point,
    ) -> Result<Normal, FitError> {
        let k = phi.len();
        let r = &at.residuals;
        let mut jac = Mat::<f64>::zeros(r.len(), k);
        for c in 0..k {
            let mut p = phi.to_vec();
            p[c] += H;
            let (rp, _) = residuals(
                self.compiled,
                engine,
                self.files,
                &self.values(&p),
                self.options,
                self.split,
            )?;
            for (i, (a, b)) in rp.iter().zip(r).enumerate() {
                jac[(i, c)] = (a - b) / H;
            }
        }
        let a = jac.transpose() * &jac;
        let g = (0..k)
            .map(|c| -(0..r.len()).map(|i| jac[(i, c)] * r[i]).sum::<f64>())
            .collect();
        Ok(Normal {
            a,
            g,
            triangle: None,
        })
    }

    /// Kaufman's simplification of the variable-projection Jacobian (Golub & Pereyra; Kaufman
    /// 1975): `J ≈ −(I − P_X) D` with `D = ∂(Xβ̂)/∂φ` at fixed β̂, so `JᵀJ = R₂₂ᵀR₂₂` and
    /// `−Jᵀr = R₂₂ᵀw₂` from the trailing block of the triangle of `[X | D | y]` (`r ⊥ X`).
    /// `D` moves only with the moving columns: `D_c = (B(φ + h e_c) − B(φ)) β̂_B / h`, `B(φ)`
    /// the values kept by the evaluation at `φ`. One pass per parameter, the last one
    /// accumulating the products of `[B | D]` (every column); the others over the moving
    /// terms alone when those make a model of their own ([`Moving`]). No residual vector and
    /// no factorisation.
    fn kaufman_normal(
        &self,
        team: &mut Team,
        phi: &[f64],
        at: &Point,
        split: &Split,
    ) -> Result<Normal, FitError> {
        let k = phi.len();
        let nb = split.moving();
        let moving = split.order.get(split.order.len() - nb..).unwrap_or(&[]);
        let beta_b: Vec<f64> = moving
            .iter()
            .map(|&j| at.beta.get(j).copied().unwrap_or(0.0))
            .collect();
        let columns = Layout::new(&self.compiled.machine, self.files).columns();
        let ext = split.extended(columns, k);
        // Each part of the passes: its rows' kept moving columns (the evaluation at φ was
        // split the same way), its rows' D (k values a row) and, in the last pass, its share
        // of the products of [B | D] and the row scratch.
        struct Part<'p> {
            kept: &'p [f64],
            d: Vec<f64>,
            row: usize,
            products: Option<projection::Products>,
            scratch: Vec<f64>,
        }
        let mut parts: Vec<Part> = at
            .kept
            .iter()
            .map(|kept| Part {
                kept,
                d: vec![0.0; kept.len() / nb.max(1) * k],
                row: 0,
                products: None,
                scratch: vec![0.0; columns + k],
            })
            .collect();
        for c in 0..k {
            let mut p = phi.to_vec();
            p[c] += H_COLUMNS;
            let values = self.values(&p);
            let last = c + 1 == k;
            let (states, layout) =
                team.at_values(&self.compiled.machine, self.files, &values, self.options)?;
            // Only the last pass needs every column (the products of [X | D]); the others
            // need the moving columns alone, which the moving terms' own model gives.
            if !last {
                if let Some((model, kind)) = &self.moving {
                    let parts_d: Vec<&mut Vec<f64>> = parts.iter_mut().map(|p| &mut p.d).collect();
                    let kept: Vec<&[f64]> = at.kept.iter().map(Vec::as_slice).collect();
                    if model.differences(
                        *kind,
                        self.files,
                        &states,
                        &values,
                        self.options,
                        Differences {
                            moving,
                            beta: &beta_b,
                            kept: &kept,
                            d: parts_d,
                            c,
                            k,
                            parts: team.parts(),
                        },
                    )? {
                        continue;
                    }
                }
            }
            for part in &mut parts {
                part.row = 0;
                part.products = last.then(|| ext.products());
            }
            team.pass(self.files, &states, &layout, &mut parts, |part, _, x, y| {
                let i = part.row;
                part.row += 1;
                let b0 = part.kept.get(i * nb..(i + 1) * nb).unwrap_or(&[]);
                let dc = difference(
                    moving.iter().map(|&j| x.get(j).copied().unwrap_or(0.0)),
                    b0,
                    &beta_b,
                );
                if let Some(slot) = part.d.get_mut(i * k + c) {
                    *slot = dc;
                }
                let Part {
                    d,
                    products,
                    scratch: row,
                    ..
                } = part;
                if let Some(products) = products {
                    // The row of [X(φ) | D]: fixed columns as evaluated, moving ones as kept.
                    for (dst, v) in row.iter_mut().zip(x) {
                        *dst = *v;
                    }
                    for (&j, b) in moving.iter().zip(b0) {
                        if let Some(dst) = row.get_mut(j) {
                            *dst = *b;
                        }
                    }
                    let di = d.get(i * k..(i + 1) * k).unwrap_or(&[]);
                    for (dst, v) in row.iter_mut().skip(columns).zip(di) {
                        *dst = *v;
                    }
                    ext.push(products, row, y);
                }
            })?;
        }
        // The parts' products summed in part order: the same bits for a given team.
        let mut products = ext.products();
        for part in &parts {
            if let Some(p) = &part.products {
                products.add(p);
            }
        }
        let red = ext.complete(&products);
        if !red.is_finite() {
            return Err(FitError::Overflow);
        }
        let q = ext.order.len() - k;
        let last = ext.order.len();
        let a = Mat::from_fn(k, k, |a, b| {
            (0..k)
                .map(|i| red.r[(q + i, q + a)] * red.r[(q + i, q + b)])
                .sum()
        });
        let g = (0..k)
            .map(|a| {
                (0..k)
                    .map(|i| red.r[(q + i, q + a)] * red.r[(q + i, last)])
                    .sum()
            })
            .collect();
        Ok(Normal {
            a,
            g,
            triangle: Some((red, ext.order)),
        })
    }

    /// The residual sum of squares and rank at `values`.
    fn rss_at(&self, team: &mut Team, values: &[f64]) -> Result<(f64, usize), FitError> {
        match self.split {
            Some(split) => {
                let p = projected(
                    self.compiled,
                    team,
                    self.files,
                    values,
                    self.options,
                    split,
                    false,
                )?;
                Ok((p.rss, p.rank))
            }
            None => {
                let (r, rank) = residuals(
                    self.compiled,
                    &mut *team.lead,
                    self.files,
                    values,
                    self.options,
                    None,
                )?;
                Ok((sumsq(&r), rank))
            }
        }
    }
}

/// The linear fit at `values` through the split, in one pass on every core of the team: the
/// moving columns' products complete the fixed triangle; `keep` keeps each row's moving
/// columns (per part).
fn projected(
    compiled: &Compiled,
    team: &mut Team,
    files: &[DataSet],
    values: &[f64],
    options: &Options,
    split: &Split,
    keep: bool,
) -> Result<Point, FitError> {
    let (states, layout) = team.at_values(&compiled.machine, files, values, options)?;
    let nb = split.moving();
    let moving = split.order.get(split.order.len() - nb..).unwrap_or(&[]);
    let mut parts: Vec<(projection::Products, Vec<f64>)> = (0..team.parts())
        .map(|_| (split.products(), Vec::new()))
        .collect();
    team.pass(
        files,
        &states,
        &layout,
        &mut parts,
        |(products, kept), _, x, y| {
            split.push(products, x, y);
            if keep {
                kept.extend(moving.iter().map(|&j| x.get(j).copied().unwrap_or(0.0)));
            }
        },
    )?;
    // Summed in part order: the same bits for a given team.
    let mut products = split.products();
    let mut kept = Vec::with_capacity(parts.len());
    for (p, k) in parts {
        products.add(&p);
        kept.push(k);
    }
    let point = point_from(split, &products, layout.columns(), options)?;
    Ok(Point {
        kept,
        products: Some(products),
        ..point
    })
}

/// The linear fit through `split` from one evaluation's `products`: β̂ over the design's
/// `columns`, the residual sum of squares and the rank (nothing kept yet).
fn point_from(
    split: &Split,
    products: &projection::Products,
    columns: usize,
    options: &Options,
) -> Result<Point, FitError> {
    let red = split.complete(products);
    if !red.is_finite() {
        return Err(FitError::Overflow);
    }
    let sol = match solve::solve(&red, Solver::Svd, options.tolerance, true) {
        Ok(s) | Err(s) => s,
    };
    let mut beta = vec![0.0; columns];
    for (&j, b) in split.order.iter().zip(&sol.beta) {
        if let Some(dst) = beta.get_mut(j) {
            *dst = *b;
        }
    }
    Ok(Point {
        rss: sol.rss,
        rank: sol.rank,
        rows: red.rows,
        beta,
        kept: Vec::new(),
        residuals: Vec::new(),
        products: None,
    })
}

/// [`optimise`], its evaluations and steps as `steps` says; `engine` is left at the optimum.
fn optimise_with(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    options: &Options,
    steps: Steps,
) -> Result<Option<NonlinearFit>, FitError> {
    let fit = Team::with(engine, options.threads, |team| {
        optimise_on(compiled, team, files, options, steps)
    })?;
    if let Some(fit) = &fit {
        design::set_values(engine, &fit.values)?;
    }
    Ok(fit)
}

/// [`optimise_with`] on a team of evaluators.
fn optimise_on(
    compiled: &Compiled,
    team: &mut Team,
    files: &[DataSet],
    options: &Options,
    steps: Steps,
) -> Result<Option<NonlinearFit>, FitError> {
    let m = &compiled.machine;
    let fitted: Vec<usize> = m
        .nonlinear
        .iter()
        .enumerate()
        .filter(|(_, p)| p.fitted)
        .map(|(i, _)| i)
        .collect();
    if fitted.is_empty() {
        return Ok(None);
    }
    let k = fitted.len();
    let start: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    // The fixed columns' triangle, factored once for every evaluation below (the start's
    // included): after it no full factorisation of the design is made until the fit at the
    // optimum.
    let (split, dependent) = if steps != Steps::Plain {
        split_for(
            compiled,
            team,
            files,
            &start,
            options,
            &fitted,
            steps == Steps::Kaufman,
        )?
    } else {
        (None, true)
    };
    let (split, start_point) = match split {
        Some((split, point)) => (Some(split), Some(point)),
        None => (None, None),
    };
    let split = split.as_ref();
    if dependent && !options.min_norm {
        // Fixed columns the others explain: a plain QR decides at once whether the design
        // is deficient, before any evaluation of the optimiser.
        refuse_deficient(compiled, &mut *team.lead, files, &start, options)?;
    }
    let kaufman = steps == Steps::Kaufman && split.is_some_and(|s| keeps(files, s.moving(), k));
    // The moving terms' own model, for the difference passes of more than one parameter
    // (with one, the only pass also needs every column).
    let moving = match (split, team.lead.kind()) {
        (Some(s), Some(kind)) if kaufman && k > 1 => s
            .order
            .get(s.order.len() - s.moving()..)
            .and_then(|cols| moving_model(m, cols))
            .map(|model| (model, kind)),
        _ => None,
    };
    let problem = Problem {
        compiled,
        files,
        options,
        split,
        kaufman,
        moving,
        values: start.clone(),
        fitted: &fitted,
    };
    let mut phi: Vec<f64> = fitted.iter().map(|&i| start[i].ln()).collect();
    // With Kaufman's steps the split's pass evaluated the start already.
    let mut at = match start_point.filter(|_| kaufman) {
        Some(point) => point,
        None => problem.evaluate(team, &phi)?,
    };
    if !options.min_norm && !dependent && at.rank < Layout::new(m, files).columns() {
        // The completed triangle decides the moving block's rank coarsely (normal
        // equations): a plain QR has the last word.
        refuse_deficient(compiled, &mut *team.lead, files, &start, options)?;
    }
    let mut lambda = 1e-3;
    let mut iterations = 0;
    // The normal equations are always those at `phi`: after the loop they are the optimum's,
    // and with Kaufman's steps their triangle is the covariance's (no further passes).
    let mut normal = problem.normal(team, &phi, &at)?;
    for _ in 0..40 {
        iterations += 1;
        // Converged when a step can buy less than a thousandth of one observation's variance:
        // the parameters then move by a few hundredths of a standard error at most, far below
        // anything a test or a reader resolves. (A relative gain of 1e-12 kept undetermined
        // time constants crawling for dozens of passes.) Before a step, the Gauss–Newton
        // model's predicted gain `gᵀ(JᵀJ)⁺g` (the gradient `Jᵀr` is exact with Kaufman's
        // Jacobian: the part it leaves out lies in span(X), orthogonal to r); after one, the
        // gain it bought.
        let variance = |p: &Point| {
            let dof = p.rows.saturating_sub(p.rank + k).max(1) as f64;
            (p.rss / dof).max(f64::MIN_POSITIVE)
        };
        let (full, _) = solve_small(&normal.a, &normal.g);
        let predicted: f64 = full.iter().zip(&normal.g).map(|(s, g)| s * g).sum();
        if !(predicted > 1e-3 * variance(&at)) {
            break;
        }
        let mut gain = None;
        for _ in 0..12 {
            let damped = Mat::from_fn(k, k, |i, j| {
                normal.a[(i, j)]
                    + if i == j {
                        lambda * normal.a[(i, i)].max(1e-300)
                    } else {
                        0.0
                    }
            });
            let (step, _) = solve_small(&damped, &normal.g);
            let trial: Vec<f64> = phi
                .iter()
                .zip(&step)
                .map(|(p, d)| p + d.clamp(-2.0, 2.0))
                .collect();
            let t = problem.evaluate(team, &trial)?;
            if t.rss < at.rss {
                gain = Some((at.rss - t.rss) / variance(&t));
                phi = trial;
                at = t;
                lambda = (lambda / 3.0).max(1e-12);
                break;
            }
            lambda *= 4.0;
        }
        let Some(gain) = gain else {
            // No step improves: `normal` is still the one at `phi`.
            break;
        };
        normal = problem.normal(team, &phi, &at)?;
        if gain <= 1e-3 {
            break;
        }
    }
    let values = problem.values(&phi);
    let (rss, rank) = (at.rss, at.rank);
    let (se, joint) = match normal.triangle {
        Some((mut red, order)) => {
            in_values(&mut red, &order, &fitted, &values);
            uncertainty(m, &red, &order, &fitted, rss, rank)
        }
        None => {
            let (red, order) = difference_triangle(
                compiled,
                &mut *team.lead,
                files,
                &values,
                &fitted,
                options,
                split,
                &at.beta,
            )?;
            uncertainty(m, &red, &order, &fitted, rss, rank)
        }
    };
    let mut verdicts = vec![None; m.nonlinear.len()];
    let dof = at.rows.saturating_sub(rank + k).max(1) as f64;
    // The columns each parameter shapes: through a split, the model's own terms; else
    // compared between evaluations.
    let columns = Layout::new(m, files).columns();
    let structural: Option<Vec<Vec<bool>>> = split.and_then(|_| {
        fitted
            .iter()
            .map(|&i| projection::moving_columns(m, &[i], columns))
            .collect()
    });
    let moved_all = match structural {
        Some(moved) => moved,
        None => moved_columns(compiled, &mut *team.lead, files, &values, &fitted, options)?,
    };
    for (&i, moved) in fitted.iter().zip(&moved_all) {
        let start = m.nonlinear.get(i).map(|p| p.value).unwrap_or(values[i]);
        // Held at its start value, the others at their optimum.
        let mut held = values.clone();
        held[i] = start;
        let (rss_held, _) = problem.rss_at(team, &held)?;
        let without = moved.iter().filter(|&&b| b).count();
        let gain = term_gain(
            compiled,
            &mut *team.lead,
            files,
            &values,
            options,
            split,
            at.products.as_ref(),
            moved,
            rss,
        )?;
        let term_p = f_test_p(gain, (without + 1) as f64, rss, dof);
        let start_p = f_test_p(rss_held - rss, 1.0, rss, dof);
        let bounded = se
            .get(i)
            .copied()
            .flatten()
            .is_some_and(|v| v.is_finite() && v < values[i].abs());
        verdicts[i] = Some(Verdict {
            term_p,
            start_p,
            determined: bounded && term_p <= ALPHA,
        });
    }
    Ok(Some(NonlinearFit {
        values,
        se,
        joint,
        iterations,
        rss,
        verdicts,
    }))
}

/// Solves a small symmetric system with the pseudo-inverse; the flag says whether a direction
/// was singular (a parameter without effect on the residuals: zero step, unbounded variance).
fn solve_small(a: &Mat<f64>, b: &[f64]) -> (Vec<f64>, bool) {
    let k = b.len();
    let Ok(svd) = a.thin_svd() else {
        return (vec![0.0; k], true);
    };
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    let top = s.iter().copied().fold(0.0, f64::max);
    let mut x = vec![0.0; k];
    let mut singular = false;
    for c in 0..k {
        let sc = s[c];
        if sc <= 1e-14 * top || sc == 0.0 {
            singular = true;
            continue;
        }
        let ub: f64 = (0..k).map(|i| u[(i, c)] * b[i]).sum();
        for j in 0..k {
            x[j] += v[(j, c)] * ub / sc;
        }
    }
    (x, singular)
}

/// For each fitted non-linear parameter, the columns whose values change when it changes (by
/// 1 %): the basis functions it shapes. Compared through a fixed pseudo-random projection of
/// each column over the rows, so no design is held; the projection at `values` is shared.
fn moved_columns(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    fitted: &[usize],
    options: &Options,
) -> Result<Vec<Vec<bool>>, FitError> {
    let mut projection = |values: &[f64]| -> Result<Vec<(f64, f64)>, FitError> {
        let (states, layout) = at_values(compiled, engine, files, values, options)?;
        let mut sums = vec![(0.0, 0.0); layout.columns()];
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        design::for_each_row(engine, files, &states, &layout, |_, x, _| {
            // xorshift: reproducible weights in [-1, 1).
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let w = (seed >> 11) as f64 / (1u64 << 52) as f64 - 1.0;
            for (s, v) in sums.iter_mut().zip(x) {
                s.0 += w * v;
                s.1 += v.abs();
            }
        })?;
        Ok(sums)
    };
    let base = projection(values)?;
    let mut out = Vec::with_capacity(fitted.len());
    for &i in fitted {
        let mut shifted = values.to_vec();
        if let Some(v) = shifted.get_mut(i) {
            *v *= 1.01;
        }
        let moved = projection(&shifted)?;
        out.push(
            base.iter()
                .zip(&moved)
                .map(|(a, b)| (a.0 - b.0).abs() > 1e-9 * a.1.max(b.1))
                .collect(),
        );
    }
    Ok(out)
}

/// p-value of a partial F-test: `gain` in the residual sum of squares bought by `q` more
/// parameters, against `rss / dof` ([`crate::statistics::f_p`]).
fn f_test_p(gain: f64, q: f64, rss: f64, dof: f64) -> f64 {
    if !(rss > 0.0) || !gain.is_finite() {
        return if gain > 0.0 { 0.0 } else { 1.0 };
    }
    let f = (gain.max(0.0) / q) / (rss / dof);
    crate::statistics::f_p(f, q, dof).unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{self, sample_points};
    use kin_data::data::Observations;

    /// A machine of one prismatic axis and one temperature input with the given errors.
    fn one_axis(errors: &str) -> String {
        format!(
            "machine m {{
    task position
    units {{ length mm, error um, tilt urad, time min }}
    axis X prismatic along x range 0 mm .. 500 mm
    input T : temperature rise range 0 K .. 5 K
    tool chain {{
        X moving
        tool t at (0, 0, -50) mm
    }}
    errors {{
        {errors}
    }}
}}"
        )
    }

    /// One axis with two lag-scaled constants of fitted time constants.
    fn two_lags() -> Compiled {
        compiled(&one_axis(
            "X.tx = linear(X) + lag(T, tau fit 25 min) * const
             X.ty = lag(T, tau fit 60 min) * const",
        ))
    }

    fn compiled(src: &str) -> Compiled {
        let out = kin_compiler::compile(src);
        let Some(c) = out.compiled else {
            panic!("{:?}", out.diagnostics)
        };
        c
    }

    /// `poses` simulated points of `m` with coefficients of size `size` (SI) and 0.3 µm noise.
    fn simulated(m: &kin_compiler::ir::Machine, size: f64, poses: usize) -> [DataSet; 1] {
        let beta: Vec<f64> = (0..m.coefficients.len())
            .map(|j| size * (1.0 + j as f64).sin())
            .collect();
        let poses = Observations::Points(sample_points(m, poses, 2));
        let options = simulate::Options {
            noise: 0.3e-6,
            seed: 3,
            ..simulate::Options::default()
        };
        let obs = simulate::simulate(m, &beta, &poses, &options).expect("simulate");
        [DataSet {
            path: "sim.csv".into(),
            observations: obs,
        }]
    }

    /// The optimiser's fits from the fixed columns' triangle equal the plain QR's, at values
    /// away from the ones the triangle was made at.
    #[test]
    fn the_projected_fit_equals_the_plain_one() {
        let src = r#"
machine m {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 300 mm
    tool chain {
        X moving
        Y moving
        tool t at (0, 0, -50) mm
    }
    errors {
        X.tx = linear(X) + periodic(X, wavelength fit 20 mm, knots 2)
        X.rz = const + linear(X)
        Y.ty = spline(Y, knots 3)
        Y.tx = fourier(Y, harmonics 1..2, wavelength fit 37 mm)
    }
}
"#;
        let c = compiled(src);
        let m = &c.machine;
        let files = simulated(m, 1e-6, 400);
        let mut engine = kin_model::interp::Interpreter::new(m).expect("interpreter");
        let fitted = [0usize, 1];
        let start: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let options = Options::default();
        let alone = &mut Team::alone(&mut engine);
        let split = split_for(&c, alone, &files, &start, &options, &fitted, false)
            .expect("passes")
            .0
            .expect("a split: only the periodic and Fourier columns move")
            .0;
        assert_eq!(split.moving(), 2 + 4);
        // The θ standard errors and each term's F-test gain through the split agree with the
        // plain QR's.
        let (r0, rank0, beta0) =
            linear_fit(&c, &mut engine, &files, &start, &options, None).expect("fit");
        let rss0 = sumsq(&r0);
        let se = |engine: &mut kin_model::interp::Interpreter, split: Option<&Split>| {
            let (red, order) =
                difference_triangle(&c, engine, &files, &start, &fitted, &options, split, &beta0)
                    .expect("covariance");
            uncertainty(m, &red, &order, &fitted, rss0, rank0)
        };
        let ((se_p, joint_p), (se_q, joint_q)) =
            (se(&mut engine, Some(&split)), se(&mut engine, None));
        // Kaufman's triangle at the same point (forward differences in log θ, one pass per
        // parameter) gives the same covariance as the central differences in θ.
        let problem = Problem {
            compiled: &c,
            files: &files,
            options: &options,
            split: Some(&split),
            kaufman: true,
            moving: None,
            values: start.clone(),
            fitted: &fitted,
        };
        let phi: Vec<f64> = fitted.iter().map(|&i| start[i].ln()).collect();
        // On two evaluators: the passes split in two parts, their products summed.
        let mut fork: Vec<Box<dyn Evaluator + Send + '_>> = vec![Box::new(engine.clone())];
        let mut team = Team::new(&mut engine, &mut fork);
        let at = problem.evaluate(&mut team, &phi).expect("evaluates");
        assert_eq!(at.kept.len(), 2, "one part a thread");
        // The split's own pass on two threads (two triangles merged) evaluates the start too:
        // the same fit as the evaluation through the one-thread split, the same rows kept.
        let (split2, first) = split_for(&c, &mut team, &files, &start, &options, &fitted, true)
            .expect("passes")
            .0
            .expect("a split");
        assert_eq!(split2.order, split.order);
        assert!(
            (first.rss - at.rss).abs() <= 1e-9 * at.rss,
            "{} vs {}",
            first.rss,
            at.rss
        );
        assert_eq!(first.rank, at.rank);
        assert_eq!(first.kept.len(), 2);
        for (a, b) in first.kept.iter().zip(&at.kept) {
            assert_eq!(a.len(), b.len());
        }
        let normal = problem.normal(&mut team, &phi, &at).expect("normal");
        // The moving terms' own model gives the differences the passes over every column
        // give, to the bit: the periodic and the Fourier terms, nothing else.
        let model = split
            .order
            .get(split.order.len() - split.moving()..)
            .and_then(|cols| moving_model(m, cols))
            .expect("a model of the moving terms");
        assert_eq!(model.machine.coefficients.len(), 6);
        assert_eq!(model.machine.errors.len(), 2);
        let through_model = Problem {
            moving: Some((model, kin_model::engine::Engine::Interp)),
            ..problem
        };
        let quick = through_model
            .normal(&mut team, &phi, &at)
            .expect("normal through the moving model");
        let bits = |n: &Normal| -> Vec<u64> {
            n.a.col_iter()
                .flat_map(|c| c.iter().copied().collect::<Vec<f64>>())
                .chain(n.g.iter().copied())
                .map(f64::to_bits)
                .collect()
        };
        assert_eq!(bits(&normal), bits(&quick));
        // And the moving model did take the pass (it may decline, and the passes over every
        // column then give the same bits trivially).
        if let Some((model, kind)) = &through_model.moving {
            let nb = split.moving();
            let moving = split.order.get(split.order.len() - nb..).unwrap_or(&[]);
            let beta: Vec<f64> = moving.iter().map(|&j| at.beta[j]).collect();
            let kept: Vec<&[f64]> = at.kept.iter().map(Vec::as_slice).collect();
            let mut d: Vec<Vec<f64>> = at
                .kept
                .iter()
                .map(|b| vec![0.0; b.len() / nb * 2])
                .collect();
            let mut p = phi.clone();
            p[0] += H_COLUMNS;
            let values = through_model.values(&p);
            let states = design::states_with(m, &files, &values).expect("states");
            let took = model
                .differences(
                    *kind,
                    &files,
                    &states,
                    &values,
                    &Options::default(),
                    Differences {
                        moving,
                        beta: &beta,
                        kept: &kept,
                        d: d.iter_mut().collect(),
                        c: 0,
                        k: 2,
                        parts: 2,
                    },
                )
                .expect("differences");
            assert!(took, "the moving model's pass");
            assert!(d.iter().flatten().any(|v| *v != 0.0));
        }
        let (mut red, order) = normal.triangle.expect("Kaufman's triangle");
        in_values(&mut red, &order, &fitted, &start);
        let (se_k, joint_k) = uncertainty(m, &red, &order, &fitted, at.rss, at.rank);
        // The joint covariance: the split's triangle has its columns in another order, and
        // A's rows belong to the coefficients, not to the triangle's positions.
        assert_eq!(joint_p.a.len(), joint_q.a.len());
        let top = joint_q.a.iter().fold(0.0f64, |t, v| t.max(v.abs()));
        for (a, b) in joint_p
            .a
            .iter()
            .zip(&joint_q.a)
            .chain(joint_p.s.iter().zip(&joint_q.s))
        {
            assert!(
                (a - b).abs() <= 1e-6 * b.abs().max(1e-9 * top),
                "joint {a} vs {b}"
            );
        }
        let top_k = joint_k.a.iter().fold(0.0f64, |t, v| t.max(v.abs()));
        for (a, b) in joint_k
            .a
            .iter()
            .zip(&joint_q.a)
            .chain(joint_k.s.iter().zip(&joint_q.s))
        {
            // Forward differences err by about 1e-6 relative to D (`H_COLUMNS`), so entries
            // that are small by cancellation are compared against the largest.
            assert!(
                (a - b).abs() <= 1e-5 * b.abs() + 1e-6 * top_k,
                "Kaufman's joint {a} vs {b}"
            );
        }
        for (a, b) in se_k.iter().zip(&se_q) {
            match (a, b) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() <= 1e-5 * b.abs(), "Kaufman's se {a} vs {b}")
                }
                other => panic!("{other:?}"),
            }
        }
        for (a, b) in se_p.iter().zip(&se_q) {
            match (a, b) {
                (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-6 * b.abs(), "se {a} vs {b}"),
                (None, None) => {}
                other => panic!("{other:?}"),
            }
        }
        let moved_all =
            moved_columns(&c, &mut engine, &files, &start, &fitted, &options).expect("moved");
        for (moved, &i) in moved_all.iter().zip(&fitted) {
            // The columns seen to move are those of the terms the parameter shapes.
            assert_eq!(
                projection::moving_columns(m, &[i], moved.len()).as_ref(),
                Some(moved)
            );
            let gain = |engine: &mut kin_model::interp::Interpreter,
                        split: Option<&Split>,
                        at: Option<&projection::Products>| {
                term_gain(&c, engine, &files, &start, &options, split, at, moved, rss0)
                    .expect("gain")
            };
            let (gp, gq) = (
                gain(&mut engine, Some(&split), None),
                gain(&mut engine, None, None),
            );
            assert!(
                (gp - gq).abs() <= (1e-6 * gq.abs()).max(1e-9 * rss0),
                "gain {gp} vs {gq}"
            );
            // From the products an evaluation kept: the same sums, no pass.
            let alone = &mut Team::alone(&mut engine);
            let kept = projected(&c, alone, &files, &start, &options, &split, false)
                .expect("evaluates")
                .products;
            let ga = gain(&mut engine, Some(&split), kept.as_ref());
            assert_eq!(ga, gp);
        }
        for values in [
            start.clone(),
            vec![20.3e-3, 36.0e-3],
            vec![19.1e-3, 41.0e-3],
        ] {
            let (rp, rank_p, bp) =
                linear_fit(&c, &mut engine, &files, &values, &options, Some(&split)).expect("fit");
            let (rq, rank_q, bq) =
                linear_fit(&c, &mut engine, &files, &values, &options, None).expect("fit");
            assert_eq!(rank_p, rank_q);
            let scale = rq.iter().map(|v| v * v).sum::<f64>().sqrt();
            let diff = rp
                .iter()
                .zip(&rq)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(
                diff <= 1e-8 * scale,
                "{values:?}: residuals differ by {diff} of {scale}"
            );
            for (a, b) in bp.iter().zip(&bq) {
                assert!((a - b).abs() <= 1e-7 * b.abs().max(1e-9), "{a} vs {b}");
            }
        }
    }

    /// Dependent fixed columns (two constants the positions cannot tell apart), fitted by
    /// minimum norm: the split leaves one out, and every linear fit of the optimiser, the
    /// optimum, σ̂ and the coefficients there equal those of the path that factors every
    /// column at each evaluation.
    #[test]
    fn dependent_fixed_columns_give_the_plain_fit() {
        let src = r#"
machine m {
    task position
    units { length mm, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 300 mm
    input T : temperature rise range 0 K .. 5 K
    tool chain {
        X moving
        Y moving
        tool t at (0, 0, -300) mm
    }
    errors {
        X.tx = const + linear(X)
        Y.tx = const
        Y.ty = spline(Y, knots 3)
        X.rz = const
        tool.tz = lag(T, tau fit 25 min) * const
        X.ry = lag(T, tau fit 60 min) * const
    }
}
"#;
        let c = compiled(src);
        let m = &c.machine;
        // The truth's time constants away from the start values, so the optimiser moves.
        let truth = compiled(
            &src.replace("tau fit 25 min", "tau 33 min")
                .replace("tau fit 60 min", "tau 45 min"),
        );
        let files = simulated(&truth.machine, 1e-5, 600);
        let mut engine = kin_model::interp::Interpreter::new(m).expect("interpreter");
        let fitted = [0usize, 1];
        let start: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let options = Options {
            min_norm: true,
            ..Options::default()
        };
        let alone = &mut Team::alone(&mut engine);
        let split = split_for(&c, alone, &files, &start, &options, &fitted, false)
            .expect("passes")
            .0
            .expect("a split")
            .0;
        assert_eq!(split.dropped(), 1, "one of the two x constants left out");
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(f64::MIN_POSITIVE);
        for values in [
            start.clone(),
            vec![30.0 * 60.0, 50.0 * 60.0],
            vec![900.0, 7000.0],
        ] {
            let (rp, rank_p, _) =
                linear_fit(&c, &mut engine, &files, &values, &options, Some(&split)).expect("fit");
            let (rq, rank_q, _) =
                linear_fit(&c, &mut engine, &files, &values, &options, None).expect("fit");
            assert_eq!(rank_p, rank_q);
            assert!(rank_q < m.coefficients.len(), "a dependent design");
            let (a, b) = (sumsq(&rp), sumsq(&rq));
            assert!(rel(a, b) <= 1e-10, "{values:?}: objective {a} vs {b}");
        }
        let run = |engine: &mut kin_model::interp::Interpreter, steps: Steps| {
            optimise_with(&c, engine, &files, &options, steps)
                .expect("optimises")
                .expect("fitted parameters")
        };
        let old = run(&mut engine, Steps::Plain);
        let truth_tau = [33.0 * 60.0, 45.0 * 60.0];
        let sigma2 = old.rss / (600.0 * 3.0 - 12.0);
        for (steps, new) in [
            (Steps::Differences, run(&mut engine, Steps::Differences)),
            (Steps::Kaufman, run(&mut engine, Steps::Kaufman)),
        ] {
            assert!(new.iterations > 1, "the optimiser moved");
            // The same steps on objectives equal to rounding give the same optimum, up to
            // the rounding the forward-difference Jacobian magnifies (a step of 1e-6); other
            // steps (Kaufman's) stop elsewhere within the convergence test's reach: a few
            // hundredths of a standard error, a thousandth of σ̂² in the sum of squares.
            let (tau_tol, rss_tol) = match steps {
                Steps::Differences => (1e-6, 1e-10 * old.rss),
                _ => (0.05, 1e-2 * sigma2),
            };
            assert!(
                (new.rss - old.rss).abs() <= rss_tol,
                "{steps:?}: rss {} vs {}",
                new.rss,
                old.rss
            );
            for (i, ((a, b), se)) in new.values.iter().zip(&old.values).zip(&new.se).enumerate() {
                let se = se.expect("fitted");
                assert!(
                    (a - b).abs() <= tau_tol * se,
                    "{steps:?}: τ {a} vs {b} (se {se})"
                );
                // The unpivoted QR of [X | D] on a dependent X gave an unbounded error here;
                // the split's is the trailing block of the independent columns' problem.
                assert!((a - truth_tau[i]).abs() < 4.0 * se, "τ {a}, se {se}");
            }
            if steps == Steps::Differences {
                assert_eq!(new.iterations, old.iterations);
                // The linear fit at each optimum: σ̂ and the minimum-norm coefficients.
                let (rn, _, bn) =
                    linear_fit(&c, &mut engine, &files, &new.values, &options, None).expect("fit");
                let (ro, _, bo) =
                    linear_fit(&c, &mut engine, &files, &old.values, &options, None).expect("fit");
                assert!(rel(sumsq(&rn), sumsq(&ro)) <= 1e-10);
                let scale = bo.iter().map(|v| v * v).sum::<f64>().sqrt();
                for (a, b) in bn.iter().zip(&bo) {
                    assert!((a - b).abs() <= 1e-8 * scale, "β {a} vs {b}");
                }
            }
        }
        // The accumulating passes split over threads: the same bits for the same number of
        // threads; against one thread, sums in another order, which Kaufman's differences
        // (a step of 1e-8) magnify in the steps: the optimum moves by ~1e-5 of a standard
        // error, far inside the convergence test's reach.
        let on = |threads: usize| {
            let options = Options {
                threads,
                ..options.clone()
            };
            optimise_with(&c, &mut engine.clone(), &files, &options, Steps::Kaufman)
                .expect("optimises")
                .expect("fitted parameters")
        };
        let (one, three, again) = (on(1), on(3), on(3));
        assert_eq!(three.values, again.values);
        assert_eq!(three.se, again.se);
        assert_eq!(three.rss.to_bits(), again.rss.to_bits());
        // The fixed triangle too is merged from three parts: rounding at this dependent
        // design's conditioning, ~1e-10 of the sum of squares.
        assert!(
            rel(three.rss, one.rss) <= 1e-9,
            "rss {} vs {}",
            three.rss,
            one.rss
        );
        for ((a, b), se) in three.values.iter().zip(&one.values).zip(&one.se) {
            let se = se.expect("fitted");
            assert!((a - b).abs() <= 1e-4 * se, "τ {a} vs {b} (se {se})");
        }
        for (a, b) in three.se.iter().zip(&one.se) {
            let (a, b) = (a.expect("fitted"), b.expect("fitted"));
            assert!(rel(a, b) <= 1e-4, "se {a} vs {b}");
        }
    }

    /// A team keeps its states between values and integrates again only the lags whose time
    /// constant moved: every call gives the states built from scratch, and a caller still
    /// holding earlier states keeps them as they were.
    #[test]
    fn a_teams_states_follow_the_time_constants_it_is_given() {
        let c = two_lags();
        let m = &c.machine;
        let files = simulated(m, 1e-6, 400);
        use super::design::FileStates;
        let lags = |st: &[FileStates]| -> Vec<u64> {
            st.iter()
                .flat_map(|f| match f {
                    FileStates::Points(s) => (0..s.len())
                        .flat_map(|r| s.get(r).lags.to_vec())
                        .collect::<Vec<f64>>(),
                    FileStates::Lengths(..) => Vec::new(),
                })
                .map(f64::to_bits)
                .collect()
        };
        let start: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let moved = |i: usize, f: f64| {
            let mut v = start.clone();
            v[i] *= f;
            v
        };
        let steps = [
            start.clone(),
            moved(0, 1.5),
            moved(1, 0.5),
            moved(1, 0.5),
            start.clone(),
        ];
        let fresh = |v: &[f64]| lags(&design::states_with(m, &files, v).expect("states"));
        assert_ne!(fresh(&steps[0]), fresh(&steps[1]), "the lags depend on τ");
        let mut engine =
            kin_model::engine::make(m, kin_model::engine::Engine::Interp).expect("engine");
        Team::with(engine.as_mut(), 2, |team| {
            let mut held = None;
            for (i, v) in steps.iter().enumerate() {
                let (st, _) = team
                    .at_values(&c.machine, &files, v, &Options::default())
                    .expect("at values");
                assert_eq!(lags(&st), fresh(v), "step {i}");
                if i == 1 {
                    held = Some(st);
                }
            }
            let held = held.expect("held");
            assert_eq!(lags(&held), fresh(&steps[1]), "a held copy is left alone");
        });
    }

    /// One time constant with no effect of its own (its derivative column inside the design's
    /// span) is unbounded; the other keeps the standard error it has without it (only the
    /// degrees of freedom differ). Before, the zero pivot made both unbounded.
    #[test]
    fn an_undetermined_parameter_leaves_the_others_bounded() {
        let c = two_lags();
        let m = &c.machine;
        let (rows, p) = (300usize, 5usize);
        let mut seed = 7u64;
        let mut draw = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let data: Vec<(Vec<f64>, f64, f64)> = (0..rows)
            .map(|_| {
                let x: Vec<f64> = (0..p).map(|_| draw()).collect();
                (x, draw(), draw())
            })
            .collect();
        // [X | D₁ | D₂ | y] with D₂ = X·w (no effect beyond the design's), and [X | D₁ | y].
        let triangle = |with_second: bool| {
            let k = p + 1 + usize::from(with_second);
            let mut acc = StreamingQr::new(k, 64);
            for (x, d1, y) in &data {
                let mut row = x.clone();
                row.push(*d1);
                if with_second {
                    row.push(x.iter().enumerate().map(|(j, v)| v * (j + 1) as f64).sum());
                }
                acc.push(&row, *y);
            }
            (acc.finish(), (0..k).collect::<Vec<usize>>())
        };
        let (both, order_both) = triangle(true);
        let (one, order_one) = triangle(false);
        // The residual sum of squares is the linear fit's, as the optimiser passes it.
        let rss = one.r[(p + 1, p + 1)].powi(2);
        let (se_both, joint_both) = uncertainty(m, &both, &order_both, &[0, 1], rss, p);
        let (se_one, _) = uncertainty(m, &one, &order_one, &[0], rss, p);
        assert_eq!(se_both[1], Some(f64::INFINITY));
        let (a, b) = (se_both[0].expect("fitted"), se_one[0].expect("fitted"));
        let dof = |k: usize| (rows - p - k) as f64;
        let want = b * (dof(1) / dof(2)).sqrt();
        assert!(
            a.is_finite() && (a - want).abs() <= 1e-10 * want,
            "{a} vs {want}"
        );
        assert!(
            joint_both.s.is_empty(),
            "no joint covariance with an unbounded parameter"
        );
    }

    #[test]
    fn a_known_term_that_moves_keeps_the_plain_path() {
        let c = compiled(&one_axis(
            "X.tx = linear(X) + 2 um/K * lag(T, tau fit 30 min)",
        ));
        let columns = c.machine.coefficients.len();
        assert!(projection::moving_columns(&c.machine, &[0], columns).is_none());
    }
}
