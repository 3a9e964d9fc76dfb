//! Loading what every command needs: a compiled machine with its bound parameters, and
//! measurement files. Problems are printed here, located in the user's file.

use std::path::{Path, PathBuf};

use kin_compiler::{bind_params, compile, Compiled, Diagnostic, Span};
use kin_data::bounded_read;
use kin_data::data::{self, Observations};

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

/// The bytes of a model, parameter file or fit report, at most
/// [`bounded_read::MAX_TEXT_BYTES`]: a device or a FIFO that never ends stops there.
fn read_bytes(path: &Path) -> Result<Vec<u8>, Failed> {
    let bytes = bounded_read::read(path, bounded_read::MAX_TEXT_BYTES).map_err(|e| {
        eprintln!("error: cannot read `{}`: {e}", path.display());
        crate::errors::record("io", format!("cannot read: {e}"), Some(path), None);
        Failed::USAGE
    })?;
    crate::warnings::note(&format!(
        "read `{}` ({})",
        path.display(),
        crate::warnings::bytes(bytes.len() as u64)
    ));
    Ok(bytes)
}

/// A `.kin` file's text and what is wrong with it before it is even compiled.
pub struct Source {
    pub text: String,
    /// A located `E0001` when the file is not UTF-8; empty otherwise.
    pub diagnostics: Vec<Diagnostic>,
}

/// Reads a `.kin` file. Bytes that are not UTF-8 become a located diagnostic on the text decoded
/// with replacement characters, so they are reported (and `kin check --format json` prints them)
/// like any other error in the file.
pub fn source(path: &Path) -> Result<Source, Failed> {
    Ok(match String::from_utf8(read_bytes(path)?) {
        Ok(text) => Source {
            text,
            diagnostics: Vec::new(),
        },
        Err(e) => {
            let start = e.utf8_error().valid_up_to();
            let byte = e.as_bytes().get(start).copied().unwrap_or(0);
            // The decoded text is the same up to `start`, where U+FFFD (3 bytes) replaces the
            // first bad sequence: the span covers it.
            let text = String::from_utf8_lossy(e.as_bytes()).into_owned();
            let span = Span::new(start, start + char::REPLACEMENT_CHARACTER.len_utf8());
            let d = Diagnostic::error(
                "E0001",
                format!(
                    "syntax error: the file is not valid UTF-8 (byte 0x{byte:02x} at byte offset {start})"
                ),
                span,
            )
            .with_label("not UTF-8")
            .with_help("save the file as UTF-8");
            Source {
                text,
                diagnostics: vec![d],
            }
        }
    })
}

/// Reads a text file (a parameter file, a fit report); not UTF-8 is an error located by line
/// and column.
pub fn read_text(path: &Path) -> Result<String, Failed> {
    String::from_utf8(read_bytes(path)?).map_err(|e| {
        let start = e.utf8_error().valid_up_to();
        let before = e.as_bytes().get(..start).unwrap_or_default();
        let line_start = before
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |i| i + 1);
        let line = 1 + before.iter().filter(|&&b| b == b'\n').count();
        let column = 1 + std::str::from_utf8(before.get(line_start..).unwrap_or_default())
            .map_or(0, |s| s.chars().count());
        eprintln!(
            "error: `{}`, line {line}, column {column}: not valid UTF-8",
            path.display()
        );
        crate::errors::record("data", "not valid UTF-8", Some(path), Some((line, column)));
        Failed::INPUT
    })
}

fn report(path: &Path, source: &str, diagnostics: &[Diagnostic], color: bool) {
    for d in diagnostics.iter().filter(|d| d.is_error()) {
        let at = render::line_column(source, d.primary_span().start);
        crate::errors::record(d.code, d.message.clone(), Some(path), Some(at));
    }
    let mut stderr = std::io::stderr().lock();
    let name = path.display().to_string();
    let _ = render::human(
        &name,
        source,
        &crate::warnings::shown(&name, diagnostics),
        color,
        &mut stderr,
    );
}

/// Compiles a machine and binds `params` (a `params { … }` file) if given.
pub fn machine(path: &Path, params: Option<&Path>, color: bool) -> Result<Compiled, Failed> {
    let source = model_text(path, color)?;
    machine_source(path, &source, params, color)
}

