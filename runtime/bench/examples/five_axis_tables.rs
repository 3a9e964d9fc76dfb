//! Prints the hand-written evaluator's tables of `examples/milling_5axis.kin` as JSON on
//! standard output: what `runtime/bench/casadi/five_axis.py` builds its CasADi model of the same
//! machine from (`runtime/bench/casadi/run.sh` runs both).

use kin_bench::baseline_5axis::{Baseline, Trig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = format!(
        "{}/../../examples/milling_5axis.kin",
        env!("CARGO_MANIFEST_DIR")
    );
    let source = std::fs::read_to_string(&path)?;
    let model = kin_model::Model::compile(&source).map_err(|e| format!("{path}: {e}"))?;
    let baseline = Baseline::new(model.machine(), Trig::Exact)?;
    println!("{}", serde_json::to_string_pretty(&baseline.tables())?);
    Ok(())
}
