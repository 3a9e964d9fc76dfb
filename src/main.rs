//! `kin`: check, simulate, evaluate and fit models of multi-axis machines.

mod bench;
mod check;
mod demo;
mod diagnose;
mod fit;
mod load;
mod render;
mod report;
mod simulate;

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(
    name = "kin",
    version,
    about = "Compiler and runtime for .kin models of multi-axis machine errors"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `--ignore`, shared by every command that reads measurement files.
#[derive(clap::Args)]
struct Ignore {
    /// Columns of the data files to skip unread, e.g. `--ignore operator,note` (an unknown
    /// column is an error otherwise).
    #[arg(long = "ignore", value_delimiter = ',', value_name = "COLUMN")]
    columns: Vec<String>,
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
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_runtime::engine::Engine,
    },
    /// Simulate measurements with a known truth: the machine's errors applied exactly
    /// (finite transforms), written in the measurement-file format.
    Simulate {
        machine: PathBuf,
        /// Parameter values (`params { … }` file); the machine's own `params` block otherwise.
        #[arg(long)]
        params: Option<PathBuf>,
        /// Poses to simulate: a point or length file (observed columns are not needed).
        #[arg(long, conflicts_with = "sample")]
        poses: Option<PathBuf>,
        /// Instead of a poses file, sample N poses over the axis ranges.
        #[arg(long)]
        sample: Option<usize>,
        /// Output file (standard output when absent).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Standard deviation of the measurement noise on positions and lengths, e.g. `0.3um`.
        #[arg(long)]
        noise: Option<String>,
        /// Standard deviation of the noise on rotations, e.g. `1urad`.
        #[arg(long)]
        noise_tilt: Option<String>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Standard deviation of each artifact's unknown placement: shift (e.g. `50um`) …
        #[arg(long)]
        artifact_shift: Option<String>,
        /// … and rotation (e.g. `20urad`), drawn once per `artifact` label of a point file.
        #[arg(long)]
        artifact_rotation: Option<String>,
        /// Standard deviation of the unknown length error of each artifact of a length file.
        #[arg(long)]
        artifact_length: Option<String>,
        /// Which error components a point file holds.
        #[arg(long, value_enum, default_value_t = simulate::Components::Position)]
        components: simulate::Components,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, default_value = "auto")]
        color: String,
    },
    /// Fit the model's coefficients to measurement files by least squares.
    Fit {
        machine: PathBuf,
        /// Point and length files (contract §3).
        #[arg(required = true)]
        data: Vec<PathBuf>,
        /// Files to check the fitted model against, not fitted to.
        #[arg(long)]
        validate: Vec<PathBuf>,
        /// Write FIT.json here (and the fitted `params { … }` next to it, as FIT.params).
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = fit::SolverArg::Qr)]
        solver: fit::SolverArg,
        /// Relative tolerance of the rank decision on the unit-scaled design.
        #[arg(long, default_value_t = 1e-10)]
        tolerance: f64,
        /// Fit only what the data can see (minimum norm) when the design is rank-deficient.
        #[arg(long)]
        min_norm: bool,
        /// Stepwise selection: remove regressors whose partial F-test p-value exceeds this
        /// level (the thesis used 1e-4, i.e. 99.99 % significance).
        #[arg(long, value_name = "ALPHA")]
        stepwise: Option<f64>,
        /// With --stepwise: re-admit removed regressors whose p-value falls below this level.
        #[arg(long, value_name = "ALPHA", requires = "stepwise")]
        enter: Option<f64>,
        /// Hold out this fraction of the rows (whole runs where lags need them) as validation.
        #[arg(long, value_name = "FRACTION")]
        holdout: Option<f64>,
        /// Seed of the held-out draw.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_runtime::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, default_value = "auto")]
        color: String,
    },
    /// The whole loop on a bundled example: fit, where it fails, the missing effect, add it,
    /// watch the error fall.
    Demo {
        /// Where to put the working copy of the model and data (a temporary folder otherwise).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// At most this many effects added.
        #[arg(long, default_value_t = 3)]
        rounds: usize,
        #[arg(long, default_value = "auto")]
        color: String,
    },
    /// Where the fitted model fails, and which physical effect is missing from it.
    Diagnose {
        machine: PathBuf,
        #[arg(required = true)]
        data: Vec<PathBuf>,
        /// Family-wise significance level of the candidate tests.
        #[arg(long, default_value_t = 0.01)]
        alpha: f64,
        /// Write DIAGNOSE.json here.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Add candidate N (as numbered in the list) to the model file and refit.
        #[arg(long, value_name = "N")]
        apply: Option<usize>,
        /// The instrument's standard deviation on positions and lengths, e.g. `0.3um`: the
        /// residuals are then judged against it (χ² test, region tests) instead of against the
        /// fit's own σ̂, and only then can the verdict be "down to the noise".
        #[arg(long, value_name = "Q")]
        noise: Option<String>,
        /// The instrument's standard deviation on rotations, e.g. `1urad`.
        #[arg(long, value_name = "Q")]
        noise_tilt: Option<String>,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_runtime::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, default_value = "auto")]
        color: String,
    },
    /// Predicted errors of the first-order model at given poses, as a measurement file.
    Eval {
        machine: PathBuf,
        poses: PathBuf,
        #[arg(long)]
        params: Option<PathBuf>,
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = simulate::Components::Pose)]
        components: simulate::Components,
        /// Add each prediction's standard uncertainty (k = 1, eq. 4.12) as columns `u_ex` …
        /// (`u_dL` for a length file), from the covariance of the fit given as --params FIT.json.
        #[arg(long, requires = "params")]
        uncertainty: bool,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_runtime::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, default_value = "auto")]
        color: String,
    },
    /// A self-contained HTML page about a fit: residuals along every axis, input and time, the residual
    /// spectrum and candidate effects (from `kin diagnose -o`), the history of the model's
    /// revisions, and the fitted parametric errors with their confidence bands.
    Report {
        machine: PathBuf,
        /// The fit report written by `kin fit -o`.
        #[arg(long)]
        fit: PathBuf,
        /// The diagnosis written by `kin diagnose -o`.
        #[arg(long)]
        diagnose: Option<PathBuf>,
        /// The fitted data files, in the fit's order (default: the paths FIT.json records).
        data: Vec<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, default_value = "auto")]
        color: String,
    },
    /// Poses per second of the interpreter and the JIT (and, for examples/milling_5axis.kin, a
    /// hand-written evaluator), and the compile time, measured in one run and printed as ratios.
    /// A measurement on this computer, not a test.
    Bench {
        machine: PathBuf,
        /// Poses sampled over the axis ranges, evaluated in turn.
        #[arg(long, default_value_t = 1000)]
        poses: usize,
        /// Seconds spent on each figure (best of 5 rounds).
        #[arg(long, default_value_t = 0.6)]
        seconds: f64,
        #[arg(long, default_value = "auto")]
        color: String,
    },
}

