//! Streaming QR: the triangular factor of `[X | y]` accumulated block by block, so memory grows
//! with the number of columns, not of rows.
//!
//! Each block of rows is stacked under the current `R` and refactored (Householder, [`tpqr`]):
//! `QR([R; B]) = Q' R'`, and `R'ᵀR' = RᵀR + BᵀB`, so the final `R` is that of the whole matrix
//! and `R[p, p]²` is the residual sum of squares of the full least-squares problem.
//!
//! On several threads the identity is used twice. Block `i` goes to worker `i mod T`, each
//! worker keeps its own triangle of the blocks it was given, in order, and at the end the
//! workers' triangles are stacked in worker order and factored once more. Which block meets
//! which arithmetic depends only on the block size and `T`, never on timing, so a fit on `T`
//! threads gives the same bits every time; with another `T` only the rounding differs (the
//! triangles are of the same Gram matrix). While the workers factor, the calling thread
//! evaluates the next rows (the evaluator is not shared): the two overlap.
//!
//! A fit whose evaluator can be copied does better on several threads: each thread evaluates
//! and factors a share of the rows into a one-thread `StreamingQr` of its own, and the
//! triangles are merged ([`super::team`]); the worker threads here serve the other callers.
//!
//! faer's own parallelism would come with its rayon feature, which makes every faer call in
//! the process parallel by default; here the threads belong to one fit.

use std::sync::mpsc::{self, Receiver, SyncSender};
use std::sync::Mutex;
use std::thread::JoinHandle;

use faer::Mat;

use super::tpqr;

/// The parallel half: one channel and one thread per worker, and the emptied blocks coming back.
#[derive(Debug)]
struct Workers {
    to: Vec<SyncSender<(Rows, usize)>>,
    // Behind a mutex only so that a `StreamingQr` is `Sync` (a binding's object may be shared
    // between threads); `send` has `&mut self` and reaches it without locking.
    spare: Mutex<Receiver<Rows>>,
    handles: Vec<JoinHandle<Triangle>>,
    /// Blocks sent so far: the next goes to worker `sent mod T`.
    sent: usize,
}

impl Workers {
    fn start(threads: usize, k: usize) -> Workers {
        let (back, spare) = mpsc::channel();
        let mut to = Vec::with_capacity(threads);
        let mut handles = Vec::with_capacity(threads);
        for _ in 0..threads {
            // One block queued per worker: the reader never runs more than a block ahead.
            let (tx, rx) = mpsc::sync_channel::<(Rows, usize)>(1);
            let back = back.clone();
            handles.push(std::thread::spawn(move || {
                let mut r = Triangle::new(k);
                for (mut block, filled) in rx {
                    r.fold(&mut block, filled);
                    // The reader may have finished and dropped its end: nothing to return to.
                    let _ = back.send(block);
                }
                r
            }));
            to.push(tx);
        }
        Workers {
            to,
            spare: Mutex::new(spare),
            handles,
            sent: 0,
        }
    }

    /// Hands a block to its worker; returns an empty block to fill next.
    fn send(&mut self, block: Rows, filled: usize) -> Rows {
        let (rows, len) = (block.rows, block.data.len());
        let t = self.sent % self.to.len();
        self.sent += 1;
        let failed = match self.to.get(t) {
            Some(tx) => tx.send((block, filled)).is_err(),
            None => true,
        };
        if failed {
            // Only a worker that died (a bug) drops its end; `finish` reports it.
            return Rows {
                data: vec![0.0; len],
                rows,
            };
        }
        let spare = match self.spare.get_mut() {
            Ok(spare) => spare.try_recv().ok(),
            Err(_) => None,
        };
        spare.unwrap_or_else(|| Rows {
            data: vec![0.0; len],
            rows,
        })
    }

    /// The workers' triangles, stacked and factored in worker order.
    fn finish(self, k: usize) -> Triangle {
        drop(self.to);
        let mut r = Triangle::new(k);
        for h in self.handles {
            match h.join() {
                Ok(part) => r.merge(&part),
                // A worker panicked: a bug in this module, carried to the caller as it was.
                Err(e) => std::panic::resume_unwind(e),
            }
        }
        r
    }
}

/// A block of rows waiting to be folded in: `rows × k`, column-major (what [`tpqr::update`]
/// works on in place).
#[derive(Debug, Clone)]
struct Rows {
    data: Vec<f64>,
    rows: usize,
}

impl Rows {
    fn new(rows: usize, k: usize) -> Rows {
        Rows {
            data: vec![0.0; rows * k],
            rows,
        }
    }
}

/// The running triangle: `k × k`, column-major, zero below the diagonal, with the scratch
/// memory of its updates.
#[derive(Debug, Clone)]
struct Triangle {
    r: Vec<f64>,
    k: usize,
    work: tpqr::Work,
}

impl Triangle {
    fn new(k: usize) -> Triangle {
        Triangle {
            r: vec![0.0; k * k],
            k,
            work: tpqr::Work::default(),
        }
    }

