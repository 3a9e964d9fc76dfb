//! Measurement files from a model with known β: exact simulation (for data with a known truth)
//! and first-order prediction (`kin eval`).
//!
//! Simulation evaluates the parametric errors of every frame and applies them as finite
//! transforms ([`kin_model::exact`]): it shares no formula with the F-matrix code, so fitting
//! simulated data tests the first-order model against an independent truth.

pub mod cycle;

use kin_compiler::ir::Machine;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use thiserror::Error;

use crate::fit::report::FitReport;
use crate::uncertainty::{PredictionCovariance, RowError};
use kin_data::data::{LengthData, Observations, PointData, Pose as DataPose, Rows};
use kin_model::exact;
use kin_model::interp::{EvalError, Interpreter, State};
use kin_model::kinematics::{FrameErrors, KinematicsError, Pose};
use kin_model::states::{StateError, States};

#[derive(Debug, Error)]
pub enum SimulateError {
    #[error(transparent)]
    State(#[from] StateError),
    #[error("line {line}: {source}")]
    Eval {
        line: usize,
        #[source]
        source: EvalError,
    },
    #[error("line {line}: {source}")]
    Kinematics {
        line: usize,
        #[source]
        source: KinematicsError,
    },
    #[error("noise must be a finite, non-negative standard deviation")]
    Noise,
    #[error("{0}")]
    Engine(String),
    #[error("the fit's covariance does not fit this model: {0}")]
    Covariance(String),
    #[error("confidence ellipsoids are of positions: they need a point file of poses, not a length file")]
    EllipsoidOfLengths,
    #[error("the confidence level must be strictly between 0 and 1")]
    Level,
}

/// Which error components a simulated point file holds, and the measurement noise.
#[derive(Debug, Clone)]
pub struct Options {
    /// `ex ey ez erx ery erz`: which to write.
    pub observe: [bool; 6],
    /// Standard deviation of the noise on positions and lengths (m) and on rotations (rad).
    pub noise: f64,
    pub noise_tilt: f64,
    pub seed: u64,
    /// Standard deviations of the unknown placement of each artifact of a point file (a shift
    /// in m and a small rotation in rad per wr axis), and of the unknown length error of each
    /// artifact of a length file (m). Zero places artifacts nominally.
    pub artifact_shift: f64,
    pub artifact_rotation: f64,
    pub artifact_length: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            observe: [true, true, true, false, false, false],
            noise: 0.0,
            noise_tilt: 0.0,
            seed: 0,
            artifact_shift: 0.0,
            artifact_rotation: 0.0,
            artifact_length: 0.0,
        }
    }
}

/// How an observed value is computed from the model.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Engine {
    Exact,
    FirstOrder,
}

/// Simulates measurements at the poses of `poses` (a poses file: the rows of a point or length
/// file, observed columns ignored) for coefficients `beta`, with the exact transforms.
pub fn simulate(
    m: &Machine,
    beta: &[f64],
    poses: &Observations,
    options: &Options,
) -> Result<Observations, SimulateError> {
    run(m, beta, poses, options, Engine::Exact)
}

/// The first-order model's prediction at the poses of `poses` by the chosen engine (`kin eval`).
pub fn predict_with(
    m: &Machine,
    beta: &[f64],
    poses: &Observations,
    observe: [bool; 6],
    engine: kin_model::engine::Engine,
) -> Result<Observations, SimulateError> {
    let mut ev =
        kin_model::engine::make(m, engine).map_err(|e| SimulateError::Engine(e.to_string()))?;
    match poses {
        Observations::Points(p) => {
            let states = States::new(m, &p.rows, &p.pose, "")?;
            let mut observed: [Option<Vec<f64>>; 6] = Default::default();
            for (k, slot) in observed.iter_mut().enumerate() {
                if observe.get(k).copied().unwrap_or(false) {
                    *slot = Some(Vec::with_capacity(states.len()));
                }
            }
            for r in 0..states.len() {
                let line = states.line.get(r).copied().unwrap_or(0);
                let e = ev
                    .error(&states.get(r), beta)
                    .map_err(|source| SimulateError::Eval { line, source })?;
                for (k, col) in observed.iter_mut().enumerate() {
                    if let Some(col) = col {
                        col.push(e.get(k).copied().unwrap_or(0.0));
                    }
                }
            }
            Ok(Observations::Points(PointData {
                rows: p.rows.clone(),
                pose: p.pose.clone(),
                observed,
                absolute: None,
            }))
        }
        Observations::Lengths(l) => {
            let [p1, p2] = &l.poses;
            let s1 = States::new(m, &l.rows, p1, "_1")?;
            let s2 = States::new(m, &l.rows, p2, "_2")?;
            let mut row = vec![0.0; m.coefficients.len()];
            let mut dl = Vec::with_capacity(s1.len());
            for r in 0..s1.len() {
                let line = s1.line.get(r).copied().unwrap_or(0);
                dl.push(
                    ev.length_and_row(&s1.get(r), &s2.get(r), beta, &mut row)
                        .map_err(|source| SimulateError::Eval { line, source })?,
                );
            }
            Ok(Observations::Lengths(LengthData {
                rows: l.rows.clone(),
                poses: l.poses.clone(),
                dl,
            }))
        }
    }
}

