//! `kin diagnose`: where the model fails, which physical effect is missing, and (with
//! `--apply N`) adding the chosen effect to the model and watching the error fall.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_runtime::diagnose::{self, Diagnosis, Settings};

use crate::fit::{self as fitcmd, FitArgs};
use crate::load::Failed;

pub struct DiagnoseArgs {
    pub fit: FitArgs,
    pub alpha: f64,
    pub output: Option<PathBuf>,
    pub apply: Option<usize>,
}

pub fn run(a: DiagnoseArgs) -> ExitCode {
    Failed::exit(diagnose_command(&a))
}

fn diagnose_command(a: &DiagnoseArgs) -> Result<(), Failed> {
    let fitted = fitcmd::fit_quietly(&a.fit)?;
    let settings = Settings {
        alpha: a.alpha,
        engine: a.fit.engine,
        ..Settings::default()
    };
    let diagnosis = diagnose::diagnose(
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
    print!(
        "{}",
        text(&diagnosis, fitted.report.sigma, fitted.report.rms)
    );
    if let Some(out) = &a.output {
        let json = serde_json::to_string_pretty(&diagnosis).map_err(|e| {
            eprintln!("error: {e}");
            Failed::USAGE
        })?;
        std::fs::write(out, json).map_err(|e| {
            eprintln!("error: cannot write `{}`: {e}", out.display());
            Failed::USAGE
        })?;
        println!("wrote {}", out.display());
    }
    if let Some(n) = a.apply {
        let Some(finding) = n.checked_sub(1).and_then(|i| diagnosis.findings.get(i)) else {
            eprintln!(
                "error: there is no candidate {n}; the list has {}",
                diagnosis.findings.len()
            );
            return Err(Failed::USAGE);
        };
        apply(
            &a.fit.machine,
            &fitted.source,
            &finding.candidate.text,
            &finding.candidate.explanation,
        )?;
        println!(
            "\nadded to {}: {}\n",
            a.fit.machine.display(),
            finding.candidate.text
        );
        // The history of the fit before the change is recorded, so the refit prints the fall.
        fitcmd::record(&a.fit.machine, &fitted.report);
        fitcmd::fit_command(&a.fit)?;
    }
    Ok(())
}

/// Adds `line` (and a comment saying why) at the end of the model's last `errors` block.
pub fn apply(path: &Path, source: &str, line: &str, why: &str) -> Result<(), Failed> {
    let file = kin_compiler::syntax::parse_file(source).map_err(|d| {
        eprintln!("error: {}", d.message);
        Failed::INPUT
    })?;
    let Some(at) = file.machine.errors_close() else {
        eprintln!("error: the model has no `errors` block to add to");
        return Err(Failed::INPUT);
    };
    let before = source.get(..at).unwrap_or("").trim_end();
    let after = source.get(at..).unwrap_or("");
    let text = format!(
        "{before}\n\n        // added by `kin diagnose`: {why}\n        {line}\n    {after}"
    );
    std::fs::write(path, text).map_err(|e| {
        eprintln!("error: cannot write `{}`: {e}", path.display());
        Failed::USAGE
    })
}

/// The terminal report: where, then what.
pub fn text(d: &Diagnosis, sigma: f64, rms: f64) -> String {
    let u = &d.error_unit;
    let mut s = format!(
        "diagnosis of `{}`: σ̂ = {:.4} {u}, residual RMS {:.4} {u}\n",
        d.machine, sigma, rms
    );
    s.push_str("\nwhere the model fails\n");
    if d.regions.is_empty() {
        s.push_str(
            "  nowhere: along every axis and input the residuals are what the noise allows\n",
        );
    }
    for r in d.regions.iter().take(8) {
        s.push_str(&format!(
            "  {} ({} observations, p = {:.1e})\n",
            r.text, r.rows, r.p
        ));
    }
    let significant: Vec<_> = d.findings.iter().filter(|f| f.significant).collect();
    s.push_str(&format!("\nwhich effect is missing (partial F-tests, Holm–Bonferroni at α = {} over {} candidates)\n", d.alpha, d.findings.len()));
    if significant.is_empty() {
        s.push_str(
            "  no candidate is significant: the model explains the data down to the noise\n",
        );
        if let Some(best) = d.findings.first() {
            s.push_str(&format!(
                "  (the strongest, `{}`, would explain {:.2} % with adjusted p = {:.2})\n",
                best.candidate.text,
                100.0 * best.explained,
                best.p_adjusted
            ));
        }
        return s;
    }
    for (i, f) in significant.iter().enumerate().take(10) {
        s.push_str(&format!(
            "  {:>2}. {:<19} explains {:>5.1} % of the residual variance (F = {:.1}, p = {:.1e}, RMS → {:.4} {u})\n      {}\n      add: {}\n",
            i + 1,
            format!("{:?}", f.candidate.family),
            100.0 * f.explained,
            f.f,
            f.p_adjusted,
            f.rms_after,
            f.candidate.explanation,
            f.candidate.text
        ));
    }
    if significant.len() > 10 {
        s.push_str(&format!(
            "  … and {} more significant candidates (see DIAGNOSE.json)\n",
            significant.len() - 10
        ));
    }
    s.push_str("\n  add one with `kin diagnose … --apply N` (or paste its line into the errors block), then refit\n");
    s
}
