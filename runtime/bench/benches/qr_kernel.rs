//! The streaming QR's update of a triangle by a block of rows, `[R; B] → R'` (n = 174 columns,
//! the 5-axis example's `[X | y]`), against a GEMM `BᵀB` of the block's shape in the same run,
//! as CPU time of the thread: `StreamingQr` (rows pushed one by one, structured update), the
//! previous fold (faer's `Mat::qr` of the stacked matrix, allocated per block), faer's
//! `qr_in_place` on a preallocated stacked matrix at several block sizes, and the rates of the
//! matrix products the structured update is made of.
//!
//! ```text
//! cargo bench -p kin-bench --bench qr_kernel -- [ROWS …]   # default 1024 4096 16384
//! QRK_ONLY=1   only StreamingQr and the products
//! ```
use std::hint::black_box;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::qr::no_pivoting::factor::{qr_in_place, qr_in_place_scratch, QrParams};
use faer::{Auto, Mat, Par, Spec};

/// CPU seconds of the calling thread (zero where the scheduler's figure cannot be read, as
/// off Linux: the rates then print as infinite rather than the bench failing).
fn cpu() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .unwrap_or(0.0)
        * 1e-9
}

fn time(mut f: impl FnMut()) -> f64 {
    f();
    let mut reps = 1;
    loop {
        let c0 = cpu();
        for _ in 0..reps {
            f();
        }
        let t = cpu() - c0;
        if t > 0.6 {
            return t / reps as f64;
        }
        reps *= 2;
    }
}

fn main() {
    let n = 174;
    let rows: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let rows = if rows.is_empty() {
        vec![1024, 4096, 16384]
    } else {
        rows
    };
    println!(
        "load {}",
        std::fs::read_to_string("/proc/loadavg").unwrap_or_else(|_| "unknown\n".into())
    );
    for &b in &rows {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(b as u64);
        let blk = Mat::from_fn(b, n, |_, _| rng.random_range(-1.0..1.0));
        let flops = 2.0 * b as f64 * (n * n) as f64;
        let g = time(|| {
            let mut c = Mat::<f64>::zeros(n, n);
            faer::linalg::matmul::matmul(
                c.as_mut(),
                faer::Accum::Add,
                blk.transpose(),
                blk.as_ref(),
                1.0,
                Par::Seq,
            );
            black_box(c);
        });
        println!("b {b}: GEMM BᵀB {:.1} GF/s", flops / g / 1e9);
        let mut r0 = blk.get(..n, ..).qr().thin_R().to_owned();
        for i in 0..n {
            for j in 0..i {
                r0[(i, j)] = 0.0;
            }
        }
        // current fold
        let only = std::env::var("QRK_ONLY").is_ok();
        let t = if only {
            0.0
        } else {
            time(|| {
                let stacked =
                    Mat::from_fn(
                        n + b,
                        n,
                        |i, j| if i < n { r0[(i, j)] } else { blk[(i - n, j)] },
                    );
                let qr = stacked.qr();
                let t = qr.thin_R();
                black_box(Mat::from_fn(
                    n,
                    n,
                    |i, j| if j >= i { t[(i, j)] } else { 0.0 },
                ));
            })
        };
        println!("  current fold: {:.2}× GEMM time", t / g);
        // The streaming QR (structured kernel) through its public API, rows pushed one by one.
        let rowsv: Vec<Vec<f64>> = (0..b)
            .map(|i| (0..n).map(|j| blk[(i, j)]).collect())
            .collect();
        let mut acc = kin_estimate::fit::StreamingQr::new(n - 1, b);
        let t = time(|| {
            for r in &rowsv {
                acc.push(&r[..n - 1], r[n - 1]);
            }
        });
        black_box(acc.rows());
        println!("  StreamingQr (push + tpqr): {:.2}× GEMM time", t / g);
        {
            use faer::linalg::matmul::matmul;
            use faer::Accum;
            for (nb, nc) in [(32usize, 142usize), (16, 158), (48, 126), (8, 8), (16, 16)] {
                let v = blk.get(.., ..nb);
                let c = blk.get(.., nb..nb + nc);
                let f = 2.0 * b as f64 * (nb * nc) as f64;
                let mut w = Mat::<f64>::zeros(nb, nc);
                let ta =
                    time(|| matmul(w.as_mut(), Accum::Replace, v.transpose(), c, 1.0, Par::Seq));
                let mut vt = Mat::<f64>::zeros(nb, b);
                let tb = time(|| {
                    vt.copy_from(v.transpose());
                    matmul(w.as_mut(), Accum::Replace, vt.as_ref(), c, 1.0, Par::Seq)
                });
                let mut wt = Mat::<f64>::zeros(nc, nb);
                let tc =
                    time(|| matmul(wt.as_mut(), Accum::Replace, c.transpose(), v, 1.0, Par::Seq));
                let mut cc = c.to_owned();
                let td = time(|| matmul(cc.as_mut(), Accum::Add, v, w.as_ref(), -1e-9, Par::Seq));
                println!(
                    "  nb {nb} nc {nc}: VᵀC {:.1} GF/s, packed Vᵀ {:.1}, CᵀV {:.1}; C −= VW {:.1}",
                    f / ta / 1e9,
                    f / tb / 1e9,
                    f / tc / 1e9,
                    f / td / 1e9
                );
            }
        }
        if std::env::var("QRK_ONLY").is_ok() {
            continue;
        }
        let mut st = Mat::<f64>::zeros(n + b, n);
        for bs in [8usize, 16, 32, 48, 64, 96] {
            for thr in [48 * 48, usize::MAX] {
                let mut h = Mat::<f64>::zeros(bs, n);
                let mut params: QrParams = <QrParams as Auto<f64>>::auto();
                params.blocking_threshold = thr;
                let mut buf = MemBuffer::new(qr_in_place_scratch::<f64>(
                    n + b,
                    n,
                    bs,
                    Par::Seq,
                    Spec::new(params),
                ));
                let t = time(|| {
                    st.get_mut(..n, ..).copy_from(&r0);
                    st.get_mut(n.., ..).copy_from(&blk);
                    qr_in_place(
                        st.as_mut(),
                        h.as_mut(),
                        Par::Seq,
                        MemStack::new(&mut buf),
                        Spec::new(params),
                    );
                    black_box(&st);
                });
                println!(
                    "  faer in place, bs {bs}, blocking_threshold {thr}: {:.2}×",
                    t / g
                );
            }
        }
    }
}
