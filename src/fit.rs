//! `kin fit`: least squares from measurement files, with the statistics a metrologist needs.

use kin_data::output::same_file;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use indicatif::{ProgressBar, ProgressStyle};
use kin_data::history;
use kin_estimate::fit::{self, report, DataSet, FitError, Options, Solver};
use kin_estimate::register;

use crate::load::{self, Failed};

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum SolverArg {
    Qr,
    Svd,
}

pub struct FitArgs {
    pub machine: PathBuf,
    pub data: Vec<PathBuf>,
    pub validate: Vec<PathBuf>,
    pub output: Option<PathBuf>,
    pub solver: SolverArg,
    pub tolerance: f64,
    pub min_norm: bool,
    pub stepwise: Option<f64>,
    pub enter: Option<f64>,
    pub holdout: Option<f64>,
    pub seed: u64,
    /// The instrument's stated noise: rows are weighted by it.
    pub noise: Option<fit::Noise>,
    /// `--noise FILE=Q`: a data file's own σ of positions and lengths.
    pub file_noise: Vec<(PathBuf, crate::args::Spread)>,
    /// `--noise-per-file`: estimate a σ per file where none is stated.
    pub noise_per_file: bool,
    pub engine: kin_model::engine::Engine,
    /// Threads of the fit (`--threads`); every core when `None`.
    pub threads: Option<usize>,
    /// Columns of the data files to skip unread.
    pub ignore: crate::args::DataOptions,
    pub color: bool,
}

/// The stated noise of `--noise` and `--noise-tilt`, SI, if either was given.
pub fn stated_noise(
    position: Option<&crate::args::Spread>,
    rotation: Option<&crate::args::Spread>,
) -> Option<fit::Noise> {
    (position.is_some() || rotation.is_some()).then(|| fit::Noise {
        position: position.map(|s| s.si),
        rotation: rotation.map(|s| s.si),
    })
}

pub fn run(a: FitArgs, format: crate::Format) -> ExitCode {
    Failed::exit(match format {
        crate::Format::Human => fit_command(&a).map(|_| ()),
        crate::Format::Json => fit_json(&a),
    })
}

/// `kin fit --format json`: the fit as FIT.json on standard output and nothing else there
/// (spec/json.md); the files and the history are written as by the human form, silently.
fn fit_json(a: &FitArgs) -> Result<(), Failed> {
    if let Some(out) = &a.output {
        check_outputs(out, a)?;
    }
    crate::rounds::hash_ahead(&a.data);
    let fitted = if streams(a) {
        fit_streamed(a)?
    } else {
        fit_quietly(a)?
    };
    if let Some(out) = &a.output {
        write_files(out, &fitted.report)?;
    }
    let _ = record_quietly(&a.machine, &fitted, None);
    println!("{}", to_json(&fitted.report)?);
    Ok(())
}

/// A document of spec/json.md as pretty-printed JSON.
pub fn to_json<T: serde::Serialize>(document: &T) -> Result<String, Failed> {
    serde_json::to_string_pretty(document).map_err(|e| {
        eprintln!("error: {e}");
        Failed::USAGE
    })
}

fn read_all(
    paths: &[PathBuf],
    compiled: &kin_compiler::Compiled,
    ignore: &crate::args::DataOptions,
) -> Result<Vec<DataSet>, Failed> {
    paths
        .iter()
        .map(|p| {
            Ok(DataSet {
                path: p.clone(),
                observations: load::observations(p, compiled, false, ignore)?,
            })
        })
        .collect()
}

/// A finished fit and what it was made from, for commands built on it (`diagnose`).
pub struct Fitted {
    pub source: String,
    pub compiled: kin_compiler::Compiled,
    pub files: Vec<DataSet>,
    pub options: Options,
    pub result: fit::FitResult,
    pub report: report::FitReport,
}

/// Fits, prints the summary, records the history (with a before/after comparison when the
/// model changed) and writes the report files.
pub fn fit_command(a: &FitArgs) -> Result<Fitted, Failed> {
    if let Some(out) = &a.output {
        check_outputs(out, a)?;
    }
    crate::rounds::hash_ahead(&a.data);
    let fitted = if streams(a) {
        fit_streamed(a)?
    } else {
        fit_quietly(a)?
    };
    finish(a, &fitted)?;
    Ok(fitted)
}

/// What `kin fit` does with a finished fit: writes the report files, records the history,
/// prints the summary and the comparison.
pub fn finish(a: &FitArgs, fitted: &Fitted) -> Result<(), Failed> {
    // Files first: when the reader of standard output has gone (`kin fit … | head -c1`), the
    // next print ends kin (SIGPIPE, see `main`), and the fit must already be on disk by then.
    if let Some(out) = &a.output {
        write_report(out, &fitted.report)?;
    }
    let compared = record_quietly(&a.machine, fitted, None);
    print!("{}", summary(&fitted.report));
    print!("{}", compared.unwrap_or_default());
    Ok(())
}

/// Every file a fit reads or keeps up to date next to the model: what an output must not be.
pub fn inputs(a: &FitArgs) -> Vec<PathBuf> {
    let mut v = vec![a.machine.clone(), history::path_for(&a.machine)];
    v.extend(a.data.iter().cloned());
    v.extend(a.validate.iter().cloned());
    v
}

