//! Load time of a one-million-row point file (3 axes + ex ey ez), the size a long automated
//! measurement campaign produces. The target is about a second in release mode.

use std::fmt::Write as _;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use kin_compiler::ir::Machine;
use kin_runtime::data::{read_file, Observations, ReadOptions};

const ROWS: usize = 1_000_000;

/// A 3-axis CMM: the reader only needs the axis names and the default units.
fn machine() -> Machine {
    let src = "machine bench {
        task measure
        units { length mm, error um }
        axis Y prismatic along y range 0 mm .. 1000 mm
        axis X prismatic along x range 0 mm .. 1000 mm
        axis Z prismatic along z range 0 mm .. 1000 mm
        tool chain {
            Y moving
            X moving
            Z moving
            tool probe
        }
    }";
    kin_compiler::compile(src)
        .compiled
        .expect("the bench machine compiles")
        .machine
}

/// Positions on a grid with sub-micrometre digits and errors of a few micrometres, written the
/// way a CMM's export writes them.
fn generate(path: &PathBuf) -> u64 {
    let mut text = String::with_capacity(ROWS * 48);
    text.push_str("# generated for the load benchmark\nX,Y,Z,ex,ey,ez\n");
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut noise = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for i in 0..ROWS {
        let x = (i % 100) as f64 * 8.0 + noise() * 1e-3;
        let y = (i / 100 % 100) as f64 * 6.0 + noise() * 1e-3;
        let z = -((i / 10_000) as f64) * 4.0 + noise() * 1e-3;
        let _ = writeln!(
            text,
            "{x:.4},{y:.4},{z:.4},{:.3},{:.3},{:.3}",
            noise() * 5.0,
            noise() * 5.0,
            noise() * 5.0
        );
    }
    if let Err(e) = std::fs::write(path, &text) {
        panic!("cannot write {}: {e}", path.display());
    }
    text.len() as u64
}

fn load(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("kin-bench-data-{}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        panic!("{e}");
    }
    let path = dir.join("points_1m.csv");
    let bytes = generate(&path);
    let m = machine();
    let options = ReadOptions::default();
    let mut group = c.benchmark_group("data");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(20));
    group.throughput(Throughput::Bytes(bytes));
    group.bench_function("read 1M point rows", |b| {
        b.iter(|| match read_file(black_box(&path), &m, &options) {
            Ok(Observations::Points(p)) => assert_eq!(p.len(), ROWS),
            Ok(_) => panic!("expected a point file"),
            Err(e) => panic!("{e}"),
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, load);
criterion_main!(benches);
