//! The optimiser's linear fits, factored once (variable projection, Golub & Pereyra 1973).
//!
//! A fitted wavelength or time constant moves only the columns of the terms it shapes; every
//! other column, the observations and the weights stay put. The triangle of the fixed columns
//! and `y` is therefore computed once; each evaluation of the optimiser then accumulates only the
//! products of the moving columns (`AᵀB`, `BᵀB`, `Bᵀy`: rows × fixed × moving operations instead
//! of the rows × columns² of a new QR) and completes the triangle of `[A | B | y]` from them:
//!
//! ```text
//! R = | R_A  S  z  |   R_Aᵀ S = AᵀB,  TᵀT = BᵀB − SᵀS,  Tᵀw = Bᵀy − Sᵀz,
//!     |  0   T  w  |   ρ'² = ρ² − ‖w‖²   (RᵀR = [A B y]ᵀ[A B y]).
//!     |  0   0  ρ' |
//! ```
//!
//! Only the small `B` block is formed from normal equations, in unit-scaled columns, and only
//! the optimiser's path uses it: the fit at the optimum is made from a new QR of every row.

use faer::Mat;
use kin_compiler::basis::{Basis, Wavelength};
use kin_compiler::ir::{Machine, Scalar, Var};

use super::qr::Reduced;
use super::solve;

/// Which columns move with the fitted non-linear parameters `fitted` (indices into
/// `Machine::nonlinear`), for `columns` design columns (coefficients first, then nuisance
/// parameters, which never move). `None` when a term without coefficients — a known error
/// that enters the observations `y` — moves too: then `y` changes and nothing can be kept.
pub(crate) fn moving_columns(m: &Machine, fitted: &[usize], columns: usize) -> Option<Vec<bool>> {
    let moves_lag = |l: usize| {
        m.lags
            .get(l)
            .is_some_and(|lag| fitted.contains(&lag.tau.index))
    };
    let mut moving = vec![false; columns];
    for term in m.errors.iter().flat_map(|e| &e.terms) {
        let by_factor = term.factors.iter().any(|f| {
            matches!(f.var, Var::Lag(l) if moves_lag(l))
                || match &f.basis {
                    Basis::Fourier {
                        wavelength: Some(Wavelength::Fitted(nl)),
                        ..
                    }
                    | Basis::Periodic {
                        wavelength: Wavelength::Fitted(nl),
                        ..
                    } => fitted.contains(&nl.index),
                    _ => false,
                }
        });
        if !(by_factor || scalar_moves(&term.scale, &moves_lag)) {
            continue;
        }
        if term.coefficients == 0 {
            return None;
        }
        let end = term.first.checked_add(term.coefficients)?;
        moving.get_mut(term.first..end)?.fill(true);
    }
    Some(moving)
}

fn scalar_moves(s: &Scalar, moves_lag: &impl Fn(usize) -> bool) -> bool {
    match s {
        Scalar::Num(_) => false,
        Scalar::Var(v) => matches!(v, Var::Lag(l) if moves_lag(*l)),
        Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => scalar_moves(a, moves_lag),
        Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
            scalar_moves(a, moves_lag) || scalar_moves(b, moves_lag)
        }
    }
}

/// The fixed part, factored: the triangle of `[A₁ | y]`, `A₁` the fixed columns the fit's rank
/// decision keeps.
///
/// When the fixed columns are dependent (data that do not see every direction, fitted by
/// minimum norm) only an independent subset `A₁` of them is kept: the optimiser needs the
/// residual of the fit, and the projection of `y` (and of the moving columns) onto
/// `span(A) = span(A₁)` does not depend on which basis of the span is used. The subset comes
/// from the same column-pivoted QR of the unit-scaled triangle, at the same tolerance, as the
/// fit's own rank decision ([`solve::pivoted_rank`]); the triangle of `[A₁ | y]` is that of the
/// kept columns of `A`'s triangle (`R_Aᵀ R_A = AᵀA`), with no pass over the rows.
#[derive(Debug, Clone)]
pub struct Split {
    /// Column indices of the design, kept fixed ones first then moving ones: the order of the
    /// completed triangle. Dropped fixed columns are not in it (their coefficient is zero).
    pub order: Vec<usize>,
    fixed: usize,
    dropped: usize,
    /// The columns of a row pushed (the design's, and an extended split's extra ones).
    columns: usize,
    base: Reduced,
}