/// Standard uncertainties (k = 1) of predicted errors, in SI: per observed component of a
/// point file, or of `dL` per row of a length file.
#[derive(Debug, Clone, PartialEq)]
pub enum Uncertainty {
    Points([Option<Vec<f64>>; 6]),
    Lengths(Vec<f64>),
}

/// The standard uncertainty of the first-order model's prediction at each pose of `poses`
/// (the square root of eq. 4.12, with the fitted non-linear parameters' share:
/// [`PredictionCovariance`]) from the covariance in `fit`, for the components `observe` (point
/// files) or `dL` (length files). The fit must belong to `m`'s coefficients
/// ([`FitReport::covariance_mismatch`]).
pub fn uncertainty(
    m: &Machine,
    fit: &FitReport,
    poses: &Observations,
    observe: [bool; 6],
    engine: kin_model::engine::Engine,
) -> Result<Uncertainty, SimulateError> {
    let cov = PredictionCovariance::new(m, fit).map_err(SimulateError::Covariance)?;
    let mut ev =
        kin_model::engine::make(m, engine).map_err(|e| SimulateError::Engine(e.to_string()))?;
    let at = |states: &States, e: RowError| SimulateError::Eval {
        line: states.line.get(e.row).copied().unwrap_or(0),
        source: e.source,
    };
    match poses {
        Observations::Points(p) => {
            let mut states = States::new(m, &p.rows, &p.pose, "")?;
            let var = cov
                .point_variances(m, ev.as_mut(), &mut states, &p.rows)
                .map_err(|e| at(&states, e))?;
            let mut out: [Option<Vec<f64>>; 6] = Default::default();
            for (c, (slot, wanted)) in out.iter_mut().zip(observe).enumerate() {
                if wanted {
                    *slot = Some(var.iter().map(|v| v[c].max(0.0).sqrt()).collect());
                }
            }
            Ok(Uncertainty::Points(out))
        }
        Observations::Lengths(l) => {
            let [p1, p2] = &l.poses;
            let mut s1 = States::new(m, &l.rows, p1, "_1")?;
            let mut s2 = States::new(m, &l.rows, p2, "_2")?;
            let var = cov
                .length_variances(m, ev.as_mut(), &mut s1, &mut s2, &l.rows)
                .map_err(|e| at(&s1, e))?;
            Ok(Uncertainty::Lengths(
                var.iter().map(|v| v.max(0.0).sqrt()).collect(),
            ))
        }
    }
}

/// The confidence ellipsoid of a predicted position error: the region
/// `(e − ê)ᵀ C⁻¹ (e − ê) ≤ χ²₃(level)` for `C` the 3×3 covariance of the prediction (eq. 4.12
/// for the three components together), which holds the model's error with probability `level`
/// when the coefficients' estimate is normal with the fit's covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct Ellipsoid {
    /// Semi-axis lengths, largest first (m): `√(λᵢ · χ²₃(level))` for `λᵢ` the eigenvalues of C.
    pub semi_axes: [f64; 3],
    /// Unit directions of the semi-axes in the workpiece reference frame's axes, in the order
    /// of `semi_axes`; each signed so that its largest component is positive.
    pub directions: [[f64; 3]; 3],
}

