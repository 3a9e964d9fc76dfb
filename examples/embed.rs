//! Embedding a `.kin` model in a Rust program with `kin_model::Model`: compile it, bind
//! parameter values, evaluate the error and its β-Jacobian at one state and over a batch, check
//! the interpreter against the JIT, evaluate from several threads, save and reload.
//!
//! ```text
//! cargo run --release --example embed [MACHINE.kin [PARAMS]]
//! ```
//!
//! Without arguments it uses `examples/bridge_cmm.kin` with the parameter values of
//! `examples/data/bridge_cmm_truth.params`. All quantities are SI (m, rad, s, K, N).

use std::error::Error;
use std::path::{Path, PathBuf};
use std::time::Instant;

use kin_model::states::States;
use kin_model::{Engine, Model, RowsBuf};

/// What the example found, for its test.
#[derive(Debug)]
pub struct Summary {
    pub coefficients: usize,
    /// Largest relative difference between the interpreter and the JIT over the batch.
    pub engines: f64,
    /// The reloaded model gives bit-identical numbers.
    pub reloaded_identical: bool,
    /// Every thread computed the same errors as the batch call.
    pub threads_agree: bool,
}

pub fn main() {
    let mut args = std::env::args().skip(1);
    let here = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let machine = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| here.join("bridge_cmm.kin"));
    let params = args.next().map(PathBuf::from).or_else(|| {
        (machine == here.join("bridge_cmm.kin")).then(|| here.join("data/bridge_cmm_truth.params"))
    });
    if let Err(e) = run(&machine, params.as_deref()) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

pub fn run(machine: &Path, params: Option<&Path>) -> Result<Summary, Box<dyn Error>> {
    // 1. Compile. Diagnostics come back as data: print them however suits the program.
    let source = std::fs::read_to_string(machine)?;
    let mut model = match Model::compile(&source) {
        Ok(model) => model,
        Err(e) => {
            for d in e.diagnostics() {
                let line = source
                    .get(..d.primary_span().start)
                    .map_or(0, |s| s.lines().count());
                eprintln!(
                    "{}:{line}: {:?}[{}]: {}",
                    machine.display(),
                    d.severity,
                    d.code,
                    d.message
                );
            }
            return Err(e.into());
        }
    };
    // 2. Bind parameter values (a `params { … }` text, e.g. the FIT.params of `kin fit`).
    if let Some(p) = params {
        model = model.with_params(&std::fs::read_to_string(p)?)?;
    }
    let n = model.coefficients();
    println!(
        "{}: {} axes, {} inputs, {} tools, {n} coefficients",
        model.machine().name,
        model.axes(),
        model.inputs(),
        model.tools()
    );

    // 3. One state: the middle of every axis range, inputs at their declared range's middle or
    //    20 °C / no rise, lags in steady state, directions positive, the first tool.
    let m = model.machine();
    let mut state = model.state();
    for (a, axis) in m.axes.iter().enumerate() {
        state.q[a] = 0.5 * (axis.range[0] + axis.range[1]);
        state.dirs[a] = 1.0;
    }
    for (i, input) in m.inputs.iter().enumerate() {
        state.inputs[i] = input
            .range
            .map_or(if input.absolute { 293.15 } else { 0.0 }, |r| {
                0.5 * (r[0] + r[1])
            });
    }
    for (l, lag) in m.lags.iter().enumerate() {
        state.lags[l] = lag.steady(state.inputs[lag.input]);
    }
    state.time = 0.0;
    let mut err = [0.0; 6];
    model.eval(&state.get(), model.beta(), &mut err)?;
    let um = err.map(|e| e * 1e6);
    println!("error at mid-range (µm, µrad): {um:.3?}");

    // 4. The error with its β-Jacobian: err = fixed + jac·β, one 6 × n block.
    let mut jac = vec![0.0; 6 * n];
    let mut err2 = [0.0; 6];
    model.eval_jacobian(&state.get(), model.beta(), &mut err2, &mut jac)?;
    let fixed: Vec<f64> = (0..6)
        .map(|r| {
            err2[r]
                - (0..n)
                    .map(|j| jac[r * n + j] * model.beta()[j])
                    .sum::<f64>()
        })
        .collect();
    println!(
        "known (fixed) part of the error (µm, µrad): {:.3?}",
        fixed.iter().map(|e| e * 1e6).collect::<Vec<_>>()
    );

    // 5. A batch: many states, rows out into buffers allocated once and reused.
    let states = States::sample(m, 10_000, 7);
    let rows = RowsBuf::from_states(&states);
    let mut errs = vec![0.0; 6 * rows.len()];
    let mut jacs = vec![0.0; 6 * n * rows.len()];
    model.eval_jacobian_rows(&rows.rows(), model.beta(), &mut errs, &mut jacs)?;
    // Timed on the second call: the first one also pays for the operating system mapping the
    // fresh buffers' pages, which reusing them avoids.
    let start = Instant::now();
    model.eval_jacobian_rows(&rows.rows(), model.beta(), &mut errs, &mut jacs)?;
    let elapsed = start.elapsed();
    println!(
        "{} states with their Jacobians in {:.2} ms ({:.0} poses/s)",
        rows.len(),
        elapsed.as_secs_f64() * 1e3,
        rows.len() as f64 / elapsed.as_secs_f64()
    );

    // 6. The interpreter, the reference, checked against the JIT on the same states.
    let mut interp = model.evaluator_with(Engine::Interp)?;
    let mut engines: f64 = 0.0;
    for r in 0..states.len().min(500) {
        let e = interp.error(&states.get(r), model.beta())?;
        for (a, b) in e.iter().zip(&errs[6 * r..6 * r + 6]) {
            engines = engines.max((a - b).abs() / a.abs().max(b.abs()).max(1e-12));
        }
    }
    println!("interpreter vs JIT: largest relative difference {engines:.1e}");

    // The error alone (a cheaper function: what a compensation needs).
    let mut only = vec![0.0; 6 * rows.len()];
    model.eval_rows(&rows.rows(), model.beta(), &mut only)?;

    // 7. One model, many threads: evaluation takes `&self` and allocates nothing.
    let threads_agree = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..4)
            .map(|t| {
                let (model, states, only) = (&model, &states, &only);
                scope.spawn(move || {
                    let mut e = [0.0; 6];
                    (t..states.len()).step_by(4).all(|r| {
                        model.eval(&states.get(r), model.beta(), &mut e).is_ok()
                            && e[..] == only[6 * r..6 * r + 6]
                    })
                })
            })
            .collect();
        handles.into_iter().all(|h| h.join().unwrap_or(false))
    });
    println!("4 threads on one model agree with the batch: {threads_agree}");

    // 8. Save (source, parameter texts, exact values) and reload: the same numbers, bit for bit.
    // One file per process and per machine: two runs in one process (the tests) must not
    // load each other's model.
    let stem = machine
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let path = std::env::temp_dir().join(format!(
        "kin-embed-example-{}-{stem}.json",
        std::process::id()
    ));
    model.save(&path)?;
    let reloaded = Model::load(&path)?;
    let _ = std::fs::remove_file(&path);
    let mut again = vec![0.0; 6 * rows.len()];
    reloaded.eval_rows(&rows.rows(), reloaded.beta(), &mut again)?;
    let reloaded_identical = again
        .iter()
        .zip(&only)
        .all(|(a, b)| a.to_bits() == b.to_bits());
    println!("saved, reloaded, identical: {reloaded_identical}");

    Ok(Summary {
        coefficients: n,
        engines,
        reloaded_identical,
        threads_agree,
    })
}
