//! `kin iso230-2` and `kin iso230-4`: the ISO 230-2 figures of a bidirectional positioning run
//! (spec/iso230-2.md) and the ISO 230-4 figures of circular tests (spec/iso230-4.md); their
//! plots as HTML pages, a positioning run's lack of fit against a model, and circular tests as
//! length observations for a fit.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_compiler::units::Dim;
use kin_standards::iso230_2::{self, Evaluation, Iso2302Error};
use kin_standards::iso230_4::{self, Iso2304Error};

use crate::load::{self, Failed};
use crate::Format;

pub struct Iso2302Args {
    pub run: PathBuf,
    pub format: Format,
    pub html: Option<PathBuf>,
    pub model: Option<PathBuf>,
    pub fit: Option<PathBuf>,
    pub axis: Option<String>,
    pub at: Vec<(String, String)>,
    pub component: Option<String>,
    pub alpha: f64,
    pub engine: kin_model::engine::Engine,
    pub color: bool,
}

pub fn run(a: Iso2302Args) -> ExitCode {
    Failed::exit(evaluate(&a))
}

/// A model's lack of fit against the run, as printed and as JSON.
struct Lof {
    model: String,
    component: String,
    test: Option<kin_diagnose::LackOfFit>,
    alpha: f64,
}

fn evaluate(a: &Iso2302Args) -> Result<(), Failed> {
    let path = a.run.as_path();
    if let Some(out) = &a.html {
        let inputs: Vec<&Path> = [Some(path), a.model.as_deref(), a.fit.as_deref()]
            .into_iter()
            .flatten()
            .collect();
        crate::files::check(out, &inputs)?;
    }
    let fail = |e: Iso2302Error| {
        eprintln!("error: {e}");
        match e {
            Iso2302Error::Io { .. } => Failed::USAGE,
            Iso2302Error::Invalid { .. } => {
                eprintln!("note: the run file's format is described in spec/iso230-2.md");
                Failed::INPUT
            }
        }
    };
    let run = iso230_2::read_file(path).map_err(fail)?;
    let e = iso230_2::evaluate(&run, path).map_err(fail)?;
    let lof = match &a.model {
        Some(model) => Some(lack_of_fit(a, model, &run)?),
        None => None,
    };
    if let Some(out) = &a.html {
        let page = crate::iso_html::iso230_2_page(
            &path.display().to_string(),
            &e,
            &run.target_unit,
            &display_unit(&run.deviation_unit),
        )
        .map_err(|err| {
            eprintln!("error: {err}");
            Failed::INPUT
        })?;
        crate::files::write(out, page.as_bytes())?;
    }
    match a.format {
        Format::Human => {
            print!(
                "{}",
                human(
                    &path.display().to_string(),
                    &e,
                    &run.target_unit,
                    &run.deviation_unit
                )
            );
            if let Some(l) = &lof {
                print!("{}", lof_text(l, &display_unit(&run.deviation_unit)));
            }
        }
        Format::Json => {
            let mut json = serde_json::json!({
                "file": path.display().to_string(),
                "unit": "m",
                "cycles": e.cycles,
                "targets": e.targets,
                "axis": e.axis,
            });
            if let Some(l) = &lof {
                json["lack_of_fit"] = serde_json::json!({
                    "model": l.model,
                    "component": l.component,
                    "alpha": l.alpha,
                    "test": l.test,
                });
            }
            println!("{json:#}");
        }
    }
    if let Some(out) = &a.html {
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}

/// The component of the model's error a run along `axis` measures: `ex`, `ey` or `ez` after
/// the axis's direction, or `--component` (a leading `-` flips its sign).
fn component_of(
    m: &kin_compiler::ir::Machine,
    axis: usize,
    given: Option<&str>,
) -> Result<(usize, f64, String), Failed> {
    const NAMES: [&str; 6] = ["ex", "ey", "ez", "erx", "ery", "erz"];
    if let Some(text) = given {
        let (sign, name) = match text.strip_prefix('-') {
            Some(n) => (-1.0, n),
            None => (1.0, text.strip_prefix('+').unwrap_or(text)),
        };
        return match NAMES.iter().position(|n| *n == name) {
            Some(k) => Ok((k, sign, text.to_string())),
            None => {
                eprintln!("error: --component `{text}`: expected ex, ey, ez, erx, ery or erz, optionally with a leading -");
                Err(Failed::USAGE)
            }
        };
    }
    let d = m.axes.get(axis).map_or([1.0, 0.0, 0.0], |a| a.direction);
    let k = (0..3)
        .max_by(|&i, &j| d[i].abs().total_cmp(&d[j].abs()))
        .unwrap_or(0);
    Ok((k, 1.0, NAMES[k].to_string()))
}

/// The model's predicted deviations at the run's approaches, and the F-test against the run's
/// replicates (spec/iso230-2.md, "Lack of fit of a model").
fn lack_of_fit(a: &Iso2302Args, model: &Path, run: &iso230_2::Run) -> Result<Lof, Failed> {
    let compiled = load::machine(model, a.fit.as_deref(), a.color)?;
    let m = &compiled.machine;
    let Some(axis_name) = &a.axis else {
        eprintln!("error: --model needs --axis: the axis the run moved");
        return Err(Failed::USAGE);
    };
    let Some(axis) = m.axes.iter().position(|x| &x.name == axis_name) else {
        eprintln!(
            "error: --axis {axis_name}: `{}` has no such axis (it has {})",
            model.display(),
            m.axes
                .iter()
                .map(|x| x.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
        return Err(Failed::USAGE);
    };
    if m.axes[axis].kind != kin_compiler::ir::JointKind::Prismatic {
        eprintln!("error: --axis {axis_name} is not a prismatic axis: ISO 230-2 runs are linear");
        return Err(Failed::USAGE);
    }
    let (component, sign, component_name) = component_of(m, axis, a.component.as_deref())?;
    // The other axes: where --at puts them, else the middle of their ranges.
    let mut fixed: Vec<f64> = m
        .axes
        .iter()
        .map(|x| (x.range[0] + x.range[1]) / 2.0)
        .collect();
    for (name, value) in &a.at {
        let Some(i) = m.axes.iter().position(|x| &x.name == name) else {
            eprintln!("error: --at {name}: `{}` has no such axis", model.display());
            return Err(Failed::USAGE);
        };
        let dim = if m.axes[i].kind == kin_compiler::ir::JointKind::Prismatic {
            Dim::LENGTH
        } else {
            Dim::ANGLE
        };
        fixed[i] = load::quantity(value, dim).map_err(|e| {
            eprintln!("error: --at {name}={value}: {e}");
            Failed::USAGE
        })?;
    }
    outside_ranges(m, axis, &fixed, run)?;
    // The approaches as a file of poses in SI units, read by the measurement-file reader so
    // the model sees exactly what a point file would give it.
    let mut csv = String::new();
    for (i, x) in m.axes.iter().enumerate() {
        let unit = if i == axis || x.kind == kin_compiler::ir::JointKind::Prismatic {
            "m"
        } else {
            "rad"
        };
        let _ = write!(csv, "{}[{unit}],", x.name);
    }
    let _ = writeln!(csv, "dir_{}", m.axes[axis].name);
    for s in &run.samples {
        for (i, v) in fixed.iter().enumerate() {
            let v = if i == axis { s.target } else { *v };
            let _ = write!(csv, "{v:e},");
        }
        let _ = writeln!(csv, "{}", if s.up { "+1" } else { "-1" });
    }
    let options = kin_data::data::ReadOptions {
        poses: true,
        ..Default::default()
    };
    let poses =
        kin_data::data::read(csv.as_bytes(), &a.run, m, &options).map_err(load::read_failed)?;
    let mut mask = [false; 6];
    mask[component] = true;
    let predicted = kin_estimate::simulate::predict_with(m, &m.beta, &poses, mask, a.engine)
        .map_err(|e| {
            eprintln!("error: {e}");
            Failed::INPUT
        })?;
    let values: Vec<f64> = match predicted {
        kin_data::data::Observations::Points(p) => p.observed[component]
            .clone()
            .unwrap_or_default()
            .into_iter()
            .map(|v| sign * v)
            .collect(),
        kin_data::data::Observations::Lengths(_) => Vec::new(),
    };
    if values.len() != run.samples.len() {
        eprintln!("error: the model gave no prediction for some approaches");
        return Err(Failed::INPUT);
    }
    Ok(Lof {
        model: model.display().to_string(),
        component: component_name,
        test: iso230_2::lack_of_fit(run, &values, 0.0, a.alpha),
        alpha: a.alpha,
    })
}

/// W0801 (an error with `--strict`) where `--at` or the run's targets put an axis outside its
/// declared range, as every command that reads poses says: the model is extrapolated there (a
/// spline's end piece continued), and a target in the wrong unit usually shows up this way.
fn outside_ranges(
    m: &kin_compiler::ir::Machine,
    axis: usize,
    fixed: &[f64],
    run: &iso230_2::Run,
) -> Result<(), Failed> {
    use kin_data::data::ranges::within;
    let length = &m.units.length;
    let declared = |i: usize| {
        let x = &m.axes[i];
        let unit = match x.kind {
            kin_compiler::ir::JointKind::Prismatic => length,
            kin_compiler::ir::JointKind::Revolute => &m.units.angle,
        };
        let [lo, hi] = x.range;
        format!(
            "its declared range {} .. {} {}",
            unit.from_si(lo),
            unit.from_si(hi),
            unit.name
        )
    };
    let mut found = Vec::new();
    for (i, (x, v)) in m.axes.iter().zip(fixed).enumerate() {
        if i != axis && !x.continuous && !within(x.range, *v) {
            found.push(format!(
                "{} is held outside {}{}: the model is extrapolated there",
                x.name,
                declared(i),
                if x.kind == kin_compiler::ir::JointKind::Prismatic {
                    format!(" (at {} {})", length.from_si(*v), length.name)
                } else {
                    String::new()
                }
            ));
        }
    }
    let range = m.axes[axis].range;
    let beyond: Vec<&iso230_2::Sample> = run
        .samples
        .iter()
        .filter(|s| !within(range, s.target))
        .collect();
    if let Some(first) = beyond.first() {
        found.push(format!(
            "{} of {} approaches put {} outside {} (first at line {}: {} {}): the model is extrapolated there",
            beyond.len(),
            run.samples.len(),
            m.axes[axis].name,
            declared(axis),
            first.line,
            length.from_si(first.target),
            length.name
        ));
    }
    if crate::warnings::strict() && !found.is_empty() {
        for message in &found {
            eprintln!(
                "error[{}]: {message} (--strict)",
                crate::warnings::OUTSIDE_RANGE
            );
            crate::errors::record("data", message.clone(), None, None);
        }
        return Err(Failed::INPUT);
    }
    for message in &found {
        crate::warnings::say(crate::warnings::OUTSIDE_RANGE, message);
    }
    Ok(())
}

fn lof_text(l: &Lof, unit: &kin_compiler::units::Unit) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\nlack of fit of `{}` ({} against the deviations), pure error from the replicates at each target and direction:",
        l.model, l.component
    );
    match &l.test {
        Some(t) => {
            let _ = writeln!(
                s,
                "  σ from replicates {:.4} {}, F = {:.3} on ({}, {}) degrees of freedom, p {}",
                t.sigma_pure / unit.scale,
                unit.name,
                t.f,
                t.dof_lack,
                t.dof_pure,
                // Below double precision's resolution of 1 − CDF the digits would mean nothing.
                if t.p < 1e-16 {
                    "< 1e-16".to_string()
                } else if t.p < 1e-3 {
                    format!("= {:.1e}", t.p)
                } else {
                    format!("= {:.3}", t.p)
                }
            );
            let _ = writeln!(
                s,
                "  {}",
                if t.consistent {
                    format!(
                        "the model explains the run's means within its repeatability (p ≥ α = {})",
                        l.alpha
                    )
                } else {
                    format!("the model does not explain the run: its errors differ from the measured means by more than the repeatability allows (p < α = {})", l.alpha)
                }
            );
        }
        None => {
            let _ = writeln!(
                s,
                "  no test: the replicates agree exactly or there is no degree of freedom left"
            );
        }
    }
    s
}

/// Deviations are shown in um when the file gives them in mm or m, as metrologists read them.
fn display_unit(unit: &kin_compiler::units::Unit) -> kin_compiler::units::Unit {
    match kin_compiler::units::Unit::atom("um") {
        Some(um) if unit.scale > um.scale && unit.name != "in" && unit.name != "mil" => um,
        _ => unit.clone(),
    }
}

/// Decimals that show the largest figure with four significant digits.
fn decimals(largest: f64) -> usize {
    if largest.is_nan() || largest <= 0.0 {
        return 3;
    }
    (3.0 - largest.log10().floor()).clamp(0.0, 12.0) as usize
}

fn human(
    name: &str,
    e: &Evaluation,
    target_unit: &kin_compiler::units::Unit,
    unit: &kin_compiler::units::Unit,
) -> String {
    let unit = display_unit(unit);
    let d = |v: f64| v / unit.scale;
    let a = &e.axis;
    let largest = [a.a, a.e, a.r, a.b]
        .into_iter()
        .chain(
            e.targets
                .iter()
                .map(|t| t.mean_up.abs().max(t.mean_down.abs())),
        )
        .fold(0.0, f64::max);
    let p = decimals(d(largest));
    let u = &unit.name;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "ISO 230-2 evaluation of {name}: {} targets, up to {} approaches per target and direction; \
         deviations in {u}",
        e.targets.len(),
        e.cycles
    );
    if e.cycles < 5 {
        let _ = writeln!(s, "note: ISO 230-2 asks for 5 cycles; this run has fewer");
    }
    let _ = writeln!(
        s,
        "\n{:>12} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
        format!("target[{}]", target_unit.name),
        "mean↑",
        "mean↓",
        "mean",
        "B_i",
        "s↑",
        "s↓",
        "R↑",
        "R↓",
        "R_i"
    );
    for t in &e.targets {
        let _ = writeln!(
            s,
            "{:>12} {:>10.p$} {:>10.p$} {:>10.p$} {:>10.p$} {:>10.p$} {:>10.p$} {:>10.p$} {:>10.p$} {:>10.p$}",
            t.target / target_unit.scale,
            d(t.mean_up),
            d(t.mean_down),
            d(t.mean),
            d(t.reversal),
            d(t.s_up),
            d(t.s_down),
            d(t.r_up),
            d(t.r_down),
            d(t.r),
        );
    }
    let _ = writeln!(s, "\n{:<48} {:>10} {:>10} {:>10}", "axis", "↑", "↓", "both");
    let mut row = |what: &str, up: Option<f64>, down: Option<f64>, both: f64| {
        let cell = |v: Option<f64>| v.map_or(String::new(), |v| format!("{:.p$}", d(v)));
        let _ = writeln!(
            s,
            "{what:<48} {:>10} {:>10} {:>10.p$} {u}",
            cell(up),
            cell(down),
            d(both)
        );
    };
    row(
        "E  systematic positioning error",
        Some(a.e_up),
        Some(a.e_down),
        a.e,
    );
    row(
        "M  mean bidirectional positional deviation",
        None,
        None,
        a.m,
    );
    row("B  reversal value (largest |B_i|)", None, None, a.b);
    row("   mean reversal value", None, None, a.b_mean);
    row(
        "R  positioning repeatability",
        Some(a.r_up),
        Some(a.r_down),
        a.r,
    );
    row("A  accuracy", Some(a.a_up), Some(a.a_down), a.a);
    s
}