/// The text of a `.kin` file, or its diagnostics printed (a file that is not UTF-8).
pub fn model_text(path: &Path, color: bool) -> Result<String, Failed> {
    let Source {
        text: source,
        diagnostics,
    } = self::source(path)?;
    if !diagnostics.is_empty() {
        report(path, &source, &diagnostics, color);
        eprintln!("{}: the machine has errors", path.display());
        return Err(Failed::INPUT);
    }
    Ok(source)
}

/// As [`machine`], from the text of `path` already read: what was compiled is exactly the text
/// the caller holds (`--apply` compares it with the file before writing).
pub fn machine_source(
    path: &Path,
    source: &str,
    params: Option<&Path>,
    color: bool,
) -> Result<Compiled, Failed> {
    let started = std::time::Instant::now();
    let out = compile(source);
    crate::warnings::note(&crate::warnings::timed(
        &format!("compiled `{}`", path.display()),
        started,
    ));
    // `// kin: allow` comments take effect before any warning of this model is printed.
    let mut diagnostics = crate::warnings::directives(source);
    diagnostics.extend(out.diagnostics.iter().cloned());
    report(path, source, &diagnostics, color);
    let Some(mut compiled) = out.compiled else {
        eprintln!("{}: the machine has errors", path.display());
        return Err(Failed::INPUT);
    };
    if let Some(p) = params {
        let text = read_text(p)?;
        // A FIT.json carries its fitted values as a `params` block, and names the machine and
        // the revision of its source it was fitted to.
        let (text, fit) = if text.trim_start().starts_with('{') {
            let fit = FitOrigin::of(p, &text)?;
            if fit.machine != compiled.machine.name {
                let message = format!(
                    "`{}` is a fit of machine `{}`, but `{}` is machine `{}`",
                    p.display(),
                    fit.machine,
                    path.display(),
                    compiled.machine.name
                );
                eprintln!("error: {message}");
                crate::errors::record("fit", message, Some(p), None);
                return Err(Failed::INPUT);
            }
            same_revision(
                p,
                path,
                source,
                &compiled.machine,
                &fit.model_hash,
                &fit.coefficients,
            )?;
            (fit.params.clone(), Some(fit))
        } else {
            (text, None)
        };
        let diagnostics = bind_params(&mut compiled.machine, &text);
        // In a fit report the lines are those of its `params` text, not of the JSON file.
        let name = match &fit {
            Some(_) => PathBuf::from(format!("{} (its `params` text)", p.display())),
            None => p.to_path_buf(),
        };
        report(&name, &text, &diagnostics, color);
        if diagnostics.iter().any(Diagnostic::is_error) {
            if let Some(fit) = fit {
                let now = kin_estimate::fit::report::model_hash(source);
                if fit.model_hash != now {
                    eprintln!(
                        "note: `{}` was fitted to another revision of `{}` (model hash {}; the \
                         file is now {now}): fit the model as it is now",
                        p.display(),
                        compiled.machine.name,
                        fit.model_hash
                    );
                }
            }
            return Err(Failed::INPUT);
        }
    }
    if compiled.machine.beta.is_empty() {
        compiled.machine.beta = vec![0.0; compiled.machine.coefficients.len()];
    }
    Ok(compiled)
}

/// The code of the warning that a fit was made of another text of the model with the same
/// coefficients (spec/cli.md).
pub const OTHER_TEXT: &str = "W0802";