/// The kept fixed columns' triangle must be well conditioned: [`Split::complete`] divides by
/// it, and the moving block's Schur complement loses about this factor times the rounding of
/// the products. Above it, the plain QR is taken.
const CONDITION: f64 = 1e8;

impl Split {
    /// `base` is the triangle of the rows restricted to the columns `moving` marks false, in
    /// column order, with `y`; `tol` the fit's relative rank tolerance. `None` when the kept
    /// fixed columns are too ill-conditioned for the completion (see [`CONDITION`]): the plain
    /// QR handles those.
    pub fn new(moving: &[bool], base: Reduced, tol: f64) -> Option<Split> {
        let fixed: Vec<usize> = (0..moving.len()).filter(|&j| !moving[j]).collect();
        let na = fixed.len();
        if base.r.nrows() != na + 1 || base.norms.len() != na {
            return None;
        }
        let (rs, _) = solve::scaled_triangle(&base);
        let rs = Mat::from_fn(na, na, |i, j| rs[i * na + j]);
        let (rank, condition, pivots) = solve::pivoted_rank(&rs, tol);
        if na > 0 && !(condition <= CONDITION) {
            return None;
        }
        let mut keep: Vec<usize> = pivots.get(..rank)?.to_vec();
        keep.sort_unstable();
        let base = if rank == na {
            base
        } else {
            // [A₁ y] = Q [R_A's kept columns | its last column]: the QR of that small matrix
            // is the triangle of [A₁ y].
            let cols: Vec<usize> = keep.iter().copied().chain([na]).collect();
            let m = Mat::from_fn(na + 1, rank + 1, |i, c| base.r[(i, cols[c])]);
            let qr = m.qr();
            let t = qr.thin_R();
            Reduced {
                r: Mat::from_fn(
                    rank + 1,
                    rank + 1,
                    |i, j| if j >= i { t[(i, j)] } else { 0.0 },
                ),
                rows: base.rows,
                norms: keep.iter().map(|&c| base.norms[c]).collect(),
                y_sum: base.y_sum,
                y_sumsq: base.y_sumsq,
            }
        };
        let mut order: Vec<usize> = keep.iter().map(|&c| fixed[c]).collect();
        order.extend((0..moving.len()).filter(|&j| moving[j]));
        Some(Split {
            order,
            fixed: rank,
            dropped: na - rank,
            columns: moving.len(),
            base,
        })
    }

    /// How many fixed columns were left out as dependent on the kept ones.
    pub fn dropped(&self) -> usize {
        self.dropped
    }

    /// The same fixed part with `extra` more moving columns after the design's `columns`
    /// (each row pushed then holds them after its design columns): the triangle of
    /// `[A | B | D | y]` without a new factorisation of `A`.
    pub(crate) fn extended(&self, columns: usize, extra: usize) -> Split {
        let mut order = self.order.clone();
        order.extend(columns..columns + extra);
        Split {
            order,
            fixed: self.fixed,
            dropped: self.dropped,
            columns: columns + extra,
            base: self.base.clone(),
        }
    }

    /// `p` with the moving columns `drop` marks (design column indices) taken out of the
    /// problem: their products are zero, so [`Split::complete`] leaves them a zero row (a lost
    /// rank) and the rest is the fit without them. `None` when `drop` marks a fixed column.
    pub fn without(&self, p: &Products, drop: &[bool]) -> Option<Products> {
        let mut out = p.clone();
        let nb = self.moving();
        let moving = self.order.get(self.fixed..)?;
        for (j, _) in drop.iter().enumerate().filter(|(_, d)| **d) {
            let c = moving.iter().position(|&o| o == j)?;
            out.ab.col_as_slice_mut(c).fill(0.0);
            for d in 0..nb {
                out.bb[(c, d)] = 0.0;
                out.bb[(d, c)] = 0.0;
            }
            out.by[c] = 0.0;
        }
        Some(out)
    }

    /// How many columns move.
    pub fn moving(&self) -> usize {
        self.order.len() - self.fixed
    }

