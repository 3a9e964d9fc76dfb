//! The 5-axis example as the C ABI benchmarks (`capi`, `casadi`) set it up: the model compiled
//! from `examples/milling_5axis.kin`, 1 000 sampled poses, one β, the C ABI's model and rows,
//! and the best-of-rounds rate they time everything with. Shared through `#[path]`.

use std::ptr::null_mut;
use std::time::{Duration, Instant};

use kin_capi::{kin_model as CModel, kin_model_compile, kin_rows, KIN_OK};
use kin_model::jit::StateRows;
use kin_model::states::States;
use kin_model::Model;

pub const POSES: usize = 1000;

pub struct Setup {
    pub source: String,
    pub model: Model,
    pub states: States,
    pub beta: Vec<f64>,
    /// The machine's non-linear parameter values, as the hand-written evaluator takes them.
    pub nonlinear: Vec<f64>,
}

pub fn setup() -> Setup {
    let path = format!(
        "{}/../../examples/milling_5axis.kin",
        env!("CARGO_MANIFEST_DIR")
    );
    let source = std::fs::read_to_string(path).expect("example");
    let model = Model::compile(&source).expect("compiles");
    let n = model.coefficients();
    let states = States::sample(model.machine(), POSES, 1);
    let beta = (0..n).map(|j| 1e-6 * ((j % 7) as f64 - 3.0)).collect();
    let nonlinear = model.machine().nonlinear.iter().map(|p| p.value).collect();
    Setup {
        source,
        model,
        states,
        beta,
        nonlinear,
    }
}

/// The example compiled through the C ABI, with β bound once (`kin_model_set_beta`) when
/// given; the caller frees it (`kin_model_free`).
pub fn c_model(source: &str, beta: Option<&[f64]>) -> *mut CModel {
    let mut out = null_mut();
    // SAFETY: a valid source and out pointer; no error buffer.
    let code = unsafe {
        kin_model_compile(
            source.as_ptr().cast(),
            source.len(),
            &mut out,
            null_mut(),
            0,
        )
    };
    assert_eq!(code, KIN_OK);
    if let Some(beta) = beta {
        // SAFETY: a live model and β of its length.
        let bound = unsafe { kin_capi::kin_model_set_beta(out, beta.as_ptr(), beta.len()) };
        assert_eq!(bound, KIN_OK);
    }
    out
}

/// The C ABI's view of `rows` (which must outlive every use of it).
pub fn c_rows(rows: &StateRows) -> kin_rows {
    kin_rows {
        n_rows: rows.len(),
        q: rows.q.as_ptr(),
        n_q: rows.q.len(),
        inputs: rows.inputs.as_ptr(),
        n_inputs: rows.inputs.len(),
        lags: rows.lags.as_ptr(),
        n_lags: rows.lags.len(),
        dirs: rows.dirs.as_ptr(),
        n_dirs: rows.dirs.len(),
        time: rows.time.as_ptr(),
        n_time: rows.time.len(),
        tool: rows.tool.as_ptr(),
        n_tool: rows.tool.len(),
    }
}

/// Poses per second of `f` over all poses, best of 5 rounds of about `budget / 5`.
pub fn rate(budget: Duration, mut f: impl FnMut()) -> f64 {
    f();
    let mut best: f64 = 0.0;
    for _ in 0..5 {
        let start = Instant::now();
        let mut rounds = 0u32;
        while start.elapsed() < budget / 5 {
            f();
            rounds += 1;
        }
        best = best.max(f64::from(rounds) * POSES as f64 / start.elapsed().as_secs_f64());
    }
    best
}
