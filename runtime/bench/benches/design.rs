//! The design issue's speed figure: choosing 50 of 10 000 candidate units for a 100-coefficient
//! model (`design::select`: greedy start, DETMAX, Fedorov swaps, six starts). A unit is one
//! point observed in three components (three rows), so that 50 units can determine 100
//! coefficients. Rows are random normal: a stand-in for a model's Jacobian rows.
//!
//! ```text
//! cargo bench -p kin-bench --bench design
//! ```

use std::time::Instant;

use kin_estimate::design::{information, select, Unit};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn main() {
    let (candidates, p, n) = (10_000usize, 100usize, 50usize);
    let mut rng = rand::rngs::StdRng::seed_from_u64(14);
    let normal = Normal::new(0.0, 1.0).unwrap_or_else(|_| unreachable!());
    let units: Vec<Unit> = (0..candidates)
        .map(|_| Unit {
            rows: (0..3 * p).map(|_| normal.sample(&mut rng)).collect(),
            observations: 3,
        })
        .collect();
    let mut steps = 0usize;
    let t = Instant::now();
    let s = select(&units, n, p, || steps += 1).unwrap_or_else(|e| panic!("{e}"));
    let elapsed = t.elapsed();
    let logdet: f64 = information(&units, &s.chosen, p)
        .cholesky()
        .map_or(f64::NAN, |c| {
            c.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum()
        });
    println!(
        "design: {n} of {candidates} units (3 rows, {p} coefficients): {:.2} s, {} exchanges, \
         {steps} steps, log det {logdet:.3}",
        elapsed.as_secs_f64(),
        s.exchanges
    );
}
