//! The candidates' pass over the rows: every candidate's columns against the base model's,
//! without the columns of one candidate meeting another's (but where they are compared).
//!
//! Testing a candidate needs the triangle of `[X | C_i | y]` (X the base model's columns, `C_i`
//! the candidate's): the part of `C_i` and `y` that X does not explain, and its products. One
//! triangle of every column at once costs rows × (base + all candidates)² and holds products
//! between candidates no test uses. Here the rows go through the base's streaming QR block by
//! block (`[R; X_b] = Q R'`, as in [`kin_estimate::fit::StreamingQr`]), and the same orthogonal `Qᵀ` is
//! applied to `[S; C_b | y_b]` — every candidate's columns and `y` — in one blocked product:
//! its top rows are the columns' coordinates in the base's space (`S`), its bottom rows the
//! parts of this block's rows orthogonal to it. Those bottom rows are summed into Gram
//! matrices of the remainders, one per group of columns (below). All of it is orthogonal, so a candidate's factor
//! `[R S_i z; 0 T_i w_i; 0 0 ρ_i]` has the inner products of `[X C_i y]`: the added-variable
//! test of the candidate, from one pass for all of them; two candidates' joint factor compares
//! the spaces they add. The cost per row is base² + 2 base × candidate columns + the groups'
//! (columns)² / 2 (one blocked Householder application and one Gram product per group and
//! block), against (base + candidate columns)² for one QR of every column.
//!
//! Only the remainders, which X does not explain, are squared into a Gram matrix: their sums
//! have no cancellation against X, so a column the base spans comes out as rounding, as in a
//! QR of all the columns. On several threads, block `i` goes to worker `i mod T` and the
//! workers' states are merged in worker order: the same bits for the same `T`.
//!
//! Not every product of remainders is summed: only those within each of the [`Split::groups`]
//! (sets of candidate columns, `y` always with them). A candidate's own test needs the products
//! of its own columns; those of two candidates are needed only where the diagnosis compares
//! them (equal residual sums, readings of one effect), a few candidates out of hundreds, which
//! a second, narrow pass sums once the tests have named them. Summing every pair of the mill's
//! 737 candidate columns was half the pass's products for none of its answers.
//! [`Accumulated::factor`] refuses columns whose products were not summed together.

use std::sync::mpsc;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::householder;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::qr::no_pivoting::factor;
use faer::{Accum, Conj, Mat, Par};

/// Which design columns are the base's, which the candidates', and which candidate columns'
/// products are summed together.
#[derive(Debug, Clone)]
pub(super) struct Split {
    /// Design columns of the base (coefficients and nuisance parameters), in order.
    pub base: Vec<usize>,
    /// Design columns of the candidates, each once: the slots.
    pub candidates: Vec<usize>,
    /// Sets of slots whose products with one another (and with `y`) are summed: one per
    /// candidate, or one for several candidates that are compared.
    pub groups: Vec<Vec<usize>>,
}

/// The products of one group's remainders.
#[derive(Debug, Clone)]
pub(super) struct Group {
    /// The group's slots, ascending.
    slots: Vec<usize>,
    /// Lower triangle of the Gram matrix of the group's remainders, `y`'s last
    /// (`slots.len() + 1` square); mirrored at the end of the pass.
    gram: Mat<f64>,
}

impl Group {
    /// Where `slot` is in this group (`None`: not in it); `y` is at `slots.len()`.
    fn at(&self, slot: usize) -> Option<usize> {
        self.slots.binary_search(&slot).ok()
    }
}

/// The groups of `split` to sum: each once, ascending, none inside a larger one (its
/// products are the larger one's).
fn groups(split: &Split) -> Vec<Vec<usize>> {
    let mut all: Vec<Vec<usize>> = split
        .groups
        .iter()
        .map(|g| {
            let mut g: Vec<usize> = g
                .iter()
                .copied()
                .filter(|&s| s < split.candidates.len())
                .collect();
            g.sort_unstable();
            g.dedup();
            g
        })
        .collect();
    // Larger first, then by content: a group is kept unless a kept one holds all of it.
    all.sort_by(|a, b| b.len().cmp(&a.len()).then_with(|| a.cmp(b)));
    let mut kept: Vec<Vec<usize>> = Vec::new();
    for g in all {
        let inside = kept
            .iter()
            .any(|k| g.iter().all(|s| k.binary_search(s).is_ok()));
        if !inside {
            kept.push(g);
        }
    }
    kept
}

