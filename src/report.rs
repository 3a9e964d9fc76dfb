//! `kin report`: one self-contained HTML page about a fit — the summary, the residuals along
//! every axis, input and time, the residual spectrum and candidate effects from `kin diagnose`,
//! the history of the model's revisions, and the fitted parametric errors with their confidence
//! bands.
//!
//! Self-contained means a file a user can mail or archive: inline CSS, inline SVG (plotters),
//! no scripts, no fonts or images fetched from anywhere.

mod compensation;
use kin_estimate::curves;
pub(crate) mod plot;
mod umap;

use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_compiler::ir::{Machine, Var};
use kin_compiler::units::Unit;
use kin_data::data::{self, Observations};
use kin_data::history::{self, Entry};
use kin_diagnose::{Diagnosis, Family};
use kin_estimate::fit::report::{model_hash, FitReport, Residual};
use thiserror::Error;

use crate::load::{self, Failed};
pub use curves::var_unit;
use curves::Curves;
use plot::{Chart, Series};

#[derive(Debug, Error)]
pub enum ReportError {
    #[error("cannot read `{path}`: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("`{path}` is not a {what}: {source}")]
    Json {
        path: PathBuf,
        what: &'static str,
        source: serde_json::Error,
    },
    #[error("cannot write `{path}`: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Plot(#[from] plot::PlotError),
}

impl ReportError {
    fn exit_code(&self) -> Failed {
        match self {
            ReportError::Read { .. } | ReportError::Write { .. } => Failed::USAGE,
            ReportError::Json { .. } | ReportError::Plot(_) => Failed::INPUT,
        }
    }
}

pub struct ReportArgs {
    pub machine: PathBuf,
    pub fit: PathBuf,
    pub diagnose: Option<PathBuf>,
    /// The fitted files, in the order they were fitted; FIT.json's own paths when empty.
    pub data: Vec<PathBuf>,
    pub output: PathBuf,
    /// Columns of the data files to skip unread.
    pub ignore: crate::args::DataOptions,
    pub color: bool,
    /// Add the compensation section (a positioning machine's error before and after
    /// compensation along each axis, and what stays).
    pub compensation: bool,
}

pub fn run(a: ReportArgs) -> ExitCode {
    Failed::exit(report_command(&a))
}

fn fail(e: ReportError) -> Failed {
    eprintln!("error: {e}");
    e.exit_code()
}

/// A text input read with the size limit of every model and report (a device or a FIFO that
/// never ends stops there).
fn read_limited(path: &Path) -> std::io::Result<String> {
    use kin_data::bounded_read::{read, BoundedReadError, MAX_TEXT_BYTES};
    let bytes = read(path, MAX_TEXT_BYTES).map_err(|e| match e {
        BoundedReadError::Io(e) => e,
        other => std::io::Error::other(other),
    })?;
    String::from_utf8(bytes).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
}

fn read_json<T: serde::de::DeserializeOwned>(
    path: &Path,
    what: &'static str,
) -> Result<T, ReportError> {
    let text = read_limited(path).map_err(|source| ReportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| ReportError::Json {
        path: path.to_path_buf(),
        what,
        source,
    })
}

/// Reads FIT.json (its NaNs, written as `null`, read back as NaN: see `FitReport`).
fn read_fit(path: &Path) -> Result<FitReport, ReportError> {
    let text = read_limited(path).map_err(|source| ReportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| ReportError::Json {
        path: path.to_path_buf(),
        what: "fit report (FIT.json)",
        source,
    })
}

pub fn report_command(a: &ReportArgs) -> Result<(), Failed> {
    let history_path = history::path_for(&a.machine);
    let mut inputs: Vec<&Path> = vec![&a.machine, &a.fit, &history_path];
    inputs.extend(a.diagnose.as_deref());
    inputs.extend(a.data.iter().map(PathBuf::as_path));
    crate::files::check(&a.output, &inputs)?;
    let source = read_limited(&a.machine).map_err(|source| {
        fail(ReportError::Read {
            path: a.machine.clone(),
            source,
        })
    })?;
    let compiled = load::machine(&a.machine, None, a.color)?;
    let m = &compiled.machine;
    let fit: FitReport = read_fit(&a.fit).map_err(fail)?;
    if a.data.is_empty() {
        // The data files FIT.json names are read too (as given, and relative to FIT.json).
        let base = a.fit.parent().unwrap_or(Path::new("."));
        let recorded: Vec<PathBuf> = fit
            .files
            .iter()
            .flat_map(|f| [PathBuf::from(&f.path), base.join(&f.path)])
            .collect();
        let recorded: Vec<&Path> = recorded.iter().map(PathBuf::as_path).collect();
        crate::files::check(&a.output, &recorded)?;
    }
    let diagnosis: Option<Diagnosis> = match &a.diagnose {
        Some(p) => Some(read_json(p, "diagnosis (DIAGNOSE.json)").map_err(fail)?),
        None => None,
    };
    let fitted: Vec<(String, String)> = fit
        .coefficients
        .iter()
        .map(|c| (c.name.clone(), c.label.clone()))
        .collect();
    load::same_revision(&a.fit, &a.machine, &source, m, &fit.model_hash, &fitted)?;
    let mut notes = Vec::new();
    if model_hash(&source) != fit.model_hash {
        notes.push(format!(
            "{} was fitted with another revision of the model (hash {}; the file is now {}). The curves below use the model as it is now.",
            a.fit.display(),
            fit.model_hash,
            model_hash(&source)
        ));
    }
    if let Some(d) = &diagnosis {
        if d.model_hash != fit.model_hash {
            notes.push(format!("the diagnosis was made for another revision of the model (hash {}) than the fit ({}).", d.model_hash, fit.model_hash));
        }
    }
    let data = load_data(m, &fit, &a.fit, &a.data, &a.ignore, &mut notes);
    let history = match history::read(&a.machine) {
        Ok(h) => {
            notes.extend(h.damage());
            h.entries
        }
        Err(e) => {
            notes.push(e.to_string());
            Vec::new()
        }
    };
    let compensation = if a.compensation {
        // The model with the fit's values bound, as `kin compensate` reads it.
        let fitted = load::machine(&a.machine, Some(&a.fit), a.color)?;
        let ranges = data_ranges_of(&data);
        let held = |v: Var| ranges.get(&v).map(|(lo, hi)| 0.5 * (lo + hi));
        Some(compensation::sweeps(&fitted.machine, &held))
    } else {
        None
    };
    let inputs = Inputs {
        machine: m,
        model_path: a.machine.display().to_string(),
        fit: &fit,
        diagnosis: diagnosis.as_ref(),
        data,
        history,
        history_path: history::path_for(&a.machine).display().to_string(),
        notes,
        compensation,
    };
    let page = html(&inputs).map_err(fail)?;
    kin_data::output::replace(&a.output, page.as_bytes()).map_err(|source| {
        fail(ReportError::Write {
            path: a.output.clone(),
            source,
        })
    })?;
    println!("wrote {}", a.output.display());
    Ok(())
}

/// The fitted files, indexed like `fit.files`: from the command line, else from the paths the
/// fit recorded (as given, then relative to FIT.json). A file that cannot be read only costs
/// its residual plots, with a note saying why.
fn load_data(
    m: &Machine,
    fit: &FitReport,
    fit_path: &Path,
    given: &[PathBuf],
    ignore: &crate::args::DataOptions,
    notes: &mut Vec<String>,
) -> Vec<Option<Observations>> {
    let options = ignore.read(false);
    if !given.is_empty() && given.len() != fit.files.len() {
        notes.push(format!(
            "{} data files were given but the fit used {}; they are matched in order.",
            given.len(),
            fit.files.len()
        ));
    }
    let base = fit_path.parent().unwrap_or(Path::new("."));
    fit.files
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let candidates: Vec<PathBuf> = match given.get(i) {
                Some(p) => vec![p.clone()],
                None if given.is_empty() => vec![PathBuf::from(&f.path), base.join(&f.path)],
                None => Vec::new(),
            };
            let mut last = None;
            for p in &candidates {
                match data::read_file(p, m, &options) {
                    Ok(o) => return Some(o),
                    Err(e) => last = Some(e.to_string()),
                }
            }
            notes.push(format!(
                "no positions for the residuals of `{}`: {}",
                f.path,
                last.unwrap_or_else(|| "no data file given for it".into())
            ));
            None
        })
        .collect()
}

