//! `kin import urdf`: a robot description turned into a `.kin` machine (spec/urdf.md).

use std::path::Path;
use std::process::ExitCode;

use kin_standards::urdf::{self, Options};

use crate::check::ObserveArg;
use crate::load::Failed;

pub struct Urdf<'a> {
    pub file: &'a Path,
    pub output: Option<&'a Path>,
    pub base: Option<String>,
    pub tip: Option<String>,
    pub observe: ObserveArg,
}

pub fn urdf(args: Urdf<'_>) -> ExitCode {
    Failed::exit(import_urdf(args))
}

fn import_urdf(args: Urdf<'_>) -> Result<(), Failed> {
    if let Some(out) = args.output {
        crate::files::check(out, &[args.file])?;
    }
    let options = Options {
        base: args.base,
        tip: args.tip,
        observe: args.observe.into(),
    };
    let imported = urdf::import_file(args.file, &options).map_err(|e| {
        eprintln!("error: {e}");
        if e.is_usage() {
            Failed::USAGE
        } else {
            eprintln!("note: what kin reads from a URDF file is described in spec/urdf.md");
            Failed::INPUT
        }
    })?;
    let summary = format!(
        "imported robot `{}`: {} moving joints from link `{}` to link `{}`{}, {} coefficients in \
         the default error model{}",
        imported.robot,
        imported.joints.len(),
        imported.base,
        imported.tip,
        if imported.fixed > 0 {
            format!(
                " ({} fixed joint{} folded into the shapes)",
                imported.fixed,
                if imported.fixed == 1 { "" } else { "s" }
            )
        } else {
            String::new()
        },
        imported.coefficients,
        left_out(&imported)
    );
    emit(&imported, args.output, &summary)
}

/// `kin import dh --convention`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum DhConvention {
    Standard,
    Modified,
}

pub struct Dh<'a> {
    pub file: &'a Path,
    pub output: Option<&'a Path>,
    pub convention: DhConvention,
    pub observe: ObserveArg,
}

/// `kin import dh`: a Denavit–Hartenberg table as a `.kin` machine.
pub fn dh(args: Dh<'_>) -> ExitCode {
    Failed::exit(import_dh(args))
}

fn import_dh(args: Dh<'_>) -> Result<(), Failed> {
    if let Some(out) = args.output {
        crate::files::check(out, &[args.file])?;
    }
    let options = Options {
        base: None,
        tip: None,
        observe: args.observe.into(),
    };
    let convention = match args.convention {
        DhConvention::Standard => kin_standards::dh::Convention::Standard,
        DhConvention::Modified => kin_standards::dh::Convention::Modified,
    };
    let imported =
        kin_standards::dh::import_file(args.file, convention, &options).map_err(|e| {
            eprintln!("error: {e}");
            if e.is_usage() {
                Failed::USAGE
            } else {
                eprintln!("note: what kin reads from a DH table is described in spec/urdf.md");
                Failed::INPUT
            }
        })?;
    let summary = format!(
        "imported `{}`: {} joints, {} coefficients in the default error model{}",
        imported.robot,
        imported.joints.len(),
        imported.coefficients,
        left_out(&imported)
    );
    emit(&imported, args.output, &summary)
}

pub struct Export<'a> {
    pub machine: &'a Path,
    pub params: Option<&'a Path>,
    /// The robot's name in a URDF (default: the machine's); unused by a DH table.
    pub name: Option<String>,
    pub output: Option<&'a Path>,
    pub color: bool,
}

/// What `kin export` writes.
#[derive(Debug, Clone, Copy)]
pub enum ExportFormat {
    Urdf,
    Dh,
    C,
}

/// `kin export urdf|dh|c`: the machine with its constant errors folded into a URDF or a DH
/// table, or its evaluator as C source.
pub fn export(args: Export<'_>, format: ExportFormat) -> ExitCode {
    Failed::exit(write_export(args, format))
}

fn write_export(args: Export<'_>, format: ExportFormat) -> Result<(), Failed> {
    if let Some(out) = args.output {
        let mut inputs = vec![args.machine];
        inputs.extend(args.params);
        crate::files::check(out, &inputs)?;
    }
    let compiled = crate::load::machine(args.machine, args.params, args.color)?;
    let m = &compiled.machine;
    if m.beta.len() != m.coefficients.len() && !m.coefficients.is_empty() {
        eprintln!(
            "warning: the model binds no parameter values (a `params` block or --params FILE): \
             the export is the nominal machine"
        );
    }
    let failed = |e: &dyn std::fmt::Display| {
        eprintln!("error: {e}");
        Failed::INPUT
    };
    let (text, mut summary, left_out) = match format {
        ExportFormat::Urdf => {
            let name = args.name.unwrap_or_else(|| m.name.clone());
            let e = urdf::export(m, &name).map_err(|e| failed(&e))?;
            let summary = format!(
                "exported `{name}`: {} joints, {} constant coefficients folded into their origins",
                e.joints, e.folded
            );
            (e.text, summary, e.left_out)
        }
        ExportFormat::Dh => {
            let table = kin_standards::dh::export(m).map_err(|e| failed(&e))?;
            let hayati = table.rows.iter().filter(|r| r.beta != 0.0).count();
            let summary = format!(
                "exported `{}` as a standard DH table: {} joints ({hayati} with Hayati's beta between nearly parallel axes), {} constant coefficients folded, base and {} tool frame{}",
                m.name,
                table.rows.len(),
                table.folded,
                table.tools.len(),
                if table.tools.len() == 1 { "" } else { "s" }
            );
            (
                kin_standards::dh::text(&table, &m.name),
                summary,
                table.left_out,
            )
        }
        ExportFormat::C => {
            let text = kin_model::jit::c_source(m).map_err(|e| failed(&e))?;
            let summary = format!(
                "exported `{}` as C source: the error, the six-row and the position-row β-Jacobians of {} coefficients; compile with -ffp-contract=off for kin's roundings",
                m.name,
                m.coefficients.len()
            );
            (text, summary, Vec::new())
        }
    };
    if !left_out.is_empty() {
        summary.push_str(&format!(
            "; left out as varying with the pose (the format has no place for them): {}",
            left_out.join(", ")
        ));
    }
    match args.output {
        Some(out) => {
            crate::files::write(out, text.as_bytes())?;
            println!("{summary}\nwrote {}", out.display());
        }
        None => {
            print!("{text}");
            eprintln!("{summary}");
        }
    }
    Ok(())
}

/// ` (N redundant terms left out: …)` of an import's summary, or nothing.
fn left_out(imported: &urdf::Imported) -> String {
    if imported.redundant.is_empty() {
        String::new()
    } else {
        format!(
            " ({} redundant terms left out: {})",
            imported.redundant.len(),
            imported.redundant.join(", ")
        )
    }
}

/// An imported model to `output` (the summary to standard output) or to standard output (the
/// summary to standard error).
fn emit(imported: &urdf::Imported, output: Option<&Path>, summary: &str) -> Result<(), Failed> {
    match output {
        Some(out) => {
            crate::files::write(out, imported.source.as_bytes())?;
            println!("{summary}\nwrote {}", out.display());
        }
        None => {
            print!("{}", imported.source);
            eprintln!("{summary}");
        }
    }
    Ok(())
}