/// What the pass accumulated.
#[derive(Debug, Clone)]
pub(super) struct Accumulated {
    /// The base's design columns ([`Split::base`]).
    pub base: Vec<usize>,
    /// The base's triangle (`kb × kb`).
    pub r: Mat<f64>,
    /// The coordinates of every candidate column (slot order) and, last, of `y` in the base's
    /// space (`kb × (slots + 1)`).
    pub s: Mat<f64>,
    /// The Gram matrices of the remainders of the groups' slots, `y`'s last in each.
    groups: Vec<Group>,
    /// The sum of squares of `y`'s remainder.
    pub ee: f64,
    /// Euclidean norm of every design column.
    pub norms: Vec<f64>,
    pub rows: usize,
}

/// A block of rows laid out as the fold factors it: `kb` rows of room for the triangle and
/// the coordinates, then one row per design row. The rows are written where the
/// factorisation reads them, so a fold neither transposes nor allocates (copying a block into
/// freshly zeroed matrices was about a sixth of the pass's time at 10⁵ poses of the 5-axis example).
struct Block {
    /// `(kb + rows) × kb`: the base's columns.
    a: Mat<f64>,
    /// `(kb + rows) × (slots + 1)`: the slots' columns, then `y`.
    rhs: Mat<f64>,
    filled: usize,
}

impl Block {
    fn new(kb: usize, wide: usize, rows: usize) -> Block {
        Block {
            a: Mat::zeros(kb + rows, kb),
            rhs: Mat::zeros(kb + rows, wide),
            filled: 0,
        }
    }

    fn full(&self) -> bool {
        self.kb() + self.filled == self.a.nrows()
    }

    fn kb(&self) -> usize {
        self.a.ncols()
    }
}

/// One worker's part.
struct State {
    r: Mat<f64>,
    s: Mat<f64>,
    groups: Vec<Group>,
    ee: f64,
    /// The factorisation's scratch, kept from block to block, and its size.
    mem: MemBuffer,
    mem_bytes: usize,
    /// A group's remainders gathered from a block (as many rows as a block has, as many
    /// columns as the widest group has, `y` included).
    gathered: Mat<f64>,
}

impl State {
    fn new(split: &Split, groups: &[Vec<usize>]) -> State {
        let (kb, slots) = (split.base.len(), split.candidates.len());
        State {
            r: Mat::zeros(kb, kb),
            s: Mat::zeros(kb, slots + 1),
            groups: groups
                .iter()
                .map(|g| Group {
                    slots: g.clone(),
                    gram: Mat::zeros(g.len() + 1, g.len() + 1),
                })
                .collect(),
            ee: 0.0,
            mem: MemBuffer::new(StackReq::EMPTY),
            mem_bytes: 0,
            gathered: Mat::zeros(0, 0),
        }
    }