impl Ellipsoid {
    /// The ellipsoid of covariance `c` (m²) at `level` (0 < level < 1).
    pub fn of(c: &[[f64; 3]; 3], level: f64) -> Result<Ellipsoid, SimulateError> {
        use statrs::distribution::{ChiSquared, ContinuousCDF};
        if !(level > 0.0 && level < 1.0) {
            return Err(SimulateError::Level);
        }
        let k2 = ChiSquared::new(3.0)
            .map_err(|_| SimulateError::Level)?
            .inverse_cdf(level);
        let m = nalgebra::Matrix3::from_fn(|i, j| c[i][j]);
        let eig = nalgebra::SymmetricEigen::new(m);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let mut out = Ellipsoid {
            semi_axes: [0.0; 3],
            directions: [[0.0; 3]; 3],
        };
        for (k, &i) in order.iter().enumerate() {
            // A covariance is positive semi-definite: a negative eigenvalue is rounding.
            out.semi_axes[k] = (eig.eigenvalues[i].max(0.0) * k2).sqrt();
            let v = eig.eigenvectors.column(i);
            let big = (0..3).fold(0, |b, j| if v[j].abs() > v[b].abs() { j } else { b });
            let sign = if v[big] < 0.0 { -1.0 } else { 1.0 };
            out.directions[k] = [sign * v[0], sign * v[1], sign * v[2]];
        }
        Ok(out)
    }
}

/// The confidence ellipsoid at `level` of the predicted position error at each pose of a point
/// file `poses`, from the covariance in `fit` ([`Ellipsoid`], [`PredictionCovariance`]).
pub fn ellipsoids(
    m: &Machine,
    fit: &FitReport,
    poses: &Observations,
    level: f64,
    engine: kin_model::engine::Engine,
) -> Result<Vec<Ellipsoid>, SimulateError> {
    let cov = PredictionCovariance::new(m, fit).map_err(SimulateError::Covariance)?;
    if !(level > 0.0 && level < 1.0) {
        return Err(SimulateError::Level);
    }
    let Observations::Points(p) = poses else {
        return Err(SimulateError::EllipsoidOfLengths);
    };
    let mut ev =
        kin_model::engine::make(m, engine).map_err(|e| SimulateError::Engine(e.to_string()))?;
    let mut states = States::new(m, &p.rows, &p.pose, "")?;
    let covariances = cov
        .position_covariances(m, ev.as_mut(), &mut states, &p.rows)
        .map_err(|e| SimulateError::Eval {
            line: states.line.get(e.row).copied().unwrap_or(0),
            source: e.source,
        })?;
    covariances
        .iter()
        .map(|c| Ellipsoid::of(c, level))
        .collect()
}

/// The first-order model's prediction at the poses of `poses`, without noise (`kin eval`).
pub fn predict(
    m: &Machine,
    beta: &[f64],
    poses: &Observations,
    observe: [bool; 6],
) -> Result<Observations, SimulateError> {
    let options = Options {
        observe,
        ..Options::default()
    };
    run(m, beta, poses, &options, Engine::FirstOrder)
}

