//! `kin demo`: the whole loop on a bundled example whose data hide two effects the starting
//! model lacks — fit, where it fails, the top candidate, adding it, the error falling — until
//! nothing significant is left and the residuals are tested against the simulated noise.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_diagnose::{self as diagnose, Settings};

use crate::diagnose::{replace_model, text, with_line};
use crate::files;
use crate::fit::{self as fitcmd, FitArgs, SolverArg};
use crate::load::Failed;

const START: &str = include_str!("../examples/demo/start.kin");
const POINTS: &str = include_str!("../examples/demo/points.csv");
/// The noise the bundled data were simulated with, in µm.
const NOISE_UM: f64 = 0.2;

pub fn run(dir: Option<PathBuf>, rounds: usize, color: bool) -> ExitCode {
    Failed::exit(demo(dir, rounds, color))
}

/// The files a demo writes in its folder: it writes over them only where it wrote them before.
const MODEL: &str = "bridge_cmm.kin";
const DATA: &str = "points.csv";
const OUTPUTS: [&str; 5] = [
    "fit.json",
    "fit.params",
    "diagnose.json",
    "report.html",
    "bridge_cmm.kin.previous",
];
/// Marks a folder as the demo's own: created with the working copy, checked before a second
/// run writes over it.
const MARKER: &str = ".kin-demo";

/// Prepares DIR for the demo: refuses (exit 2) a folder the user chose that holds a file of the
/// demo's names the demo did not write, else marks it as the demo's. The default folder
/// (`kin-demo-USER` in the temporary folder) is the demo's own by its name: an older kin wrote it
/// without a marker, and refusing it would break `kin demo` for no user's benefit.
fn claim(dir: &Path, chosen: bool) -> Result<(), Failed> {
    let marker = dir.join(MARKER);
    if chosen && !marker.exists() {
        let history = kin_data::history::path_for(&dir.join(MODEL));
        let mut names = vec![dir.join(MODEL), dir.join(DATA), history];
        names.extend(OUTPUTS.iter().map(|n| dir.join(n)));
        if let Some(foreign) = names.iter().find(|p| p.exists()) {
            eprintln!(
                "error: `{}` was not written by `kin demo` (no {MARKER} in `{}`); the demo does not write over it. \
                 Choose an empty or new folder with --dir.",
                foreign.display(),
                dir.display()
            );
            return Err(Failed::USAGE);
        }
    }
    std::fs::create_dir_all(dir).map_err(|e| {
        eprintln!("error: cannot create `{}`: {e}", dir.display());
        Failed::USAGE
    })?;
    files::write(
        &marker,
        b"This folder is a working copy of `kin demo`; a later `kin demo --dir` here may replace its files.\n",
    )
}

fn demo(dir: Option<PathBuf>, rounds: usize, color: bool) -> Result<(), Failed> {
    let chosen = dir.is_some();
    // One folder per user: on a shared machine another user's `kin-demo` is not ours to
    // replace, nor readable to us.
    let dir = dir.unwrap_or_else(|| {
        let user = std::env::var("USER")
            .ok()
            .filter(|u| {
                !u.is_empty()
                    && u.chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
            })
            .unwrap_or_else(|| "user".into());
        std::env::temp_dir().join(format!("kin-demo-{user}"))
    });
    claim(&dir, chosen)?;
    let write = |name: &str, text: &str| -> Result<PathBuf, Failed> {
        let path = dir.join(name);
        files::write(&path, text.as_bytes())?;
        Ok(path)
    };
    let model = write(MODEL, START)?;
    let data = write(DATA, POINTS)?;
    let history = kin_data::history::path_for(&model);
    if let Err(e) = std::fs::remove_file(&history) {
        if e.kind() != std::io::ErrorKind::NotFound {
            eprintln!("error: cannot remove `{}`: {e}", history.display());
            return Err(Failed::USAGE);
        }
    }
    println!("kin demo — a bridge CMM measured at 2500 points (simulated, {NOISE_UM} µm noise, two effects hidden)");
    println!("working copy: {}\n", dir.display());
    let args = FitArgs {
        machine: model.clone(),
        data: vec![data],
        validate: Vec::new(),
        output: None,
        solver: SolverArg::Qr,
        tolerance: 1e-10,
        min_norm: false,
        stepwise: None,
        enter: None,
        holdout: None,
        seed: 0,
        noise: None,
        file_noise: Vec::new(),
        noise_per_file: false,
        threads: None,
        engine: kin_model::engine::Engine::default(),
        ignore: Default::default(),
        color,
    };
    for round in 1..=rounds + 1 {
        println!("━━ step {round}: fit {} ━━", model.display());
        let fitted = fitcmd::fit_quietly(&args)?;
        let r = &fitted.report;
        println!(
            "  {} observations, {} coefficients: σ̂ = {:.4} {u}, residual RMS {:.4} {u}",
            r.rows,
            r.columns,
            r.sigma,
            r.rms,
            u = r.error_unit
        );
        // The demo knows its simulated noise: the verdict is made against it.
        let settings = Settings {
            noise: Some(NOISE_UM * 1e-6),
            ..Settings::default()
        };
        let d = diagnose::diagnose(
            &fitted.compiled,
            &fitted.source,
            &fitted.files,
            &fitted.result,
            &fitted.options,
            &settings,
        )
        .map_err(|e| {
            eprintln!("error: {e}");
            Failed::INPUT
        })?;
        let top = d.findings.iter().find(|f| f.significant);
        // A revision about to be replaced keeps its text in its history record.
        let replaced = (top.is_some() && round <= rounds).then_some(fitted.source.as_str());
        fitcmd::record(&model, &fitted, replaced);
        let report = text(&d, r.sigma, r.rms);
        // The diagnosis text without its own header line.
        println!("{}", report.lines().skip(1).collect::<Vec<_>>().join("\n"));
        let Some(top) = top else {
            println!(
                "\n━━ done: {}: σ̂ = {:.4} µm for {NOISE_UM} µm simulated ━━",
                crate::diagnose::verdict(&d),
                r.sigma
            );
            let fit_json = dir.join("fit.json");
            fitcmd::write_report_files(&fit_json, r)?;
            let diagnosis = dir.join("diagnose.json");
            let json = serde_json::to_string_pretty(&d).map_err(|e| {
                eprintln!("error: {e}");
                Failed::USAGE
            })?;
            files::write(&diagnosis, json.as_bytes())?;
            let html = dir.join("report.html");
            crate::report::report_command(&crate::report::ReportArgs {
                machine: model.clone(),
                fit: fit_json,
                diagnose: Some(diagnosis),
                data: args.data.clone(),
                output: html.clone(),
                ignore: Default::default(),
                color,
                compensation: false,
            })?;
            println!("open {} in a browser: residuals, spectra, candidates, the error history and the fitted error curves", html.display());
            return Ok(());
        };
        if round > rounds {
            println!("\n(stopping after {rounds} rounds)");
            return Ok(());
        }
        println!(
            "\n  → adding candidate 1 to the model: {}\n",
            top.candidate.text
        );
        let revision = with_line(
            &fitted.source,
            &top.candidate.text,
            &top.candidate.explanation,
        )?;
        replace_model(&model, &fitted.source, &revision.text)?;
    }
    Ok(())
}