    /// Folds the rows of `block` in (its top `kb` rows are overwritten).
    fn fold(&mut self, block: &mut Block) {
        let filled = block.filled;
        if filled == 0 {
            return;
        }
        let kb = self.r.nrows();
        let wide = self.s.ncols();
        let m = kb + filled;
        // `[R; X_b]` and `[S; C_b | y_b]`: the triangle's lower part is zero.
        for j in 0..kb {
            for i in 0..kb {
                block.a[(i, j)] = if i <= j { self.r[(i, j)] } else { 0.0 };
            }
        }
        for j in 0..wide {
            for i in 0..kb {
                block.rhs[(i, j)] = self.s[(i, j)];
            }
        }
        let mut a = block.a.as_mut().subrows_mut(0, m);
        let mut rhs = block.rhs.as_mut().subrows_mut(0, m);
        if kb > 0 {
            // What `Mat::qr` does (the same block size, sequential), in place: the Householder
            // basis stays below the triangle, which the application reads as unit-triangular.
            let bs = factor::recommended_block_size::<f64>(m, kb);
            let mut coeff = Mat::<f64>::zeros(bs, kb.min(m));
            let req = StackReq::any_of(&[
                factor::qr_in_place_scratch::<f64>(m, kb, bs, Par::Seq, Default::default()),
                householder::apply_block_householder_sequence_transpose_on_the_left_in_place_scratch::<f64>(
                    m,
                    bs,
                    wide,
                ),
            ]);
            if self.mem_bytes < req.unaligned_bytes_required() {
                self.mem = MemBuffer::new(req);
                self.mem_bytes = req.unaligned_bytes_required();
            }
            factor::qr_in_place(
                a.as_mut(),
                coeff.as_mut(),
                Par::Seq,
                MemStack::new(&mut self.mem),
                Default::default(),
            );
            householder::apply_block_householder_sequence_transpose_on_the_left_in_place_with_conj(
                a.as_ref(),
                coeff.as_ref(),
                Conj::No,
                rhs.as_mut(),
                Par::Seq,
                MemStack::new(&mut self.mem),
            );
            for j in 0..kb {
                for i in 0..=j {
                    self.r[(i, j)] = a[(i, j)];
                }
            }
            for j in 0..wide {
                for i in 0..kb {
                    self.s[(i, j)] = rhs[(i, j)];
                }
            }
        }
        let y = wide - 1;
        self.ee += (kb..m).map(|i| rhs[(i, y)].powi(2)).sum::<f64>();
        let rest = rhs.as_ref().subrows(kb, filled);
        let widest = self
            .groups
            .iter()
            .map(|g| g.slots.len() + 1)
            .max()
            .unwrap_or(0);
        if self.gathered.nrows() < filled || self.gathered.ncols() < widest {
            self.gathered = Mat::zeros(filled.max(self.gathered.nrows()), widest);
        }
        for g in &mut self.groups {
            // The group's columns side by side, `y` last: one product for the group.
            let w = g.slots.len() + 1;
            let mut part = self.gathered.as_mut().submatrix_mut(0, 0, filled, w);
            for (c, &slot) in g.slots.iter().chain([&y]).enumerate() {
                part.as_mut().col_mut(c).copy_from(rest.col(slot));
            }
            let part = part.as_ref();
            // The Gram matrix is symmetric: only its lower triangle is summed (half the flops
            // of the full product); [`accumulate`] mirrors it once at the end.
            triangular::matmul(
                g.gram.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Add,
                part.transpose(),
                BlockStructure::Rectangular,
                part,
                BlockStructure::Rectangular,
                1.0,
                Par::Seq,
            );
        }
        block.filled = 0;
    }

    /// Folds another worker's state in: its triangle and coordinates are rows like any others.
    fn merge(&mut self, other: State) {
        let kb = self.r.nrows();
        let wide = self.s.ncols();
        let mut block = Block::new(kb, wide, kb);
        for i in 0..kb {
            for j in 0..kb {
                block.a[(kb + i, j)] = other.r[(i, j)];
            }
            for j in 0..wide {
                block.rhs[(kb + i, j)] = other.s[(i, j)];
            }
        }
        block.filled = kb;
        self.fold(&mut block);
        self.ee += other.ee;
        for (g, o) in self.groups.iter_mut().zip(&other.groups) {
            g.gram += &o.gram;
        }
    }
}