/// Refuses, before the fit, a FIT.json (or the FIT.params beside it) that would replace an input
/// or cannot be written.
fn check_outputs(out: &Path, a: &FitArgs) -> Result<(), Failed> {
    let inputs = inputs(a);
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    if out == Path::new("-") {
        eprintln!(
            "error: -o names the FIT.json file, with FIT.params written beside it; for FIT.json \
             on standard output use --format json"
        );
        return Err(Failed::USAGE);
    }
    let params = out.with_extension("params");
    if params == out {
        eprintln!(
            "error: `{}` would be both FIT.json and FIT.params; name the output `….json`",
            out.display()
        );
        return Err(Failed::USAGE);
    }
    crate::files::check(out, &inputs)?;
    crate::files::check(&params, &inputs)
}

/// Data files together at least this large are fitted without holding their rows (see
/// [`fit::stream`]): below it the rows take less memory than a few hundred megabytes and the
/// whole-file path is as good.
const STREAM_FROM_BYTES: u64 = 64 << 20;

/// Whether `kin fit` streams the data files: large regular files (a pipe cannot be read once
/// per pass), nothing held out or validated. The machine is checked by [`fit_streamed`].
fn streams(a: &FitArgs) -> bool {
    // A stated noise weights rows by kind, which needs every kind of row the files hold
    // checked before the fit (the whole-file path does it).
    if !a.validate.is_empty() || a.holdout.is_some() || a.noise.is_some() {
        return false;
    }
    // σs per file are estimated by refitting (the whole-file path does it).
    if a.noise_per_file || !a.file_noise.is_empty() {
        return false;
    }
    // So are they when a file states its own in its header (or its header is bad: the
    // whole-file path reports it).
    let header =
        |d: &PathBuf| kin_data::data::noise::stated_noise(d).map_or(true, |n| !n.is_empty());
    if a.data.iter().any(header) {
        return false;
    }
    let mut total = 0u64;
    for path in &a.data {
        match std::fs::metadata(path) {
            Ok(meta) if meta.is_file() => total = total.saturating_add(meta.len()),
            // Not a regular file, or not there: the whole-file reader says what is wrong.
            _ => return false,
        }
    }
    total >= STREAM_FROM_BYTES
}

/// Whether the header of the file at `path` names a measured position (`px`): such a file is
/// registered, which needs it whole. Any failure to read says no (the reader reports it).
fn holds_positions(path: &Path) -> bool {
    use std::io::BufRead;
    let Ok(file) = std::fs::File::open(path) else {
        return false;
    };
    // The header is the first line that is not a comment or blank, within the first MiB.
    let reader = std::io::BufReader::new(std::io::Read::take(file, 1 << 20));
    for line in reader.lines() {
        let Ok(line) = line else { return false };
        let text = line.trim().trim_start_matches('\u{feff}');
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        return text.split([',', ';', '\t']).any(|cell| {
            let name = cell.trim().trim_matches('"');
            let name = name.split('[').next().unwrap_or(name).trim();
            kin_data::data::MEASURED.contains(&name)
        });
    }
    false
}

/// As [`fit_quietly`], reading the data files a block of rows at a time in each pass; falls
/// back to it for a machine that cannot be streamed (fitted non-linear parameters, lags).
fn fit_streamed(a: &FitArgs) -> Result<Fitted, Failed> {
    given_once(a)?;
    let source = load::model_text(&a.machine, a.color)?;
    let compiled = load::machine_source(&a.machine, &source, None, a.color)?;
    if !fit::stream::streamable(&compiled) || a.data.iter().any(|p| holds_positions(p)) {
        return fit_quietly(a);
    }
    let m = &compiled.machine;
    let options = options(a);
    let read = a.ignore.read(false);
    // The rows are not counted before the fit (that would be one more pass over the files):
    // the progress shows the rows done in each pass.
    let bar = ProgressBar::new_spinner();
    crate::warnings::hush(&bar);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} {spinner} {pos} rows")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    let mut engine = kin_model::engine::make(m, a.engine).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let mut progress = |pass: &'static str, done: usize| {
        bar.set_message(pass);
        bar.set_position(done as u64);
    };
    let streamed = fit::stream::fit(
        &compiled,
        engine.as_mut(),
        &a.data,
        &read,
        &options,
        &mut progress,
    );
    bar.finish_and_clear();
    drop(engine);
    let streamed = match streamed {
        Ok(s) => s,
        Err(FitError::Read(e)) => return Err(load::read_failed(e)),
        Err(e) => return Err(fit_failed(a, &source, e)),
    };
    let report = report::build(
        m,
        &source,
        a.engine.name(),
        &streamed.files,
        &[],
        &streamed.result,
        &options,
    );
    Ok(Fitted {
        source,
        compiled,
        files: streamed.files,
        options,
        result: streamed.result,
        report,
    })
}

fn options(a: &FitArgs) -> Options {
    let defaults = Options::default();
    Options {
        solver: match a.solver {
            SolverArg::Qr => Solver::Qr,
            SolverArg::Svd => Solver::Svd,
        },
        tolerance: a.tolerance,
        min_norm: a.min_norm,
        stepwise: a.stepwise.map(|remove| fit::Stepwise {
            remove,
            enter: a.enter,
        }),
        noise: a.noise,
        threads: a.threads.unwrap_or(defaults.threads),
        ..defaults
    }
}