fn run(
    m: &Machine,
    beta: &[f64],
    poses: &Observations,
    options: &Options,
    engine: Engine,
) -> Result<Observations, SimulateError> {
    if !(options.noise >= 0.0
        && options.noise.is_finite()
        && options.noise_tilt >= 0.0
        && options.noise_tilt.is_finite())
    {
        return Err(SimulateError::Noise);
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(options.seed);
    let mut gauss = |sigma: f64| -> f64 {
        match Normal::new(0.0, sigma) {
            Ok(d) if sigma > 0.0 => d.sample(&mut rng),
            _ => 0.0,
        }
    };
    let mut model = Model::new(m, beta, engine)?;
    match poses {
        Observations::Points(p) => {
            let states = States::new(m, &p.rows, &p.pose, "")?;
            let mut observed: [Option<Vec<f64>>; 6] = Default::default();
            for (k, slot) in observed.iter_mut().enumerate() {
                if options.observe.get(k).copied().unwrap_or(false) {
                    *slot = Some(Vec::with_capacity(states.len()));
                }
            }
            // Each artifact's true placement: a rigid displacement (t, ω) drawn once per label.
            let labels = p
                .rows
                .artifact
                .as_ref()
                .map(|g| g.labels.len())
                .unwrap_or(0);
            let placements: Vec<[f64; 6]> = (0..labels)
                .map(|_| {
                    let mut d = [0.0; 6];
                    for (k, v) in d.iter_mut().enumerate() {
                        *v = gauss(if k < 3 {
                            options.artifact_shift
                        } else {
                            options.artifact_rotation
                        });
                    }
                    d
                })
                .collect();
            for r in 0..states.len() {
                let line = states.line.get(r).copied().unwrap_or(0);
                let mut e = model.error(&states.get(r), line)?;
                if let Some(d) = p
                    .rows
                    .artifact_of(r)
                    .and_then(|a| placements.get(a as usize))
                {
                    // A point p of a displaced artifact is found at p + t + ω × p: the observed
                    // error grows by that, and the orientation by ω (first order in the
                    // displacement, which the fit models the same way).
                    let pos = model.position(&states.get(r), line)?;
                    let w = [d[3], d[4], d[5]];
                    let cross = [
                        w[1] * pos[2] - w[2] * pos[1],
                        w[2] * pos[0] - w[0] * pos[2],
                        w[0] * pos[1] - w[1] * pos[0],
                    ];
                    for k in 0..3 {
                        e[k] += d[k] + cross[k];
                        e[3 + k] += w[k];
                    }
                }
                for (k, col) in observed.iter_mut().enumerate() {
                    if let Some(col) = col {
                        let sigma = if k < 3 {
                            options.noise
                        } else {
                            options.noise_tilt
                        };
                        col.push(e.get(k).copied().unwrap_or(0.0) + gauss(sigma));
                    }
                }
            }
            Ok(Observations::Points(PointData {
                rows: p.rows.clone(),
                pose: p.pose.clone(),
                observed,
                absolute: None,
            }))
        }
        Observations::Lengths(l) => {
            let [p1, p2] = &l.poses;
            let s1 = States::new(m, &l.rows, p1, "_1")?;
            let s2 = States::new(m, &l.rows, p2, "_2")?;
            let labels = l
                .rows
                .artifact
                .as_ref()
                .map(|g| g.labels.len())
                .unwrap_or(0);
            let lengths: Vec<f64> = (0..labels)
                .map(|_| gauss(options.artifact_length))
                .collect();
            let mut dl = Vec::with_capacity(s1.len());
            for r in 0..s1.len() {
                let line = s1.line.get(r).copied().unwrap_or(0);
                let artifact = l
                    .rows
                    .artifact_of(r)
                    .and_then(|a| lengths.get(a as usize))
                    .copied()
                    .unwrap_or(0.0);
                dl.push(
                    model.length(&s1.get(r), &s2.get(r), line)? + artifact + gauss(options.noise),
                );
            }
            Ok(Observations::Lengths(LengthData {
                rows: l.rows.clone(),
                poses: l.poses.clone(),
                dl,
            }))
        }
    }
}

/// One engine with its scratch.
struct Model<'m> {
    m: &'m Machine,
    beta: &'m [f64],
    it: Interpreter<'m>,
    engine: Engine,
    e1: FrameErrors,
    e2: FrameErrors,
    row: Vec<f64>,
}

impl<'m> Model<'m> {
    fn new(m: &'m Machine, beta: &'m [f64], engine: Engine) -> Result<Self, SimulateError> {
        let it = Interpreter::new(m).map_err(|source| SimulateError::Eval { line: 0, source })?;
        Ok(Model {
            m,
            beta,
            it,
            engine,
            e1: FrameErrors::zeros(m),
            e2: FrameErrors::zeros(m),
            row: vec![0.0; m.coefficients.len()],
        })
    }

    /// The reported error (task sign) at one state.
    fn error(&mut self, s: &State, line: usize) -> Result<[f64; 6], SimulateError> {
        let eval = |source| SimulateError::Eval { line, source };
        match self.engine {
            Engine::FirstOrder => self.it.error(s, self.beta).map_err(eval),
            Engine::Exact => {
                self.it
                    .frame_errors(s, self.beta, &mut self.e1)
                    .map_err(eval)?;
                let pose = Pose {
                    q: s.q,
                    tool: s.tool,
                    tool_offset: s.tool_offset,
                };
                let e = exact::positioning_error(self.m, &pose, &self.e1)
                    .map_err(|source| SimulateError::Kinematics { line, source })?;
                Ok((e * self.m.task.sign()).into())
            }
        }
    }

    /// The nominal tool position in wr.
    fn position(&mut self, s: &State, line: usize) -> Result<[f64; 3], SimulateError> {
        self.it
            .nominal_position(s)
            .map_err(|source| SimulateError::Eval { line, source })
    }

