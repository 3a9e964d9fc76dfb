//! The Householder QR of a triangle with a block of rows under it, `[R; B] = Q [R'; 0]`, done
//! without ever touching the zeros of `R` (LAPACK calls this shape "triangular-pentagonal",
//! `dtpqrt`).
//!
//! Column `j`'s reflector only has to annihilate `B[:, j]` into `R[j, j]`: every row of `R`
//! below `j` is already zero in that column. So the reflector is `e_j` in the triangle and a
//! vector `v_j` in the block, and applying it costs `4·b` flops per column it touches; the
//! whole update is `2·b·n²` flops, the Householder count of the block alone. A general QR of
//! the stacked `(n + b) × n` matrix does the same on the triangle's zeros too and, for the
//! sizes a fit streams, ran at a third of the GEMM rate. Here the columns are taken in panels;
//! a panel's reflectors are combined into `I − Y T Yᵀ` (compact WY, `T` upper triangular, the
//! forward accumulation of LAPACK's `dlarft`) and applied to the columns right of it by two
//! matrix products, so almost all flops run at the GEMM rate. Inside a panel the same is done
//! recursively, down to a few columns treated one at a time.
//!
//! The arithmetic is that of Householder QR (backward stable, any rank): no normal equations.
//! It depends only on the shapes, so the same rows give the same bits.

use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::{Accum, MatMut, MatRef, Par};

/// Columns whose reflectors are combined and applied together to the rest of the matrix.
const PANEL: usize = 32;
/// Below this width a panel is factored a column at a time.
const LEAF: usize = 8;

/// Scratch memory of [`update`], kept between blocks so a stream allocates once.
#[derive(Debug, Default, Clone)]
pub(super) struct Work {
    tau: Vec<f64>,
    /// `n × n`, column-major: for every range of columns the recursion factors, its
    /// reflectors' `T` is the diagonal block of the range.
    t: Vec<f64>,
    z: Vec<f64>,
    w: Vec<f64>,
}

/// `r` (`n × n`, column-major, upper triangular; entries below the diagonal are left alone
/// and must be zero) := the triangle of `[r; b]`. `b` holds `rows` rows of `n` columns,
/// column-major with column stride `ldb`; it is overwritten with the reflectors.
pub(super) fn update(
    r: &mut [f64],
    n: usize,
    b: &mut [f64],
    ldb: usize,
    rows: usize,
    work: &mut Work,
) {
    if rows == 0 || n == 0 {
        return;
    }
    work.tau.clear();
    work.tau.resize(n, 0.0);
    work.t.clear();
    work.t.resize(n * n, 0.0);
    let mut m = Mats { r, n, b, ldb, rows };
    let mut j0 = 0;
    while j0 < n {
        let j1 = (j0 + PANEL).min(n);
        factor(&mut m, j0, j1, work);
        apply(&mut m, j0, j1, j1, n, work);
        j0 = j1;
    }
}

/// The two matrices being updated.
struct Mats<'a> {
    r: &'a mut [f64],
    n: usize,
    b: &'a mut [f64],
    ldb: usize,
    rows: usize,
}

impl Mats<'_> {
    fn b_cols(&self, c0: usize, c1: usize) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice_with_stride(
            &self.b[c0 * self.ldb..],
            self.rows,
            c1 - c0,
            self.ldb,
        )
    }

    /// `dst` (`(a1 − a0) × (c1 − c0)`, column-major) := or += `B[:, a0..a1]ᵀ B[:, c0..c1]`,
    /// the products of the block's columns the panels' `T` and updates are made of.
    fn cross(&self, a: (usize, usize), c: (usize, usize), dst: &mut [f64], accum: Accum) {
        let (ra, rc) = (self.b_cols(a.0, a.1), self.b_cols(c.0, c.1));
        matmul(
            MatMut::from_column_major_slice_mut(dst, ra.ncols(), rc.ncols()),
            accum,
            ra.transpose(),
            rc,
            1.0,
            Par::Seq,
        );
    }
}

/// Factors columns `j0..j1`, applying each reflector only to the others of that range, and
/// leaves their `T` in `work.t`.
fn factor(m: &mut Mats, j0: usize, j1: usize, work: &mut Work) {
    if j1 - j0 <= LEAF {
        for j in j0..j1 {
            reflect(m, j, j1, work);
        }
        leaf_t(m, j0, j1, work);
        return;
    }
    let mid = j0 + (j1 - j0) / 2;
    factor(m, j0, mid, work);
    apply(m, j0, mid, mid, j1, work);
    factor(m, mid, j1, work);
    join_t(m, j0, mid, j1, work);
}