/// Accepts a fit (`FIT.json` at `fit_path`, of the model hashed `hash` with these coefficient
/// names and labels) for the model `source` at `model_path`: as it is when the text is the one
/// fitted; with warning W0802 when only the text changed (a comment, a layout, a start value)
/// and the coefficients are the same; refused (exit 1) when the coefficients changed, since the
/// fitted values would then be read into other terms or not at all.
pub fn same_revision(
    fit_path: &Path,
    model_path: &Path,
    source: &str,
    m: &kin_compiler::ir::Machine,
    hash: &str,
    coefficients: &[(String, String)],
) -> Result<(), Failed> {
    let now = kin_estimate::fit::report::model_hash(source);
    if hash == now {
        return Ok(());
    }
    let model: Vec<(&str, &str)> = m
        .coefficients
        .iter()
        .map(|c| (c.name.as_str(), c.label.as_str()))
        .collect();
    let fitted: Vec<(&str, &str)> = coefficients
        .iter()
        .map(|(n, l)| (n.as_str(), l.as_str()))
        .collect();
    if model == fitted {
        crate::warnings::say(
            OTHER_TEXT,
            &format!(
                "`{}` was fitted to another text of `{}` (model hash {hash}, now {now}) with the same coefficients; refit if a knot, a range or an offset changed",
                fit_path.display(),
                model_path.display()
            ),
        );
        return Ok(());
    }
    let first = model
        .iter()
        .zip(&fitted)
        .position(|(a, b)| a != b)
        .unwrap_or(model.len().min(fitted.len()));
    let describe = |c: Option<&(&str, &str)>| match c {
        Some((n, l)) => format!("`{n}` ({l})"),
        None => "nothing".to_string(),
    };
    let message = format!(
        "`{}` is a fit of another revision of `{}`: the model has {} coefficients, the fit {}; the first that differs is {} in the model and {} in the fit. Fit the model as it is now (`kin fit`).",
        fit_path.display(),
        model_path.display(),
        model.len(),
        fitted.len(),
        describe(model.get(first)),
        describe(fitted.get(first))
    );
    eprintln!("error: {message}");
    crate::errors::record("fit", message, Some(fit_path), None);
    Err(Failed::INPUT)
}

/// What a `FIT.json` given as `--params` says about where its values come from.
struct FitOrigin {
    machine: String,
    model_hash: String,
    params: String,
    /// The fitted coefficients' names and labels, in order.
    coefficients: Vec<(String, String)>,
}

impl FitOrigin {
    fn of(path: &Path, text: &str) -> Result<FitOrigin, Failed> {
        let value: Option<serde_json::Value> = serde_json::from_str(text).ok();
        let field = |name: &str| {
            value
                .as_ref()
                .and_then(|v| v.get(name)?.as_str().map(str::to_string))
        };
        let coefficients = value
            .as_ref()
            .and_then(|v| v.get("coefficients")?.as_array().cloned())
            .unwrap_or_default()
            .iter()
            .map(|c| {
                let text = |k: &str| c.get(k).and_then(|x| x.as_str()).unwrap_or("").to_string();
                (text("name"), text("label"))
            })
            .collect();
        match (field("params"), field("machine"), field("model_hash")) {
            (Some(params), Some(machine), Some(model_hash)) => Ok(FitOrigin {
                machine,
                model_hash,
                params,
                coefficients,
            }),
            _ => {
                eprintln!(
                    "error: `{}` is JSON but not a fit report written by `kin fit -o` (with \
                     `machine`, `model_hash` and `params`)",
                    path.display()
                );
                crate::errors::record(
                    "fit",
                    "JSON but not a fit report written by `kin fit -o`",
                    Some(path),
                    None,
                );
                Err(Failed::INPUT)
            }
        }
    }
}

/// Reads a fit report (`FIT.json`, written by `kin fit -o`).
pub fn fit_report(path: &Path) -> Result<kin_estimate::fit::report::FitReport, Failed> {
    let text = read_text(path)?;
    serde_json::from_str(&text).map_err(|e| {
        eprintln!(
            "error: `{}` is not a fit report written by `kin fit -o`: {e}",
            path.display()
        );
        let at = (e.line() > 0).then(|| (e.line(), e.column()));
        crate::errors::record(
            "fit",
            format!("not a fit report written by `kin fit -o`: {e}"),
            Some(path),
            at,
        );
        Failed::INPUT
    })
}

/// Reads a measurement file (or, with `poses`, a file of poses whose observed columns may be
/// absent), as `data` says (columns to skip, the separator).
pub fn observations(
    path: &Path,
    compiled: &Compiled,
    poses: bool,
    data: &crate::args::DataOptions,
) -> Result<Observations, Failed> {
    let options = data.read(poses);
    let started = std::time::Instant::now();
    // Reading a large file takes seconds: a spinner says it is under way (on a terminal).
    let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let bar = (size >= LARGE_FILE).then(|| {
        crate::warnings::spinner(&format!(
            "reading `{}` ({})",
            path.display(),
            crate::warnings::bytes(size)
        ))
    });
    let read = data::read_file(path, &compiled.machine, &options);
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let obs = read.map_err(read_failed)?;
    let rows = match &obs {
        Observations::Points(p) => p.rows.len(),
        Observations::Lengths(l) => l.rows.len(),
    };
    crate::warnings::note(&crate::warnings::timed(
        &format!(
            "read {rows} rows of `{}` ({})",
            path.display(),
            crate::warnings::bytes(size)
        ),
        started,
    ));
    outside_ranges(path, &compiled.machine, &obs)?;
    Ok(obs)
}