fn use_color(choice: &str) -> bool {
    match choice {
        "always" => true,
        "never" => false,
        _ => std::io::stderr().is_terminal(),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Check {
            file,
            format,
            color,
            observe,
            aligned,
            no_identify,
            engine,
        } => {
            let color = use_color(&color);
            let identify = (!no_identify).then_some((observe, aligned));
            check::run(&file, format, color, identify, engine)
        }
        Command::Simulate {
            machine,
            params,
            poses,
            sample,
            output,
            noise,
            noise_tilt,
            seed,
            artifact_shift,
            artifact_rotation,
            artifact_length,
            components,
            ignore,
            color,
        } => simulate::simulate(simulate::SimulateArgs {
            machine,
            params,
            poses,
            sample,
            output,
            noise,
            noise_tilt,
            seed,
            artifact_shift,
            artifact_rotation,
            artifact_length,
            components,
            ignore: ignore.columns,
            color: use_color(&color),
        }),
        Command::Fit {
            machine,
            data,
            validate,
            output,
            solver,
            tolerance,
            min_norm,
            stepwise,
            enter,
            holdout,
            seed,
            engine,
            ignore,
            color,
        } => fit::run(fit::FitArgs {
            machine,
            data,
            validate,
            output,
            solver,
            tolerance,
            min_norm,
            stepwise,
            enter,
            holdout,
            seed,
            engine,
            ignore: ignore.columns,
            color: use_color(&color),
        }),
        Command::Demo { dir, rounds, color } => demo::run(dir, rounds, use_color(&color)),
        Command::Diagnose {
            machine,
            data,
            alpha,
            output,
            apply,
            noise,
            noise_tilt,
            engine,
            ignore,
            color,
        } => diagnose::run(diagnose::DiagnoseArgs {
            fit: fit::FitArgs {
                machine,
                data,
                validate: Vec::new(),
                output: None,
                solver: fit::SolverArg::Qr,
                tolerance: 1e-10,
                min_norm: false,
                stepwise: None,
                enter: None,
                holdout: None,
                seed: 0,
                engine,
                ignore: ignore.columns,
                color: use_color(&color),
            },
            alpha,
            output,
            apply,
            noise,
            noise_tilt,
        }),
        Command::Eval {
            machine,
            poses,
            params,
            output,
            components,
            engine,
            ignore,
            uncertainty,
            color,
        } => simulate::eval(simulate::EvalArgs {
            machine: &machine,
            params: params.as_deref(),
            poses: &poses,
            output: output.as_deref(),
            components,
            engine,
            ignore: &ignore.columns,
            uncertainty,
            color: use_color(&color),
        }),
        Command::Report {
            machine,
            fit,
            diagnose,
            data,
            output,
            ignore,
            color,
        } => report::run(report::ReportArgs {
            machine,
            fit,
            diagnose,
            data,
            output,
            ignore: ignore.columns,
            color: use_color(&color),
        }),
        Command::Bench {
            machine,
            poses,
            seconds,
            color,
        } => bench::run(&machine, poses, seconds, use_color(&color)),
    }
}