    /// The reported length error between two states.
    fn length(&mut self, a: &State, b: &State, line: usize) -> Result<f64, SimulateError> {
        let eval = |source| SimulateError::Eval { line, source };
        match self.engine {
            Engine::FirstOrder => self
                .it
                .length_and_row(a, b, self.beta, &mut self.row)
                .map_err(eval),
            Engine::Exact => {
                self.it
                    .frame_errors(a, self.beta, &mut self.e1)
                    .map_err(eval)?;
                self.it
                    .frame_errors(b, self.beta, &mut self.e2)
                    .map_err(eval)?;
                let pa = Pose {
                    q: a.q,
                    tool: a.tool,
                    tool_offset: a.tool_offset,
                };
                let pb = Pose {
                    q: b.q,
                    tool: b.tool,
                    tool_offset: b.tool_offset,
                };
                let d = exact::length_error(self.m, &pa, &self.e1, &pb, &self.e2)
                    .map_err(|source| SimulateError::Kinematics { line, source })?;
                Ok(d * self.m.task.sign())
            }
        }
    }
}

/// A point poses table of `n` states sampled over the machine's ranges, for `kin simulate
/// --sample N` and for tests: the rows a poses file would hold.
pub fn sample_points(m: &Machine, n: usize, seed: u64) -> PointData {
    let states = States::sample(m, n, seed);
    let mut pose = DataPose {
        axes: vec![Vec::with_capacity(n); m.axes.len()],
        // Each pose is held still: reached moving in + where the model reads a direction.
        dir: kin_model::states::held_directions(m, n),
    };
    let mut dirs: Vec<Vec<f64>> = vec![Vec::with_capacity(n); m.axes.len()];
    let mut rows = Rows {
        line: (1..=n).collect(),
        tool: Vec::with_capacity(n),
        inputs: vec![None; m.inputs.len()],
        ..Rows::default()
    };
    let mut inputs: Vec<Vec<f64>> = vec![Vec::with_capacity(n); m.inputs.len()];
    for r in 0..n {
        let s = states.get(r);
        for (a, col) in pose.axes.iter_mut().enumerate() {
            col.push(s.q.get(a).copied().unwrap_or(0.0));
        }
        for (a, col) in dirs.iter_mut().enumerate() {
            col.push(s.dirs.get(a).copied().unwrap_or(1.0));
        }
        for (i, col) in inputs.iter_mut().enumerate() {
            col.push(s.inputs.get(i).copied().unwrap_or(0.0));
        }
        rows.tool.push(s.tool);
    }
    let used = kin_model::states::used_vars(m);
    for (a, col) in dirs.into_iter().enumerate() {
        if used.contains(&kin_compiler::ir::Var::Direction(a)) {
            if let Some(slot) = pose.dir.get_mut(a) {
                *slot = Some(col);
            }
        }
    }
    for (i, col) in inputs.into_iter().enumerate() {
        if let Some(slot) = rows.inputs.get_mut(i) {
            *slot = Some(col);
        }
    }
    if !m.lags.is_empty() {
        // A sampled table is one run in steady state: one minute between rows.
        rows.time = Some((0..n).map(|r| 60.0 * r as f64).collect());
    }
    PointData {
        rows,
        pose,
        observed: Default::default(),
        absolute: None,
    }
}