/// Each data file's own σs (`--noise FILE=Q` over its `# noise:` header lines), and whether σs
/// are estimated per file: when any file states one, or with `--noise-per-file`. Without
/// either, nothing per file: the fit is the one of `--noise` alone, bit for bit.
fn per_file_noise(a: &FitArgs) -> Result<(Vec<fit::Noise>, bool), Failed> {
    for (path, _) in &a.file_noise {
        if !a.data.iter().any(|d| same_file(d, path)) {
            eprintln!(
                "error: --noise {}=…: no data file of the fit is {}",
                path.display(),
                path.display()
            );
            return Err(Failed::USAGE);
        }
    }
    let mut out = Vec::with_capacity(a.data.len());
    for d in &a.data {
        // A pipe or a missing file has no header to read here: the reader reports it.
        let header = if std::fs::metadata(d).is_ok_and(|m| m.is_file()) {
            kin_data::data::noise::stated_noise(d).map_err(|e| {
                eprintln!("error: {e}");
                Failed::INPUT
            })?
        } else {
            kin_data::data::noise::StatedNoise::default()
        };
        let flag = a
            .file_noise
            .iter()
            .rev()
            .find(|(p, _)| same_file(d, p))
            .map(|(_, s)| s.si);
        out.push(fit::Noise {
            position: flag.or(header.position),
            rotation: header.rotation,
        });
    }
    let stated = out
        .iter()
        .any(|n| n.position.is_some() || n.rotation.is_some());
    if !stated && !a.noise_per_file {
        return Ok((Vec::new(), false));
    }
    Ok((out, true))
}

/// Refuses a data file given twice (fitted and validated, or fitted twice under two
/// spellings): its rows would count twice, every standard error shrink by √2, and a validation
/// on fitted rows would look better than any new measurement.
fn given_once(a: &FitArgs) -> Result<(), Failed> {
    let all: Vec<&PathBuf> = a.data.iter().chain(&a.validate).collect();
    let fitted = a.data.len();
    for (i, p) in all.iter().enumerate() {
        let Some(j) = all[..i].iter().position(|q| same_file(q, p)) else {
            continue;
        };
        let first = all[j];
        let also = if first == *p {
            String::new()
        } else {
            format!(" (also as `{}`)", first.display())
        };
        let why = if j < fitted && i >= fitted {
            "a validation on fitted rows says nothing of new measurements"
        } else {
            "its rows would count twice and every standard error shrink by √2"
        };
        eprintln!(
            "error: `{}` is given twice{also}: {why}; give each file once",
            p.display()
        );
        return Err(Failed::USAGE);
    }
    Ok(())
}

/// Prints why a fit failed: a rank-deficient design with the invisible combinations located
/// in the model.
/// Dependent coefficients shown when a fit is refused for them (all of them with `-v`).
const SHOWN_DEPENDENCIES: usize = 5;

fn fit_failed(a: &FitArgs, source: &str, e: FitError) -> Failed {
    match e {
        FitError::RankDeficient {
            rank,
            columns,
            diagnostics,
        } => {
            // The sentence that matters first; then the first few combinations the data cannot
            // see (a 2-row file against a large model has hundreds: `-v` shows every one, and
            // `kin check --plan` summarises them per error component).
            eprintln!("error: the data determine only {rank} of {columns} parameters");
            let shown = if crate::warnings::verbose() {
                diagnostics.len()
            } else {
                diagnostics.len().min(SHOWN_DEPENDENCIES)
            };
            let mut stderr = std::io::stderr().lock();
            let _ = crate::render::human(
                &a.machine.display().to_string(),
                source,
                &diagnostics[..shown],
                a.color,
                &mut stderr,
            );
            if shown < diagnostics.len() {
                eprintln!(
                    "… and {} more coefficients the data cannot tell apart (-v shows every one; `kin check {} --plan DATA…` summarises them per error component)",
                    diagnostics.len() - shown,
                    a.machine.display()
                );
            }
            if diagnostics.is_empty() {
                // The rank decision and the analysis that names combinations differ in their
                // threshold only when the user moved it.
                eprintln!(
                    "At --tolerance {} a direction whose singular value is below that fraction of the largest counts as not determined; the analysis names no combination at its own threshold: a smaller --tolerance (default 1e-10) keeps them, or --min-norm fits the visible part.",
                    a.tolerance
                );
            } else {
                eprintln!(
                    "Remove or constrain those terms, add observations that separate them, or fit the visible part with --min-norm."
                );
            }
            Failed::INPUT
        }
        e => {
            eprintln!("error: {e}");
            Failed::INPUT
        }
    }
}