    /// `self` := the triangle of `[self; block[..filled]]`; the block's rows are consumed
    /// (overwritten by reflectors).
    fn fold(&mut self, block: &mut Rows, filled: usize) {
        let filled = filled.min(block.rows);
        tpqr::update(
            &mut self.r,
            self.k,
            &mut block.data,
            block.rows,
            filled,
            &mut self.work,
        );
    }

    /// `self` := the triangle of `[self; other]`.
    fn merge(&mut self, other: &Triangle) {
        let mut rows = Rows {
            data: other.r.clone(),
            rows: self.k,
        };
        self.fold(&mut rows, self.k);
    }

    fn to_mat(&self) -> Mat<f64> {
        let k = self.k;
        Mat::from_fn(k, k, |i, j| if j >= i { self.r[j * k + i] } else { 0.0 })
    }
}

/// Rows staged before they are copied into the block.
const STAGE: usize = 32;

/// Copies the first `staged` rows of `stage` (row-major, `k` wide) into `block` from row
/// `filled` on (as many as fit); returns the rows the block then holds.
fn unstage(stage: &[f64], staged: usize, k: usize, block: &mut Rows, filled: usize) -> usize {
    let n = staged.min(block.rows.saturating_sub(filled));
    for (j, column) in block.data.chunks_exact_mut(block.rows).enumerate().take(k) {
        let dst = &mut column[filled..filled + n];
        for (s, cell) in dst.iter_mut().enumerate() {
            *cell = stage[s * k + j];
        }
    }
    filled + n
}

#[derive(Debug)]
pub struct StreamingQr {
    k: usize,
    r: Triangle,
    block: Rows,
    filled: usize,
    /// The latest rows, row-major (`STAGE × k`), copied into `block` a few at a time: written
    /// one row at a time, the column-major block would take a cache line (and, a column being
    /// `block` rows long, a page) per value.
    stage: Vec<f64>,
    staged: usize,
    rows: usize,
    norms2: Vec<f64>,
    y_sum: f64,
    threads: usize,
    /// Started at the first full block when `threads > 1`: a problem of one block is
    /// factored on the calling thread, as on one thread.
    workers: Option<Workers>,
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
    /// `columns` unknowns; rows are buffered `block` at a time; one thread.
    pub fn new(columns: usize, block: usize) -> Self {
        Self::with_threads(columns, block, 1)
    }

    /// As [`StreamingQr::new`], the blocks factored on `threads` worker threads (see the
    /// module's documentation; 0 counts as 1).
    pub fn with_threads(columns: usize, block: usize, threads: usize) -> Self {
        let k = columns + 1;
        let block = block.max(k);
        StreamingQr {
            k,
            r: Triangle::new(k),
            block: Rows::new(block, k),
            filled: 0,
            stage: vec![0.0; STAGE * k],
            staged: 0,
            rows: 0,
            norms2: vec![0.0; columns],
            y_sum: 0.0,
            threads: threads.max(1),
            workers: None,
        }
    }

    pub fn push(&mut self, x: &[f64], y: f64) {
        let k = self.k;
        let from = self.staged * k;
        if let Some(row) = self.stage.get_mut(from..from + k) {
            row.fill(0.0);
            for ((cell, v), n) in row.iter_mut().zip(x).zip(&mut self.norms2) {
                *cell = *v;
                *n += v * v;
            }
            row[k - 1] = y;
        }
        self.y_sum += y;
        self.staged += 1;
        self.rows += 1;
        if self.staged == STAGE || self.filled + self.staged == self.block.rows {
            self.filled = unstage(&self.stage, self.staged, k, &mut self.block, self.filled);
            self.staged = 0;
        }
        if self.filled == self.block.rows {
            if self.threads > 1 && self.workers.is_none() {
                self.workers = Some(Workers::start(self.threads, self.k));
            }
            self.flush();
        }
    }

    fn flush(&mut self) {
        if self.filled == 0 {
            return;
        }
        match &mut self.workers {
            Some(w) => {
                let empty = Rows::new(0, 0);
                let full = std::mem::replace(&mut self.block, empty);
                self.block = w.send(full, self.filled);
            }
            None => self.r.fold(&mut self.block, self.filled),
        }
        self.filled = 0;
    }

    pub fn finish(mut self) -> Reduced {
        self.filled = unstage(
            &self.stage,
            self.staged,
            self.k,
            &mut self.block,
            self.filled,
        );
        self.staged = 0;
        self.flush();
        let k = self.k;
        if let Some(w) = self.workers.take() {
            self.r = w.finish(k);
        }
        let r = self.r.to_mat();
        self.reduced(r)
    }