pub struct Iso2304Args {
    pub run: PathBuf,
    pub format: Format,
    pub radius: Option<f64>,
    pub plane: Option<[String; 2]>,
    pub html: Option<PathBuf>,
    pub lengths: Option<PathBuf>,
    pub centre: Vec<(String, String)>,
    pub measure: bool,
}

pub fn run_circular(a: Iso2304Args) -> ExitCode {
    Failed::exit(circular(&a))
}

fn circular(a: &Iso2304Args) -> Result<(), Failed> {
    let path = a.run.as_path();
    for out in [&a.html, &a.lengths].into_iter().flatten() {
        crate::files::check(out, &[path])?;
    }
    if let (Some(h), Some(l)) = (&a.html, &a.lengths) {
        if kin_data::output::same_file(h, l) || h == l {
            eprintln!("error: --html and --lengths name the same file");
            return Err(Failed::USAGE);
        }
    }
    let fail = |e: Iso2304Error| {
        eprintln!("error: {e}");
        match e {
            Iso2304Error::Io { .. } => Failed::USAGE,
            Iso2304Error::Invalid { .. } => {
                eprintln!("note: the circular-test file's format is described in spec/iso230-4.md");
                Failed::INPUT
            }
        }
    };
    let mut run = iso230_4::read_file(path).map_err(fail)?;
    // Options override what the file's comments say.
    if a.radius.is_some() {
        run.setup.radius = a.radius;
    }
    if a.plane.is_some() {
        run.setup.plane = a.plane.clone();
    }
    let e = iso230_4::evaluate(&run, path).map_err(fail)?;
    let unit = display_unit(&run.deviation_unit);
    let lengths = match &a.lengths {
        Some(_) => Some(length_file(a, &run)?),
        None => None,
    };
    if let Some(out) = &a.html {
        let page = crate::iso_html::iso230_4_page(&path.display().to_string(), &run, &e, &unit)
            .map_err(|err| {
                eprintln!("error: {err}");
                Failed::INPUT
            })?;
        crate::files::write(out, page.as_bytes())?;
    }
    if let (Some(out), Some(text)) = (&a.lengths, &lengths) {
        crate::files::write(out, text.as_bytes())?;
    }
    match a.format {
        Format::Human => print!("{}", circular_text(&path.display().to_string(), &e, &unit)),
        Format::Json => {
            let json = serde_json::json!({
                "file": path.display().to_string(),
                "unit": "m",
                "setup": e.setup,
                "runs": e.runs,
            });
            println!("{json:#}");
        }
    }
    for out in [&a.html, &a.lengths].into_iter().flatten() {
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}

fn circular_text(name: &str, e: &iso230_4::Evaluation, unit: &kin_compiler::units::Unit) -> String {
    let d = |v: f64| v / unit.scale;
    let largest = e
        .runs
        .iter()
        .flat_map(|r| [&r.ccw, &r.cw, &r.both])
        .flatten()
        .map(|f| f.g.max(f.f_max.abs()).max(f.f_min.abs()))
        .fold(0.0, f64::max);
    let p = decimals(d(largest));
    let u = &unit.name;
    let mut s = String::new();
    let _ = write!(s, "ISO 230-4 evaluation of {name}:");
    if let Some(r) = e.setup.radius {
        let _ = write!(s, " radius {} mm,", crate::report::num(r * 1e3, 6));
    }
    if let Some([x, y]) = &e.setup.plane {
        let _ = write!(s, " plane {x}{y},");
    }
    if let Some(f) = &e.setup.feed {
        let _ = write!(s, " feed {f},");
    }
    let _ = writeln!(s, " deviations in {u}");
    for r in &e.runs {
        let _ = writeln!(
            s,
            "\nrun {}\n{:<36} {:>10} {:>10} {:>10}",
            r.run, "", "ccw", "cw", "both"
        );
        let mut row = |what: &str, get: &dyn Fn(&iso230_4::Figures) -> f64| {
            let cell = |f: &Option<iso230_4::Figures>| {
                f.as_ref()
                    .map_or("—".to_string(), |f| format!("{:.p$}", d(get(f))))
            };
            let _ = writeln!(
                s,
                "{what:<36} {:>10} {:>10} {:>10} {u}",
                cell(&r.ccw),
                cell(&r.cw),
                cell(&r.both)
            );
        };
        row("G  circular deviation", &|f| f.g);
        row("F  radial deviation, largest", &|f| f.f_max);
        row("F  radial deviation, least", &|f| f.f_min);
        row("   centre offset, first axis", &|f| f.circle.centre[0]);
        row("   centre offset, second axis", &|f| f.circle.centre[1]);
        row("   radius error (least squares)", &|f| {
            f.circle.radius_error
        });
        let _ = writeln!(
            s,
            "{:<36} {:>32} {u}",
            "H  circular hysteresis",
            r.h.map_or("—".to_string(), |h| format!("{:.p$}", d(h)))
        );
    }
    s
}

/// The ball-bar samples as a length file (spec/data.md) by [`iso230_4::bar_lengths`]: the pivot
/// at the centre pose as point 1, the nominal circle point as point 2, one `artifact` label per
/// run for the bar's unknown length, the reading as `dL` with the task's sign.
fn length_file(a: &Iso2304Args, run: &iso230_4::CircularRun) -> Result<String, Failed> {
    let usage = |what: String| {
        eprintln!("error: --lengths: {what}");
        Failed::USAGE
    };
    let Some(plane @ [p, q]) = &run.setup.plane else {
        return Err(usage(
            "the plane is needed: --plane X,Y or a `# plane: X,Y` line in the file".into(),
        ));
    };
    let Some(radius) = run.setup.radius else {
        return Err(usage(
            "the nominal radius is needed: --radius 150mm or a `# radius: 150 mm` line".into(),
        ));
    };
    if a.centre.is_empty() {
        return Err(usage(
            "the centre pose is needed: --centre with every axis of the machine, e.g. --centre X=250mm,Y=250mm,Z=-100mm".into(),
        ));
    }
    // Every axis at its centre value, in mm or deg as written; the plane's two must be lengths.
    let mut axes: Vec<iso230_4::PoseAxis> = Vec::new();
    for (name, value) in &a.centre {
        if axes.iter().any(|x| &x.name == name) {
            return Err(usage(format!("--centre names {name} twice")));
        }
        let (length, v) = match load::quantity(value, Dim::LENGTH) {
            Ok(v) => (true, v),
            Err(_) => match load::quantity(value, Dim::ANGLE) {
                Ok(v) => (false, v),
                Err(e) => return Err(usage(format!("--centre {name}={value}: {e}"))),
            },
        };
        axes.push(iso230_4::PoseAxis {
            name: name.clone(),
            length,
            value: v,
        });
    }
    let bars = iso230_4::bar_lengths(&run.samples, plane, radius, &axes, a.measure).map_err(
        |e| match e {
            iso230_4::LengthsError::PlaneAxisMissing => {
                usage(format!("--centre must give both plane axes {p} and {q}"))
            }
            iso230_4::LengthsError::PlaneAxisNotLength => usage(format!(
                "the plane axes {p} and {q} must be positioned by lengths"
            )),
        },
    )?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# ball-bar lengths from `{}` by kin iso230-4: point 1 the pivot at the centre pose, point 2 \
         the circle point at radius {} mm, dL = {}(reading − nominal radius)",
        a.run.display(),
        crate::report::num(radius * 1e3, 9),
        if a.measure { "−" } else { "" }
    );
    for (i, l) in bars.runs.iter().enumerate() {
        let _ = writeln!(out, "# artifact bar{}: run `{l}`", i + 1);
    }
    let unit = |length: bool| if length { "mm" } else { "deg" };
    let mut header: Vec<String> = Vec::new();
    for end in ["1", "2"] {
        for x in &axes {
            header.push(format!("{}_{end}[{}]", x.name, unit(x.length)));
        }
    }
    header.push(format!("dir_{p}_2"));
    header.push(format!("dir_{q}_2"));
    header.push("artifact".into());
    header.push("dL[um]".into());
    let _ = writeln!(out, "{}", header.join(","));
    let shown = |length: bool, v: f64| if length { v * 1e3 } else { v.to_degrees() };
    let pivot: Vec<f64> = axes.iter().map(|x| x.value).collect();
    for row in &bars.rows {
        let mut cells: Vec<String> = Vec::new();
        for end in [&pivot, &row.point] {
            for (x, v) in axes.iter().zip(end) {
                cells.push(format!("{}", shown(x.length, *v)));
            }
        }
        for positive in row.positive {
            cells.push(if positive { "+1" } else { "-1" }.into());
        }
        cells.push(format!("bar{}", row.bar + 1));
        cells.push(format!("{}", row.dl * 1e6));
        let _ = writeln!(out, "{}", cells.join(","));
    }
    Ok(out)
}