/// Runs the pass: `visit` hands every row (design row `x`, observation `y`) to its callback.
/// Rows are gathered `block` at a time and folded on `threads` threads (1: on this one).
pub(super) fn accumulate<E>(
    split: &Split,
    width: usize,
    block: usize,
    threads: usize,
    visit: impl FnOnce(&mut dyn FnMut(&[f64], f64)) -> Result<(), E>,
) -> Result<Accumulated, E> {
    let kb = split.base.len();
    let wide = split.candidates.len() + 1;
    let block = block.max(kb + wide).max(1);
    let groups = groups(split);
    let mut norms2 = vec![0.0; width];
    let mut rows = 0usize;
    let threads = threads.max(1);
    let new_block = || Block::new(kb, wide, block);
    let mut fill = |buf: &mut Block, x: &[f64], y: f64| {
        // One element per column: the block is column-major for the factorisation, and the
        // `kb + wide` columns' current cache lines stay in cache while consecutive rows fill them.
        let at = kb + buf.filled;
        for (c, &j) in split.base.iter().enumerate() {
            buf.a[(at, c)] = x.get(j).copied().unwrap_or(0.0);
        }
        for (c, &j) in split.candidates.iter().enumerate() {
            buf.rhs[(at, c)] = x.get(j).copied().unwrap_or(0.0);
        }
        buf.rhs[(at, wide - 1)] = y;
        for (n, v) in norms2.iter_mut().zip(x) {
            *n += v * v;
        }
        buf.filled += 1;
        rows += 1;
    };
    let state = if threads == 1 {
        let mut state = State::new(split, &groups);
        let mut buf = new_block();
        visit(&mut |x, y| {
            fill(&mut buf, x, y);
            if buf.full() {
                state.fold(&mut buf);
            }
        })?;
        state.fold(&mut buf);
        state
    } else {
        std::thread::scope(|scope| -> Result<State, E> {
            let (back, spare) = mpsc::channel::<Block>();
            let mut to = Vec::with_capacity(threads);
            let mut handles = Vec::with_capacity(threads);
            for _ in 0..threads {
                // A rendezvous: a block is handed over when its worker is free, so only the
                // workers' blocks and the one being filled exist (a queue of one per worker held
                // two more, 55 MB at 10⁵ poses of the 5-axis example, and was no faster).
                let (tx, rx) = mpsc::sync_channel::<Block>(0);
                let back = back.clone();
                let groups = &groups;
                handles.push(scope.spawn(move || {
                    let mut state = State::new(split, groups);
                    for mut b in rx {
                        state.fold(&mut b);
                        let _ = back.send(b);
                    }
                    state
                }));
                to.push(tx);
            }
            let mut sent = 0usize;
            let mut buf = new_block();
            let mut send = |buf: &mut Block| {
                let next = spare.try_recv().unwrap_or_else(|_| new_block());
                let full = std::mem::replace(buf, next);
                // A worker only drops its end by panicking, which the join below carries on.
                let _ = to[sent % threads].send(full);
                sent += 1;
            };
            let visited = visit(&mut |x, y| {
                fill(&mut buf, x, y);
                if buf.full() {
                    send(&mut buf);
                }
            });
            if buf.filled > 0 {
                send(&mut buf);
            }
            drop(to);
            let mut merged: Option<State> = None;
            for h in handles {
                let part = match h.join() {
                    Ok(part) => part,
                    Err(e) => std::panic::resume_unwind(e),
                };
                match &mut merged {
                    None => merged = Some(part),
                    Some(m) => m.merge(part),
                }
            }
            visited?;
            Ok(merged.unwrap_or_else(|| State::new(split, &groups)))
        })?
    };
    let mut groups = state.groups;
    for g in &mut groups {
        for j in 0..g.gram.ncols() {
            for i in 0..j {
                g.gram[(i, j)] = g.gram[(j, i)];
            }
        }
    }
    Ok(Accumulated {
        base: split.base.clone(),
        r: state.r,
        s: state.s,
        groups,
        ee: state.ee,
        norms: norms2.iter().map(|v| v.sqrt()).collect(),
        rows,
    })
}

impl Accumulated {
    /// Takes in the groups of a later pass over the same rows (its slot `i` is this pass's
    /// `slot_of[i]`), so that [`Accumulated::factor`] can join their columns.
    pub fn include(&mut self, later: Accumulated, slot_of: &[usize]) {
        for g in later.groups {
            let mut order: Vec<(usize, usize)> = g
                .slots
                .iter()
                .enumerate()
                .filter_map(|(i, &s)| slot_of.get(s).map(|&t| (t, i)))
                .collect();
            if order.len() != g.slots.len() {
                continue;
            }
            order.sort_unstable();
            // The group's matrix in the ascending order of this pass's slots, `y` last.
            let from: Vec<usize> = order
                .iter()
                .map(|&(_, i)| i)
                .chain([g.slots.len()])
                .collect();
            let gram = Mat::from_fn(from.len(), from.len(), |a, b| g.gram[(from[a], from[b])]);
            self.groups.push(Group {
                slots: order.into_iter().map(|(t, _)| t).collect(),
                gram,
            });
        }
    }