    /// Accumulates one row's products (`x` in design column order) into `acc`, products of
    /// this split.
    pub fn push(&self, acc: &mut Products, x: &[f64], y: f64) {
        acc.push(x, y);
    }

    /// Empty products for one evaluation.
    pub fn products(&self) -> Products {
        Products::new(
            self.order.get(self.fixed..).unwrap_or(&[]).to_vec(),
            self.columns,
        )
    }

    /// The triangle of `[A | B | y]` (columns in [`Split::order`]) from the fixed part and one
    /// evaluation's products.
    pub fn complete(&self, p: &Products) -> Reduced {
        let (na, nb) = (self.fixed, self.moving());
        let k = na + nb + 1;
        let base = &self.base.r;
        let mut r = Mat::<f64>::zeros(k, k);
        for i in 0..na {
            for j in i..na {
                r[(i, j)] = base[(i, j)];
            }
            r[(i, k - 1)] = base[(i, na)];
        }
        // S = R_A⁻ᵀ AᵀB by forward substitution. A triangular solve's rounding does not depend
        // on how the rows are scaled, so A's units need no care here.
        for c in 0..nb {
            for i in 0..na {
                let mut v = p.ab[(self.order[i], c)];
                for l in 0..i {
                    v -= base[(l, i)] * r[(l, na + c)];
                }
                r[(i, na + c)] = v / base[(i, i)];
            }
        }
        // T from the Schur complement BᵀB − SᵀS, in unit-scaled B columns so the zero-pivot
        // test is relative: a column the others explain to rounding leaves a zero row, which
        // the solver reads as a lost rank.
        let norms: Vec<f64> = (0..nb).map(|c| p.bb[(c, c)].max(0.0).sqrt()).collect();
        let scale = |c: usize| norms.get(c).copied().filter(|v| *v > 0.0).unwrap_or(1.0);
        let mut t = Mat::<f64>::zeros(nb, nb);
        let mut w = vec![0.0; nb];
        for c in 0..nb {
            for d in c..nb {
                let mut v = p.bb[(c, d)];
                for i in 0..na {
                    v -= r[(i, na + c)] * r[(i, na + d)];
                }
                v /= scale(c) * scale(d);
                for l in 0..c {
                    v -= t[(l, c)] * t[(l, d)];
                }
                if d == c {
                    if v <= PIVOT {
                        break;
                    }
                    t[(c, c)] = v.sqrt();
                } else {
                    t[(c, d)] = v / t[(c, c)];
                }
            }
            if t[(c, c)] == 0.0 {
                continue;
            }
            // T̃ᵀw = D_B⁻¹(Bᵀy − Sᵀz).
            let mut v = p.by[c];
            for i in 0..na {
                v -= r[(i, na + c)] * base[(i, na)];
            }
            v /= scale(c);
            for l in 0..c {
                v -= t[(l, c)] * w[l];
            }
            w[c] = v / t[(c, c)];
        }
        for c in 0..nb {
            for d in c..nb {
                r[(na + c, na + d)] = t[(c, d)] * scale(d);
            }
            r[(na + c, k - 1)] = w[c];
        }
        let rho2 = base[(na, na)].powi(2) - w.iter().map(|v| v * v).sum::<f64>();
        r[(k - 1, k - 1)] = rho2.max(0.0).sqrt();
        let mut all_norms: Vec<f64> = self.base.norms.iter().take(na).copied().collect();
        all_norms.extend(norms);
        Reduced {
            r,
            rows: self.base.rows,
            norms: all_norms,
            y_sum: self.base.y_sum,
            y_sumsq: self.base.y_sumsq,
        }
    }
}

/// A moving column whose part outside the others' span has at most this squared length
/// (relative to its own) counts as dependent: the normal equations of the moving block resolve
/// no finer than about √ε of a column.
const PIVOT: f64 = 1e-12;

