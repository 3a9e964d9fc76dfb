//! Loading what every command needs: a compiled machine with its bound parameters, and
//! measurement files. Problems are printed here, located in the user's file.

use std::path::Path;

use kin_compiler::{bind_params, compile, Compiled, Diagnostic};
use kin_runtime::data::{self, Observations, ReadOptions};

use crate::render;

/// Why a command stopped, as its exit code; the message has been printed already.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Failed(pub u8);

impl Failed {
    /// The user's machine, parameters or data are wrong (diagnostics were printed).
    pub const INPUT: Failed = Failed(1);
    /// The command line or the file system: a missing file, an unwritable output, bad options.
    pub const USAGE: Failed = Failed(2);

    pub fn exit(result: Result<(), Failed>) -> std::process::ExitCode {
        match result {
            Ok(()) => std::process::ExitCode::SUCCESS,
            Err(Failed(code)) => std::process::ExitCode::from(code),
        }
    }
}

fn read_text(path: &Path) -> Result<String, Failed> {
    std::fs::read_to_string(path).map_err(|e| {
        eprintln!("error: cannot read `{}`: {e}", path.display());
        Failed::USAGE
    })
}

fn report(path: &Path, source: &str, diagnostics: &[Diagnostic], color: bool) {
    let mut stderr = std::io::stderr().lock();
    let _ = render::human(
        &path.display().to_string(),
        source,
        diagnostics,
        color,
        &mut stderr,
    );
}

/// Compiles a machine and binds `params` (a `params { … }` file) if given.
pub fn machine(path: &Path, params: Option<&Path>, color: bool) -> Result<Compiled, Failed> {
    let source = read_text(path)?;
    machine_source(path, &source, params, color)
}

/// As [`machine`], from the text of `path` already read: what was compiled is exactly the text
/// the caller holds (`--apply` compares it with the file before writing).
pub fn machine_source(
    path: &Path,
    source: &str,
    params: Option<&Path>,
    color: bool,
) -> Result<Compiled, Failed> {
    let out = compile(source);
    report(path, source, &out.diagnostics, color);
    let Some(mut compiled) = out.compiled else {
        eprintln!("{}: the machine has errors", path.display());
        return Err(Failed::INPUT);
    };
    if let Some(p) = params {
        let mut text = read_text(p)?;
        // A FIT.json carries its fitted values as a `params` block.
        if text.trim_start().starts_with('{') {
            match serde_json::from_str::<serde_json::Value>(&text)
                .ok()
                .and_then(|v| v.get("params")?.as_str().map(str::to_string))
            {
                Some(params) => text = params,
                None => {
                    eprintln!(
                        "error: `{}` is JSON but not a fit report with `params`",
                        p.display()
                    );
                    return Err(Failed::INPUT);
                }
            }
        }
        let diagnostics = bind_params(&mut compiled.machine, &text);
        report(p, &text, &diagnostics, color);
        if diagnostics.iter().any(Diagnostic::is_error) {
            return Err(Failed::INPUT);
        }
    }
    if compiled.machine.beta.is_empty() {
        compiled.machine.beta = vec![0.0; compiled.machine.coefficients.len()];
    }
    Ok(compiled)
}

/// Reads a fit report (`FIT.json`, written by `kin fit -o`).
pub fn fit_report(path: &Path) -> Result<kin_runtime::fit::report::FitReport, Failed> {
    let text = read_text(path)?;
    serde_json::from_str(&text).map_err(|e| {
        eprintln!(
            "error: `{}` is not a fit report written by `kin fit -o`: {e}",
            path.display()
        );
        Failed::INPUT
    })
}

/// Reads a measurement file (or, with `poses`, a file of poses whose observed columns may be
/// absent), skipping the columns named in `ignore`.
pub fn observations(
    path: &Path,
    compiled: &Compiled,
    poses: bool,
    ignore: &[String],
) -> Result<Observations, Failed> {
    let options = ReadOptions {
        poses,
        ignore: ignore.to_vec(),
    };
    data::read_file(path, &compiled.machine, &options).map_err(|e| {
        eprintln!("error: {e}");
        match e {
            data::ReadError::Io { .. } => Failed::USAGE,
            data::ReadError::Invalid { problems, .. } => {
                let unknown: Vec<&str> = problems
                    .iter()
                    .filter_map(|p| match p {
                        data::Problem::UnknownColumn { name, .. } => Some(name.as_str()),
                        _ => None,
                    })
                    .collect();
                if !unknown.is_empty() {
                    eprintln!(
                        "help: a column kin should not read can be skipped: --ignore {}",
                        unknown.join(",")
                    );
                }
                Failed::INPUT
            }
        }
    })
}

/// Parses `0.3um`, `0.3 um` or `2urad` into SI, checking the dimension.
pub fn quantity(text: &str, dim: kin_compiler::units::Dim, what: &str) -> Result<f64, String> {
    let text = text.trim();
    let split = text
        .find(|c: char| {
            !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E')
        })
        .unwrap_or(text.len());
    let (num, unit) = text.split_at(split);
    let value: f64 = num
        .parse()
        .map_err(|_| format!("{what}: `{text}` does not start with a number"))?;
    let unit = kin_compiler::units::Unit::parse(unit.trim())
        .map_err(|e| format!("{what}: {e} in `{text}`"))?;
    if unit.dim != dim {
        return Err(format!(
            "{what}: `{text}` is {}, expected {}",
            unit.dim.describe(),
            dim.describe()
        ));
    }
    Ok(unit.as_difference().to_si(value))
}
