//! `kin diagnose`: where the model fails, which physical effect is missing, and (with
//! `--apply N`) adding the chosen effect to the model and watching the error fall.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_runtime::diagnose::{self, Diagnosis, Settings};
use kin_runtime::output;

use crate::files;
use crate::fit::{self as fitcmd, FitArgs};
use crate::load::Failed;

pub struct DiagnoseArgs {
    pub fit: FitArgs,
    pub alpha: f64,
    pub output: Option<PathBuf>,
    pub apply: Option<usize>,
    /// Apply a candidate that is not significant.
    pub force: bool,
    /// Show what `--apply` would add; change nothing.
    pub dry_run: bool,
}

pub fn run(a: DiagnoseArgs) -> ExitCode {
    Failed::exit(diagnose_command(&a))
}

fn diagnose_command(a: &DiagnoseArgs) -> Result<(), Failed> {
    if let Some(out) = &a.output {
        let inputs = fitcmd::inputs(&a.fit);
        let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
        files::check(out, &inputs)?;
    }
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
        files::write(out, json.as_bytes())?;
        println!("wrote {}", out.display());
    }
    let Some(n) = a.apply else {
        return Ok(());
    };
    let Some(finding) = n.checked_sub(1).and_then(|i| diagnosis.findings.get(i)) else {
        eprintln!(
            "error: there is no candidate {n}; the list has {}",
            diagnosis.findings.len()
        );
        return Err(Failed::USAGE);
    };
    if !finding.significant && !a.force {
        eprintln!(
            "error: candidate {n} (`{}`) is not significant (adjusted p = {:.2} at α = {}); the model was not changed. \
             Add it anyway with --apply {n} --force",
            finding.candidate.text, finding.p_adjusted, diagnosis.alpha
        );
        return Err(Failed::INPUT);
    }
    let model = &a.fit.machine;
    let revision = with_line(
        &fitted.source,
        &finding.candidate.text,
        &finding.candidate.explanation,
    )?;
    if a.dry_run {
        println!(
            "\n--dry-run: would add to {} at line {} (nothing was written):",
            model.display(),
            revision.line
        );
        for l in &revision.added {
            println!("+ {l}");
        }
        return Ok(());
    }
    replace_model(model, &fitted.source, &revision.text)?;
    println!(
        "\nadded to {}: {}\n(the previous text is in {})\n",
        model.display(),
        finding.candidate.text,
        previous_path(model).display()
    );
    // The fit before the change is recorded with the text it was made of, so the refit prints
    // the fall and the revision can be restored from the history.
    fitcmd::record(model, &fitted.report, Some(&fitted.source));
    fitcmd::fit_command(&a.fit)?;
    Ok(())
}

/// Where `--apply` keeps the model's text from before its last change.
pub fn previous_path(model: &Path) -> PathBuf {
    output::beside(model, ".previous")
}

/// A model's text with a line added, and what was added where (for `--dry-run`).
pub struct Revision {
    pub text: String,
    /// The added lines, as they appear in the new text.
    pub added: Vec<String>,
    /// The 1-based line of the new text where they start.
    pub line: usize,
}

/// `source` with `line` (and a comment saying why) at the end of the model's last `errors`
/// block.
pub fn with_line(source: &str, line: &str, why: &str) -> Result<Revision, Failed> {
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
    let added = vec![
        format!("        // added by `kin diagnose`: {why}"),
        format!("        {line}"),
    ];
    let text = format!("{before}\n\n{}\n    {after}", added.join("\n"));
    Ok(Revision {
        text,
        // `before`, then an empty line.
        line: before.lines().count() + 2,
        added,
    })
}

/// Replaces the model file `path`, whose text was `base` when it was read, with `revised`.
/// Under an advisory lock on `PATH.lock` (so two `--apply` runs take turns) the file is read
/// again: if it is no longer `base` — edited meanwhile, or changed by another `--apply` — nothing
/// is written and the command fails, so no edit is reverted and no added line is lost. `base`
/// is kept in `PATH.previous` before the model is replaced.
pub fn replace_model(path: &Path, base: &str, revised: &str) -> Result<(), Failed> {
    let _lock = output::lock_beside(path).map_err(|e| {
        eprintln!("error: cannot lock `{}`: {e}", path.display());
        Failed::USAGE
    })?;
    let now = std::fs::read_to_string(path).map_err(|e| {
        eprintln!("error: cannot read `{}` again: {e}", path.display());
        Failed::USAGE
    })?;
    if now != base {
        eprintln!(
            "error: `{}` changed since this command read it (edited, or revised by another `kin diagnose --apply`); \
             it was not written, so the change is kept. Diagnose it again.",
            path.display()
        );
        return Err(Failed::USAGE);
    }
    files::write(&previous_path(path), base.as_bytes())?;
    files::write(path, revised.as_bytes())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_changed_since_it_was_read_is_not_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.kin");
        std::fs::write(&model, "base\n// edited meanwhile\n").unwrap();
        assert_eq!(
            replace_model(&model, "base\n", "base\nadded\n"),
            Err(Failed::USAGE)
        );
        assert_eq!(
            std::fs::read_to_string(&model).unwrap(),
            "base\n// edited meanwhile\n"
        );
        assert!(!previous_path(&model).exists());
    }

    #[test]
    fn an_unchanged_model_is_replaced_and_its_text_kept() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.kin");
        std::fs::write(&model, "base\n").unwrap();
        replace_model(&model, "base\n", "base\nadded\n").unwrap();
        assert_eq!(std::fs::read_to_string(&model).unwrap(), "base\nadded\n");
        assert_eq!(
            std::fs::read_to_string(previous_path(&model)).unwrap(),
            "base\n"
        );
    }
}