/// The fit alone: diagnostics of the inputs are printed, results are returned.
pub fn fit_quietly(a: &FitArgs) -> Result<Fitted, Failed> {
    given_once(a)?;
    let source = load::model_text(&a.machine, a.color)?;
    let compiled = load::machine_source(&a.machine, &source, None, a.color)?;
    let m = &compiled.machine;
    // The files are read on the fit's threads.
    let read = crate::args::DataOptions {
        threads: a.threads,
        ..a.ignore.clone()
    };
    let files = read_all(&a.data, &compiled, &read)?;
    let mut validate = read_all(&a.validate, &compiled, &read)?;
    let files = match a.holdout {
        Some(f) => {
            let (fitted, held) = fit::holdout(&files, f, a.seed);
            validate.extend(held);
            fitted
        }
        None => files,
    };
    let mut options = options(a);
    (options.file_noise, options.components) = per_file_noise(a)?;
    let (files, validate, registration) =
        registered(a, &source, &compiled, files, validate, &options)?;
    let total = fit::count_rows(&files) as u64;
    let bar = ProgressBar::new(2 * total);
    crate::warnings::hush(&bar);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} rows ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut engine = kin_model::engine::make(m, a.engine).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let mut progress = |pass: &'static str, done: usize| {
        bar.set_message(pass);
        bar.set_position(if pass == "residuals" {
            total + done as u64
        } else {
            done as u64
        });
    };
    let result = fit::fit(
        &compiled,
        engine.as_mut(),
        &files,
        &validate,
        &options,
        &mut progress,
    );
    bar.finish_and_clear();
    // The engine borrows the machine, which the result takes along.
    drop(engine);
    let result = match result {
        Ok(r) => r,
        Err(e) => return Err(fit_failed(a, &source, e)),
    };
    let mut report = report::build(
        m,
        &source,
        a.engine.name(),
        &files,
        &validate,
        &result,
        &options,
    );
    if let Some(reg) = &registration {
        report.registration = register::report(m, reg, &result);
    }
    Ok(Fitted {
        source,
        compiled,
        files,
        options,
        result,
        report,
    })
}

/// The fitted and the validation files, and the registration of those of absolute positions.
type Registered = (Vec<DataSet>, Vec<DataSet>, Option<register::Registration>);

/// Files of absolute positions registered jointly with the model (spec/data.md, "Absolute
/// positions"): the files as observed errors at the instrument's placement, the held-out or
/// validation files likewise, and the registration; other data as they are.
fn registered(
    a: &FitArgs,
    source: &str,
    compiled: &kin_compiler::Compiled,
    files: Vec<DataSet>,
    validate: Vec<DataSet>,
    options: &Options,
) -> Result<Registered, Failed> {
    if !register::any_absolute(&files) && !register::any_absolute(&validate) {
        return Ok((files, validate, None));
    }
    let mut engine = kin_model::engine::make(&compiled.machine, a.engine).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let spinner = ProgressBar::new_spinner();
    crate::warnings::hush(&spinner);
    spinner.set_message("registering the instrument");
    let failed = |e: register::RegisterError| match e {
        // A fit that fails (a rank-deficient design, say) says why as any fit does.
        register::RegisterError::Fit(e) => fit_failed(a, source, e),
        e => {
            eprintln!("error: {e}");
            Failed::INPUT
        }
    };
    let mut reg = register::register(compiled, engine.as_mut(), &files, options, &mut |_, _| {
        spinner.tick()
    })
    .map_err(failed)?;
    let validate = register::observe_with(engine.as_mut(), &reg, &validate).map_err(failed)?;
    spinner.finish_and_clear();
    // The registration keeps its placements; the files it turned into errors go to the fit.
    let files = std::mem::take(&mut reg.files);
    Ok((files, validate, Some(reg)))
}

/// Appends this fit to the model's history and prints how it compares with the last fit of
/// the same data (see [`record_quietly`]). `replaced` is the model's text when this revision is
/// being replaced (`--apply`), kept in the record. A history that cannot be read or written is
/// reported but does not fail the fit; damaged lines in it are skipped with a warning.
pub fn record(model: &Path, fitted: &Fitted, replaced: Option<&str>) {
    if let Some(text) = record_quietly(model, fitted, replaced) {
        print!("{text}");
    }
}

/// As [`record`], returning the comparison instead of printing it: "model revised" with the
/// before/after when the last fit of the same data (same paths and contents, same weighting)
/// was of another revision, "unchanged" when it was of this one, "new data" when these data
/// were never fitted before — fits of different data are never compared.
pub fn record_quietly(model: &Path, fitted: &Fitted, replaced: Option<&str>) -> Option<String> {
    let entry = crate::rounds::entry(fitted, replaced);
    let entries = match history::read(model) {
        Ok(h) => {
            // Once per command: `--apply` and the demo record several fits.
            static WARNED: AtomicBool = AtomicBool::new(false);
            if let Some(damage) = h.damage() {
                if !WARNED.swap(true, Ordering::Relaxed) {
                    eprintln!("warning: {damage}");
                }
            }
            h.entries
        }
        Err(e) => {
            eprintln!("warning: {e}");
            Vec::new()
        }
    };
    let compared = match history::relation(&entries, &entry.model_hash, entry.data_hash.as_deref()) {
        history::Relation::First => None,
        history::Relation::Revised(before) => Some(comparison(before, &entry)),
        history::Relation::Unchanged(before) => Some(format!(
            "\n  unchanged: the model and the data are those of the fit of {} (σ̂ {:.4} → {:.4} {})\n",
            crate::report::utc(before.time),
            before.sigma,
            entry.sigma,
            entry.error_unit
        )),
        history::Relation::NewData => Some(
            "\n  new data: these files (paths and contents) or their weighting were not fitted before; \
             the history compares fits of the same data only\n"
                .to_string(),
        ),
    };
    // Recorded before anything is printed, for the reason given in `fit_command`.
    if let Err(e) = history::append(model, &entry) {
        eprintln!("warning: {e}");
    }
    compared
}

