//! Streaming QR: the triangular factor of `[X | y]` accumulated block by block, so memory grows
//! with the number of columns, not of rows.
//!
//! Each block of rows is stacked under the current `R` and refactored (Householder, faer):
//! `QR([R; B]) = Q' R'`, and `R'ᵀR' = RᵀR + BᵀB`, so the final `R` is that of the whole matrix
//! and `R[p, p]²` is the residual sum of squares of the full least-squares problem.

use faer::Mat;

#[derive(Debug, Clone)]
pub struct StreamingQr {
    k: usize,
    r: Mat<f64>,
    block: Mat<f64>,
    filled: usize,
    rows: usize,
    norms2: Vec<f64>,
    y_sum: f64,
}

/// The accumulated problem: `r` is `k × k` upper triangular (`k` = columns + 1, y last).
#[derive(Debug, Clone)]
pub struct Reduced {
    pub r: Mat<f64>,
    pub rows: usize,
    /// Euclidean norms of the columns of X (for unit-length scaling, thesis §3.2.2).
    pub norms: Vec<f64>,
    pub y_sum: f64,
    pub y_sumsq: f64,
}

impl Reduced {
    /// The statistics square and sum the triangle (RᵀR = [X y]ᵀ[X y], the residual sum of
    /// squares, σ̂): finite rows can still overflow there. True when every column's sum of
    /// squares is finite.
    pub fn is_finite(&self) -> bool {
        self.norms.iter().all(|v| v.is_finite())
            && (0..self.r.ncols()).all(|j| {
                (0..self.r.nrows())
                    .map(|i| self.r[(i, j)].powi(2))
                    .sum::<f64>()
                    .is_finite()
            })
    }
}

impl StreamingQr {
    /// `columns` unknowns; rows are buffered `block` at a time.
    pub fn new(columns: usize, block: usize) -> Self {
        let k = columns + 1;
        let block = block.max(k);
        StreamingQr {
            k,
            r: Mat::zeros(k, k),
            block: Mat::zeros(block, k),
            filled: 0,
            rows: 0,
            norms2: vec![0.0; columns],
            y_sum: 0.0,
        }
    }

    pub fn push(&mut self, x: &[f64], y: f64) {
        let i = self.filled;
        for (j, v) in x.iter().take(self.k - 1).enumerate() {
            self.block[(i, j)] = *v;
            if let Some(n) = self.norms2.get_mut(j) {
                *n += v * v;
            }
        }
        self.block[(i, self.k - 1)] = y;
        self.y_sum += y;
        self.filled += 1;
        self.rows += 1;
        if self.filled == self.block.nrows() {
            self.flush();
        }
    }

    fn flush(&mut self) {
        if self.filled == 0 {
            return;
        }
        let (k, b) = (self.k, self.filled);
        let stacked = Mat::from_fn(k + b, k, |i, j| {
            if i < k {
                self.r[(i, j)]
            } else {
                self.block[(i - k, j)]
            }
        });
        let qr = stacked.qr();
        let r = qr.thin_R();
        self.r = Mat::from_fn(k, k, |i, j| if j >= i { r[(i, j)] } else { 0.0 });
        self.filled = 0;
    }

    pub fn finish(mut self) -> Reduced {
        self.flush();
        let k = self.k;
        // ‖y‖² is the squared norm of R's last column (RᵀR = [X y]ᵀ[X y]).
        let y_sumsq = (0..k).map(|i| self.r[(i, k - 1)].powi(2)).sum();
        Reduced {
            r: self.r,
            rows: self.rows,
            norms: self.norms2.iter().map(|v| v.sqrt()).collect(),
            y_sum: self.y_sum,
            y_sumsq,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn streaming_r_matches_the_gram_matrix_of_all_rows() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(4);
        let (m, p) = (1000, 7);
        let rows: Vec<(Vec<f64>, f64)> = (0..m)
            .map(|_| {
                (
                    (0..p).map(|_| rng.random_range(-1.0..1.0)).collect(),
                    rng.random_range(-1.0..1.0),
                )
            })
            .collect();
        let mut acc = StreamingQr::new(p, 64);
        for (x, y) in &rows {
            acc.push(x, *y);
        }
        let red = acc.finish();
        assert_eq!(red.rows, m);
        // RᵀR must equal AᵀA for A = [X y].
        for a in 0..=p {
            for b in 0..=p {
                let col = |r: &(Vec<f64>, f64), j: usize| if j < p { r.0[j] } else { r.1 };
                let gram: f64 = rows.iter().map(|r| col(r, a) * col(r, b)).sum();
                let rtr: f64 = (0..=p).map(|i| red.r[(i, a)] * red.r[(i, b)]).sum();
                assert!(
                    (gram - rtr).abs() < 1e-9 * (1.0 + gram.abs()),
                    "({a},{b}): {gram} vs {rtr}"
                );
            }
        }
        let y2: f64 = rows.iter().map(|r| r.1 * r.1).sum();
        assert!((red.y_sumsq - y2).abs() < 1e-9 * y2);
    }
}