/// One evaluation's products of the moving columns. They depend only on which columns move,
/// not on the fixed triangle, so they can be summed in the same pass that factors it.
#[derive(Debug, Clone)]
pub(crate) struct Products {
    /// The moving columns, in design order (a split's `order` after its fixed columns).
    moving: Vec<usize>,
    /// `XᵀB` over every column of a row (row j of column j): `AᵀB` is its kept fixed rows.
    ab: Mat<f64>,
    bb: Mat<f64>,
    by: Vec<f64>,
    /// The current row's moving values.
    b: Vec<f64>,
}

impl Products {
    /// Empty products of the columns `moving` (design indices, increasing) for rows of
    /// `columns` values: those [`Split::products`] gives for a split with these moving columns.
    pub fn new(moving: Vec<usize>, columns: usize) -> Products {
        let nb = moving.len();
        Products {
            moving,
            ab: Mat::zeros(columns, nb),
            bb: Mat::zeros(nb, nb),
            by: vec![0.0; nb],
            b: Vec::with_capacity(nb),
        }
    }

    /// Accumulates one row (`x` in design column order).
    pub fn push(&mut self, x: &[f64], y: f64) {
        let Products {
            moving,
            ab,
            bb,
            by,
            b,
        } = self;
        b.clear();
        b.extend(moving.iter().map(|&j| x.get(j).copied().unwrap_or(0.0)));
        for (c, &bc) in b.iter().enumerate() {
            // Most moving columns are zero on most rows (a lag of one input, one component).
            if bc == 0.0 {
                continue;
            }
            // Against every column of the row, in design order: a contiguous multiply-add the
            // compiler vectorises, where picking the kept fixed columns out of the row would
            // cost a scattered load each (what is not a kept fixed column is never read).
            for (dst, &xv) in ab.col_as_slice_mut(c).iter_mut().zip(x) {
                *dst += xv * bc;
            }
            for (d, &bd) in b.iter().enumerate() {
                bb[(c, d)] += bc * bd;
            }
            by[c] += bc * y;
        }
    }

    /// Adds the products of other rows (a part of a pass split over threads).
    pub fn add(&mut self, other: &Products) {
        for (dst, src) in [(&mut self.ab, &other.ab), (&mut self.bb, &other.bb)] {
            // Products of one split always match; faer's sum would panic on a mismatch.
            if (dst.nrows(), dst.ncols()) == (src.nrows(), src.ncols()) {
                *dst += src;
            }
        }
        for (dst, src) in self.by.iter_mut().zip(&other.by) {
            *dst += src;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::qr::StreamingQr;
    use rand::{Rng, SeedableRng};

    /// Rows of `p` columns (scaled very differently, as units make them) and their y.
    fn rows(m: usize, p: usize, seed: u64) -> Vec<(Vec<f64>, f64)> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..m)
            .map(|_| {
                let x: Vec<f64> = (0..p)
                    .map(|j| rng.random_range(-1.0..1.0) * 10f64.powi(j as i32 % 5 - 2))
                    .collect();
                let y = rng.random_range(-1.0..1.0);
                (x, y)
            })
            .collect()
    }

    fn split(rows: &[(Vec<f64>, f64)], moving: &[bool]) -> Option<(Split, Reduced)> {
        let fixed = moving.iter().filter(|&&b| !b).count();
        let mut acc = StreamingQr::new(fixed, 64);
        for (x, y) in rows {
            let a: Vec<f64> = x
                .iter()
                .zip(moving)
                .filter(|(_, &m)| !m)
                .map(|(v, _)| *v)
                .collect();
            acc.push(&a, *y);
        }
        let split = Split::new(moving, acc.finish(), 1e-10)?;
        let mut products = split.products();
        for (x, y) in rows {
            split.push(&mut products, x, *y);
        }
        let red = split.complete(&products);
        Some((split, red))
    }