/// "Before → after" of two revisions of a model.
pub fn comparison(before: &history::Entry, after: &history::Entry) -> String {
    let u = &after.error_unit;
    let mut s = format!(
        "\n  model revised: {} → {} parameters   σ̂ {:.4} → {:.4} {u}   RMS {:.4} → {:.4} {u} ({:+.1} %)\n",
        before.parameters,
        after.parameters,
        before.sigma,
        after.sigma,
        before.rms,
        after.rms,
        100.0 * (after.rms - before.rms) / before.rms.max(f64::MIN_POSITIVE)
    );
    for f in &after.files {
        if let Some(b) = before.files.iter().find(|b| b.path == f.path) {
            s.push_str(&format!(
                "    {:<36} RMS {:.4} → {:.4} {u}\n",
                short(&f.path, 36),
                b.rms,
                f.rms
            ));
            // Ratios to a stated noise compare alike; ratios to each fit's own estimate of a
            // file's σ (`--noise-per-file`) do not: the physical RMS does, in every case.
            // Shown where the file's RMS is not already one physical quantity: ratios, or µm
            // and µrad rows in one number.
            let shown = *u == STATED || f.units.len() > 1;
            let physical: Vec<String> = f
                .units
                .iter()
                .filter(|_| shown)
                .filter_map(|a| {
                    let was = b.units.iter().find(|x| x.unit == a.unit)?;
                    Some(format!("{:.4} → {:.4} {}", was.rms, a.rms, a.unit))
                })
                .collect();
            if !physical.is_empty() {
                s.push_str(&format!("    {:<36} RMS {}\n", "", physical.join(", ")));
            }
        }
    }
    s
}

/// Writes FIT.json and FIT.params.
pub fn write_report_files(path: &Path, rep: &report::FitReport) -> Result<(), Failed> {
    write_report(path, rep)
}

fn write_report(path: &Path, rep: &report::FitReport) -> Result<(), Failed> {
    write_files(path, rep)?;
    println!(
        "wrote {} and {}",
        path.display(),
        path.with_extension("params").display()
    );
    Ok(())
}

/// FIT.json and FIT.params, each replaced atomically.
fn write_files(path: &Path, rep: &report::FitReport) -> Result<(), Failed> {
    crate::files::write(path, to_json(rep)?.as_bytes())?;
    crate::files::write(&path.with_extension("params"), rep.params.as_bytes())
}

/// Where each file's instrument and targets were found (files of absolute positions).
fn registration_lines(r: &report::FitReport) -> String {
    let mut s = String::new();
    let three = |v: &[f64; 3], digits: usize| {
        let v: Vec<String> = v
            .iter()
            .map(|x| format!("{:.*}", digits, x + 0.0))
            .collect();
        format!("({})", v.join(", "))
    };
    for p in &r.registration {
        let (l, a) = (&p.length_unit, &p.angle_unit);
        s.push_str(&format!(
            "\n  instrument of {}: origin at {} {l}, axes turned by {} {a} (rotation vector), in the workpiece frame\n",
            short(&p.file, 36),
            three(&p.instrument_position, 4),
            three(&p.instrument_rotation, 5),
        ));
        s.push_str(&format!(
            "    standard uncertainty: {} {l} shift, {} {a} rotation of the workpiece frame\n",
            three(&p.shift_u, 4),
            three(&p.rotation_u, 6),
        ));
        for t in &p.targets {
            let name = if t.label.is_empty() {
                "target".to_string()
            } else {
                format!("target `{}`", t.label)
            };
            s.push_str(&format!(
                "    {name} at {} ± {} {l} on the tool\n",
                three(&t.offset, 4),
                three(&t.offset_u, 4),
            ));
            if let (Some(turn), Some(u)) = (&t.turn, &t.turn_u) {
                s.push_str(&format!(
                    "      turned by {} {a} (rotation vector) ± {} {a} from the tool frame\n",
                    three(turn, 5),
                    three(u, 6),
                ));
            }
        }
    }
    s
}