/// The reflector of column `j` (stored in `b[:, j]`, its scalar in `tau[j]`), applied to
/// columns `j + 1 .. c1`.
fn reflect(m: &mut Mats, j: usize, c1: usize, work: &mut Work) {
    let (ldb, rows, n) = (m.ldb, m.rows, m.n);
    let (left, right) = m.b.split_at_mut((j + 1) * ldb);
    let v = &mut left[j * ldb..j * ldb + rows];
    // faer's norm scales against overflow and underflow.
    let xnorm = MatRef::from_column_major_slice(v, rows, 1).norm_l2();
    let alpha = m.r[j * n + j];
    if xnorm == 0.0 {
        // Nothing under the diagonal: the identity (τ = 0).
        work.tau[j] = 0.0;
        return;
    }
    let beta = -alpha.hypot(xnorm).copysign(alpha);
    let tau = (beta - alpha) / beta;
    // |α − β| = |α| + |β| ≥ ‖x‖ > 0: the reciprocal is finite. Multiplying by it, as LAPACK's
    // `dlarfg` does, instead of dividing every entry: a division costs several multiplies.
    let scale = 1.0 / (alpha - beta);
    for x in v.iter_mut() {
        *x *= scale;
    }
    m.r[j * n + j] = beta;
    work.tau[j] = tau;
    let k = c1 - j - 1;
    if k == 0 {
        return;
    }
    // w = τ (R[j, c] + vᵀ B[:, c]) for the other columns, then R[j, c] −= w and B −= v wᵀ: one
    // row-vector product and one rank-one update through faer, whose kernels use the widest
    // vectors the CPU has.
    let v = MatRef::from_column_major_slice(v, rows, 1);
    let mut c = MatMut::from_column_major_slice_with_stride_mut(right, rows, k, ldb);
    work.w.clear();
    work.w.resize(k, 0.0);
    for (i, w) in work.w.iter_mut().enumerate() {
        *w = m.r[(j + 1 + i) * n + j];
    }
    let mut w = MatMut::from_row_major_slice_mut(&mut work.w, 1, k);
    matmul(w.rb_mut(), Accum::Add, v.transpose(), c.rb(), 1.0, Par::Seq);
    for (i, w) in work.w.iter_mut().enumerate() {
        *w *= tau;
        m.r[(j + 1 + i) * n + j] -= *w;
    }
    matmul(
        c.rb_mut(),
        Accum::Add,
        v,
        MatRef::from_row_major_slice(&work.w, 1, k),
        -1.0,
        Par::Seq,
    );
}

/// `T` of the reflectors `j0..j1` from scratch (LAPACK's `dlarft`, forward):
/// `H_{j0} ⋯ H_{j1−1} = I − Y T Yᵀ`, `T[i, i] = τᵢ`, `T[..i, i] = −τᵢ T[..i, ..i] Y[:, ..i]ᵀ yᵢ`.
/// The reflectors' parts in the triangle are distinct unit vectors, so `YᵀY = VᵀV` of their
/// parts in the block.
fn leaf_t(m: &Mats, j0: usize, j1: usize, work: &mut Work) {
    let (nb, n) = (j1 - j0, m.n);
    work.z.clear();
    work.z.resize(nb * nb, 0.0);
    m.cross((j0, j1), (j0, j1), &mut work.z, Accum::Replace);
    let (t, z, tau) = (&mut work.t, &work.z, &work.tau[j0..j1]);
    // T[a, b] of the range at t[(j0 + b)·n + j0 + a].
    let at = |a: usize, b: usize| (j0 + b) * n + j0 + a;
    for i in 0..nb {
        t[at(i, i)] = tau[i];
        for l in 0..i {
            let s: f64 = (l..i).map(|c| t[at(l, c)] * z[i * nb + c]).sum();
            t[at(l, i)] = -tau[i] * s;
        }
    }
}

/// `T` of `j0..j1` from those of `j0..mid` and `mid..j1`:
/// `T = [T₁  −T₁ (V₁ᵀV₂) T₂; 0  T₂]` (only the off-diagonal block is new).
fn join_t(m: &Mats, j0: usize, mid: usize, j1: usize, work: &mut Work) {
    let (n1, n2, n) = (mid - j0, j1 - mid, m.n);
    work.z.clear();
    work.z.resize(n1 * n2, 0.0);
    m.cross((j0, mid), (mid, j1), &mut work.z, Accum::Replace);
    let t = &mut work.t;
    let z = &mut work.z;
    // z := z T₂ (T₂ upper: column c of the product reads columns ≤ c; right to left).
    for c in (0..n2).rev() {
        for a in 0..n1 {
            let s: f64 = (0..=c)
                .map(|l| z[l * n1 + a] * t[(mid + c) * n + mid + l])
                .sum();
            z[c * n1 + a] = s;
        }
    }
    // T₁₂ = −T₁ z (T₁ upper: row a reads rows ≥ a).
    for c in 0..n2 {
        for a in 0..n1 {
            let s: f64 = (a..n1)
                .map(|l| t[(j0 + l) * n + j0 + a] * z[c * n1 + l])
                .sum();
            t[(mid + c) * n + j0 + a] = -s;
        }
    }
}

