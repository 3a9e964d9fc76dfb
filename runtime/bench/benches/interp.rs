//! Interpreter throughput: poses per second for the error alone and for the error plus its
//! full β-Jacobian, on every bundled example (the 5-axis mill is the JIT's reference).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use kin_model::interp::Interpreter;
use kin_model::states::States;

const POSES: usize = 1000;

fn machine(name: &str) -> kin_compiler::ir::Machine {
    let path = format!("{}/../../examples/{name}.kin", env!("CARGO_MANIFEST_DIR"));
    let src = std::fs::read_to_string(path).expect("example");
    kin_compiler::compile(&src)
        .compiled
        .expect("compiles")
        .machine
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("interpreter");
    group.throughput(Throughput::Elements(POSES as u64));
    for name in ["milling_5axis", "bridge_cmm", "robot_6axis"] {
        let m = machine(name);
        let n = m.coefficients.len();
        let states = States::sample(&m, POSES, 1);
        let beta: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 7) as f64 - 3.0)).collect();
        let mut it = Interpreter::new(&m).expect("interpreter");
        let mut jac = vec![0.0; 6 * n];
        let mut err = [0.0; 6];
        group.bench_with_input(
            BenchmarkId::new("error+jacobian", format!("{name} ({n} coefficients)")),
            &(),
            |b, _| {
                b.iter(|| {
                    for r in 0..POSES {
                        it.error_and_jacobian(&states.get(r), &beta, &mut err, &mut jac)
                            .expect("eval");
                    }
                    std::hint::black_box(&jac);
                })
            },
        );
        group.bench_with_input(
            BenchmarkId::new("error", format!("{name} ({n} coefficients)")),
            &(),
            |b, _| {
                b.iter(|| {
                    for r in 0..POSES {
                        std::hint::black_box(it.error(&states.get(r), &beta).expect("eval"));
                    }
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