/// The terminal summary: the fit, a table per observation file, a table per error component.
pub fn summary(r: &report::FitReport) -> String {
    let mut s = String::new();
    let _ = &r.tilt_unit;
    let kept = r.coefficients.iter().filter(|c| c.kept).count() + r.nuisance.len();
    let selected = if kept < r.columns {
        format!(", {kept} kept by stepwise selection")
    } else {
        String::new()
    };
    s.push_str(&format!(
        "fit of `{}`: {} observations, {} parameters{selected} (rank {}, condition {:.3e}), {} degrees of freedom\n",
        r.machine, r.rows, r.columns, r.rank, r.condition, r.dof
    ));
    s.push_str(&sigma_line(r));
    s.push_str("\n  file                                   rows      RMS      max  outliers\n");
    for f in &r.files {
        s.push_str(&format!(
            "  {:<36} {:>6} {:>8.4} {:>8.4} {:>9}\n",
            short(&f.path, 36),
            f.rows,
            f.rms,
            f.max,
            f.outliers
        ));
        for c in &f.components {
            s.push_str(&format!(
                "    {:<34} {:>6} {:>8.4} {:>8.4}   {}\n",
                c.name, c.rows, c.rms, c.max, c.unit
            ));
        }
    }
    for f in &r.validation {
        s.push_str(&format!(
            "  {:<36} {:>6} {:>8.4} {:>8.4}  (validation)\n",
            short(&f.path, 36),
            f.rows,
            f.rms,
            f.max
        ));
        // Per component, each in its own unit: the file's line mixes µm and µrad where it
        // holds both.
        if f.components.len() > 1 {
            for c in &f.components {
                s.push_str(&format!(
                    "    {:<34} {:>6} {:>8.4} {:>8.4}   {}\n",
                    c.name, c.rows, c.rms, c.max, c.unit
                ));
            }
        }
    }
    s.push_str(&registration_lines(r));
    s.push_str("\n  error component   coefficients (value ± standard error)\n");
    // A component whose terms are not contiguous (`X.tx = spline(X, …)` and, after other
    // lines, `X.tx += backlash(X)`) takes several rows: each then says which terms it holds.
    let base_of = |name: &str| name.rsplit_once('[').map(|(b, _)| b.to_string());
    let mut runs: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut previous: Option<String> = None;
    for c in &r.coefficients {
        let base = base_of(&c.name);
        if base != previous {
            if let Some(b) = &base {
                *runs.entry(b.clone()).or_default() += 1;
            }
        }
        previous = base;
    }
    let mut i = 0;
    while i < r.coefficients.len() {
        let base = r.coefficients[i]
            .name
            .rsplit_once('[')
            .map(|(b, _)| b.to_string())
            .unwrap_or_default();
        let unit = r.coefficients[i].unit.clone();
        // The component's ISO 230-1 name (`EXX`), beside kin's; a constant that is a location
        // or squareness error carries that name on its own value (`(-EC0Y)`).
        let is_location = |n: &str| n.trim_start_matches('-').chars().nth(2) == Some('0');
        let iso = r.coefficients[i..]
            .iter()
            .take_while(|c| c.name.starts_with(&format!("{base}[")))
            .filter_map(|c| c.iso.as_deref())
            .find(|n| !is_location(n))
            .map(|n| format!(" {n}"))
            .unwrap_or_default();
        let mut parts = Vec::new();
        let mut forms: Vec<String> = Vec::new();
        while i < r.coefficients.len() && r.coefficients[i].name.starts_with(&format!("{base}[")) {
            let c = &r.coefficients[i];
            // `spline(X):s^2` → `spline(X)`: the term, once per row.
            let form = c.label.split(['#', ':']).next().unwrap_or("").to_string();
            if !form.is_empty() && !forms.contains(&form) {
                forms.push(form);
            }
            // Coefficients of scaled terms carry derived units: name them where they differ.
            let own = if c.unit == unit {
                String::new()
            } else {
                format!(" {}", c.unit)
            };
            if c.note.is_some() {
                // A minimum-norm fit's undetermined coefficient: no value ± error is printed.
                parts.push("undetermined".to_string());
            } else if c.kept {
                let location = match (c.iso.as_deref().filter(|n| is_location(n)), &c.robot) {
                    (Some(n), Some(r)) => format!(" ({n}, {r})"),
                    (Some(n), None) => format!(" ({n})"),
                    (None, Some(r)) => format!(" ({r})"),
                    (None, None) => String::new(),
                };
                parts.push(format!("{:.3}±{:.3}{own}{location}", c.value, c.se));
            } else {
                parts.push("—".to_string());
            }
            i += 1;
        }
        let named = format!("{base}{iso}");
        let terms = if runs.get(&base).copied().unwrap_or(0) > 1 && !forms.is_empty() {
            format!(" {}:", forms.join(" + "))
        } else {
            String::new()
        };
        s.push_str(&format!(
            "  {named:<16} [{unit}]{terms} {}\n",
            parts.join("  ")
        ));
    }
    if !r.stations.is_empty() {
        s.push_str("\n  errors at stations along their axis (value ± standard uncertainty)\n");
        for t in &r.stations {
            let iso = t
                .iso
                .as_deref()
                .map(|n| format!(" {n}"))
                .unwrap_or_default();
            let named = format!("{}{iso}", t.error);
            let values: Vec<String> = t
                .positions
                .iter()
                .zip(t.values.iter().zip(&t.u))
                .map(|(p, (v, u))| {
                    if v.is_nan() {
                        format!("{p}: undetermined")
                    } else if u.is_nan() {
                        format!("{p}: {v:.3}±?")
                    } else {
                        format!("{p}: {v:.3}±{u:.3}")
                    }
                })
                .collect();
            s.push_str(&format!(
                "  {named:<16} [{}] along {} [{}]{}: {}\n",
                t.unit,
                t.axis,
                t.position_unit,
                if t.partial {
                    " (its terms of this axis only)"
                } else {
                    ""
                },
                values.join("  ")
            ));
        }
    }
    if let Some(e) = &r.estimability {
        for g in &e.groups {
            if g.determined.is_empty() {
                s.push_str(&format!(
                    "  not determined at all: {}\n",
                    g.members.join(", ")
                ));
            } else {
                s.push_str(&format!(
                    "  cannot separate {}; determined: {}\n",
                    g.members.join(", "),
                    g.determined.join("; ")
                ));
            }
        }
    }
    for n in &r.nonlinear {
        match (&n.note, n.label.as_str()) {
            (Some(note), "undetermined") => {
                s.push_str(&format!("  {:<40} undetermined: {note}\n", n.name));
            }
            (Some(note), _) => s.push_str(&format!(
                "  {:<40} {:.4} ± {:.4} {} ({}: {note})\n",
                n.name, n.value, n.se, n.unit, n.label
            )),
            (None, _) => s.push_str(&format!(
                "  {:<40} {:.4} ± {:.4} {} ({})\n",
                n.name, n.value, n.se, n.unit, n.label
            )),
        }
    }
    // A registration's parameters are shown with its placement (above); here they would be
    // its last step, zero.
    let registered = |name: &str| name.starts_with("instrument ") || name.starts_with("target ");
    for n in r.nuisance.iter().filter(|n| !registered(&n.name)) {
        s.push_str(&format!(
            "  {:<40} {:.4} ± {:.4} {}\n",
            n.name, n.value, n.se, n.unit
        ));
    }
    if !r.outliers.is_empty() {
        s.push_str(&format!(
            "\n  {} flagged observations (|studentized| > {:.2} or Cook's distance > {:.3}):\n",
            r.outliers.len(),
            r.outlier_threshold,
            r.cook_threshold
        ));
        for o in r.outliers.iter().take(10) {
            let path = r
                .files
                .get(o.file as usize)
                .map(|f| f.path.as_str())
                .unwrap_or("?");
            s.push_str(&format!(
                "    {path}:{} {} residual {:.4} studentized {:.2} Cook {:.3}\n",
                o.line, o.component, o.residual, o.studentized, o.cook
            ));
        }
    }
    if let Some(sw) = &r.stepwise {
        let removed: usize = sw.components.iter().map(|c| c.removed.len()).sum();
        s.push_str(&format!(
            "\n  stepwise selection (remove at p > {}): {} regressors removed\n",
            sw.alpha_remove, removed
        ));
        for c in sw
            .components
            .iter()
            .filter(|c| !c.kept.is_empty() && !c.removed.is_empty())
        {
            s.push_str(&format!(
                "    {:<14} kept {}\n",
                c.component,
                c.kept.join(", ")
            ));
        }
        let gone: Vec<&str> = sw
            .components
            .iter()
            .filter(|c| c.kept.is_empty())
            .map(|c| c.component.as_str())
            .collect();
        if !gone.is_empty() {
            s.push_str(&format!("    removed entirely: {}\n", gone.join(", ")));
        }
    }
    for c in &r.constrained {
        s.push_str(&format!("  constrained (minimum norm): {c}\n"));
    }
    for c in &r.cancelling {
        let values: Vec<String> = c
            .members
            .iter()
            .filter_map(|name| r.coefficients.iter().find(|e| &e.name == name))
            .map(|e| format!("{} = {:.4} ± {:.4} {}", e.name, e.value, e.se, e.unit))
            .collect();
        s.push_str(&format!(
            "\n  warning: {} cancel each other: alone the largest moves the fitted values by {:.0} σ̂, \
             together they move them by {:.1} σ̂ — the data determine their joint effect far better \
             than either. Large values that cancel are most often an effect the model lacks, \
             imitated by alike terms: check before reading them as the machine's geometry or \
             compensating with them (`kin diagnose`)\n",
            match values.split_last() {
                Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
                _ => values.join(""),
            },
            c.largest,
            c.joint
        ));
    }
    // A set that cancels is said above; a weak one that does not is said here.
    for w in r
        .weak
        .iter()
        .filter(|w| !r.cancelling.iter().any(|c| c.members == w.members))
    {
        let members: Vec<String> = w
            .members
            .iter()
            .zip(&w.inflation)
            .filter_map(|(name, vif)| {
                let e = r.coefficients.iter().find(|e| &e.name == name)?;
                Some(format!(
                    "{} = {:.4} ± {:.4} {} (standard error {:.0}× what the data would give it alone)",
                    e.name,
                    e.value,
                    e.se,
                    e.unit,
                    vif.sqrt()
                ))
            })
            .collect();
        s.push_str(&format!(
            "\n  warning: the data barely determine {}: {} — each alone is poorly known, only \
             a combination well; `kin check MODEL --plan DATA --detail` shows which, and poses \
             that move them apart would fix it\n",
            if members.len() == 1 {
                "this coefficient"
            } else {
                "these coefficients"
            },
            members.join(", ")
        ));
    }
    s
}

