//! `kin`: check, simulate, evaluate and fit models of multi-axis machines.

mod args;
mod bench;
mod check;
mod compensate;
mod correct;
mod demo;
mod design;
mod diagnose;
mod errors;
mod files;
mod fit;
mod fmt;
mod folder;
mod grid;
mod help;
mod import;
mod init;
mod iso;
mod iso_html;
mod load;
mod manual;
mod predict;
mod render;
mod report;
mod rounds;
mod simulate;
mod warnings;
mod writeback;

use std::path::PathBuf;
use std::process::ExitCode;

use args::{Color, Spread};
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(
    name = "kin",
    version,
    about = "Compiler and runtime for .kin models of multi-axis machine errors"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Do not print warnings of these codes, e.g. `--allow W0101,W0801` (spec/cli.md lists
    /// them); errors are always printed.
    #[arg(long, global = true, value_delimiter = ',', value_name = "CODE", value_parser = warnings::parse_code)]
    allow: Vec<String>,
    /// Print no warnings and no progress bars (errors and results as usual).
    #[arg(short, long, global = true)]
    quiet: bool,
    /// Say on standard error what each step did: the files read and written with their sizes
    /// and rows, the time each step took, the engine used, the run's total time.
    #[arg(short, long, global = true, conflicts_with = "quiet")]
    verbose: bool,
    /// Make poses outside an axis's declared range an error (exit 1) instead of warning W0801.
    #[arg(long, global = true)]
    strict: bool,
}

/// `--ignore` and `--delimiter`, shared by every command that reads measurement files.
#[derive(clap::Args)]
struct Ignore {
    /// Columns of the data files to skip unread, e.g. `--ignore operator,note` (an unknown
    /// column is an error otherwise).
    #[arg(long = "ignore", value_delimiter = ',', value_name = "COLUMN")]
    columns: Vec<String>,
    /// The data files' separator: `,`, `;` or `tab` (detected from the header line otherwise;
    /// with `;` or `tab` numbers may use a decimal comma; spec/data.md).
    #[arg(long, value_name = "SEP", value_parser = args::delimiter)]
    delimiter: Option<u8>,
}

impl Ignore {
    fn options(self) -> args::DataOptions {
        args::DataOptions {
            ignore: self.columns,
            delimiter: self.delimiter,
            threads: None,
        }
    }
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Format {
    Human,
    Json,
}

#[derive(Subcommand)]
enum Command {
    /// Start a new machine from a template: a commented `.kin` model that checks clean, written
    /// as DIR/machine.kin (never over an existing file). Without a template, the list.
    #[command(after_help = "Examples:
  kin init --list                   # the templates, one line each
  kin init mill-3axis mill          # writes mill/machine.kin; then: kin check mill/machine.kin
  kin init bridge-cmm               # writes machine.kin in the current folder")]
    Init {
        /// The machine to start from.
        #[arg(value_enum)]
        template: Option<init::Template>,
        /// The folder to write machine.kin into, created if it does not exist (default: the
        /// current folder).
        #[arg(value_name = "DIR")]
        dir: Option<PathBuf>,
        /// List the templates, one line each (what `kin init` alone does too).
        #[arg(long, conflicts_with_all = ["template", "dir"])]
        list: bool,
    },
    /// Type-check a machine: report every problem, or print a summary of the model.
    #[command(after_help = "Examples:
  kin check examples/bridge_cmm.kin
  kin check examples/milling_5axis.kin --observe position --format json
  kin check mill.kin --no-identify          # syntax, types and units only")]
    Check {
        file: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// Colour in diagnostics: auto (on a terminal), always or never.
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
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
        /// Instead of sampled poses, analyse this plan: point or length files (error columns
        /// not needed), together; reports what it determines (spec/design.md).
        #[arg(long, num_args = 1.., value_name = "FILE")]
        plan: Vec<PathBuf>,
        /// With --plan: every group, combination and coefficient (σ per unit noise, VIF), not
        /// only the summary per error component.
        #[arg(long, requires = "plan")]
        detail: bool,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
    },
    /// Simulate measurements with a known truth: the machine's errors applied exactly
    /// (finite transforms), written in the measurement-file format.
    #[command(after_help = "Examples:
  kin simulate examples/bridge_cmm.kin --sample 2000 --noise 0.3um --seed 7 -o points.csv
  kin simulate mill.kin --poses plan.csv --components pose -o measured.csv
  kin simulate mill.kin --cycle 'spindle T_spindle 2 K per 1000 rpm tau 40 min; warmup 8000 rpm 2 h; stop 1 h' --every 2min --noise 0.5um -o warmup.csv
  kin simulate mill.kin --cycle cycle.csv --poses corners.csv --noise 0.5um -o measured.csv")]
    Simulate {
        machine: PathBuf,
        /// Parameter values (`params { … }` file); the machine's own `params` block otherwise.
        #[arg(long)]
        params: Option<PathBuf>,
        /// Poses to simulate: a point or length file (observed columns are not needed; the
        /// format is in spec/data.md).
        #[arg(long, conflicts_with = "sample")]
        poses: Option<PathBuf>,
        /// Instead of a poses file, sample N poses over the axis ranges (1 to 10⁸).
        #[arg(long, value_parser = args::poses)]
        sample: Option<usize>,
        /// A duty cycle: a time series file (`time`, inputs, optionally `run` and axis
        /// columns; spec/data.md) or a generator such as `spindle T_s 2 K per 1000 rpm tau
        /// 40 min; warmup 8000 rpm 2 h; steps 2000,4000 rpm 30 min; stop 1 h` (spec/cli.md,
        /// "Duty cycles"). Each sample is measured at every pose of --poses (default: every axis
        /// at mid-range), so the lag states evolve as in a real warm-up.
        #[arg(long, conflicts_with = "sample", value_name = "FILE|TEXT")]
        cycle: Option<String>,
        /// With a generated --cycle: the sampling interval (default 1min).
        #[arg(long, requires = "cycle", value_parser = args::duration)]
        every: Option<Spread>,
        /// Output file (standard output when absent); never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// `json`: standard output holds the measurements as one JSON document (spec/json.md,
        /// "Measurements"); `-o` still writes the file.
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// Standard deviation of the measurement noise on positions and lengths, e.g. `0.3um`.
        #[arg(long, value_parser = args::length_spread, allow_hyphen_values = true)]
        noise: Option<Spread>,
        /// Standard deviation of the noise on rotations, e.g. `1urad`.
        #[arg(long, value_parser = args::angle_spread, allow_hyphen_values = true)]
        noise_tilt: Option<Spread>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Standard deviation of each artifact's unknown placement: shift (e.g. `50um`) …
        #[arg(long, value_parser = args::length_spread, allow_hyphen_values = true)]
        artifact_shift: Option<Spread>,
        /// … and rotation (e.g. `20urad`), drawn once per `artifact` label of a point file.
        #[arg(long, value_parser = args::angle_spread, allow_hyphen_values = true)]
        artifact_rotation: Option<Spread>,
        /// Standard deviation of the unknown length error of each artifact of a length file.
        #[arg(long, value_parser = args::length_spread, allow_hyphen_values = true)]
        artifact_length: Option<Spread>,
        /// Which error components a point file holds.
        #[arg(long, value_enum, default_value_t = simulate::Components::Position)]
        components: simulate::Components,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Fit the model's coefficients to measurement files by least squares.
    #[command(after_help = "Examples:
  kin fit examples/bridge_cmm.kin examples/data/bridge_cmm_points.csv -o fit.json
  kin fit mill.kin laser_x.csv ballbar.csv --noise 0.5um -o fit.json
  kin fit mill.kin points.csv --stepwise 1e-4 --holdout 0.2 -o fit.json
  kin fit mill.kin big_run.csv --threads 2 -o fit.json")]
    Fit {
        machine: PathBuf,
        /// Point and length files (measurement files: spec/data.md). Files of 64 MiB or more
        /// together are read a block of rows at a time and never held whole (not with
        /// --validate, --holdout, --noise, fitted wavelengths or time constants, or lags;
        /// spec/cli.md).
        #[arg(required = true)]
        data: Vec<PathBuf>,
        /// Files to check the fitted model against, not fitted to.
        #[arg(long)]
        validate: Vec<PathBuf>,
        /// Write FIT.json here (and the fitted `params { … }` next to it, as FIT.params); never
        /// one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = fit::SolverArg::Qr)]
        solver: fit::SolverArg,
        /// Relative tolerance of the rank decision on the unit-scaled design (0 < T < 1): a
        /// direction whose singular value is below T times the largest is not determined.
        #[arg(long, default_value_t = 1e-10, value_parser = args::tolerance, allow_hyphen_values = true)]
        tolerance: f64,
        /// Fit only what the data can see (minimum norm) when the design is rank-deficient.
        #[arg(long)]
        min_norm: bool,
        /// Stepwise selection: remove regressors whose partial F-test p-value exceeds this
        /// level (the thesis used 1e-4, i.e. 99.99 % significance); 0 < ALPHA < 1.
        #[arg(long, value_name = "ALPHA", value_parser = args::level, allow_hyphen_values = true)]
        stepwise: Option<f64>,
        /// With --stepwise: re-admit removed regressors whose p-value falls below this level
        /// (0 < ALPHA < 1).
        #[arg(
            long,
            value_name = "ALPHA",
            requires = "stepwise",
            value_parser = args::level,
            allow_hyphen_values = true
        )]
        enter: Option<f64>,
        /// Hold out this fraction of the rows (whole runs where lags need them) as validation
        /// (0 < FRACTION < 1).
        #[arg(long, value_name = "FRACTION", value_parser = args::fraction, allow_hyphen_values = true)]
        holdout: Option<f64>,
        /// Seed of the held-out draw.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// The instrument's standard deviation on positions and lengths, e.g. `0.3um`: every
        /// row is divided by its stated noise (weighted least squares), σ̂ becomes σ̂/σ and is
        /// tested against 1 (χ²). Rotation rows then need --noise-tilt. `FILE=Q` (repeatable)
        /// states one data file's own σ, as a `# noise: Q` line above its header does; files
        /// without one then get a σ estimated per file (spec/cli.md, "Noise per file").
        #[arg(long, value_name = "[FILE=]Q", value_parser = args::noise_arg, allow_hyphen_values = true)]
        noise: Vec<args::NoiseArg>,
        /// Estimate a σ per data file (and kind of row) wherever none is stated: variance
        /// components, reweighted until stable, each file's rows weighed by its own σ.
        #[arg(long)]
        noise_per_file: bool,
        /// The instrument's standard deviation on rotations, e.g. `1urad`.
        #[arg(long, value_name = "Q", value_parser = args::stated_angle_noise, allow_hyphen_values = true)]
        noise_tilt: Option<Spread>,
        /// `json`: standard output holds FIT.json alone (spec/json.md), `-o` still writes it.
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
        /// Threads evaluating the rows, factoring them and computing their leverages, each its
        /// own share (1 to 256; default every core this process may use). The same count gives
        /// the same bits on every run.
        #[arg(long, value_name = "N", value_parser = args::threads)]
        threads: Option<usize>,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// The whole loop on a bundled example: fit, where it fails, the missing effect, add it,
    /// watch the error fall.
    #[command(after_help = "Examples:
  kin demo
  kin demo --dir demo --rounds 1     # keep the working copy, add one effect")]
    Demo {
        /// Where to put the working copy of the model and data (a temporary folder otherwise): a
        /// new or empty folder, or one an earlier `kin demo` wrote (marked by `.kin-demo`).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// At most this many effects added (0 to 100).
        #[arg(long, default_value_t = 3, value_parser = args::rounds)]
        rounds: usize,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Where the fitted model fails, and which physical effect is missing from it.
    #[command(after_help = "Examples:
  kin diagnose examples/bridge_cmm.kin examples/data/bridge_cmm_points.csv
  kin diagnose mill.kin points.csv --noise 0.3um -o diagnose.json
  kin diagnose mill.kin poses.csv --noise 0.3um --noise-tilt 20urad   # µm and µrad rows weighed by their σ
  kin diagnose mill.kin points.csv --apply 1 --dry-run     # show the line, change nothing")]
    Diagnose {
        machine: PathBuf,
        /// Point and length files (measurement files: spec/data.md).
        #[arg(required = true)]
        data: Vec<PathBuf>,
        /// Family-wise significance level of the candidate tests (0 < A < 1).
        #[arg(long, default_value_t = 0.01, value_parser = args::level, allow_hyphen_values = true)]
        alpha: f64,
        /// Write DIAGNOSE.json here; never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Add candidate N (as numbered in the list) to the model file and refit; refused if the
        /// file changed since it was read. The text before the change is kept in
        /// MACHINE.previous and in its history record.
        #[arg(long, value_name = "N")]
        apply: Option<usize>,
        /// With --apply: add a candidate that is not significant, or whose refit is doubtful
        /// (refused otherwise).
        #[arg(long, requires = "apply")]
        force: bool,
        /// With --apply: print the lines that would be added, change nothing.
        #[arg(long, requires = "apply")]
        dry_run: bool,
        /// Also list every candidate proposed that is not a finding, with the reason (already
        /// in the model, not testable on these data, another reading chosen, …).
        #[arg(long)]
        explain: bool,
        /// The instrument's standard deviation on positions and lengths, e.g. `0.3um`: every fit
        /// of the diagnosis divides each row by its kind's σ (weighted least squares), and the
        /// residuals are judged against it (χ² test, region tests) instead of against the
        /// fit's own σ̂; only then can the verdict be "down to the noise". `FILE=Q`
        /// (repeatable) states one data file's own σ, as a `# noise: Q` line above its header
        /// does; the other files' σs are then estimated per file, every fit of the diagnosis
        /// weighs each file by its own, and outliers are judged against it.
        #[arg(long, value_name = "[FILE=]Q", value_parser = args::noise_arg, allow_hyphen_values = true)]
        noise: Vec<args::NoiseArg>,
        /// Estimate a σ per data file (and kind of row) wherever none is stated, and weigh
        /// every fit of the diagnosis by it.
        #[arg(long)]
        noise_per_file: bool,
        /// The instrument's standard deviation on rotations, e.g. `20urad` (pose data need both).
        #[arg(long, value_name = "Q", value_parser = args::stated_angle_noise, allow_hyphen_values = true)]
        noise_tilt: Option<Spread>,
        /// `json`: standard output holds DIAGNOSE.json alone (spec/json.md); not with --apply.
        #[arg(long, value_enum, default_value_t = Format::Human, conflicts_with = "apply")]
        format: Format,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Turn another format's machine description into a `.kin` model.
    #[command(
        subcommand,
        after_help = "Examples:
  kin import urdf examples/urdf/ur5.urdf -o ur5.kin"
    )]
    Import(ImportCommand),
    /// Write a machine in another format, with its fitted values.
    #[command(
        subcommand,
        after_help = "Examples:
  kin export urdf examples/robot_6axis.kin --params FIT.params -o robot.urdf"
    )]
    Export(ExportCommand),
    /// ISO 230-2 figures of a bidirectional positioning run along one axis: per target the
    /// mean deviations, standard uncertainties and reversal value; E, M, B, R and A.
    #[command(
        name = "iso230-2",
        after_help = "Examples:
  kin iso230-2 run.csv
  kin iso230-2 run.csv --html run.html          # the standard's plot of x̄ ± 2s per direction
  kin iso230-2 run.csv --model mill.kin --fit fit.json --axis X --at Y=0mm,Z=-100mm"
    )]
    Iso2302 {
        /// The run: columns target, deviation, direction (+1/-1), cycle (spec/iso230-2.md).
        run: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// Write an HTML page with the figures and the plot of the mean deviations ± 2s per
        /// direction; never the run, replaced atomically.
        #[arg(long, value_name = "OUT.html")]
        html: Option<PathBuf>,
        /// Test this model's predicted errors against the run: the lack-of-fit F-test against
        /// the scatter of the replicates at each target and direction (spec/iso230-2.md).
        #[arg(long, requires = "axis")]
        model: Option<PathBuf>,
        /// With --model: the model's parameters (FIT.json or a params file); its own otherwise.
        #[arg(long, requires = "model")]
        fit: Option<PathBuf>,
        /// With --model: the axis the run moved.
        #[arg(long, requires = "model")]
        axis: Option<String>,
        /// With --model: where the other axes stood, e.g. `Y=0mm,Z=-100mm` (the middle of their
        /// ranges otherwise).
        #[arg(long, value_delimiter = ',', value_name = "AXIS=Q", value_parser = axis_value, requires = "model")]
        at: Vec<(String, String)>,
        /// With --model: the error component the run measured, `ex` … `erz`, `-ex` to flip its
        /// sign (default: the one along the axis).
        #[arg(long, requires = "model", allow_hyphen_values = true)]
        component: Option<String>,
        /// With --model: significance level of the test (0 < A < 1).
        #[arg(long, default_value_t = 0.01, value_parser = args::level, allow_hyphen_values = true)]
        alpha: f64,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// ISO 230-3 figures of thermal tests from their time series: the environmental temperature
    /// variation error (ETVE, each displacement's range) and the spindle thermal drift (each
    /// displacement's drift from the start, the spindle axis' tilts from sensor pairs), with
    /// the drift and temperature plots.
    #[command(
        name = "iso230-3",
        after_help = "Examples:
  kin iso230-3 etve.csv
  kin iso230-3 spindle.csv --html spindle.html   # drift, tilts and temperatures over time
  kin iso230-3 spindle.csv --format json"
    )]
    Iso2303 {
        /// The test: columns time, displacements X Y Z (or X1 X2 Y1 Y2 Z1 Z2 with
        /// `# separation: 100 mm` before the header) and temperatures T… (spec/iso230-3.md).
        run: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// A self-contained HTML page with the standard's plots.
        #[arg(long, value_name = "OUT.html")]
        html: Option<PathBuf>,
    },
    /// ISO 230-4 figures of circular tests (a ball bar): per direction the circular deviation
    /// G, radial deviation F, least-squares centre offset and radius error; the bidirectional G
    /// and the circular hysteresis H; a polar plot; the samples as lengths for a fit.
    #[command(
        name = "iso230-4",
        after_help = "Examples:
  kin iso230-4 ballbar.csv
  kin iso230-4 ballbar.csv --html ballbar.html   # the polar plot of both directions
  kin iso230-4 ballbar.csv --radius 150mm --plane X,Y --lengths bars.csv --centre X=250mm,Y=250mm,Z=-100mm"
    )]
    Iso2304 {
        /// The test: columns angle, deviation, direction (ccw/cw), optionally run; the radius,
        /// plane and feed in `# key: value` lines before the header (spec/iso230-4.md).
        run: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        /// The nominal radius, e.g. `150mm` (overrides the file's `# radius:` line).
        #[arg(long, value_name = "Q", value_parser = args::radius)]
        radius: Option<f64>,
        /// The plane's two axes, first to second counter-clockwise, e.g. `X,Y` (overrides the
        /// file's `# plane:` line).
        #[arg(long, value_name = "A,B", value_parser = plane_arg)]
        plane: Option<[String; 2]>,
        /// Write an HTML page with the figures and the polar plot of each run; never the test
        /// file, replaced atomically.
        #[arg(long, value_name = "OUT.html")]
        html: Option<PathBuf>,
        /// Write the samples as a length file for `kin fit` (spec/data.md): the pivot at the
        /// centre pose, the circle point, one artifact per run; needs --centre, the radius and
        /// the plane.
        #[arg(long, value_name = "OUT.csv", requires = "centre")]
        lengths: Option<PathBuf>,
        /// With --lengths: the centre pose, every axis of the machine, e.g.
        /// `X=250mm,Y=250mm,Z=-100mm`.
        #[arg(long, value_delimiter = ',', value_name = "AXIS=Q", value_parser = axis_value, requires = "lengths")]
        centre: Vec<(String, String)>,
        /// With --lengths: the machine is a measuring machine (`task measure`): dL is the
        /// reading with its sign flipped (spec/iso230-4.md).
        #[arg(long, requires = "lengths")]
        measure: bool,
    },
    /// The fitted model's drift over a duty cycle (a time series of inputs), with its standard
    /// uncertainty including the fitted time constants', and against the observations the cycle
    /// holds (thesis §5.1.3).
    ///
    /// The cycle is a measurement file with `time` and the model's inputs (spec/data.md, "Time
    /// series"); without --poses the drift is predicted at the cycle's own axis columns, or, when
    /// it has none, with every axis at the middle of its range. The output is a measurement file:
    /// the prediction as `ex … erz`, its standard uncertainty as `u_…`, the observations as `obs_…`.
    #[command(after_help = "Examples:
  kin predict mill.kin --fit warmup_fit.json stepped_cycle.csv -o drift.csv --html drift.html
  kin predict mill.kin --fit warmup_fit.json cycle.csv --poses corners.csv -o drift.csv")]
    Predict {
        machine: PathBuf,
        /// The fit report written by `kin fit -o` (its values and covariance).
        #[arg(long)]
        fit: PathBuf,
        /// The duty cycle: `time`, the inputs, optionally `run`, axis columns and observations.
        cycle: PathBuf,
        /// A point file of poses at which to predict the drift (each over the whole cycle).
        #[arg(long)]
        poses: Option<PathBuf>,
        /// Output file (standard output when absent); never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// A self-contained HTML page: the drift over time with its band, and the observations.
        #[arg(long, value_name = "R.html")]
        html: Option<PathBuf>,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Predicted errors of the first-order model at given poses, as a measurement file.
    #[command(after_help = "Examples:
  kin eval mill.kin poses.csv --params fit.json --uncertainty -o predicted.csv
  kin eval mill.kin poses.csv --params fit.json --uncertainty --ellipsoid 95 -o predicted.csv
  kin eval robot.kin joints.csv --nominal -o poses.csv      # forward kinematics, with the errors")]
    Eval {
        machine: PathBuf,
        /// A point or length file of poses; observed columns are not needed (spec/data.md).
        poses: PathBuf,
        #[arg(long)]
        params: Option<PathBuf>,
        /// Output file (standard output when absent); never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// `json`: standard output holds the predictions as one JSON document (spec/json.md,
        /// "Measurements"); `-o` still writes the file.
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        #[arg(long, value_enum, default_value_t = simulate::Components::Pose)]
        components: simulate::Components,
        /// Add each prediction's standard uncertainty (k = 1, eq. 4.12) as columns `u_ex` …
        /// (`u_dL` for a length file), from the covariance of the fit given as --params FIT.json.
        #[arg(long, requires = "params")]
        uncertainty: bool,
        /// With --uncertainty: the confidence ellipsoid of each pose's position error at this
        /// level in percent (e.g. `--ellipsoid 95`): semi-axes `ell_a1…3` and their directions
        /// `ell_u1x … ell_u3z` (point files).
        #[arg(long, requires = "uncertainty", value_parser = args::percent)]
        ellipsoid: Option<f64>,
        /// Add the nominal tool pose in the workpiece frame (a point file): position `px`, `py`,
        /// `pz` (length unit) and orientation `prx`, `pry`, `prz` (rotation vector, angle unit),
        /// the forward kinematics of the nominal machine.
        #[arg(long)]
        nominal: bool,
        /// What evaluates the model: the JIT (native code) or the interpreter (the reference).
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// A self-contained HTML page about a fit: residuals along every axis, input and time, the residual
    /// spectrum and candidate effects (from `kin diagnose -o`), the history of the model's
    /// revisions, and the fitted parametric errors with their confidence bands.
    #[command(after_help = "Examples:
  kin report mill.kin --fit fit.json --diagnose diagnose.json -o report.html
  kin report mill.kin --fit fit.json points.csv -o report.html   # data moved since the fit
  kin report mill.kin --fit fit.json --compensation -o report.html")]
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
        /// The HTML page to write; never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: PathBuf,
        /// Add a section with the predicted error before and after compensation along each
        /// axis (a positioning machine; as `kin compensate` computes it) and what stays.
        #[arg(long)]
        compensation: bool,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Corrections of a positioning machine's axes that cancel its fitted errors (Soons 1993,
    /// §2.3.5), at commanded poses, or as controller tables.
    ///
    /// The CSV holds per pose the predicted error (ex … erz), the correction to add to each
    /// axis command (corr_AXIS), the error the model predicts after it (rest_…: what the axes
    /// cannot correct) and the standard uncertainty of the prediction (u_…).
    #[command(
        verbatim_doc_comment,
        after_help = "Examples:
  kin compensate mill.kin --fit fit.json --grid X=0:500:50,Y=0:400:50,Z=-100 -o corrections.csv
  kin compensate mill.kin --fit fit.json --poses commanded.csv --correct position -o corrections.csv
  kin compensate mill.kin --fit fit.json --grid X=0:500:25 --table linuxcnc -o tables/
  kin compensate mill.kin --fit fit.json --grid X=0:500:25,Y=0:400:25,Z=-100 --table sinumerik -o sinumerik/
  kin compensate mill.kin --fit fit.json --grid X=0:500:10,Y=0:400:10,Z=-300:0:10 --table volcomp -o volcomp/"
    )]
    Compensate {
        machine: PathBuf,
        /// The fit report written by `kin fit -o` (a fit of another machine is refused).
        #[arg(long)]
        fit: PathBuf,
        /// Commanded poses: a point file's pose columns (axes, dir_AXIS, tool, inputs, time).
        #[arg(long, conflicts_with = "grid", required_unless_present = "grid")]
        poses: Option<PathBuf>,
        /// Commanded poses on a grid: comma-separated NAME=VALUE or NAME=FROM:TO:STEP, NAME an
        /// axis (the model's length or angle unit) or an input (its declared unit), plus
        /// dir_AXIS=+1|-1 and tool=NAME. A range always ends at TO; an axis left out is held
        /// at 0. Example: X=0:500:50,Y=0:400:50,Z=-100,T_spindle=0.
        #[arg(long, value_name = "SPEC")]
        grid: Option<String>,
        /// What the corrections minimise: the whole tool location or its position only.
        #[arg(long, value_enum, default_value_t = compensate::Correct::Pose)]
        correct: compensate::Correct,
        /// The axes the corrections of --poses or --grid may move, comma-separated (e.g.
        /// X,Y,Z); the others stay at the commanded positions. Default: every axis for
        /// `--correct pose`; for `--correct position` the prismatic axes (every axis of a
        /// machine without one, such as an arm).
        #[arg(long, value_name = "AXES", conflicts_with = "table")]
        axes: Option<String>,
        /// Write controller tables instead of the CSV, into the folder -o, for every axis --grid
        /// ranges over (the grid's STEP is the table's spacing), evaluated with the other axes at
        /// the middle of their grid values; kin-compensation.txt and standard error say what the
        /// tables cannot hold, each table's interpolation error and the error left over the
        /// grid. `linuxcnc`: AXIS.comp (COMP_FILE, COMP_FILE_TYPE = 0), both directions, in the
        /// model's units. `sinumerik`: AX_EEC.INI ($AA_ENC_COMP leadscrew tables) and NC_CEC.INI
        /// ($AN_CEC tables of one axis's correction along another, and per-direction tables
        /// where the model has backlash), mm/deg, equidistant grid. `isg-lsec`: AXIS.lis (ISG
        /// kw.ssfk bilateral leadscrew lists, 0.1 um). `volcomp`: AXIS.csv (ISG CSV, the ISO
        /// 230-1 component errors X EXX EYX EZX EAX EBX ECX of axes named X Y Z A B C, mm and
        /// rad).
        #[arg(long, value_enum, requires = "grid")]
        table: Option<compensate::Table>,
        /// The CSV (a folder with --table); never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// A measuring machine's coordinates corrected by its fitted model: measured minus
    /// predicted error, with each corrected coordinate's standard uncertainty (eq. 4.12).
    ///
    /// POINTS.csv holds a pose per row (axis positions, dir_AXIS, tool, inputs, time, as in a
    /// point file; error columns there are not read into the result). The output adds the
    /// measured coordinates x y z (nominal kinematics), x_corrected …, and u_x ….
    #[command(
        verbatim_doc_comment,
        after_help = "Examples:
  kin correct cmm.kin --fit fit.json points.csv -o corrected.csv"
    )]
    Correct {
        machine: PathBuf,
        /// The fit report written by `kin fit -o` (a fit of another machine is refused).
        #[arg(long)]
        fit: PathBuf,
        points: PathBuf,
        /// The corrected CSV; never one of the inputs, replaced atomically.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Plan a calibration: choose N of the candidate measurements that determine the model best
    /// (D-optimal, artifacts' placements as nuisance parameters), or score a plan (spec/design.md).
    #[command(after_help = "Examples:
  kin design cmm.kin --generate ballbar --plane X,Y -o candidates.csv
  kin design mill.kin --generate stepgauge --axis X --pitch 20mm --levels 3 -o gauge.csv
  kin design cmm.kin --generate plate --plane X,Y --length 400mm --step 100mm -o plates.csv
  kin design mill.kin --generate rtest --sphere 0,0,50 --sphere 150,0,80 -o rtest.csv
  kin design cmm.kin --candidates candidates.csv -n 6 -o plan.csv
  kin design cmm.kin --evaluate my_plan.csv --candidates candidates.csv")]
    Design {
        machine: PathBuf,
        /// A point or length file of candidate measurements (error columns not needed); rows of
        /// one `artifact` label are chosen together.
        #[arg(long)]
        candidates: Option<PathBuf>,
        /// How many units (rows, or artifact labels) to choose; a unit may be chosen twice.
        #[arg(short = 'n', value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
        n: Option<u64>,
        /// The plan to write: the candidate file's header and the chosen lines.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Score this plan instead (prediction variances over --candidates when given).
        #[arg(long, conflicts_with_all = ["n", "output"])]
        evaluate: Option<PathBuf>,
        /// Write candidates for an artifact to -o instead: `ballbar` (bars in a plane),
        /// `stepgauge` (along an axis), `plate` (ball or hole plate in a plane, each placement an
        /// artifact), `rtest` (a sphere followed through the rotary axes' sweeps).
        #[arg(long, value_parser = ["ballbar", "stepgauge", "plate", "rtest"], conflicts_with_all = ["candidates", "evaluate", "n"])]
        generate: Option<String>,
        /// Ball bar: its length; step gauge: first to last face; plate: the side of its grid.
        #[arg(long, value_parser = args::length_spread, default_value = "400mm")]
        length: Spread,
        /// The grid step of the artifact's placement (first sphere, first face, first feature).
        #[arg(long, value_parser = args::length_spread, default_value = "50mm")]
        step: Spread,
        /// Step gauge: the spacing of its faces; plate: the spacing of its features.
        #[arg(long, value_parser = args::length_spread, default_value = "50mm")]
        pitch: Spread,
        /// Ball bar: its orientation step; plate: its rotation step; R-test: the rotary axes' step.
        #[arg(long, value_parser = args::angle_spread, default_value = "15deg")]
        angle_step: Spread,
        /// Ball bar, plate: the two prismatic axes of the plane, e.g. `--plane X,Y` (default: the first two).
        #[arg(long, value_delimiter = ',')]
        plane: Vec<String>,
        /// Step gauge: the prismatic axis it lies along (default: the first).
        #[arg(long)]
        axis: Option<String>,
        /// Positions of each prismatic axis outside the plane or across the gauge, evenly spaced
        /// with the ends included (1: the middle of the range).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=100))]
        levels: u64,
        /// R-test: a sphere centre in the workpiece frame, `x,y,z` (mm unless a unit is given);
        /// repeat for more spheres (default: (0,0,50), (100,0,50), (0,100,50) mm).
        #[arg(long, value_parser = args::point)]
        sphere: Vec<[f64; 3]>,
        /// Every group, combination and coefficient (σ per unit noise, VIF), not only the
        /// summary per error component.
        #[arg(long)]
        detail: bool,
        #[arg(long, value_enum, default_value_t = Format::Human)]
        format: Format,
        #[arg(long, default_value = "jit")]
        engine: kin_model::engine::Engine,
        #[command(flatten)]
        ignore: Ignore,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Format .kin files in place: indentation, spacing, blank lines; every comment and line
    /// break kept, the meaning unchanged (spec/tooling.md). Without files, standard input to
    /// standard output.
    #[command(after_help = "Examples:
  kin fmt examples/bridge_cmm.kin         # rewrite the file (atomically) if it changes
  kin fmt --check examples                # CI: exit 1 and show a diff for each file that would change
  kin fmt < mill.kin > mill.formatted.kin")]
    Fmt {
        /// Files to format, or folders searched for `*.kin` files.
        #[arg(value_name = "FILE")]
        files: Vec<PathBuf>,
        /// Change nothing: list the files that would change, with a diff, on standard error,
        /// and exit 1 if there are any.
        #[arg(long)]
        check: bool,
        /// Colour in the syntax errors of files that cannot be formatted.
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// A Language Server Protocol server on standard input and output, for editors: diagnostics
    /// as you type, hover, go to definition, references, completion, outline, formatting
    /// (spec/tooling.md).
    #[command(after_help = "Examples:
  kin lsp   # started by the editor's LSP client; editors/vscode starts it for VS Code")]
    Lsp,
    /// Poses per second of the interpreter and the JIT (and, for examples/milling_5axis.kin, a
    /// hand-written evaluator), and the compile time, measured in one run and printed as ratios;
    /// the batch path (into one N-row output, and in cache-sized blocks) against one pose per
    /// call, all six rows, position rows and error only, and the memory's write floor for the
    /// batch's rows, in interleaved rounds. A measurement on this computer, not a test.
    #[command(after_help = "Examples:
  kin bench examples/milling_5axis.kin
  kin bench examples/milling_5axis.kin --poses 20000 --seconds 2   # a batch as large as a fit's")]
    Bench {
        machine: PathBuf,
        /// Poses sampled over the axis ranges, evaluated in turn (1 to 10⁸).
        #[arg(long, default_value_t = 1000, value_parser = args::poses)]
        poses: usize,
        /// Seconds spent on each figure (5 rounds), 0 < S ≤ 86400.
        #[arg(long, default_value_t = 0.6, value_parser = args::seconds, allow_hyphen_values = true)]
        seconds: f64,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// Shell completion script on standard output (bash, zsh, fish, elvish, powershell).
    #[command(after_help = "Examples:
  kin completions bash > ~/.local/share/bash-completion/completions/kin
  kin completions zsh > ~/.zfunc/_kin
  kin completions fish > ~/.config/fish/completions/kin.fish")]
    Completions {
        /// The shell the script is for.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Manual pages generated from this command line: `kin.1` on standard output, or one page
    /// per command (kin.1, kin-fit.1, …) into the folder given with -o.
    #[command(after_help = "Examples:
  kin man -o ~/.local/share/man/man1 && man kin-fit
  kin man | man -l -")]
    Man {
        /// A folder to write every page into (replaced atomically); standard output otherwise.
        #[arg(short, long, value_name = "DIR")]
        output: Option<PathBuf>,
    },
}

/// Rust starts programs with SIGPIPE ignored, so writing to a pipe whose reader has gone
/// (`kin fit … | head -c1`) fails with EPIPE and `print!` panics (exit 101). The default
/// disposition ends the process quietly, as every other command-line tool does, with the
/// conventional status (killed by SIGPIPE; 141 in a shell).
#[cfg(unix)]
fn restore_default_sigpipe() {
    // SAFETY: called first in `main`, before any thread is started; `SIG_DFL` is a valid
    // disposition for SIGPIPE and the previous handler returned is not needed.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn restore_default_sigpipe() {}

/// `print!` panics when standard output (or error) cannot be written: a full disk, `>
/// /dev/full`, a closed terminal. That is not a bug of kin but the end of its output: say so on
/// standard error if it can still be written, and exit 1 (the files kin writes are replaced
/// atomically, so nothing was cut). Every other panic keeps the default report.
fn quiet_output_failures() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let message = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.starts_with("failed printing to std") {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "error: {message}");
            std::process::exit(1);
        }
        default(info);
    }));
}

