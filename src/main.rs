//! `kin`: check, simulate, evaluate and fit models of multi-axis machines.

mod check;
mod render;

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(name = "kin", version, about = "Compiler and runtime for .kin models of multi-axis machine errors")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Format {
    Human,
    Json,
}

#[derive(Subcommand)]
enum Command {
    /// Type-check a machine: report every problem, or print a summary of the model.
    Check {
        file: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// Colour in diagnostics: auto (on a terminal), always or never.
        #[arg(long, default_value = "auto")]
        color: String,
        /// What the identifiability analysis assumes is observed at poses sampled over the ranges:
        /// the full tool location by default (what the model describes), or less.
        #[arg(long, value_enum, default_value_t = check::ObserveArg::Pose)]
        observe: check::ObserveArg,
        /// Assume the measured artifact's placement is unknown (six alignment parameters).
        #[arg(long)]
        aligned: bool,
        /// Skip the identifiability analysis.
        #[arg(long)]
        no_identify: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Check { file, format, color, observe, aligned, no_identify } => {
            let color = match color.as_str() {
                "always" => true,
                "never" => false,
                _ => std::io::stderr().is_terminal(),
            };
            let identify = (!no_identify).then_some((observe, aligned));
            check::run(&file, format, color, identify)
        }
    }
}