/// Everything a page is made of, loaded and checked.
pub struct Inputs<'a> {
    pub machine: &'a Machine,
    pub model_path: String,
    pub fit: &'a FitReport,
    pub diagnosis: Option<&'a Diagnosis>,
    /// The fitted files' observations, indexed like `fit.files`.
    pub data: Vec<Option<Observations>>,
    pub history: Vec<Entry>,
    pub history_path: String,
    /// Warnings shown at the top of the page.
    pub notes: Vec<String>,
    /// The compensation section's sweeps (`--compensation`), or why there are none.
    pub compensation: Option<Result<compensation::View, String>>,
}

pub(crate) const CSS: &str = r#"
*{box-sizing:border-box}
body{margin:0;background:#eef0f3;color:#1d2330;font:15px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif}
main{max-width:1320px;margin:0 auto;padding:28px 36px 56px;background:#fff;min-height:100vh}
h1{font-size:27px;margin:0 0 2px}
h2{font-size:20px;margin:40px 0 10px;padding-bottom:5px;border-bottom:2px solid #e2e5ea}
h3{font-size:15px;margin:22px 0 8px;color:#394150}
p{margin:6px 0 10px}
.meta{color:#5b6475;font-size:13.5px;margin-bottom:14px}
.note{color:#5b6475;font-size:13.5px}
.warn{background:#fff4e0;border-left:4px solid #e69f00;padding:8px 12px;margin:8px 0;font-size:14px}
.ok{background:#e8f6f0;border-left:4px solid #009e73;padding:8px 12px;margin:8px 0;font-size:14px}
.cards{display:grid;grid-template-columns:repeat(auto-fill,minmax(136px,1fr));gap:10px;margin:14px 0}
.card{border:1px solid #e2e5ea;border-radius:8px;padding:10px 12px;background:#fafbfc}
.card .v{font-size:18px;font-weight:600;font-variant-numeric:tabular-nums;white-space:nowrap}
.card .k{font-size:12.5px;color:#5b6475}
table{border-collapse:collapse;font-size:13.5px;margin:8px 0 14px;font-variant-numeric:tabular-nums}
th,td{padding:5px 10px;border-bottom:1px solid #e6e8ec;text-align:right;vertical-align:top}
th{background:#f2f4f7;font-weight:600;white-space:nowrap}
td.l,th.l{text-align:left}
td:not(.l),td.nw{white-space:nowrap}
tr.current td{background:#eef6fc;font-weight:600}
code{font-family:ui-monospace,SFMono-Regular,Menlo,Consolas,monospace;font-size:12.5px;background:#f2f4f7;padding:1px 5px;border-radius:3px;white-space:pre-wrap}
.why{display:block;color:#5b6475;font-size:12.5px;margin-top:3px}
.sig{color:#b42318;font-weight:700}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(360px,1fr));gap:12px;align-items:start}
figure{margin:0;border:1px solid #e2e5ea;border-radius:6px;padding:4px;background:#fff}
figure svg{display:block;width:100%;height:auto}
.legend{font-size:13px;color:#394150;margin:4px 0 8px}
.sw{display:inline-block;width:13px;height:13px;border-radius:2px;vertical-align:-2px;margin:0 5px 0 14px}
.sw:first-child{margin-left:0}
.sw.dot{border-radius:50%;width:10px;height:10px;vertical-align:0}
.sw.line{width:20px;height:3px;vertical-align:4px;border-radius:0}
.sw.dash{width:20px;height:0;vertical-align:4px;border-radius:0;border-top:2px dashed;background:none!important}
.sw.area{opacity:.3}
figcaption{font-size:12.5px;color:#394150;padding:2px 8px 4px;line-height:1.7}
details{margin:10px 0}
summary{cursor:pointer;font-weight:600}
nav{font-size:13.5px;margin:6px 0 0}
nav a{color:#0072b2;text-decoration:none;margin-right:14px}
footer{margin-top:40px;color:#8a92a3;font-size:12px}
"#;

/// The page.
pub fn html(inp: &Inputs) -> Result<String, ReportError> {
    let fit = inp.fit;
    let mut s = String::with_capacity(1 << 20);
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n<title>kin report: {}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<main>\n",
        esc(&fit.machine)
    );
    let _ = write!(
        s,
        "<h1>Fit report: <code>{}</code></h1>\n<div class=\"meta\">model <code>{}</code> (hash {}) · {} observations in {} file{} · solver {} · engine {}</div>\n",
        esc(&fit.machine),
        esc(&inp.model_path),
        esc(&fit.model_hash),
        fit.rows,
        fit.files.len(),
        if fit.files.len() == 1 { "" } else { "s" },
        esc(&fit.solver),
        esc(&fit.engine)
    );
    s.push_str("<nav><a href=\"#summary\">Summary</a><a href=\"#residuals\">Residuals</a>");
    if inp.diagnosis.is_some() {
        s.push_str("<a href=\"#spectrum\">Spectrum</a><a href=\"#candidates\">Candidates</a>");
    }
    s.push_str("<a href=\"#history\">History</a><a href=\"#curves\">Parametric errors</a><a href=\"#uncertainty\">Uncertainty</a>");
    if inp.compensation.is_some() {
        s.push_str("<a href=\"#compensation\">Compensation</a>");
    }
    s.push_str("</nav>\n");
    for n in &inp.notes {
        let _ = writeln!(s, "<div class=\"warn\">{}</div>", esc(n));
    }
    summary(&mut s, inp);
    residuals(&mut s, inp)?;
    if let Some(d) = inp.diagnosis {
        spectrum(&mut s, d)?;
        candidates(&mut s, d);
    }
    history_section(&mut s, inp)?;
    curves_section(&mut s, inp)?;
    stations_section(&mut s, fit);
    umap::section(&mut s, inp.machine, fit, &data_ranges(inp));
    if let Some(c) = &inp.compensation {
        compensation_section(&mut s, c)?;
    }
    coefficients(&mut s, fit);
    let _ = write!(s, "<footer>kin {} · a self-contained page: no scripts, no external resources.</footer>\n</main>\n</body>\n</html>\n", env!("CARGO_PKG_VERSION"));
    Ok(s)
}

fn summary(s: &mut String, inp: &Inputs) {
    let f = inp.fit;
    let u = esc(&f.error_unit);
    // With a stated noise, σ̂, the RMS and the max are ratios to it.
    let su = if f.weights.is_some() {
        "σ".to_string()
    } else {
        u.clone()
    };
    s.push_str("<section id=\"summary\">\n<h2>Summary</h2>\n<div class=\"cards\">\n");
    let kept = f.coefficients.iter().filter(|c| c.kept).count() + f.nuisance.len();
    let cards = [
        (
            format!("{} {su}", num(f.sigma, 4)),
            if f.weights.is_some() {
                "σ̂/σ, against the stated noise".to_string()
            } else {
                "σ̂, noise estimate".to_string()
            },
        ),
        (
            format!("{} {su}", num(f.rms, 4)),
            "residual RMS".to_string(),
        ),
        (
            format!("{} {su}", num(f.max, 4)),
            "largest |residual|".to_string(),
        ),
        (num(f.r2, 6), "R², variance explained".to_string()),
        (format!("{}", f.rows), "observations".to_string()),
        (
            format!("{kept} / {}", f.columns),
            "parameters kept / fitted".to_string(),
        ),
        (
            format!("{}", f.rank),
            format!("rank (condition {})", num(f.condition, 3)),
        ),
        (format!("{}", f.dof), "degrees of freedom".to_string()),
    ];
    for (v, k) in cards {
        let _ = writeln!(
            s,
            "<div class=\"card\"><div class=\"v\">{v}</div><div class=\"k\">{}</div></div>",
            esc(&k)
        );
    }
    s.push_str("</div>\n");
    let rotations = f
        .files
        .iter()
        .flat_map(|x| &x.components)
        .any(|c| c.name.starts_with("er"));
    if let Some(w) = &f.weights {
        let mut stated = Vec::new();
        if let Some(p) = w.position {
            stated.push(format!("{} {u} on positions and lengths", num(p, 4)));
        }
        if let Some(t) = w.rotation {
            stated.push(format!("{} {} on rotations", num(t, 4), esc(&w.tilt_unit)));
        }
        let _ = writeln!(
            s,
            "<p class=\"note\">Every row was divided by the instrument's stated noise ({}): σ̂, the RMS and the max are ratios to it, the per-component figures below are in their own units. χ² = {} on {} degrees of freedom, p = {}: {}.</p>",
            stated.join(", "),
            num(w.chi2, 1),
            w.dof,
            pval(w.p),
            if w.p < 0.01 { "the residuals exceed the stated noise" } else { "consistent with the stated noise" }
        );
    } else if rotations && f.tilt_unit != f.error_unit {
        let _ = writeln!(s, "<p class=\"note\">Rotation residuals are in {}; one {} counts as one {} in σ̂ and the RMS.</p>", esc(&f.tilt_unit), esc(&f.tilt_unit), u);
    }
    s.push_str(
        "<table>\n<tr><th class=\"l\">file</th><th class=\"l\">kind</th><th>rows</th><th>RMS</th><th>max</th><th>outliers</th><th class=\"l\">per component: RMS (max)</th></tr>\n",
    );
    let rows = f
        .files
        .iter()
        .map(|x| (x, ""))
        .chain(f.validation.iter().map(|x| (x, " (validation)")));
    for (file, tag) in rows {
        let comps: Vec<String> = file
            .components
            .iter()
            .map(|c| {
                format!(
                    "{} {} ({}) {}",
                    esc(&c.name),
                    num(c.rms, 3),
                    num(c.max, 3),
                    esc(&c.unit)
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "<tr><td class=\"l\"><code>{}</code>{tag}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"l\">{}</td></tr>",
            esc(&file.path),
            esc(&file.kind),
            file.rows,
            num(file.rms, 4),
            num(file.max, 4),
            file.outliers,
            comps.join(" · ")
        );
    }
    s.push_str("</table>\n");
    if !f.outliers.is_empty() {
        let _ = writeln!(
            s,
            "<h3>Outliers</h3>\n<p class=\"note\">Rows with |studentized residual| &gt; {} or Cook's distance &gt; {}, largest first{}.</p>",
            num(f.outlier_threshold, 3),
            num(f.cook_threshold, 3),
            if f.outliers.len() > 20 { " (the first 20)" } else { "" }
        );
        let mut out: Vec<&Residual> = f.outliers.iter().collect();
        out.sort_by(|a, b| b.studentized.abs().total_cmp(&a.studentized.abs()));
        s.push_str("<table>\n<tr><th class=\"l\">file:line</th><th class=\"l\">component</th><th>residual</th><th>studentized</th><th>leverage</th><th>Cook</th></tr>\n");
        for r in out.iter().take(20) {
            let path = f
                .files
                .get(r.file as usize)
                .map(|x| x.path.as_str())
                .unwrap_or("?");
            let _ = writeln!(
                s,
                "<tr><td class=\"l\"><code>{}:{}</code></td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(path),
                r.line,
                esc(&r.component),
                num(r.residual, 4),
                num(r.studentized, 3),
                num(r.leverage, 3),
                num(r.cook, 3)
            );
        }
        s.push_str("</table>\n");
    }
    s.push_str("</section>\n");
}

/// The order components are shown in.
const COMPONENTS: [&str; 7] = ["ex", "ey", "ez", "erx", "ery", "erz", "dL"];

/// Beyond this many markers per plot the rows are thinned evenly (outliers always kept): the
/// picture does not change, the page stays small enough to open.
const MAX_MARKERS: usize = 5000;

/// A residual with the state it was observed at.
struct Placed {
    /// The value of every variable of [`along`], in its order and display unit; NaN where the
    /// data do not say.
    values: Vec<f64>,
    residual: f64,
    outlier: bool,
}

/// The variables residuals are plotted along: the axes, the inputs, then time. Named as
/// `kin diagnose` names them, since its bins are matched to the plots by name.
pub fn along(m: &Machine) -> Vec<(String, Var)> {
    let axes = m
        .axes
        .iter()
        .enumerate()
        .map(|(a, x)| (x.name.clone(), Var::Axis(a)));
    let inputs = m
        .inputs
        .iter()
        .enumerate()
        .map(|(i, x)| (x.name.clone(), Var::Input(i)));
    axes.chain(inputs)
        .chain(std::iter::once(("time".to_string(), Var::Time)))
        .collect()
}

/// A variable's value at a residual's row in SI, NaN when the file has no such column. A
/// length's residual belongs to the whole segment, so it is placed at the midpoint of its two
/// ends; inputs and time are shared by both ends, so their midpoint is the row's own value.
pub fn value(obs: &Observations, row: usize, v: Var) -> f64 {
    let x = match obs {
        Observations::Points(p) => p.value(v, row),
        Observations::Lengths(l) => match (l.value(v, 0, row), l.value(v, 1, row)) {
            (Some(a), Some(b)) => Some(0.5 * (a + b)),
            _ => None,
        },
    };
    x.unwrap_or(f64::NAN)
}

/// What a variable's values over the placed residuals allow to be shown.
enum Spread {
    /// No row has a value: the data have no such column.
    Absent,
    /// Every row has the same value, in the display unit: a plot would be one vertical line.
    Constant(f64),
    Varies,
}

fn spread(points: &BTreeMap<usize, Vec<Placed>>, v: usize) -> Spread {
    let (lo, hi) = points
        .values()
        .flatten()
        .filter_map(|p| p.values.get(v).copied())
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(x), hi.max(x))
        });
    if lo > hi {
        Spread::Absent
    } else if lo == hi {
        Spread::Constant(lo)
    } else {
        Spread::Varies
    }
}

fn residuals(s: &mut String, inp: &Inputs) -> Result<(), ReportError> {
    let m = inp.machine;
    let f = inp.fit;
    s.push_str("<section id=\"residuals\">\n<h2>Residuals along each axis, input and time</h2>\n");
    if f.residuals.is_empty() {
        let _ = writeln!(
            s,
            "<p class=\"note\">FIT.json holds no per-row residuals ({} rows were left out for size); the summary above still holds.</p>\n</section>",
            f.residuals_omitted
        );
        return Ok(());
    }
    // Row of each source line, per file.
    let lines: Vec<Option<HashMap<usize, usize>>> = inp
        .data
        .iter()
        .map(|d| {
            d.as_ref().map(|o| {
                o.rows()
                    .line
                    .iter()
                    .enumerate()
                    .map(|(r, &l)| (l, r))
                    .collect()
            })
        })
        .collect();
    let vars = along(m);
    let units: Vec<Unit> = vars.iter().map(|(_, v)| curves::var_unit(m, *v)).collect();
    let mut by_component: BTreeMap<usize, Vec<Placed>> = BTreeMap::new();
    let mut unplaced = 0usize;
    for r in &f.residuals {
        let Some(c) = COMPONENTS.iter().position(|c| *c == r.component) else {
            continue;
        };
        let obs = inp.data.get(r.file as usize).and_then(|d| d.as_ref());
        let row = lines
            .get(r.file as usize)
            .and_then(|l| l.as_ref())
            .and_then(|l| l.get(&(r.line as usize)));
        let (Some(obs), Some(&row)) = (obs, row) else {
            unplaced += 1;
            continue;
        };
        let values = vars
            .iter()
            .zip(&units)
            .map(|((_, v), u)| u.from_si(value(obs, row, *v)))
            .collect();
        by_component.entry(c).or_default().push(Placed {
            values,
            residual: r.residual,
            outlier: r.studentized.abs() > f.outlier_threshold || r.cook > f.cook_threshold,
        });
    }
    let band = Band::of(inp);
    let _ = writeln!(
        s,
        "<p>Each residual (measured − fitted) against the position of every axis, every input the model declares and time. The green band is {}: about 997 in 1000 residuals fall inside it when the model is complete and the noise is that. A pattern along an axis is a geometric effect the model lacks; a pattern along an input or in time is a thermal drift, a load or a lag it lacks.{}</p>",
        band.said,
        if f.files.iter().any(|x| x.kind == "lengths") { " A length's residual is placed at the midpoint of its two ends." } else { "" }
    );
    let mut items = vec![
        Key::dot(plot::BLUE, "residual"),
        Key::dot(plot::RED, "outlier"),
        Key::area(plot::GREEN, band.key),
    ];
    if inp.diagnosis.is_some_and(|d| !d.bins.is_empty()) {
        items.push(Key::line(plot::ORANGE, "binned RMS (±)"));
        items.push(Key::dashed(
            plot::PURPLE,
            "allowed RMS (±), noise and model uncertainty",
        ));
    }
    let _ = writeln!(s, "<div class=\"legend\">{}</div>", keys(&items));
    if unplaced > 0 {
        let _ = writeln!(s, "<p class=\"note\">{unplaced} residuals are not shown: their data file was not available (see the notes above).</p>");
    }
    // Decided once over every component, so each component's grid has the same plots in the
    // same places and can be compared at a glance.
    let mut shown_vars = Vec::new();
    if !by_component.is_empty() {
        for (v, ((name, var), unit)) in vars.iter().zip(&units).enumerate() {
            match spread(&by_component, v) {
                Spread::Varies => shown_vars.push(v),
                // Most data have no time column; that needs no remark.
                Spread::Absent if matches!(var, Var::Time) => {}
                Spread::Absent => {
                    let _ = writeln!(
                        s,
                        "<p class=\"note\"><code>{}</code>: not in the data, so there is no plot along it.</p>",
                        esc(name)
                    );
                }
                Spread::Constant(x) => {
                    let _ = writeln!(
                        s,
                        "<p class=\"note\"><code>{}</code>: all values are equal ({} {} in every row), so there is no plot along it.</p>",
                        esc(name),
                        trimmed(x),
                        esc(&unit.name)
                    );
                }
            }
        }
    }
    for (c, points) in &by_component {
        let name = COMPONENTS.get(*c).copied().unwrap_or("?");
        let unit = if (3..6).contains(c) {
            &f.tilt_unit
        } else {
            &f.error_unit
        };
        let shown = thin(points);
        let _ = writeln!(
            s,
            "<h3>{} <span class=\"note\">({} rows{})</span></h3>\n<div class=\"grid\">",
            esc(&component_title(name)),
            points.len(),
            if shown.len() < points.len() {
                format!(", {} shown", shown.len())
            } else {
                String::new()
            }
        );
        let panel = Panel {
            component: name,
            unit,
            band: if (3..6).contains(c) {
                band.rotation
            } else {
                band.position
            },
            diagnosis: inp.diagnosis,
            shown: &shown,
        };
        for &v in &shown_vars {
            let (Some((var_name, _)), Some(xu)) = (vars.get(v), units.get(v)) else {
                continue;
            };
            let x: Vec<f64> = shown
                .iter()
                .map(|p| p.values.get(v).copied().unwrap_or(f64::NAN))
                .collect();
            let svg = residual_plot(
                &panel,
                &x,
                format!("{name} along {var_name}"),
                format!("{var_name} [{}]", xu.name),
                var_name,
            )?;
            let _ = writeln!(s, "<figure>{svg}</figure>");
        }
        s.push_str("</div>\n");
    }
    s.push_str("</section>\n");
    Ok(())
}

/// The ±3σ band of the residual plots: what the residuals are held against. It is never the
/// σ̂ of a fit that may be poor (a band that grows with the misfit would hide it), but the stated
/// noise when there is one, or else the σ̂ of the best fit of the same data in the history.
struct Band {
    /// Half-widths for position (and length) residuals and for rotation residuals, in their
    /// display units.
    position: f64,
    rotation: f64,
    /// What the band is, for the text above the plots.
    said: String,
    key: &'static str,
}

impl Band {
    fn of(inp: &Inputs) -> Band {
        let f = inp.fit;
        let (eu, tu) = (esc(&f.error_unit), esc(&f.tilt_unit));
        let stated = f
            .weights
            .as_ref()
            .map(|w| (w.position, w.rotation, "kin fit --noise"))
            .or_else(|| {
                inp.diagnosis
                    .filter(|d| d.noise.stated.is_some() || d.noise.stated_tilt.is_some())
                    .map(|d| (d.noise.stated, d.noise.stated_tilt, "kin diagnose --noise"))
            });
        if let Some((p, t, by)) = stated {
            let mut parts = Vec::new();
            if let Some(p) = p {
                parts.push(format!("±{} {eu} on positions", num(3.0 * p, 3)));
            }
            if let Some(t) = t {
                parts.push(format!("±{} {tu} on rotations", num(3.0 * t, 3)));
            }
            return Band {
                position: p.map_or(f64::NAN, |v| 3.0 * v),
                rotation: t.map_or(f64::NAN, |v| 3.0 * v),
                said: format!(
                    "±3σ of the instrument's stated noise ({}, from <code>{by}</code>)",
                    parts.join(", ")
                ),
                key: "±3σ, stated noise",
            };
        }
        // The best fit of these data: the lowest σ̂ among the history's fits of the data this
        // fit was made of (its record has the same model hash, rows and unit).
        let data = inp
            .history
            .iter()
            .rev()
            .find(|e| {
                e.model_hash == f.model_hash && e.rows == f.rows && e.error_unit == f.error_unit
            })
            .and_then(|e| e.data_hash.clone());
        let best = data.and_then(|d| {
            inp.history
                .iter()
                .filter(|e| e.data_hash.as_deref() == Some(d.as_str()) && e.sigma.is_finite())
                .min_by(|a, b| a.sigma.total_cmp(&b.sigma))
        });
        match best {
            Some(b) if b.sigma < f.sigma => Band {
                position: 3.0 * b.sigma,
                rotation: 3.0 * b.sigma,
                said: format!(
                    "±3σ̂ = ±{} {eu} (rotations: {tu}), σ̂ of the best fit of these data in the history (fitted {} UTC, model <code>{}</code>), not this fit's σ̂ = {}; no instrument noise was stated",
                    num(3.0 * b.sigma, 3),
                    utc(b.time),
                    esc(b.model_hash.get(..8).unwrap_or(&b.model_hash)),
                    num(f.sigma, 4)
                ),
                key: "±3σ̂, best fit of these data",
            },
            _ => Band {
                position: 3.0 * f.sigma,
                rotation: 3.0 * f.sigma,
                said: format!(
                    "±3σ̂ = ±{} {eu} (rotations: {tu}), σ̂ of this fit, the best of these data in the history; no instrument noise was stated, so the band is the model's own scatter and says nothing of the absolute level (state it with <code>--noise</code>)",
                    num(3.0 * f.sigma, 3)
                ),
                key: "±3σ̂ of this fit",
            },
        }
    }
}

/// What the residual plots of one component share.
struct Panel<'a> {
    component: &'a str,
    /// The residuals' unit.
    unit: &'a str,
    /// Half-width of the band, in the residuals' unit (NaN: none).
    band: f64,
    diagnosis: Option<&'a Diagnosis>,
    /// The residuals drawn, after thinning.
    shown: &'a [&'a Placed],
}

/// One plot of a component's residuals against `x` (one value per shown residual, in the unit
/// `x_label` names), with the ±3σ̂ band and the diagnosis's bins along `variable`.
fn residual_plot(
    p: &Panel,
    x: &[f64],
    title: String,
    x_label: String,
    variable: &str,
) -> Result<String, ReportError> {
    let mut chart = Chart::new(
        title,
        x_label,
        format!("{} residual [{}]", p.component, p.unit),
        (420, 290),
    );
    chart.y_symmetric = true;
    if p.band.is_finite() {
        chart.series.push(Series::HBand {
            lo: -p.band,
            hi: p.band,
            color: plot::GREEN,
            opacity: 0.13,
        });
    }
    let pick = |outlier: bool| -> Vec<(f64, f64)> {
        p.shown
            .iter()
            .zip(x)
            .filter(|(r, _)| r.outlier == outlier)
            .map(|(r, &x)| (x, r.residual))
            .collect()
    };
    chart.series.push(Series::Points {
        points: pick(false),
        color: plot::BLUE,
        radius: 2,
        opacity: 0.5,
    });
    chart.series.push(Series::Points {
        points: pick(true),
        color: plot::RED,
        radius: 3,
        opacity: 0.95,
    });
    if let Some(d) = p.diagnosis {
        bins_overlay(&mut chart, d, p.component, variable);
    }
    Ok(chart.svg()?)
}

/// Every k-th point so at most [`MAX_MARKERS`] remain, plus every outlier.
fn thin(points: &[Placed]) -> Vec<&Placed> {
    let step = points.len().div_ceil(MAX_MARKERS).max(1);
    points
        .iter()
        .enumerate()
        .filter(|(i, p)| p.outlier || i % step == 0)
        .map(|(_, p)| p)
        .collect()
}

/// The diagnosis's binned residual RMS and what the noise and the model's uncertainty allow,
/// as step lines (±) over the residuals of the same component and variable.
fn bins_overlay(chart: &mut Chart, d: &Diagnosis, component: &str, variable: &str) {
    let mut bins: Vec<_> = d
        .bins
        .iter()
        .filter(|b| b.component == component && b.variable == variable && b.rows > 0)
        .collect();
    if bins.is_empty() {
        return;
    }
    bins.sort_by(|a, b| a.lo.total_cmp(&b.lo));
    let steps = |v: &dyn Fn(&kin_diagnose::Bin) -> f64, sign: f64| -> Vec<(f64, f64)> {
        let mut pts = Vec::new();
        for b in &bins {
            pts.push((b.lo, sign * v(b)));
            pts.push((b.hi, sign * v(b)));
        }
        pts
    };
    for sign in [1.0, -1.0] {
        chart.series.push(Series::Line {
            points: steps(&|b| b.allowed, sign),
            color: plot::PURPLE,
            width: 1,
            dashed: true,
        });
        chart.series.push(Series::Line {
            points: steps(&|b| b.rms, sign),
            color: plot::ORANGE,
            width: 2,
            dashed: false,
        });
    }
}

fn component_title(c: &str) -> String {
    let what = match c {
        "ex" | "ey" | "ez" => format!("position error in {}", &c[1..]),
        "erx" | "ery" | "erz" => format!("rotation error about {}", &c[2..]),
        "dL" => "length error".to_string(),
        _ => String::new(),
    };
    format!("{c}: {what}")
}

fn spectrum(s: &mut String, d: &Diagnosis) -> Result<(), ReportError> {
    s.push_str("<section id=\"spectrum\">\n<h2>Residual spectrum</h2>\n");
    if d.spectra.is_empty() {
        s.push_str("<p class=\"note\">The diagnosis holds no spectrum.</p>\n</section>\n");
        return Ok(());
    }
    let panels = d.spectra.len();
    let _ = writeln!(
        s,
        "<p>Lomb–Scargle periodogram of the residuals along each axis (the sampling need not be uniform). A peak that stands out names the wavelength of a periodic error the model lacks — a leadscrew pitch, a scale period. The false-alarm probability says how likely so high a peak is from noise alone in one panel; since {panels} panels are searched, each is also given corrected for all of them (Šidák: 1 − (1 − p)<sup>{panels}</sup>), which is the one to read: the highest of {panels} peaks is expected to look rarer than it is.</p>\n<div class=\"grid\">"
    );
    for sp in &d.spectra {
        let peak = sp
            .power
            .iter()
            .enumerate()
            .filter(|(_, p)| p.is_finite())
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, _)| i);
        let mut chart = Chart::new(
            format!("{} along {}", sp.component, sp.variable),
            format!("wavelength [{}] (log scale)", sp.unit),
            "normalised power",
            (420, 290),
        );
        chart.x_log = true;
        chart.y_zero = true;
        let pts: Vec<(f64, f64)> = sp
            .wavelengths
            .iter()
            .copied()
            .zip(sp.power.iter().copied())
            .collect();
        chart.series.push(Series::Line {
            points: pts,
            color: plot::BLUE,
            width: 1,
            dashed: false,
        });
        // The peak is named under the plot, not on it: a label at the plot's edge would be cut.
        let mut caption = String::new();
        if let Some(i) = peak {
            if let (Some(&w), Some(&p)) = (sp.wavelengths.get(i), sp.power.get(i)) {
                chart.series.push(Series::Points {
                    points: vec![(w, p)],
                    color: plot::RED,
                    radius: 4,
                    opacity: 1.0,
                });
                caption = format!(
                    "<figcaption>{}highest peak at λ = {} {}, false-alarm probability {} in this panel, {} over the {panels} panels</figcaption>",
                    keys(&[Key::dot(plot::RED, "")]),
                    num(w, 4),
                    esc(&sp.unit),
                    pval(sp.peak_false_alarm),
                    pval(sidak(sp.peak_false_alarm, panels))
                );
            }
        }
        let _ = writeln!(s, "<figure>{}{caption}</figure>", chart.svg()?);
    }
    s.push_str("</div>\n</section>\n");
    Ok(())
}

/// The probability that at least one of `k` independent tests at level `p` is this extreme
/// (Šidák), computed without cancellation for small p.
fn sidak(p: f64, k: usize) -> f64 {
    if !(0.0..=1.0).contains(&p) {
        return p;
    }
    -(k as f64 * (-p).ln_1p()).exp_m1()
}

fn family(f: Family) -> &'static str {
    match f {
        Family::CrossCoupling => "cross-coupling",
        Family::MoreKnots => "more knots",
        Family::Periodic => "periodic",
        Family::Backlash => "backlash",
        Family::Thermal => "thermal",
        Family::Drift => "drift",
        Family::RevoluteHarmonics => "revolute harmonics",
        Family::AbbeAngular => "Abbe (angular)",
        Family::Constant => "constant",
        Family::ErrorMotion => "error motion",
    }
}

fn candidates(s: &mut String, d: &Diagnosis) {
    s.push_str(
        "<section id=\"candidates\">\n<h2>Where the model fails, and what is missing</h2>\n",
    );
    if d.regions.is_empty() {
        // "The noise" only when a stated noise was tested; else the reference is σ̂ itself.
        if d.noise.chi2.is_some() {
            s.push_str("<div class=\"ok\">No region of the workspace has residuals larger than the stated noise allows.</div>\n");
        } else {
            s.push_str("<div class=\"ok\">No region of the workspace stands out against the model's own residual scatter σ̂ (no instrument noise was stated, so this says nothing of the absolute level).</div>\n");
        }
    } else {
        s.push_str("<ul>\n");
        for r in &d.regions {
            let _ = writeln!(
                s,
                "<li>{} <span class=\"note\">(RMS {}× σ̂ over {} rows, p = {})</span></li>",
                esc(&r.text),
                num(r.ratio, 3),
                r.rows,
                pval(r.p)
            );
        }
        s.push_str("</ul>\n");
    }
    let significant = d.findings.iter().filter(|f| f.significant).count();
    let _ = writeln!(
        s,
        "<h3>Candidate effects</h3>\n<p>Each candidate is a term that could be added to the model's <code>errors {{ … }}</code>, tested against the residuals with a partial F-test; p-values are adjusted for testing them all (Holm–Bonferroni) at a family-wise level α = {}. Ranked: significant first, then by the residual variance explained.</p>",
        plot::tick(d.alpha)
    );
    if significant == 0 {
        let _ = writeln!(s, "<div class=\"ok\">No candidate is significant at α = {}: nothing these data can show is missing from the model.</div>", plot::tick(d.alpha));
    }
    if d.findings.is_empty() {
        s.push_str("</section>\n");
        return;
    }
    let u = esc(&d.error_unit);
    let header = format!("<table>\n<tr><th>rank</th><th class=\"l\">family</th><th class=\"l\">target</th><th class=\"l\">add to the model</th><th>explained</th><th>F</th><th>p</th><th>adjusted p</th><th class=\"l\">significant</th><th>RMS after [{u}]</th></tr>\n");
    // Every significant candidate and the strongest others up front; a long tail of
    // insignificant ones would bury them, so it is folded away.
    let shown = significant.max(SHOWN_CANDIDATES).min(d.findings.len());
    s.push_str(&header);
    for (i, f) in d.findings.iter().enumerate() {
        if i == shown {
            let _ = write!(s, "</table>\n<details>\n<summary>{} more candidates, none significant</summary>\n{header}", d.findings.len() - shown);
        }
        let c = &f.candidate;
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td class=\"l nw\">{}</td><td class=\"l\"><code>{}</code></td><td class=\"l\"><code>{}</code><span class=\"why\">{}</span></td><td>{} %</td><td>{}</td><td>{}</td><td>{}</td><td class=\"l\">{}</td><td>{}</td></tr>",
            i + 1,
            family(c.family),
            esc(&c.target),
            esc(&c.text),
            esc(&c.explanation),
            num(100.0 * f.explained, 3),
            num(f.f, 4),
            pval(f.p),
            pval(f.p_adjusted),
            if f.significant { "<span class=\"sig\">yes</span>" } else { "no" },
            num(f.rms_after, 4)
        );
    }
    s.push_str("</table>\n");
    if d.findings.len() > shown {
        s.push_str("</details>\n");
    }
    s.push_str("</section>\n");
}

/// Candidates listed before the rest is folded away (all significant ones are always listed).
const SHOWN_CANDIDATES: usize = 8;

/// The fits of the model's history, one per round: consecutive fits of one revision on the
/// same data show as the last of them.
fn revisions(h: &[Entry]) -> Vec<&Entry> {
    let mut out: Vec<&Entry> = Vec::new();
    for e in h {
        match out.last_mut() {
            Some(last) if last.model_hash == e.model_hash && last.data_hash == e.data_hash => {
                *last = e
            }
            _ => out.push(e),
        }
    }
    out
}

/// At most this many rounds get their kept residual plots in the report (the latest ones).
const ROUND_PLOTS: usize = 12;

/// Each round's residuals as they were when it was fitted: the binned mean and ±RMS its
/// history record kept, per component and variable.
fn round_plots(s: &mut String, revs: &[&Entry], current: &str) -> Result<(), ReportError> {
    let kept: Vec<(usize, &&Entry)> = revs
        .iter()
        .enumerate()
        .filter(|(_, e)| !e.binned.is_empty())
        .collect();
    if kept.is_empty() {
        return Ok(());
    }
    let skip = kept.len().saturating_sub(ROUND_PLOTS);
    let _ = writeln!(
        s,
        "<h3>Residuals of each round, as they were</h3>\n<p>What each round's fit left, kept in its history record as residuals binned along every variable ({} equal bins over the range; the line is the bin's mean residual, the band ± its RMS). A pattern that a later round removed stays visible here.{}</p>",
        history::MAX_BINS,
        if skip > 0 { format!(" The {skip} oldest rounds are left out.") } else { String::new() }
    );
    for (i, e) in kept.into_iter().skip(skip) {
        let open = if e.model_hash == current { " open" } else { "" };
        let _ = writeln!(
            s,
            "<details class=\"round\" id=\"round-{}\"{open}><summary>Round {} — fitted {} UTC, model <code>{}</code>, σ̂ {} {}</summary>\n<div class=\"grid\">",
            i + 1,
            i + 1,
            utc(e.time),
            esc(e.model_hash.get(..8).unwrap_or(&e.model_hash)),
            num(e.sigma, 4),
            esc(&e.error_unit)
        );
        for b in &e.binned {
            let mut chart = Chart::new(
                format!("round {}: {} along {}", i + 1, b.component, b.variable),
                format!("{} [{}]", b.variable, b.variable_unit),
                format!("{} residual [{}]", b.component, b.unit),
                (420, 290),
            );
            chart.y_symmetric = true;
            let x: Vec<f64> = b.bins.iter().map(|k| k.at).collect();
            chart.series.push(Series::Band {
                x: x.clone(),
                lower: b.bins.iter().map(|k| k.mean - k.rms).collect(),
                upper: b.bins.iter().map(|k| k.mean + k.rms).collect(),
                color: plot::BLUE,
                opacity: 0.18,
            });
            chart.series.push(Series::Line {
                points: x
                    .iter()
                    .copied()
                    .zip(b.bins.iter().map(|k| k.mean))
                    .collect(),
                color: plot::BLUE,
                width: 2,
                dashed: false,
            });
            let _ = writeln!(s, "<figure>{}</figure>", chart.svg()?);
        }
        s.push_str("</div>\n</details>\n");
    }
    Ok(())
}

fn history_section(s: &mut String, inp: &Inputs) -> Result<(), ReportError> {
    s.push_str("<section id=\"history\">\n<h2>Error history across model revisions</h2>\n");
    let revs = revisions(&inp.history);
    if revs.is_empty() {
        let _ = writeln!(s, "<p class=\"note\">No history yet: <code>kin fit</code> records each fit in <code>{}</code>.</p>\n</section>", esc(&inp.history_path));
        return Ok(());
    }
    let u = revs
        .last()
        .map(|e| e.error_unit.clone())
        .unwrap_or_else(|| inp.fit.error_unit.clone());
    let _ = writeln!(
        s,
        "<p>Residual RMS and σ̂ of the last fit of each revision of the model on each data set (from <code>{}</code>). Adding the effect the data show makes the error fall towards the noise. Changes are given only between fits of the same data (same files, same contents, same weighting): a fit of other data is marked “new data”.</p>",
        esc(&inp.history_path)
    );
    let mut chart = Chart::new(
        "Residual RMS per model revision",
        "revision",
        format!("RMS, σ̂ [{u}]"),
        (760, 320),
    );
    chart.x_integer = true;
    chart.y_zero = true;
    let at = |f: &dyn Fn(&Entry) -> f64| -> Vec<(f64, f64)> {
        revs.iter()
            .enumerate()
            .map(|(i, e)| ((i + 1) as f64, f(e)))
            .collect()
    };
    let mut items = vec![
        Key::line(plot::BLUE, "RMS, all files"),
        Key::dashed(plot::ORANGE, "σ̂"),
    ];
    chart.series.push(Series::Line {
        points: at(&|e| e.rms),
        color: plot::BLUE,
        width: 3,
        dashed: false,
    });
    chart.series.push(Series::Points {
        points: at(&|e| e.rms),
        color: plot::BLUE,
        radius: 4,
        opacity: 1.0,
    });
    chart.series.push(Series::Line {
        points: at(&|e| e.sigma),
        color: plot::ORANGE,
        width: 2,
        dashed: true,
    });
    let mut paths: Vec<&str> = Vec::new();
    for e in &revs {
        for f in &e.files {
            if !paths.contains(&f.path.as_str()) {
                paths.push(&f.path);
            }
        }
    }
    if paths.len() > 1 {
        for (k, p) in paths.iter().enumerate() {
            let pts: Vec<(f64, f64)> = revs
                .iter()
                .enumerate()
                .map(|(i, e)| {
                    (
                        (i + 1) as f64,
                        e.files
                            .iter()
                            .find(|f| f.path == *p)
                            .map(|f| f.rms)
                            .unwrap_or(f64::NAN),
                    )
                })
                .collect();
            let color = plot::PALETTE.get(2 + k % 4).copied().unwrap_or(plot::GREY);
            chart.series.push(Series::Line {
                points: pts,
                color,
                width: 1,
                dashed: false,
            });
            items.push(Key::line(color, &short(p, 40)));
        }
    }
    let _ = writeln!(
        s,
        "<figure style=\"max-width:780px\">{}<figcaption>{}</figcaption></figure>",
        chart.svg()?,
        keys(&items)
    );
    let _ = writeln!(s, "<table>\n<tr><th>revision</th><th class=\"l\">fitted (UTC)</th><th class=\"l\">model hash</th><th>parameters</th><th>rows</th><th>σ̂ [{u}]</th><th>RMS [{u}]</th><th>change</th></tr>", u = esc(&u));
    // A change is stated only between fits of the same data: another data set's RMS says
    // nothing of whether the model improved.
    let mut before: Option<&Entry> = None;
    for (i, e) in revs.iter().enumerate() {
        let change = match before {
            None => "—".into(),
            Some(b) if b.data_hash.is_some() && b.data_hash == e.data_hash => {
                if b.model_hash == e.model_hash {
                    "unchanged".into()
                } else {
                    format!(
                        "{:+.1} %",
                        100.0 * (e.rms - b.rms) / b.rms.max(f64::MIN_POSITIVE)
                    )
                }
            }
            Some(_) if e.data_hash.is_none() => "— (data not recorded)".into(),
            Some(_) => "new data".into(),
        };
        let _ = writeln!(
            s,
            "<tr{}><td>{}</td><td class=\"l\">{}</td><td class=\"l\"><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            if e.model_hash == inp.fit.model_hash { " class=\"current\"" } else { "" },
            i + 1,
            utc(e.time),
            esc(e.model_hash.get(..8).unwrap_or(&e.model_hash)),
            e.parameters,
            e.rows,
            num(e.sigma, 4),
            num(e.rms, 4),
            change
        );
        before = Some(e);
    }
    s.push_str("</table>\n");
    round_plots(s, &revs, &inp.fit.model_hash)?;
    s.push_str("</section>\n");
    Ok(())
}

/// The ranges of the inputs and of time over the data, for the curves' axes.
fn data_ranges(inp: &Inputs) -> curves::Ranges {
    data_ranges_of(&inp.data)
}

/// The span of every input and of time over the fitted files.
fn data_ranges_of(data: &[Option<Observations>]) -> curves::Ranges {
    let mut out = curves::Ranges::new();
    let mut add = |v: Var, values: &[f64]| {
        for &x in values.iter().filter(|x| x.is_finite()) {
            let e = out.entry(v).or_insert((x, x));
            e.0 = e.0.min(x);
            e.1 = e.1.max(x);
        }
    };
    for o in data.iter().flatten() {
        let rows = o.rows();
        for (i, col) in rows.inputs.iter().enumerate() {
            if let Some(col) = col {
                add(Var::Input(i), col);
            }
        }
        if let Some(t) = &rows.time {
            add(Var::Time, t);
        }
    }
    out.retain(|_, (lo, hi)| hi > lo);
    out
}

fn curves_section(s: &mut String, inp: &Inputs) -> Result<(), ReportError> {
    let m = inp.machine;
    s.push_str("<section id=\"curves\">\n<h2>Fitted parametric errors</h2>\n");
    let c: Curves = match curves::curves(m, inp.fit, &data_ranges(inp)) {
        Ok(c) => c,
        Err(e) => {
            let _ = writeln!(
                s,
                "<div class=\"warn\">The parametric errors cannot be drawn: {}</div>\n</section>",
                esc(&e.to_string())
            );
            return Ok(());
        }
    };
    let _ = writeln!(
        s,
        "<p>The fitted part of each parametric error of the model, in its frame's own axes, along each variable it depends on, with the ≈ 95 % confidence band (± 2 standard errors from the coefficients' covariance, eq. 4.12). Known fixed terms are not included. The other variables are held at: {}.</p>",
        esc(&c.reference.join(", "))
    );
    let _ = writeln!(
        s,
        "<p class=\"note\">Where an error also depends on another variable, it is drawn at that variable's lowest, middle and highest value; where it depends on the direction of motion, once for each direction.</p>\n<div class=\"legend\">{}</div>\n<div class=\"grid\">",
        keys(&[Key::line(plot::BLUE, "fitted error"), Key::area(plot::BLUE, "≈ 95 % confidence band")])
    );
    for cv in &c.curves {
        let mut chart = Chart::new(
            cv.target.clone(),
            format!("{} [{}]", cv.variable, cv.x_unit),
            format!("{} [{}]", cv.target, cv.y_unit),
            (420, 290),
        );
        let color = |k: usize| {
            plot::PALETTE
                .get(k % plot::PALETTE.len())
                .copied()
                .unwrap_or(plot::BLUE)
        };
        for (k, line) in cv.lines.iter().enumerate() {
            let lower: Vec<f64> = line
                .value
                .iter()
                .zip(&line.band)
                .map(|(v, b)| v - b)
                .collect();
            let upper: Vec<f64> = line
                .value
                .iter()
                .zip(&line.band)
                .map(|(v, b)| v + b)
                .collect();
            let opacity = if cv.lines.len() > 1 { 0.14 } else { 0.22 };
            chart.series.push(Series::Band {
                x: cv.x.clone(),
                lower,
                upper,
                color: color(k),
                opacity,
            });
        }
        let mut items = Vec::new();
        for (k, line) in cv.lines.iter().enumerate() {
            chart.series.push(Series::Line {
                points: cv
                    .x
                    .iter()
                    .copied()
                    .zip(line.value.iter().copied())
                    .collect(),
                color: color(k),
                width: 2,
                dashed: false,
            });
            items.push(Key::line(
                color(k),
                line.label.as_deref().unwrap_or("fitted"),
            ));
        }
        // A single line is explained by the section's legend.
        let caption = if cv.lines.len() > 1 {
            format!("<figcaption>{}</figcaption>", keys(&items))
        } else {
            String::new()
        };
        let _ = writeln!(s, "<figure>{}{caption}</figure>", chart.svg()?);
    }
    s.push_str("</div>\n");
    if !c.constants.is_empty() {
        s.push_str("<h3>Constant parametric errors</h3>\n<p class=\"note\">Errors that depend on no variable: squareness and location constants.</p>\n<table>\n<tr><th class=\"l\">error</th><th>value</th><th>95 % band (±)</th><th class=\"l\">unit</th></tr>\n");
        for k in &c.constants {
            let _ = writeln!(
                s,
                "<tr><td class=\"l\"><code>{}</code></td><td>{}</td><td>{}</td><td class=\"l\">{}</td></tr>",
                esc(&k.target),
                num(k.value, 4),
                num(k.band, 3),
                esc(&k.unit)
            );
        }
        s.push_str("</table>\n");
    }
    s.push_str("</section>\n");
    Ok(())
}

/// Every error that varies along one axis, at stations along it (FIT.json `stations`): the
/// numbers a laser run along the axis would be compared with.
fn stations_section(s: &mut String, f: &FitReport) {
    if f.stations.is_empty() {
        return;
    }
    s.push_str("<section id=\"stations\">\n<h2>Errors at stations along their axis</h2>\n<p>Each error that varies along one axis, evaluated at the ends of the axis' range and at round steps between, with its standard uncertainty (eq. 4.12), under kin's name and ISO 230-1's. Where a component has other terms (backlash, inputs, another axis), only its terms of this axis are included, as marked.</p>\n");
    for t in &f.stations {
        let iso = t
            .iso
            .as_deref()
            .map(|n| format!(" · <code>{}</code>", esc(n)))
            .unwrap_or_default();
        let partial = if t.partial {
            " (its terms of this axis only)"
        } else {
            ""
        };
        let _ = write!(
            s,
            "<h3><code>{}</code>{iso} along {}{partial}</h3>\n<table>\n<tr><th class=\"l\">{} [{}]</th>",
            esc(&t.error),
            esc(&t.axis),
            esc(&t.axis),
            esc(&t.position_unit)
        );
        for p in &t.positions {
            let _ = write!(s, "<th>{}</th>", num(*p, 4));
        }
        let _ = write!(
            s,
            "</tr>\n<tr><td class=\"l\">value [{}]</td>",
            esc(&t.unit)
        );
        for v in &t.values {
            let _ = write!(s, "<td>{}</td>", num(*v, 3));
        }
        let _ = write!(s, "</tr>\n<tr><td class=\"l\">standard uncertainty</td>");
        for u in &t.u {
            let _ = write!(s, "<td>{}</td>", num(*u, 2));
        }
        s.push_str("</tr>\n</table>\n");
    }
    s.push_str("</section>\n");
}

/// Before and after compensation along each axis (`--compensation`).
fn compensation_section(
    s: &mut String,
    c: &Result<compensation::View, String>,
) -> Result<(), ReportError> {
    s.push_str(
        "<section id=\"compensation\">\n<h2>Compensation: predicted error before and after</h2>\n",
    );
    let v = match c {
        Ok(v) => v,
        Err(why) => {
            let _ = writeln!(
                s,
                "<div class=\"warn\">No compensation: {}</div>\n</section>",
                esc(why)
            );
            return Ok(());
        }
    };
    let _ = writeln!(
        s,
        "<p>The fitted model's predicted error of the tool, before software compensation and after it (thesis §2.3.5, as <code>kin compensate</code> computes it: corrections added to the axis commands, re-checked with the exact transforms). Each axis is swept over its range; the others are held at: {}.</p>",
        esc(&v.reference.join(", "))
    );
    let _ = writeln!(
        s,
        "<p class=\"note\">What stays after compensation is what the axes cannot correct: a position error where the joints cannot move the tool that way, and the orientation error of a machine with fewer than three rotary axes. It is the model's prediction; the fit's own uncertainty comes on top.</p>\n<div class=\"legend\">{}</div>\n<div class=\"grid\">",
        keys(&[
            Key::line(plot::ORANGE, "before compensation"),
            Key::dashed(plot::BLUE, "after compensation"),
        ])
    );
    for sw in &v.sweeps {
        for (what, unit, before, after) in [
            ("position error", &v.error_unit, &sw.before, &sw.after),
            (
                "orientation error",
                &v.tilt_unit,
                &sw.tilt_before,
                &sw.tilt_after,
            ),
        ] {
            let mut chart = Chart::new(
                format!("{what} along {}", sw.axis),
                format!("{} [{}]", sw.axis, sw.unit),
                format!("|{what}| [{unit}]"),
                (420, 290),
            );
            chart.y_zero = true;
            // "After" dashed: where nothing is corrected it lies on "before", and both show.
            for (values, color, dashed) in
                [(before, plot::ORANGE, false), (after, plot::BLUE, true)]
            {
                chart.series.push(Series::Line {
                    points: sw.x.iter().copied().zip(values.iter().copied()).collect(),
                    color,
                    width: 2,
                    dashed,
                });
            }
            let _ = writeln!(s, "<figure>{}</figure>", chart.svg()?);
        }
    }
    s.push_str("</div>\n<table>\n<tr><th class=\"l\">axis swept</th>");
    let _ = writeln!(
        s,
        "<th>max position error before [{0}]</th><th>after [{0}]</th><th>max orientation error before [{1}]</th><th>after [{1}]</th><th>rank</th></tr>",
        esc(&v.error_unit),
        esc(&v.tilt_unit)
    );
    let max = |x: &[f64]| x.iter().copied().fold(0.0_f64, f64::max);
    for sw in &v.sweeps {
        let _ = writeln!(
            s,
            "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&sw.axis),
            num(max(&sw.before), 3),
            num(max(&sw.after), 3),
            num(max(&sw.tilt_before), 3),
            num(max(&sw.tilt_after), 3),
            sw.rank
        );
    }
    s.push_str("</table>\n<p class=\"note\">Rank: how many of the six error components the axes can move (the fewest along the sweep).</p>\n</section>\n");
    Ok(())
}

fn coefficients(s: &mut String, f: &FitReport) {
    let _ = writeln!(s, "<details>\n<summary>All {} coefficients</summary>\n<table>\n<tr><th class=\"l\">name</th><th class=\"l\">ISO 230-1</th><th class=\"l\">multiplies</th><th>value</th><th>standard error</th><th class=\"l\">unit</th><th class=\"l\">kept</th></tr>", f.coefficients.len() + f.nonlinear.len());
    for c in f.coefficients.iter().chain(&f.nonlinear) {
        let _ = writeln!(
            s,
            "<tr><td class=\"l\"><code>{}</code></td><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td></tr>",
            esc(&c.name),
            c.iso
                .as_deref()
                .map(|n| format!("<code>{}</code>", esc(n)))
                .unwrap_or_default(),
            esc(&c.label),
            num(c.value, 5),
            num(c.se, 3),
            esc(&c.unit),
            if c.kept { "yes" } else { "removed" }
        );
    }
    s.push_str("</table>\n</details>\n");
}

/// One entry of a legend written in HTML under a figure (plotters' own legend box would sit
/// on top of the data).
struct Key {
    color: plotters::style::RGBColor,
    text: String,
    class: &'static str,
}

impl Key {
    fn line(color: plotters::style::RGBColor, text: &str) -> Key {
        Key {
            color,
            text: text.to_string(),
            class: "line",
        }
    }
    fn dashed(color: plotters::style::RGBColor, text: &str) -> Key {
        Key {
            color,
            text: text.to_string(),
            class: "dash",
        }
    }
    fn area(color: plotters::style::RGBColor, text: &str) -> Key {
        Key {
            color,
            text: text.to_string(),
            class: "area",
        }
    }
    fn dot(color: plotters::style::RGBColor, text: &str) -> Key {
        Key {
            color,
            text: text.to_string(),
            class: "dot",
        }
    }
}

fn keys(items: &[Key]) -> String {
    let mut out = String::new();
    for k in items {
        let c = plot::css(k.color);
        let _ = write!(
            out,
            "<span class=\"sw {}\" style=\"color:{c};background-color:{c}\"></span>{}",
            k.class,
            esc(&k.text)
        );
    }
    out
}

/// HTML text escaping.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

// The curves label their reference state with the same significant digits as the report.
pub use kin_estimate::curves::num;

/// `v` to six significant digits without trailing zeros: a value read from a file, where
/// `20.0000` would claim a precision nobody wrote.
fn trimmed(v: f64) -> String {
    let s = num(v, 6);
    let (mantissa, exponent) = s
        .split_once('e')
        .map_or((s.as_str(), None), |(m, e)| (m, Some(e)));
    let mantissa = if mantissa.contains('.') {
        mantissa.trim_end_matches('0').trim_end_matches('.')
    } else {
        mantissa
    };
    match exponent {
        Some(e) => format!("{mantissa}e{e}"),
        None => mantissa.to_string(),
    }
}

fn pval(p: f64) -> String {
    if !p.is_finite() {
        "—".into()
    } else if p < 1e-16 {
        // Below double precision's resolution of 1 − CDF: the digits would mean nothing.
        "< 1e-16".into()
    } else if p < 1e-3 {
        format!("{p:.1e}")
    } else {
        format!("{p:.3}")
    }
}

fn short(p: &str, width: usize) -> String {
    let n = p.chars().count();
    if n <= width {
        p.to_string()
    } else {
        format!("…{}", p.chars().skip(n + 1 - width).collect::<String>())
    }
}

/// Unix seconds as `YYYY-MM-DD hh:mm` UTC (Hinnant's civil-from-days).
pub fn utc(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{d:02} {:02}:{:02}",
        rem / 3600,
        rem % 3600 / 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_and_text_are_safe_for_html() {
        assert_eq!(esc("a<b & \"c\""), "a&lt;b &amp; &quot;c&quot;");
        assert_eq!(num(0.195548, 4), "0.1955");
        assert_eq!(num(f64::NAN, 4), "—");
        assert_eq!(num(279.96, 3), "280");
        assert_eq!(num(2.5e-6, 3), "2.50e-6");
        assert_eq!(trimmed(19.999_999_999_999_98), "20");
        assert_eq!(trimmed(0.25), "0.25");
        assert_eq!(trimmed(1500.0), "1500");
        assert_eq!(trimmed(2.5e-6), "2.5e-6");
        assert_eq!(trimmed(f64::NAN), "—");
        assert_eq!(pval(3e-7), "3.0e-7");
        assert_eq!(utc(0), "1970-01-01 00:00");
        assert_eq!(utc(1_767_225_600 + 3_723), "2026-01-01 01:02");
    }

    #[test]
    fn sidak_corrects_for_the_panels() {
        assert!((sidak(0.01, 1) - 0.01).abs() < 1e-15);
        assert!((sidak(0.01, 6) - (1.0 - 0.99f64.powi(6))).abs() < 1e-12);
        assert!((sidak(1e-12, 6) - 6e-12).abs() < 1e-20);
        assert_eq!(sidak(1.0, 6), 1.0);
    }

    #[test]
    fn consecutive_fits_of_one_revision_collapse() {
        let e = |hash: &str, rms: f64| Entry {
            time: 0,
            model_hash: hash.into(),
            parameters: 1,
            rows: 1,
            sigma: rms,
            rms,
            error_unit: "um".into(),
            files: Vec::new(),
            source: None,
            data_hash: None,
            binned: Vec::new(),
        };
        let h = vec![e("a", 3.0), e("a", 2.5), e("b", 1.0), e("a", 2.0)];
        let r: Vec<f64> = revisions(&h).iter().map(|e| e.rms).collect();
        assert_eq!(r, vec![2.5, 1.0, 2.0]);
    }
}
