//! `kin demo`: the whole loop on a bundled example whose data hide two effects the starting
//! model lacks — fit, where it fails, the top candidate, adding it, the error falling — until
//! nothing significant is left and the residuals are tested against the simulated noise.

use std::path::PathBuf;
use std::process::ExitCode;

use kin_runtime::diagnose::{self, Settings};

use crate::diagnose::{apply, text};
use crate::fit::{self as fitcmd, FitArgs, SolverArg};
use crate::load::Failed;

const START: &str = include_str!("../examples/demo/start.kin");
const POINTS: &str = include_str!("../examples/demo/points.csv");
/// The noise the bundled data were simulated with, in µm.
const NOISE_UM: f64 = 0.2;

pub fn run(dir: Option<PathBuf>, rounds: usize, color: bool) -> ExitCode {
    Failed::exit(demo(dir, rounds, color))
}

fn demo(dir: Option<PathBuf>, rounds: usize, color: bool) -> Result<(), Failed> {
    let dir = dir.unwrap_or_else(|| std::env::temp_dir().join("kin-demo"));
    let write = |name: &str, text: &str| -> Result<PathBuf, Failed> {
        std::fs::create_dir_all(&dir).map_err(|e| {
            eprintln!("error: cannot create `{}`: {e}", dir.display());
            Failed::USAGE
        })?;
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| {
            eprintln!("error: cannot write `{}`: {e}", path.display());
            Failed::USAGE
        })?;
        Ok(path)
    };
    let model = write("bridge_cmm.kin", START)?;
    let data = write("points.csv", POINTS)?;
    let _ = std::fs::remove_file(kin_runtime::history::path_for(&model));
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
        engine: kin_runtime::engine::Engine::default(),
        ignore: Vec::new(),
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
        fitcmd::record(&model, r);
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
        let report = text(&d, r.sigma, r.rms);
        // The diagnosis text without its own header line.
        println!("{}", report.lines().skip(1).collect::<Vec<_>>().join("\n"));
        let Some(top) = d.findings.iter().find(|f| f.significant) else {
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
            std::fs::write(&diagnosis, json).map_err(|e| {
                eprintln!("error: cannot write `{}`: {e}", diagnosis.display());
                Failed::USAGE
            })?;
            let html = dir.join("report.html");
            crate::report::report_command(&crate::report::ReportArgs {
                machine: model.clone(),
                fit: fit_json,
                diagnose: Some(diagnosis),
                data: args.data.clone(),
                output: html.clone(),
                ignore: Vec::new(),
                color,
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
        apply(
            &model,
            &fitted.source,
            &top.candidate.text,
            &top.candidate.explanation,
        )?;
    }
    Ok(())
}
