//! `kin bench MACHINE`: poses per second of the interpreter, the JIT and (for the 5-axis
//! example) a hand-written evaluator, and the compile time, measured in one run and printed with
//! their ratios. A measurement, not a test: see `kin_bench`.

use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

use kin_bench::{measure, Options};

use crate::load::{self, Failed};

pub fn run(path: &Path, poses: usize, seconds: f64, color: bool) -> ExitCode {
    Failed::exit(bench(path, poses, seconds, color))
}

fn bench(path: &Path, poses: usize, seconds: f64, color: bool) -> Result<(), Failed> {
    if poses == 0 || !(seconds.is_finite() && seconds > 0.0) {
        eprintln!("error: --poses must be at least 1 and --seconds positive");
        return Err(Failed::USAGE);
    }
    // Problems in the machine are reported as every command reports them.
    load::machine(path, None, color)?;
    let source = std::fs::read_to_string(path).map_err(|e| {
        eprintln!("error: cannot read `{}`: {e}", path.display());
        Failed::USAGE
    })?;
    let options = Options {
        poses,
        time: Duration::from_secs_f64(seconds),
        ..Options::default()
    };
    eprintln!(
        "measuring {} (about {:.0} s)…",
        path.display(),
        seconds * 21.0 + 0.5
    );
    match measure(&source, &options) {
        Ok(figures) => {
            print!("{figures}");
            Ok(())
        }
        Err(e) => {
            eprintln!("error: {e}");
            Err(Failed::INPUT)
        }
    }
}