/// Applies `(I − Y T Yᵀ)ᵀ` of the reflectors `j0..j1` (with `work.t` their `T`) to columns
/// `c0..c1` of `[R; B]`.
fn apply(m: &mut Mats, j0: usize, j1: usize, c0: usize, c1: usize, work: &mut Work) {
    let (nb, nc, n) = (j1 - j0, c1 - c0, m.n);
    if nc == 0 {
        return;
    }
    // W = Yᵀ C = R[j0..j1, c0..c1] + Vᵀ B[:, c0..c1].
    work.w.clear();
    work.w.resize(nb * nc, 0.0);
    for c in 0..nc {
        let from = (c0 + c) * n + j0;
        work.w[c * nb..(c + 1) * nb].copy_from_slice(&m.r[from..from + nb]);
    }
    m.cross((j0, j1), (c0, c1), &mut work.w, Accum::Add);
    // Z = Tᵀ W (T upper triangular: a triangular product, vectorised by faer), then
    // R[j0..j1, c0..c1] −= Z; B[:, c0..c1] −= V Z.
    work.z.clear();
    work.z.resize(nb * nc, 0.0);
    triangular::matmul(
        MatMut::from_column_major_slice_mut(&mut work.z, nb, nc),
        BlockStructure::Rectangular,
        Accum::Replace,
        MatRef::from_column_major_slice_with_stride(&work.t[j0 * n + j0..], nb, nb, n).transpose(),
        BlockStructure::TriangularLower,
        MatRef::from_column_major_slice(&work.w, nb, nc),
        BlockStructure::Rectangular,
        1.0,
        Par::Seq,
    );
    std::mem::swap(&mut work.w, &mut work.z);
    for c in 0..nc {
        let from = (c0 + c) * n + j0;
        for (x, w) in m.r[from..from + nb].iter_mut().zip(&work.w[c * nb..]) {
            *x -= w;
        }
    }
    let (ldb, rows) = (m.ldb, m.rows);
    let (vpart, cpart) = m.b.split_at_mut(c0 * ldb);
    let v = MatRef::from_column_major_slice_with_stride(&vpart[j0 * ldb..], rows, nb, ldb);
    let c = MatMut::from_column_major_slice_with_stride_mut(cpart, rows, nc, ldb);
    matmul(
        c,
        Accum::Add,
        v,
        MatRef::from_column_major_slice(&work.w, nb, nc),
        -1.0,
        Par::Seq,
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;
    use rand::{Rng, SeedableRng};

    /// RᵀR of the update equals R₀ᵀR₀ + BᵀB, for widths around the panel and leaf sizes,
    /// with a zero column and a rank-deficient block.
    #[test]
    fn the_update_keeps_the_gram_matrix() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        for (n, rows) in [
            (1, 5),
            (7, 3),
            (8, 40),
            (9, 40),
            (33, 100),
            (70, 300),
            (97, 64),
        ] {
            let r0 = Mat::from_fn(n, n, |i, j| {
                if j >= i {
                    rng.random_range(-1.0..1.0)
                } else {
                    0.0
                }
            });
            let mut b = Mat::from_fn(rows, n, |_, _| rng.random_range(-1.0..1.0));
            if n > 3 {
                for i in 0..rows {
                    b[(i, 2)] = 0.0;
                    b[(i, n - 1)] = b[(i, 0)] - b[(i, 1)];
                }
            }
            let gram = r0.transpose() * &r0 + b.transpose() * &b;
            let mut r: Vec<f64> = (0..n * n).map(|x| r0[(x % n, x / n)]).collect();
            let ldb = rows + 3;
            let mut bs = vec![f64::NAN; ldb * n];
            for j in 0..n {
                for i in 0..rows {
                    bs[j * ldb + i] = b[(i, j)];
                }
            }
            update(&mut r, n, &mut bs, ldb, rows, &mut Work::default());
            let rm = Mat::from_fn(n, n, |i, j| if j >= i { r[j * n + i] } else { 0.0 });
            let got = rm.transpose() * &rm;
            let scale = gram.norm_max();
            assert!(
                (&got - &gram).norm_max() <= 1e-13 * scale,
                "n {n} rows {rows}"
            );
            for j in 0..n {
                for i in j + 1..n {
                    assert_eq!(r[j * n + i], 0.0, "below the diagonal");
                }
            }
        }
    }
}
