//! How long `kin_compiler::compile` takes on each bundled example (`examples/*.kin`, read at
//! run time, so new examples are measured without touching this file). The target: checking a
//! 5-axis model takes well under 10 ms.
//!
//! `cargo bench --bench check` (add `-- --warm-up-time 1 --measurement-time 3` for a quick run).
//! Two groups: `parse` (text → syntax tree only) and `check` (the whole of `compile`: parse,
//! resolve, check the error models, lower to IR).

use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use kin_compiler::compile;

fn examples() -> Vec<(String, String)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let mut out: Vec<(String, String)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "kin"))
        .filter_map(|p| {
            let text = std::fs::read_to_string(&p).ok()?;
            Some((p.file_stem()?.to_string_lossy().into_owned(), text))
        })
        .collect();
    out.sort();
    out
}

fn bench(c: &mut Criterion) {
    let examples = examples();
    assert!(!examples.is_empty(), "no examples/*.kin to benchmark");
    // One line per example, so the figures can be read against the size of each model.
    for (name, source) in &examples {
        let out = compile(source);
        let errors = out.diagnostics.iter().filter(|d| d.is_error()).count();
        match &out.compiled {
            Some(c) => eprintln!(
                "{name}: {} bytes, {} axes, {} error models, {} coefficients",
                source.len(),
                c.machine.axes.len(),
                c.machine.errors.len(),
                c.machine.coefficients.len()
            ),
            None => eprintln!(
                "{name}: {} bytes, does not check ({errors} errors); timing the failing check",
                source.len()
            ),
        }
    }

    let mut parse = c.benchmark_group("parse");
    for (name, source) in &examples {
        parse.throughput(Throughput::Bytes(source.len() as u64));
        parse.bench_with_input(BenchmarkId::from_parameter(name), source, |b, s| {
            b.iter(|| kin_compiler::syntax::parse_file(black_box(s)).is_ok())
        });
    }
    parse.finish();

    let mut check = c.benchmark_group("check");
    for (name, source) in &examples {
        check.throughput(Throughput::Bytes(source.len() as u64));
        check.bench_with_input(BenchmarkId::from_parameter(name), source, |b, s| {
            b.iter(|| compile(black_box(s)))
        });
    }
    check.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
