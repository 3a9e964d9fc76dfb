//! `kin init`: a machine template written into a folder, so that a new user starts from a model
//! that checks clean and says in its comments what each block means, instead of an empty file.
//! The templates are `.kin` files beside this one, compiled into the binary; a test checks that
//! each passes `kin check` and `kin fmt --check` (`tests/tutorial.rs`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::ValueEnum;

use crate::load::Failed;

/// The machines `kin init` can start from.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Template {
    /// A bridge coordinate measuring machine: Y bridge, X carriage, Z ram, four styli.
    #[value(name = "bridge-cmm")]
    BridgeCmm,
    /// A 3-axis vertical milling machine: X table on a Y saddle, Z headstock.
    #[value(name = "mill-3axis")]
    Mill3Axis,
    /// A 5-axis table-table mill: X, Y, Z and a C rotary table on an A trunnion.
    #[value(name = "mill-5axis")]
    Mill5Axis,
    /// A 6-axis articulated arm (from a URDF or a DH table: `kin import`).
    #[value(name = "arm-6axis")]
    Arm6Axis,
}

impl Template {
    /// The template's text, as `kin init` writes it.
    pub fn text(self) -> &'static str {
        match self {
            Template::BridgeCmm => include_str!("bridge_cmm.kin"),
            Template::Mill3Axis => include_str!("mill_3axis.kin"),
            Template::Mill5Axis => include_str!("mill_5axis.kin"),
            Template::Arm6Axis => include_str!("arm_6axis.kin"),
        }
    }

    /// The name on the command line (`mill-3axis`).
    fn name(self) -> String {
        self.to_possible_value()
            .map(|v| v.get_name().to_string())
            .unwrap_or_default()
    }

    /// The one-line description `--list` prints (the variant's doc comment).
    fn summary(self) -> String {
        self.to_possible_value()
            .and_then(|v| v.get_help().map(ToString::to_string))
            .unwrap_or_default()
    }
}

/// The file a template is written to, in the folder given.
pub const MODEL: &str = "machine.kin";

/// `kin init [TEMPLATE] [DIR]`: without a template (or with `--list`), the list of templates.
pub fn run(template: Option<Template>, dir: Option<PathBuf>) -> ExitCode {
    match template {
        None => {
            list();
            ExitCode::SUCCESS
        }
        // No folder: the current one, named as the user would (`machine.kin`, not `./machine.kin`).
        Some(t) => Failed::exit(write(t, &dir.unwrap_or_default())),
    }
}

fn list() {
    println!("templates (kin init TEMPLATE [DIR] writes DIR/{MODEL}):");
    let names: Vec<(String, String)> = Template::value_variants()
        .iter()
        .map(|t| (t.name(), t.summary()))
        .collect();
    let width = names.iter().map(|(n, _)| n.len()).max().unwrap_or(0);
    for (name, summary) in names {
        println!("  {name:width$}  {summary}");
    }
}

/// Writes the template as DIR/machine.kin, creating DIR if needed; an existing file of that
/// name is refused (exit 2), never replaced: a user who runs `kin init` twice must not lose the
/// model they have edited since.
fn write(template: Template, dir: &Path) -> Result<(), Failed> {
    let usage = |message: String, file: &Path| {
        eprintln!("error: {message}");
        crate::errors::record("io", message, Some(file), None);
        Failed::USAGE
    };
    if dir.exists() && !dir.is_dir() {
        return Err(usage(
            format!(
                "`{}` is a file, not a folder: give a folder for the template",
                dir.display()
            ),
            dir,
        ));
    }
    let path = dir.join(MODEL);
    // Checked before the folder is created, so a refusal leaves nothing behind; `create_new`
    // checks again at the moment of writing.
    if std::fs::symlink_metadata(&path).is_ok() {
        return Err(exists(&path));
    }
    std::fs::create_dir_all(dir).map_err(|e| {
        usage(
            format!("cannot create the folder `{}`: {e}", dir.display()),
            dir,
        )
    })?;
    let text = template.text();
    kin_data::output::create_new(&path, text.as_bytes()).map_err(|e| {
        if e.kind() == std::io::ErrorKind::AlreadyExists {
            exists(&path)
        } else {
            usage(format!("cannot write `{}`: {e}", path.display()), &path)
        }
    })?;
    crate::warnings::note(&format!(
        "wrote `{}` ({})",
        path.display(),
        crate::warnings::bytes(text.len() as u64)
    ));
    // The summary is the `--list` sentence; in the middle of a line it reads in lower case.
    let summary = template.summary();
    let mut chars = summary.chars();
    let summary: String = chars
        .next()
        .map(|c| c.to_lowercase().chain(chars).collect())
        .unwrap_or_default();
    println!("wrote {}: {summary}", path.display());
    println!(
        "next: read its comments, change it to your machine, then `kin check {}`",
        path.display()
    );
    Ok(())
}

fn exists(path: &Path) -> Failed {
    let message = format!(
        "`{}` exists already; kin init never writes over a file. Choose another folder, or move the file away first.",
        path.display()
    );
    eprintln!("error: {message}");
    crate::errors::record("io", message, Some(path), None);
    Failed::USAGE
}
