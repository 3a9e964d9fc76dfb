//! Lag states over long time series: `States::integrate_lags` (thesis eq. 3.41–3.48, exact
//! ramp updates per run) over 10 k, 100 k and 1 M rows of a two-input, two-lag model. The
//! integration is one pass per lag and run, so the time per row must not grow with the rows:
//! criterion's throughput (rows/s) of the three sizes should agree within noise. After the
//! group, the CPU time per row of each size (this thread's, which the load of other processes
//! does not inflate as it does wall time) is printed too.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use kin_data::data::{Groups, Pose, Rows};
use kin_model::states::States;

const SRC: &str = "machine bench {
    task position
    units { length mm, error um, time min, temperature degC }
    axis X prismatic along x range 0 mm .. 500 mm
    input T_spindle : temperature rise
    input T_room : temperature rise
    tool chain { X moving  tool t at (0, 0, 0) mm }
    workpiece chain { workpiece at (0, 0, 0) mm }
    errors {
        X.tz = lag(T_spindle, tau fit 30 min) * const
        X.tx = lag(T_room, tau fit 90 min) * const
    }
}";

/// `n` rows sampled every 10 s in runs of 10 000 (a day's warm-ups), inputs a slow wave.
fn rows(n: usize) -> (Rows, Pose) {
    let time: Vec<f64> = (0..n).map(|r| (r % 10_000) as f64 * 10.0).collect();
    let spindle: Vec<f64> = time
        .iter()
        .map(|t| 5.0 * (t / 3000.0).sin().abs())
        .collect();
    let room: Vec<f64> = time.iter().map(|t| (t / 20000.0).sin()).collect();
    let rows = Rows {
        line: (1..=n).collect(),
        time: Some(time),
        run: Some(Groups {
            of_row: (0..n).map(|r| (r / 10_000) as u32).collect(),
            labels: (0..n.div_ceil(10_000)).map(|k| format!("r{k}")).collect(),
        }),
        tool: vec![0; n],
        inputs: vec![Some(spindle), Some(room)],
        ..Rows::default()
    };
    let pose = Pose {
        axes: vec![vec![250e-3; n]],
        dir: vec![None],
    };
    (rows, pose)
}

fn bench(c: &mut Criterion) {
    let m = kin_compiler::compile(SRC)
        .compiled
        .expect("the bench machine compiles")
        .machine;
    let mut group = c.benchmark_group("lag_integration");
    group.sample_size(10);
    for n in [10_000usize, 100_000, 1_000_000] {
        let (rows, pose) = rows(n);
        let mut states = States::new(&m, &rows, &pose, "").expect("states");
        let taus = [1700.0, 5100.0];
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| states.integrate_lags(&m, &rows, black_box(&taus)))
        });
    }
    group.finish();
    cpu_per_row(&m);
}

/// The CPU time this thread has used, s (Linux: utime + stime of /proc/thread-self/stat, in
/// clock ticks of 1/100 s); `None` elsewhere.
fn thread_cpu() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    // The fields after the command name, which is in parentheses and may hold spaces.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// On a loaded machine wall time counts the time other processes hold the CPU; the CPU time of
/// this thread does not. About 2·10⁷ rows per size (a second or so), the CPU time per row.
fn cpu_per_row(m: &kin_compiler::ir::Machine) {
    let taus = [1700.0, 5100.0];
    for n in [10_000usize, 100_000, 1_000_000] {
        let (rows, pose) = rows(n);
        let Ok(mut states) = States::new(m, &rows, &pose, "") else {
            return;
        };
        let passes = 20_000_000 / n;
        let Some(start) = thread_cpu() else { return };
        for _ in 0..passes {
            states.integrate_lags(m, &rows, black_box(&taus));
            black_box(&states);
        }
        let Some(end) = thread_cpu() else { return };
        println!(
            "lag_integration/{n}: CPU {:.1} ns per row ({passes} passes, {:.2} s)",
            (end - start) / (passes * n) as f64 * 1e9,
            end - start
        );
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