/// The poses table of a time series (`kin simulate --cycle`): at each row of `series` (its
/// time, run and inputs), one row per pose of `poses`, all at the row's time, so each pose is
/// measured once per sample as a thermal test does. Lines number the rows from 1.
pub fn series_points(m: &Machine, series: &Rows, poses: &[Vec<f64>]) -> PointData {
    let n = series.len() * poses.len();
    let mut rows = Rows {
        line: (1..=n).collect(),
        tool: vec![0; n],
        inputs: series
            .inputs
            .iter()
            .map(|c| c.as_ref().map(|_| Vec::with_capacity(n)))
            .collect(),
        time: series.time.as_ref().map(|_| Vec::with_capacity(n)),
        ..Rows::default()
    };
    rows.inputs.resize(m.inputs.len(), None);
    let mut run = series.run.as_ref().map(|g| kin_data::data::Groups {
        of_row: Vec::with_capacity(n),
        labels: g.labels.clone(),
    });
    let mut pose = DataPose {
        axes: vec![Vec::with_capacity(n); m.axes.len()],
        // Each pose is held still: reached moving in + where the model reads a direction.
        dir: kin_model::states::held_directions(m, n),
    };
    for r in 0..series.len() {
        for q in poses {
            if let (Some(t), Some(src)) = (rows.time.as_mut(), series.time.as_ref()) {
                t.push(src.get(r).copied().unwrap_or(f64::NAN));
            }
            for (dst, src) in rows.inputs.iter_mut().zip(&series.inputs) {
                if let (Some(d), Some(s)) = (dst.as_mut(), src.as_ref()) {
                    d.push(s.get(r).copied().unwrap_or(f64::NAN));
                }
            }
            if let Some(g) = run.as_mut() {
                g.of_row.push(series.run_of(r));
            }
            for (col, x) in pose.axes.iter_mut().zip(q) {
                col.push(*x);
            }
        }
    }
    rows.run = run;
    PointData {
        rows,
        pose,
        observed: Default::default(),
        absolute: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// χ²₃ quantiles from the tables (Abramowitz & Stegun, table 26.8).
    const CHI2_3_95: f64 = 7.814_727_903;
    const CHI2_3_50: f64 = 2.365_973_884;

    fn covariance() -> [[f64; 3]; 3] {
        // L Lᵀ for a fixed lower-triangular L: positive definite and far from diagonal.
        let l = [[2.0, 0.0, 0.0], [1.5, 0.7, 0.0], [-0.4, 0.9, 0.3]];
        let mut c = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] = (0..3).map(|k| l[i][k] * l[j][k]).sum();
            }
        }
        c
    }

    #[test]
    fn the_semi_axes_are_the_chi2_scaled_eigen_pairs() {
        let c = covariance();
        for (level, k2) in [(0.95, CHI2_3_95), (0.5, CHI2_3_50)] {
            let e = Ellipsoid::of(&c, level).unwrap();
            assert!(e.semi_axes[0] >= e.semi_axes[1] && e.semi_axes[1] >= e.semi_axes[2]);
            // Trace and determinant are invariants: Σ a² = χ²·tr C, Π a² = χ²³·det C.
            let trace = c[0][0] + c[1][1] + c[2][2];
            let sum: f64 = e.semi_axes.iter().map(|a| a * a).sum();
            assert!(
                (sum - k2 * trace).abs() < 1e-9 * sum,
                "{sum} vs {}",
                k2 * trace
            );
            let det = nalgebra::Matrix3::from_fn(|i, j| c[i][j]).determinant();
            let prod: f64 = e.semi_axes.iter().map(|a| a * a).product();
            assert!((prod - k2.powi(3) * det).abs() < 1e-9 * prod);
            for (k, u) in e.directions.iter().enumerate() {
                // C u = λ u with λ = a²/χ², and the directions orthonormal.
                let lambda = e.semi_axes[k].powi(2) / k2;
                for i in 0..3 {
                    let cu: f64 = (0..3).map(|j| c[i][j] * u[j]).sum();
                    assert!((cu - lambda * u[i]).abs() < 1e-9, "axis {k}");
                }
                for (m, v) in e.directions.iter().enumerate() {
                    let dot: f64 = (0..3).map(|i| u[i] * v[i]).sum();
                    let want = if k == m { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-12);
                }
            }
        }
    }

    /// Monte Carlo over the covariance: the share of normal draws inside the ellipsoid is its
    /// level, within four binomial standard deviations.
    #[test]
    fn the_ellipsoid_holds_its_level_of_normal_draws() {
        let c = covariance();
        let l = nalgebra::Matrix3::from_fn(|i, j| c[i][j])
            .cholesky()
            .unwrap()
            .l();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let n = 40_000;
        for level in [0.5, 0.95] {
            let e = Ellipsoid::of(&c, level).unwrap();
            let inside = (0..n)
                .filter(|_| {
                    let z = nalgebra::Vector3::from_fn(|_, _| normal.sample(&mut rng));
                    let x = l * z;
                    let r: f64 = (0..3)
                        .map(|k| {
                            let u = nalgebra::Vector3::from(e.directions[k]);
                            (x.dot(&u) / e.semi_axes[k]).powi(2)
                        })
                        .sum();
                    r <= 1.0
                })
                .count();
            let share = inside as f64 / n as f64;
            let sd = (level * (1.0 - level) / n as f64).sqrt();
            assert!((share - level).abs() < 4.0 * sd, "{share} vs {level}");
        }
    }

    #[test]
    fn a_level_outside_zero_to_one_is_refused() {
        assert!(Ellipsoid::of(&covariance(), 1.0).is_err());
        assert!(Ellipsoid::of(&covariance(), 0.0).is_err());
        assert!(Ellipsoid::of(&covariance(), f64::NAN).is_err());
    }
}