/// W0801 for every pose of `obs` outside an axis's declared range (an error with `--strict`):
/// the model was fitted or declared there, and beyond it is extrapolation.
pub fn outside_ranges(
    path: &Path,
    machine: &kin_compiler::ir::Machine,
    obs: &Observations,
) -> Result<(), Failed> {
    let outside = data::ranges::outside(machine, obs);
    if crate::warnings::strict() && !outside.is_empty() {
        for o in &outside {
            let message = format!("{}: {o}", path.display());
            eprintln!(
                "error[{}]: {message} (--strict)",
                crate::warnings::OUTSIDE_RANGE
            );
            crate::errors::record("data", message, Some(path), None);
        }
        return Err(Failed::INPUT);
    }
    for o in outside {
        crate::warnings::say(
            crate::warnings::OUTSIDE_RANGE,
            &format!("{}: {o}", path.display()),
        );
    }
    Ok(())
}

/// The axis positions of a file of poses (`--poses`), one vector a row in the model's axis
/// order (NaN where a column is absent); `option` names the flag in the error when the file
/// is a length file, which has no single pose a row.
pub fn pose_list(
    path: &Path,
    compiled: &Compiled,
    data: &crate::args::DataOptions,
    option: &str,
) -> Result<Vec<Vec<f64>>, Failed> {
    match observations(path, compiled, true, data)? {
        Observations::Points(p) => Ok((0..p.rows.len())
            .map(|r| {
                p.pose
                    .axes
                    .iter()
                    .map(|c| c.get(r).copied().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect()),
        Observations::Lengths(_) => {
            eprintln!(
                "error: `{}`: {option} takes a point file of poses",
                path.display()
            );
            Err(Failed::INPUT)
        }
    }
}

/// Files at least this large show a spinner while they are read (some 10⁵ rows: about a
/// second).
const LARGE_FILE: u64 = 16 << 20;

/// Prints a measurement file's read error (with a hint for unknown columns) and gives the exit
/// code: 2 when the file cannot be read, 1 when what it holds is wrong.
pub fn read_failed(e: data::ReadError) -> Failed {
    eprintln!("error: {e}");
    match e {
        data::ReadError::Io { ref path, .. } | data::ReadError::TooLarge { ref path, .. } => {
            crate::errors::record("io", e.to_string(), Some(path), None);
            Failed::USAGE
        }
        data::ReadError::Invalid { problems, path, .. } => {
            for p in &problems {
                // A problem of a whole row is placed at its first column.
                let at = p
                    .location()
                    .map(|(line, column)| (line, column.unwrap_or(1)));
                crate::errors::record("data", p.to_string(), Some(&path), at);
            }
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
            eprintln!("note: the format of measurement files is described in spec/data.md");
            Failed::INPUT
        }
    }
}

/// Parses `0.3um`, `0.3 um` or `2urad` into SI, checking the dimension (the option's name is
/// added by the command-line parser).
pub fn quantity(text: &str, dim: kin_compiler::units::Dim) -> Result<f64, String> {
    let text = text.trim();
    let split = text
        .find(|c: char| {
            !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E')
        })
        .unwrap_or(text.len());
    let (num, unit) = text.split_at(split);
    let value: f64 = num
        .parse()
        .map_err(|_| format!("`{text}` does not start with a number"))?;
    if unit.trim().is_empty() {
        // A bare number would be read in some unit the user did not say: 0.3 of what?
        let example = match dim {
            kin_compiler::units::Dim::LENGTH => "um",
            kin_compiler::units::Dim::ANGLE => "urad",
            kin_compiler::units::Dim::TEMPERATURE => "degC",
            kin_compiler::units::Dim::TIME => "s",
            _ => "",
        };
        return Err(format!(
            "`{text}` has no unit ({} expected): write it with one, e.g. `{num}{example}`",
            dim.describe()
        ));
    }
    let unit =
        kin_compiler::units::Unit::parse(unit.trim()).map_err(|e| format!("{e} in `{text}`"))?;
    if unit.dim != dim {
        return Err(format!(
            "`{text}` is {}, expected {}",
            unit.dim.describe(),
            dim.describe()
        ));
    }
    Ok(unit.as_difference().to_si(value))
}