/// The formats `kin import` reads.
#[derive(Subcommand)]
enum ImportCommand {
    /// A URDF robot description (ROS): the serial chain from a base link to a tip link as a
    /// `.kin` machine (joints, axes, origins, limits) with a default error model for calibration
    /// (spec/urdf.md).
    #[command(after_help = "Examples:
  kin import urdf examples/urdf/ur5.urdf -o ur5.kin
  kin import urdf arm.urdf --tip tool0 --observe position -o arm.kin
  kin import urdf arm.urdf --base base_link --tip camera_link     # print the model")]
    Urdf {
        /// The URDF file (plain URDF: expand a xacro file first).
        file: PathBuf,
        /// Output `.kin` file (standard output when absent); never the input, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// The link the chain starts from, the machine's base (default: the tree's root link).
        #[arg(long, value_name = "LINK")]
        base: Option<String>,
        /// The link the chain ends at, the tool (default: the only leaf below the base, or the
        /// one leaf with the most moving joints above it).
        #[arg(long, value_name = "LINK")]
        tip: Option<String>,
        /// What the default error model is made identifiable for: the full tool pose, or
        /// positions only (a laser tracker), or lengths (as `kin check --observe`).
        #[arg(long, value_enum, default_value_t = check::ObserveArg::Pose)]
        observe: check::ObserveArg,
    },
    /// A Denavit–Hartenberg table (CSV: a, alpha, d, theta per joint, optional joint, type,
    /// lower, upper; units in brackets, default mm and deg), standard or modified, as a `.kin`
    /// machine with the same default error model as a URDF import (spec/urdf.md).
    #[command(after_help = "Examples:
  kin import dh ur10.csv -o ur10.kin
  kin import dh puma.csv --convention modified --observe position -o puma.kin")]
    Dh {
        /// The table.
        file: PathBuf,
        /// Output `.kin` file (standard output when absent); never the input, replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// `standard` (Rz(θ) Tz(d) Tx(a) Rx(α) per joint) or `modified` (Craig: Rx(α) Tx(a)
        /// Rz(θ) Tz(d), the row of joint i holding a and α of the link before it).
        #[arg(long, value_enum, default_value_t = import::DhConvention::Standard)]
        convention: import::DhConvention,
        /// What the default error model is made identifiable for (as for `import urdf`).
        #[arg(long, value_enum, default_value_t = check::ObserveArg::Pose)]
        observe: check::ObserveArg,
    },
}

