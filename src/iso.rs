//! `kin iso230-2`: the ISO 230-2 figures of a bidirectional positioning run (spec/iso230-2.md).

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;

use kin_runtime::iso230_2::{self, Evaluation, Iso2302Error};

use crate::load::Failed;
use crate::Format;

pub fn run(path: &Path, format: Format) -> ExitCode {
    Failed::exit(evaluate(path, format))
}

fn evaluate(path: &Path, format: Format) -> Result<(), Failed> {
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
    match format {
        Format::Human => print!(
            "{}",
            human(
                &path.display().to_string(),
                &e,
                &run.target_unit,
                &run.deviation_unit
            )
        ),
        Format::Json => {
            let json = serde_json::json!({
                "file": path.display().to_string(),
                "unit": "m",
                "cycles": e.cycles,
                "targets": e.targets,
                "axis": e.axis,
            });
            println!("{json:#}");
        }
    }
    Ok(())
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
    // Deviations are shown in um when the file gives them in mm or m, as metrologists read them.
    let um = kin_compiler::units::Unit::atom("um");
    let unit = match um {
        Some(um) if unit.scale > um.scale && unit.name != "in" && unit.name != "mil" => um,
        _ => unit.clone(),
    };
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