    /// Rows pushed so far.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// The triangle of every row pushed so far, the stream going on: a copy of the triangle
    /// with the pending block folded in, as [`finish`](Self::finish) would give now. `None`
    /// once worker threads hold parts of the triangle (`threads > 1` and a full block seen):
    /// those parts are only joined at the end.
    pub fn snapshot(&self) -> Option<Reduced> {
        if self.workers.is_some() {
            return None;
        }
        let mut r = self.r.clone();
        let mut block = self.block.clone();
        let filled = unstage(&self.stage, self.staged, self.k, &mut block, self.filled);
        r.fold(&mut block, filled);
        Some(self.reduced(r.to_mat()))
    }

    fn reduced(&self, r: Mat<f64>) -> Reduced {
        let k = self.k;
        // ‖y‖² is the squared norm of R's last column (RᵀR = [X y]ᵀ[X y]).
        let y_sumsq = (0..k).map(|i| r[(i, k - 1)].powi(2)).sum();
        Reduced {
            r,
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

    /// A snapshot mid-stream is what finishing there gives, bit for bit, and the stream goes
    /// on; an accumulator can be held by an object shared between threads.
    #[test]
    fn a_snapshot_is_the_finish_of_the_rows_so_far() {
        fn shared<T: Send + Sync>() {}
        shared::<StreamingQr>();
        let row = |i: usize| -> (Vec<f64>, f64) {
            let t = i as f64 * 0.37;
            (vec![1.0, t.sin(), t.cos(), t * 1e-3], (2.0 * t).sin())
        };
        let (mut a, mut b) = (StreamingQr::new(4, 16), StreamingQr::new(4, 16));
        for i in 0..50 {
            let (x, y) = row(i);
            a.push(&x, y);
            b.push(&x, y);
        }
        let snap = a.snapshot().expect("single-threaded");
        let done = b.finish();
        assert_eq!(snap.rows, 50);
        assert_eq!(snap.r, done.r);
        assert_eq!(snap.norms, done.norms);
        assert_eq!(snap.y_sumsq.to_bits(), done.y_sumsq.to_bits());
        let (x, y) = row(50);
        a.push(&x, y);
        assert_eq!(a.rows(), 51);
        assert_eq!(a.finish().rows, 51);
    }
    use rand::{Rng, SeedableRng};

    /// The structured update gives the solution faer's Householder QR of the whole matrix
    /// gives (the factorisation the stream used before), to 1e-10 relative on every
    /// coefficient: 3 000 rows of 60 columns of scales 1e-6 … 1e3, two of them nearly
    /// dependent (condition ≈ 1e4 after scaling), streamed in blocks of 256 on one thread and
    /// on two. (Two backward-stable factorisations differ by about the condition number times
    /// the rounding unit: at 1e7 the worst coefficient moved by 1e-8 relative.)
    #[test]
    fn the_solution_is_that_of_a_dense_householder_qr() {
        use super::super::solve::{solve, Solver};
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        let (m, p) = (3000, 60);
        let scale: Vec<f64> = (0..p)
            .map(|j| 10f64.powf(-6.0 + 9.0 * j as f64 / p as f64))
            .collect();
        let mut x = Mat::from_fn(m, p, |_, j| rng.random_range(-1.0..1.0) * scale[j]);
        // Two nearly dependent columns.
        for i in 0..m {
            x[(i, 7)] = x[(i, 3)] / scale[3] * scale[7] + 1e-4 * x[(i, 7)];
        }
        let truth: Vec<f64> = (0..p).map(|j| (1.0 + j as f64) / scale[j]).collect();
        let y: Vec<f64> = (0..m)
            .map(|i| {
                (0..p).map(|j| x[(i, j)] * truth[j]).sum::<f64>()
                    + 1e-3 * rng.random_range(-1.0..1.0)
            })
            .collect();
        let dense = {
            let a = Mat::from_fn(m, p + 1, |i, j| if j < p { x[(i, j)] } else { y[i] });
            let qr = a.qr();
            let t = qr.thin_R();
            let r = Mat::from_fn(p + 1, p + 1, |i, j| if j >= i { t[(i, j)] } else { 0.0 });
            Reduced {
                y_sumsq: (0..=p).map(|i| r[(i, p)].powi(2)).sum(),
                r,
                rows: m,
                norms: (0..p).map(|j| x.col(j).norm_l2()).collect(),
                y_sum: y.iter().sum(),
            }
        };
        let want = solve(&dense, Solver::Qr, 1e-10, false).expect("full rank");
        for threads in [1, 2] {
            let mut acc = StreamingQr::with_threads(p, 256, threads);
            let mut row = vec![0.0; p];
            for (i, yi) in y.iter().enumerate() {
                for (j, v) in row.iter_mut().enumerate() {
                    *v = x[(i, j)];
                }
                acc.push(&row, *yi);
            }
            let got = solve(&acc.finish(), Solver::Qr, 1e-10, false).expect("full rank");
            for (j, (a, b)) in got.beta.iter().zip(&want.beta).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-10 * b.abs(),
                    "{threads} threads, β{j}: {a} vs {b}"
                );
            }
            assert!((got.rss - want.rss).abs() <= 1e-10 * want.rss);
        }
    }

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