/// The unit σ̂, the RMS and the max are in, as the history and the summary name it: a stated
/// noise makes them ratios to that noise.
pub fn sigma_unit(r: &report::FitReport) -> String {
    if r.weights.is_some() {
        STATED.to_string()
    } else {
        r.error_unit.clone()
    }
}

/// The unit of σ̂ of a fit weighted by a stated noise: σ̂ / σ.
pub const STATED: &str = "σ (stated)";

/// Whether the fit mixed rows of positions (or lengths) with rows of rotations.
fn mixes_kinds(r: &report::FitReport) -> bool {
    let rotation = |c: &report::ComponentSummary| c.name.starts_with("er");
    let comps = || r.files.iter().flat_map(|f| &f.components);
    comps().any(rotation) && comps().any(|c| !rotation(c))
}

/// What σ̂ of an unweighted fit of rows in both kinds of unit is, when it is that.
pub fn mixed_units(r: &report::FitReport) -> Option<String> {
    if r.weights.is_some() || !mixes_kinds(r) {
        return None;
    }
    let (u, t) = (&r.error_unit, &r.tilt_unit);
    Some(format!(
        "σ̂ mixes {u} on positions and lengths with {t} on rotations, one {t} weighing as one {u}; \
         state the instrument's noise with --noise and --noise-tilt to weigh them by it"
    ))
}