pub struct Iso2303Args {
    pub run: PathBuf,
    pub format: Format,
    pub html: Option<PathBuf>,
}

pub fn run_thermal(a: Iso2303Args) -> ExitCode {
    Failed::exit(thermal(&a))
}

fn thermal(a: &Iso2303Args) -> Result<(), Failed> {
    use kin_standards::iso230_3::{self, Iso2303Error};
    let path = a.run.as_path();
    if let Some(out) = &a.html {
        crate::files::check(out, &[path])?;
    }
    let run = iso230_3::read_file(path).map_err(|e| {
        eprintln!("error: {e}");
        match e {
            Iso2303Error::Io { .. } => Failed::USAGE,
            Iso2303Error::Invalid { .. } => {
                eprintln!("note: the thermal-test file's format is described in spec/iso230-3.md");
                Failed::INPUT
            }
        }
    })?;
    let e = iso230_3::evaluate(&run);
    if let Some(out) = &a.html {
        let page = crate::iso_html::iso230_3_page(&path.display().to_string(), &run, &e).map_err(
            |err| {
                eprintln!("error: {err}");
                Failed::INPUT
            },
        )?;
        crate::files::write(out, page.as_bytes())?;
    }
    match a.format {
        Format::Human => {
            let um = |v: f64| v * 1e6;
            println!(
                "ISO 230-3 thermal test `{}`: {} samples over {:.2} h",
                path.display(),
                e.samples,
                e.duration / 3600.0
            );
            println!("  displacement     ETVE (range)    drift from start        at      end");
            for c in &e.displacements {
                println!(
                    "  {:<12} {:>12.3} um {:>12.3} um {:>8.1} min {:>8.3} um",
                    c.name,
                    um(c.range),
                    um(c.drift),
                    c.drift_at / 60.0,
                    um(c.end)
                );
            }
            for t in &e.tilts {
                let f = &t.figures;
                println!(
                    "  tilt {:<7} {:>12.3} urad {:>10.3} urad {:>8.1} min {:>8.3} urad",
                    t.pair,
                    f.range * 1e6,
                    f.drift * 1e6,
                    f.drift_at / 60.0,
                    f.end * 1e6
                );
            }
            for c in &e.temperatures {
                println!(
                    "  {:<12} {:>12.3} K  {:>12.3} K  {:>8.1} min {:>8.3} K",
                    c.name,
                    c.range,
                    c.drift,
                    c.drift_at / 60.0,
                    c.end
                );
            }
        }
        Format::Json => {
            let json = serde_json::json!({
                "file": path.display().to_string(),
                "units": { "displacement": "m", "tilt": "rad", "temperature": "K", "time": "s" },
                "duration": e.duration,
                "samples": e.samples,
                "displacements": e.displacements,
                "tilts": e.tilts.iter().map(|t| &t.figures).collect::<Vec<_>>(),
                "temperatures": e.temperatures,
            });
            println!("{json:#}");
        }
    }
    if let Some(out) = &a.html {
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}