    /// A factor `F` of `[X | C | y]` (`FᵀF` its Gram matrix) for the candidate columns `slots`:
    /// the base's columns, the slots', `y` last. Only inner products of its columns are
    /// meaningful: the rows below the base's are a symmetric square root of the remainders'
    /// Gram matrix, not a triangle. `None` when no group of the pass summed the products of
    /// all of `slots` (a pair of candidates no comparison named).
    pub fn factor(&self, slots: &[usize]) -> Option<Mat<f64>> {
        let kb = self.r.nrows();
        let q = slots.len();
        let k = kb + q + 1;
        let y = self.s.ncols() - 1;
        let group = self
            .groups
            .iter()
            .find(|g| slots.iter().all(|&s| g.at(s).is_some()))?;
        // Where each of `slots` (and, last, `y`) is in the group's matrix.
        let inside: Vec<usize> = slots
            .iter()
            .map(|&s| group.at(s).unwrap_or(0))
            .chain([group.slots.len()])
            .collect();
        let at = |c: usize| slots.get(c).copied().unwrap_or(y);
        let mut f = Mat::zeros(k, k);
        for a in 0..kb {
            for b in a..kb {
                f[(a, b)] = self.r[(a, b)];
            }
            for c in 0..=q {
                f[(a, kb + c)] = self.s[(a, at(c))];
            }
        }
        // The root of the unit-diagonal Gram matrix, scaled back (`F = √(D⁻¹GD⁻¹) D`): the
        // columns' sizes differ by many orders (units, and `y` a residual), and an eigenvalue
        // solver's rounding is relative to the largest.
        let gram = |a: usize, b: usize| group.gram[(inside[a], inside[b])];
        let d: Vec<f64> = (0..=q)
            .map(|a| gram(a, a).max(0.0).sqrt())
            .map(|v| if v > 0.0 { v } else { 1.0 })
            .collect();
        let sub = Mat::from_fn(q + 1, q + 1, |a, b| gram(a, b) / (d[a] * d[b]));
        let root = root(&sub);
        for a in 0..=q {
            for b in 0..=q {
                f[(kb + a, kb + b)] = root[(a, b)] * d[b];
            }
        }
        Some(f)
    }
}