/// σ̂ of a fit with a σ per file: the overall ratios, then each file's σ (stated or
/// estimated) and its σ̂.
fn per_file_lines(r: &report::FitReport, per: &report::NoisePerFile) -> String {
    let mut out = format!(
        "  σ̂/σ = {:.4}   RMS {:.4} σ   max {:.4} σ   {}   (every row divided by its own file's σ)\n",
        r.sigma, r.rms, r.max, r2_text(r.r2)
    );
    let how = if per.converged {
        format!("{} weighted fits", per.iterations)
    } else {
        format!(
            "not settled after {} weighted fits: the σs below are the last ones",
            per.iterations
        )
    };
    out.push_str(&format!("  noise per file ({how}):\n"));
    for f in &per.files {
        let kind = match f.kind {
            fit::components::RowKind::Position => "positions",
            fit::components::RowKind::Rotation => "rotations",
        };
        let line = if f.stated {
            format!(
                "    {:<24} {kind:<9} σ = {:.4} {u} stated    σ̂ = {:.4} {u} (σ̂/σ = {:.3})",
                f.file,
                f.sigma,
                f.sigma_hat,
                f.ratio,
                u = f.unit
            )
        } else {
            format!(
                "    {:<24} {kind:<9} σ̂ = {:.4} {u} estimated",
                f.file,
                f.sigma,
                u = f.unit
            )
        };
        out.push_str(&line);
        out.push_str(&format!(
            "   {} rows, {:.1} degrees of freedom, {} outliers\n",
            f.rows, f.redundancy, f.outliers
        ));
    }
    out
}

/// σ̂, RMS and max, saying what they are: ratios to the stated noise, with its χ² test; in the
/// error unit; or, for mixed rows without a stated noise, in the error unit for positions and
/// the tilt unit for rotations (one tilt unit weighing as one error unit).
fn sigma_line(r: &report::FitReport) -> String {
    let u = &r.error_unit;
    if let Some(per) = &r.noise_per_file {
        return per_file_lines(r, per);
    }
    if let Some(w) = &r.weights {
        let mut stated = Vec::new();
        // To 12 significant digits: a stated 1 mm read back in µm is 1000.0000000000001.
        let shown = |v: f64| format!("{}", format!("{v:.11e}").parse::<f64>().unwrap_or(v));
        if let Some(p) = w.position {
            stated.push(format!(
                "{} {} on positions and lengths",
                shown(p),
                w.error_unit
            ));
        }
        if let Some(t) = w.rotation {
            stated.push(format!("{} {} on rotations", shown(t), w.tilt_unit));
        }
        let verdict = if w.p < 0.01 {
            "the residuals exceed the stated noise"
        } else {
            "consistent with the stated noise"
        };
        return format!(
            "  σ̂/σ = {:.4}   RMS {:.4} σ   max {:.4} σ   {}   (every row divided by the stated noise: {})\n  \
             χ² = {:.1} on {} degrees of freedom, p = {:.3}: {verdict}\n",
            r.sigma,
            r.rms,
            r.max,
            r2_text(r.r2),
            stated.join(", "),
            w.chi2,
            w.dof,
            w.p
        );
    }
    if let Some(note) = mixed_units(r) {
        return format!(
            "  σ̂ = {:.4}   residual RMS {:.4}   max {:.4}   {}   ({note})\n",
            r.sigma,
            r.rms,
            r.max,
            r2_text(r.r2)
        );
    }
    format!(
        "  σ̂ = {:.4} {u}   residual RMS {:.4} {u}   max {:.4} {u}   {}\n",
        r.sigma,
        r.rms,
        r.max,
        r2_text(r.r2)
    )
}

/// `R² = 0.997…`, or why there is none: data that do not vary (all zero, a perfect machine
/// simulated without noise) explain nothing, and 0/0 is not a number to print.
fn r2_text(r2: f64) -> String {
    if r2.is_finite() {
        format!("R² = {r2:.6}")
    } else {
        "R² undefined (the observations do not vary)".into()
    }
}

fn short(p: &str, n: usize) -> String {
    let count = p.chars().count();
    if count <= n {
        p.to_string()
    } else {
        format!("…{}", p.chars().skip(count - n + 1).collect::<String>())
    }
}