/// The formats `kin export` writes.
#[derive(Subcommand)]
enum ExportCommand {
    /// A URDF robot description with every constant error of the model (its `params` or
    /// `--params`) folded into the joints' origins, for a ROS user to load (spec/urdf.md,
    /// "Export"). Terms that vary with the pose are left out and listed.
    #[command(after_help = "Examples:
  kin export urdf examples/ur10/ur10.kin --params FIT.params -o ur10_calibrated.urdf
  kin export urdf arm.kin --name arm                 # print the URDF")]
    Urdf {
        /// The machine.
        machine: PathBuf,
        /// Parameter values (`params { … }`, e.g. the FIT.params `kin fit` writes).
        #[arg(long, value_name = "FILE")]
        params: Option<PathBuf>,
        /// The robot's name in the URDF (default: the machine's).
        #[arg(long)]
        name: Option<String>,
        /// Output `.urdf` file (standard output when absent); replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// The calibrated robot as a standard Denavit–Hartenberg table (with Hayati's beta between
    /// nearly parallel joints) and its base and tool frames, every constant error of the model
    /// folded in; `kin import dh` reads it back (spec/urdf.md, "Export").
    #[command(after_help = "Examples:
  kin export dh examples/ur10/ur10.kin --params FIT.params -o ur10_calibrated_dh.csv
  kin export dh arm.kin                              # print the table")]
    Dh {
        /// The machine: one serial chain (the tool chain; the workpiece chain fixed).
        machine: PathBuf,
        /// Parameter values (`params { … }`, e.g. the FIT.params `kin fit` writes).
        #[arg(long, value_name = "FILE")]
        params: Option<PathBuf>,
        /// Output `.csv` file (standard output when absent); replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
    /// The model's evaluator as C source, for a program to compile in: the error, the error
    /// with its six-row β-Jacobian and the position rows, the same operations as kin's JIT,
    /// with the fitted values (`params` or `--params`) as the default β (spec/performance.md,
    /// "The evaluator as C source"). Compile with -ffp-contract=off for kin's roundings.
    #[command(after_help = "Examples:
  kin export c examples/milling_5axis.kin --params FIT.params -o mill.c
  cc -O3 -march=native -ffp-contract=off -c mill.c")]
    C {
        /// The machine.
        machine: PathBuf,
        /// Parameter values (`params { … }`, e.g. the FIT.params `kin fit` writes): the β the
        /// functions use when called with NULL.
        #[arg(long, value_name = "FILE")]
        params: Option<PathBuf>,
        /// Output `.c` file (standard output when absent); replaced atomically.
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[arg(long, value_enum, default_value_t = Color::Auto)]
        color: Color,
    },
}

/// Whether the command line asks for JSON (`--format json` or `--format=json`), read before
/// parsing so that a usage error, too, can be answered with a JSON document.
fn asks_json(args: &[std::ffi::OsString]) -> bool {
    args.iter()
        .zip(args.iter().skip(1))
        .any(|(a, b)| a == "--format" && b == "json")
        || args.iter().any(|a| a == "--format=json")
}

/// The number an exit code stands for (kin uses 0, 1 and 2; spec/cli.md).
fn exit_number(code: ExitCode) -> u8 {
    if code == ExitCode::SUCCESS {
        0
    } else if code == ExitCode::from(2) {
        2
    } else {
        1
    }
}

fn main() -> ExitCode {
    restore_default_sigpipe();
    quiet_output_failures();
    let started = std::time::Instant::now();
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let json = asks_json(&args);
    errors::set_json(json);
    let mut command = help::document(Cli::command());
    let parsed = command
        .try_get_matches_from_mut(&args)
        .and_then(|m| Cli::from_arg_matches(&m).map(|cli| (m, cli)))
        .and_then(|(m, cli)| {
            // clap checks a conflict within one command's arguments; `kin -q fit -v` puts
            // the two global flags on different levels, so the rule is enforced here too.
            if cli.quiet && cli.verbose {
                Err(command.error(
                    clap::error::ErrorKind::ArgumentConflict,
                    "the argument '--quiet' cannot be used with '--verbose'",
                ))
            } else {
                Ok((m, cli))
            }
        });
    let (matches, cli) = match parsed {
        Ok(parsed) => parsed,
        Err(e) => {
            // `--help` and `--version` are not failures; a usage error is (exit 2).
            if json && e.use_stderr() {
                let _ = e.print();
                errors::record("usage", e.render().to_string().trim(), None, None);
                errors::finish(2);
                return ExitCode::from(2);
            }
            e.exit()
        }
    };
    warnings::set(warnings::Switches {
        allow: cli.allow,
        quiet: cli.quiet,
        verbose: cli.verbose,
        strict: cli.strict,
    });
    let name = matches.subcommand_name().unwrap_or("").to_string();
    if let Some((_, m)) = matches.subcommand() {
        if let Ok(Some(engine)) = m.try_get_one::<kin_model::engine::Engine>("engine") {
            warnings::note(&format!("engine: {}", engine.name()));
        }
    }
    let code = run(cli.command);
    let exit = exit_number(code);
    errors::finish(exit);
    warnings::note(&warnings::timed(
        &format!("`kin {name}` ended with exit code {exit}"),
        started,
    ));
    code
}

fn run(command: Command) -> ExitCode {
    match command {
        // `--list` asks for what no template gives (clap refuses it beside a template or DIR).
        Command::Init {
            template,
            dir,
            list: _,
        } => init::run(template, dir),
        Command::Check {
            file,
            format,
            color,
            observe,
            aligned,
            no_identify,
            plan,
            detail,
            engine,
        } => {
            let color = color.enabled();
            if !plan.is_empty() {
                return load::Failed::exit(design::check_plan(
                    &file, &plan, format, engine, color, detail,
                ));
            }
            let identify = (!no_identify).then_some((observe, aligned));
            check::run(&file, format, color, identify, engine)
        }
        Command::Simulate {
            machine,
            params,
            poses,
            sample,
            cycle,
            every,
            output,
            format,
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
            cycle,
            every,
            output,
            json: format == Format::Json,
            noise,
            noise_tilt,
            seed,
            artifact_shift,
            artifact_rotation,
            artifact_length,
            components,
            ignore: ignore.options(),
            color: color.enabled(),
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
            noise,
            noise_per_file,
            noise_tilt,
            engine,
            threads,
            ignore,
            color,
            format,
        } => {
            let (noise, file_noise) = match args::split_noise(noise) {
                Ok(n) => n,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            };
            fit::run(
                fit::FitArgs {
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
                    noise: fit::stated_noise(noise.as_ref(), noise_tilt.as_ref()),
                    file_noise,
                    noise_per_file,
                    engine,
                    threads,
                    ignore: ignore.options(),
                    color: color.enabled(),
                },
                format,
            )
        }
        Command::Demo { dir, rounds, color } => demo::run(dir, rounds, color.enabled()),
        Command::Diagnose {
            machine,
            data,
            alpha,
            output,
            apply,
            force,
            dry_run,
            explain,
            noise,
            noise_per_file,
            noise_tilt,
            engine,
            ignore,
            color,
            format,
        } => {
            let (noise, file_noise) = match args::split_noise(noise) {
                Ok(n) => n,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            };
            diagnose::run(diagnose::DiagnoseArgs {
                fit: fit::FitArgs {
                    machine,
                    data,
                    validate: Vec::new(),
                    output: None,
                    solver: fit::SolverArg::Qr,
                    tolerance: 1e-10,
                    // A model the data do not fully determine is diagnosed on its determined part
                    // (its undetermined coefficients are marked so), not refused.
                    min_norm: true,
                    stepwise: None,
                    enter: None,
                    holdout: None,
                    seed: 0,
                    // Every fit of the diagnosis weighs its rows by the stated noise, kind by kind
                    // (positions and lengths by --noise, rotations by --noise-tilt).
                    noise: fit::stated_noise(noise.as_ref(), noise_tilt.as_ref()),
                    file_noise,
                    noise_per_file,
                    engine,
                    threads: None,
                    ignore: ignore.options(),
                    color: color.enabled(),
                },
                alpha,
                output,
                apply,
                force,
                dry_run,
                explain,
                noise,
                noise_tilt,
                format,
            })
        }
        Command::Predict {
            machine,
            fit,
            cycle,
            poses,
            output,
            html,
            engine,
            ignore,
            color,
        } => predict::predict(predict::PredictArgs {
            machine,
            fit,
            cycle,
            poses,
            output,
            html,
            engine,
            data: ignore.options(),
            color: color.enabled(),
        }),
        Command::Eval {
            machine,
            poses,
            params,
            output,
            format,
            components,
            engine,
            ignore,
            uncertainty,
            ellipsoid,
            nominal,
            color,
        } => simulate::eval(simulate::EvalArgs {
            machine: &machine,
            params: params.as_deref(),
            poses: &poses,
            output: output.as_deref(),
            json: format == Format::Json,
            components,
            engine,
            ignore: &ignore.options(),
            uncertainty,
            ellipsoid,
            nominal,
            color: color.enabled(),
        }),
        Command::Report {
            machine,
            fit,
            diagnose,
            data,
            output,
            compensation,
            ignore,
            color,
        } => {
            let bar = warnings::spinner("writing the report");
            let code = report::run(report::ReportArgs {
                machine,
                fit,
                diagnose,
                data,
                output,
                ignore: ignore.options(),
                color: color.enabled(),
                compensation,
            });
            bar.finish_and_clear();
            code
        }
        Command::Compensate {
            machine,
            fit,
            poses,
            grid,
            correct,
            axes,
            table,
            output,
            ignore,
            color,
        } => {
            let bar = warnings::spinner("computing the corrections");
            let code = compensate::run(compensate::CompensateArgs {
                machine,
                fit,
                poses,
                grid,
                correct,
                axes,
                table,
                output,
                ignore: ignore.options(),
                color: color.enabled(),
            });
            bar.finish_and_clear();
            code
        }
        Command::Correct {
            machine,
            fit,
            points,
            output,
            ignore,
            color,
        } => correct::run(correct::CorrectArgs {
            machine,
            fit,
            points,
            output,
            ignore: ignore.options(),
            color: color.enabled(),
        }),
        Command::Design {
            machine,
            candidates,
            n,
            output,
            evaluate,
            generate,
            length,
            step,
            angle_step,
            plane,
            pitch,
            axis,
            levels,
            sphere,
            detail,
            format,
            engine,
            ignore,
            color,
        } => load::Failed::exit(design::run(design::DesignArgs {
            generate: generate
                .as_deref()
                .and_then(kin_estimate::generate::Kind::parse)
                .map(|kind| kin_estimate::generate::Generate {
                    kind,
                    length: length.si,
                    step: step.si,
                    pitch: pitch.si,
                    angle_step: angle_step.si,
                    plane,
                    axis,
                    levels: usize::try_from(levels).unwrap_or(1),
                    spheres: sphere,
                }),
            machine,
            candidates,
            n: n.and_then(|v| usize::try_from(v).ok()),
            output,
            evaluate,
            format,
            engine,
            ignore: ignore.options(),
            color: color.enabled(),
            detail,
        })),
        Command::Fmt {
            files,
            check,
            color,
        } => load::Failed::exit(fmt::run(&files, check, color.enabled())),
        Command::Lsp => kin_lsp::run(),
        Command::Bench {
            machine,
            poses,
            seconds,
            color,
        } => bench::run(&machine, poses, seconds, color.enabled()),
        Command::Iso2302 {
            run,
            format,
            html,
            model,
            fit,
            axis,
            at,
            component,
            alpha,
            engine,
            color,
        } => iso::run(iso::Iso2302Args {
            run,
            format,
            html,
            model,
            fit,
            axis,
            at,
            component,
            alpha,
            engine,
            color: color.enabled(),
        }),
        Command::Iso2303 { run, format, html } => {
            iso::run_thermal(iso::Iso2303Args { run, format, html })
        }
        Command::Iso2304 {
            run,
            format,
            radius,
            plane,
            html,
            lengths,
            centre,
            measure,
        } => iso::run_circular(iso::Iso2304Args {
            run,
            format,
            radius,
            plane,
            html,
            lengths,
            centre,
            measure,
        }),
        Command::Import(ImportCommand::Urdf {
            file,
            output,
            base,
            tip,
            observe,
        }) => import::urdf(import::Urdf {
            file: &file,
            output: output.as_deref(),
            base,
            tip,
            observe,
        }),
        Command::Export(ExportCommand::Urdf {
            machine,
            params,
            name,
            output,
            color,
        }) => import::export(
            import::Export {
                machine: &machine,
                params: params.as_deref(),
                name,
                output: output.as_deref(),
                color: color.enabled(),
            },
            import::ExportFormat::Urdf,
        ),
        Command::Export(ExportCommand::Dh {
            machine,
            params,
            output,
            color,
        }) => import::export(
            import::Export {
                machine: &machine,
                params: params.as_deref(),
                name: None,
                output: output.as_deref(),
                color: color.enabled(),
            },
            import::ExportFormat::Dh,
        ),
        Command::Export(ExportCommand::C {
            machine,
            params,
            output,
            color,
        }) => import::export(
            import::Export {
                machine: &machine,
                params: params.as_deref(),
                name: None,
                output: output.as_deref(),
                color: color.enabled(),
            },
            import::ExportFormat::C,
        ),
        Command::Import(ImportCommand::Dh {
            file,
            output,
            convention,
            observe,
        }) => import::dh(import::Dh {
            file: &file,
            output: output.as_deref(),
            convention,
            observe,
        }),
        Command::Completions { shell } => {
            manual::completions(help::document(Cli::command()), shell)
        }
        Command::Man { output } => manual::man(help::document(Cli::command()), output.as_deref()),
    }
}

/// `AXIS=QUANTITY` of `--at` and `--centre` (the quantity is checked against the axis later).
fn axis_value(text: &str) -> Result<(String, String), String> {
    match text.split_once('=') {
        Some((a, q)) if !a.trim().is_empty() && !q.trim().is_empty() => {
            Ok((a.trim().to_string(), q.trim().to_string()))
        }
        _ => Err(format!("`{text}`: expected AXIS=VALUE, e.g. X=250mm")),
    }
}

fn plane_arg(text: &str) -> Result<[String; 2], String> {
    kin_standards::iso230_4::plane(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `kin help COMMAND` reads like `cargo help build`: every argument and option of every
    /// command has help text, every command a description and examples.
    #[test]
    fn every_argument_has_help_and_every_command_examples() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for arg in cmd.get_arguments() {
                if arg.is_hide_set() {
                    continue;
                }
                if arg.get_help().is_none() && arg.get_long_help().is_none() {
                    missing.push(format!("`{path}` {}: no help", arg.get_id()));
                }
            }
            for sub in cmd.get_subcommands() {
                let p = format!("{path} {}", sub.get_name());
                if sub.get_about().is_none() && sub.get_long_about().is_none() {
                    missing.push(format!("`{p}`: no description"));
                }
                let examples = [sub.get_after_help(), sub.get_after_long_help()]
                    .into_iter()
                    .flatten()
                    .any(|t| {
                        let t = t.to_string();
                        t.contains("Examples:")
                            && t.lines().any(|l| l.trim_start().starts_with("kin "))
                    });
                if !examples {
                    missing.push(format!("`{p}`: no Examples section"));
                }
                walk(sub, &p, missing);
            }
        }
        let mut missing = Vec::new();
        walk(&help::document(Cli::command()), "kin", &mut missing);
        assert!(missing.is_empty(), "{missing:#?}");
        // The check itself can fail: the bare definition lacks the shared help.
        let mut bare = Vec::new();
        walk(&Cli::command(), "kin", &mut bare);
        assert!(bare.iter().any(|m| m.contains("color")), "{bare:?}");
    }

    #[test]
    fn json_is_recognised_in_both_spellings() {
        let args = |v: &[&str]| v.iter().map(std::ffi::OsString::from).collect::<Vec<_>>();
        assert!(asks_json(&args(&["kin", "fit", "--format", "json"])));
        assert!(asks_json(&args(&["kin", "fit", "--format=json"])));
        assert!(!asks_json(&args(&["kin", "fit", "--format", "human"])));
        assert!(!asks_json(&args(&["kin", "fit", "json"])));
    }

    /// Every example line in `--help` (`kin …`, a `#` starting a comment) is a valid command line:
    /// an option renamed or removed fails here before a user copies a stale example.
    #[test]
    fn every_example_in_help_parses() {
        let cli = Cli::command();
        let mut seen = 0;
        for sub in cli.get_subcommands() {
            let help = [sub.get_after_help(), sub.get_long_about(), sub.get_about()];
            for text in help.into_iter().flatten() {
                for line in text.to_string().lines() {
                    let line = line.trim().trim_start_matches("Example:").trim();
                    let line = line.split(" #").next().unwrap_or("");
                    let line = line.split(" >").next().unwrap_or("");
                    let line = line.split(" &&").next().unwrap_or("");
                    let line = line.split(" |").next().unwrap_or("");
                    if !line.starts_with("kin ") {
                        continue;
                    }
                    // Words as a POSIX shell splits them: a '…' or "…" span is one word.
                    let mut words: Vec<String> = Vec::new();
                    let (mut word, mut quote, mut started) = (String::new(), None, false);
                    for c in line.chars() {
                        match (quote, c) {
                            (Some(q), c) if c == q => quote = None,
                            (Some(_), c) => word.push(c),
                            (None, '\'' | '"') => (quote, started) = (Some(c), true),
                            (None, c) if c.is_whitespace() => {
                                if started {
                                    words.push(std::mem::take(&mut word));
                                }
                                started = false;
                            }
                            (None, c) => {
                                word.push(c);
                                started = true;
                            }
                        }
                    }
                    if started {
                        words.push(word);
                    }
                    assert!(quote.is_none(), "`{line}`: an unclosed quote");
                    if let Err(e) = Cli::try_parse_from(&words) {
                        panic!("`{line}` in the help of `kin {}`: {e}", sub.get_name());
                    }
                    seen += 1;
                }
            }
        }
        assert!(seen >= 12, "only {seen} examples found");
    }
}