/// The symmetric square root of a Gram matrix (negative rounding in its eigenvalues as zero).
fn root(g: &Mat<f64>) -> Mat<f64> {
    let n = g.nrows();
    let sym = nalgebra::DMatrix::from_fn(n, n, |a, b| 0.5 * (g[(a, b)] + g[(b, a)]));
    let eig = sym.symmetric_eigen();
    let mut out = Mat::zeros(n, n);
    for (l, &v) in eig.eigenvalues.iter().enumerate() {
        let s = v.max(0.0).sqrt();
        if s == 0.0 {
            continue;
        }
        for a in 0..n {
            for b in 0..n {
                out[(a, b)] += eig.eigenvectors[(a, l)] * s * eig.eigenvectors[(b, l)];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Rows of 4 base columns (the last twice the first: a deficient base, as a minimum-norm
    /// fit has), 3 candidate columns (the second a combination of base columns) and y, in units
    /// far apart; the design holds a column the pass leaves out.
    fn rows(n: usize) -> Vec<(Vec<f64>, f64)> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        (0..n)
            .map(|_| {
                let b: Vec<f64> = (0..3).map(|_| rng.random_range(-1.0..1.0)).collect();
                let c0 = 1e3 * rng.random_range(-1.0..1.0);
                let c2 = 1e-4 * rng.random_range(-1.0..1.0);
                let x = vec![
                    b[0],
                    1e-3 * b[1],
                    5.0,
                    c0,
                    2.0 * b[0],
                    b[1] - 0.5 * b[2],
                    rng.random_range(-1.0..1.0),
                    c2,
                    1e2 * b[2],
                ];
                let y = 1e-6 * (b[0] + c0 * 1e-3 + rng.random_range(-1.0..1.0));
                (x, y)
            })
            .collect()
    }

    fn run(data: &[(Vec<f64>, f64)], split: &Split, block: usize, threads: usize) -> Accumulated {
        accumulate::<()>(split, 9, block, threads, |push| {
            for (x, y) in data {
                push(x, *y);
            }
            Ok(())
        })
        .expect("no error")
    }

    /// The factor of the base with any candidate columns squares to the Gram matrix of those
    /// columns of the rows, to rounding relative to each column's size; a column the base spans
    /// has a remainder of rounding; the same threads give the same bits, other threads the
    /// same products.
    #[test]
    fn a_candidates_factor_has_the_products_of_its_columns() {
        let data = rows(1000);
        let split = Split {
            base: vec![0, 1, 2, 4, 8],
            candidates: vec![3, 5, 7],
            groups: vec![vec![2, 0, 1], vec![1]],
        };
        let gram = |a: usize, b: usize| -> f64 {
            let col = |r: &(Vec<f64>, f64), c: usize| if c == 9 { r.1 } else { r.0[c] };
            data.iter().map(|r| col(r, a) * col(r, b)).sum()
        };
        for threads in [1, 2] {
            let acc = run(&data, &split, 64, threads);
            assert_eq!(acc.rows, 1000);
            // The group inside the larger one is not summed again.
            assert_eq!(acc.groups.len(), 1);
            let again = run(&data, &split, 64, threads);
            assert_eq!(acc.groups[0].gram, again.groups[0].gram);
            assert_eq!(acc.s, again.s);
            for slots in [vec![0usize], vec![1, 2], vec![2, 0, 1]] {
                let f = acc.factor(&slots).expect("summed together");
                let design: Vec<usize> = split
                    .base
                    .iter()
                    .copied()
                    .chain(slots.iter().map(|&s| split.candidates[s]))
                    .chain([9])
                    .collect();
                assert_eq!(f.nrows(), design.len());
                for (a, &da) in design.iter().enumerate() {
                    for (b, &db) in design.iter().enumerate() {
                        let got: f64 = (0..f.nrows()).map(|i| f[(i, a)] * f[(i, b)]).sum();
                        let want = gram(da, db);
                        let size = (gram(da, da) * gram(db, db)).sqrt();
                        assert!(
                            (got - want).abs() <= 1e-11 * size,
                            "threads {threads} slots {slots:?} ({da}, {db}): {got} against {want}"
                        );
                    }
                }
            }
            // Slot 1 is `b1 − b2/2`: in the base's span, nothing of it remains.
            let g = &acc.groups[0].gram;
            assert!(g[(1, 1)].sqrt() < 1e-13 * gram(5, 5).sqrt(), "{g:?}");
        }
    }

    /// Candidates summed apart give each its own products, the same bits as summed together
    /// in one group; two of them are refused together until a later pass sums them, whose
    /// products then join theirs.
    #[test]
    fn products_are_summed_within_groups_only() {
        let data = rows(700);
        let apart = Split {
            base: vec![0, 1, 2, 4, 8],
            candidates: vec![3, 5, 7],
            groups: vec![vec![0], vec![1, 2]],
        };
        let together = Split {
            groups: vec![vec![0, 1, 2]],
            ..apart.clone()
        };
        let mut a = run(&data, &apart, 64, 2);
        let t = run(&data, &together, 64, 2);
        assert_eq!(a.groups.len(), 2);
        for slots in [vec![0usize], vec![1, 2], vec![2], vec![1]] {
            let fa = a.factor(&slots).expect("summed");
            let ft = t.factor(&slots).expect("summed");
            let close = fa.col_iter().zip(ft.col_iter()).all(|(x, y)| {
                x.iter()
                    .zip(y.iter())
                    .all(|(p, q)| (p - q).abs() <= 1e-12 * (p.abs() + q.abs() + 1e-300))
            });
            assert!(close, "{slots:?}");
        }
        assert!(a.factor(&[0, 1]).is_none());
        assert!(a.factor(&[2, 0]).is_none());
        // A later pass over the candidate columns 7 and 3 alone (its slots 0 and 1 are this
        // pass's 2 and 0): the pair is then joined.
        let later = Split {
            base: apart.base.clone(),
            candidates: vec![7, 3],
            groups: vec![vec![0, 1]],
        };
        a.include(run(&data, &later, 64, 2), &[2, 0]);
        let joined = a.factor(&[2, 0]).expect("joined by the later pass");
        let whole = t.factor(&[2, 0]).expect("summed");
        for (x, y) in joined.col_iter().zip(whole.col_iter()) {
            for (p, q) in x.iter().zip(y.iter()) {
                assert!(
                    (p - q).abs() <= 1e-11 * (p.abs() + q.abs() + 1e-300),
                    "{p} {q}"
                );
            }
        }
    }
}