    #[test]
    fn the_completed_triangle_squares_to_the_gram_matrix_of_every_column() {
        let moving = [false, true, false, false, true, false, true];
        let data = rows(500, moving.len(), 3);
        let (split, red) = split(&data, &moving).expect("independent fixed columns");
        let k = moving.len() + 1;
        // Column c of the completed problem: design column order[c], y last.
        let col = |row: &(Vec<f64>, f64), c: usize| split.order.get(c).map_or(row.1, |&j| row.0[j]);
        for a in 0..k {
            for b in 0..k {
                let gram: f64 = data.iter().map(|r| col(r, a) * col(r, b)).sum();
                let rtr: f64 = (0..k).map(|i| red.r[(i, a)] * red.r[(i, b)]).sum();
                let scale = (data.iter().map(|r| col(r, a).powi(2)).sum::<f64>()
                    * data.iter().map(|r| col(r, b).powi(2)).sum::<f64>())
                .sqrt();
                assert!(
                    (gram - rtr).abs() <= 1e-12 * scale,
                    "({a}, {b}): {gram} vs {rtr}"
                );
            }
        }
        // The residual sum of squares of the whole problem is the last diagonal entry squared.
        let rss = red.r[(k - 1, k - 1)].powi(2);
        let mut full = StreamingQr::new(moving.len(), 64);
        for (x, y) in &data {
            full.push(x, *y);
        }
        let full = full.finish();
        assert!((rss - full.r[(k - 1, k - 1)].powi(2)).abs() <= 1e-10 * rss);
    }

    #[test]
    fn a_moving_column_the_fixed_ones_explain_leaves_a_zero_row() {
        let moving = [false, false, true];
        let mut data = rows(200, 3, 5);
        for r in &mut data {
            r.0[2] = 2.0 * r.0[0] - 3.0 * r.0[1];
        }
        let (_, red) = split(&data, &moving).expect("split");
        assert_eq!(red.r[(2, 2)], 0.0);
        assert_eq!(red.r[(2, 3)], 0.0);
    }

    #[test]
    fn dropped_moving_columns_give_the_fit_without_them() {
        let moving = [false, true, false, true, true];
        let data = rows(400, moving.len(), 11);
        let (split, _) = split(&data, &moving).expect("split");
        let mut products = split.products();
        for (x, y) in &data {
            split.push(&mut products, x, *y);
        }
        let drop = [false, false, false, true, false];
        let masked = split
            .without(&products, &drop)
            .expect("moving columns only");
        let red = split.complete(&masked);
        let k = moving.len() + 1;
        let rss = red.r[(k - 1, k - 1)].powi(2);
        // The same problem with column 3 left out, by a plain QR.
        let mut plain = StreamingQr::new(moving.len() - 1, 64);
        for (x, y) in &data {
            let kept: Vec<f64> = x
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != 3)
                .map(|(_, v)| *v)
                .collect();
            plain.push(&kept, *y);
        }
        let plain = plain.finish();
        let want = plain.r[(k - 2, k - 2)].powi(2);
        assert!((rss - want).abs() <= 1e-10 * want, "{rss} vs {want}");
        // A fixed column cannot be dropped this way.
        assert!(split
            .without(&products, &[true, false, false, false, false])
            .is_none());
    }

    /// Dependent fixed columns: one is left out, and the completed problem's residual sum of
    /// squares is the minimum-norm fit's of every column. Fails if the kept triangle were not
    /// that of the kept columns (a wrong basis of the span leaves a different residual).
    #[test]
    fn dependent_fixed_columns_are_left_out_with_the_same_residual() {
        let moving = [false, false, true, false, true];
        let mut data = rows(300, moving.len(), 7);
        for r in &mut data {
            // Column 3 a combination of columns 0 and 1, in other units.
            r.0[3] = 1e3 * r.0[0] - 0.5 * r.0[1];
            // y partly explained by fixed and moving columns, so a wrong projection would
            // show.
            r.1 += 2.0 * r.0[0] - r.0[2] + 3e-3 * r.0[4];
        }
        let (split, red) = split(&data, &moving).expect("split");
        assert_eq!(split.dropped(), 1);
        assert_eq!(split.order.len(), moving.len() - 1);
        let mut full = StreamingQr::new(moving.len(), 64);
        for (x, y) in &data {
            full.push(x, *y);
        }
        let full = full.finish();
        let of = |red: &Reduced| match solve::solve(red, solve::Solver::Svd, 1e-10, true) {
            Ok(s) | Err(s) => (s.rss, s.rank),
        };
        let ((rss, rank), (want, want_rank)) = (of(&red), of(&full));
        assert_eq!(rank, want_rank);
        assert!((rss - want).abs() <= 1e-10 * want, "{rss} vs {want}");
    }
}
