//! `kin correct`: a measuring machine's coordinates corrected by its fitted model (Soons 1993,
//! §2.3.5: a measurement is corrected by subtracting the predicted error), with each corrected
//! coordinate's standard uncertainty from the fit's covariance (eq. 4.12).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_data::data::{self, ExtraColumn, ExtraQuantity, Observations, WriteOptions};
use kin_estimate::simulate::{self, Uncertainty};
use kin_model::interp::Interpreter;
use kin_model::states::States;

use crate::load::{self, Failed};

pub struct CorrectArgs {
    pub machine: PathBuf,
    pub fit: PathBuf,
    pub points: PathBuf,
    pub output: PathBuf,
    pub ignore: crate::args::DataOptions,
    pub color: bool,
}

pub fn run(a: CorrectArgs) -> ExitCode {
    Failed::exit(correct(a))
}

const POSITION: [bool; 6] = [true, true, true, false, false, false];

fn correct(a: CorrectArgs) -> Result<(), Failed> {
    let inputs: [&Path; 3] = [&a.machine, &a.fit, &a.points];
    crate::files::check(&a.output, &inputs)?;
    let compiled = load::machine(&a.machine, Some(&a.fit), a.color)?;
    let m = &compiled.machine;
    if m.task.sign() > 0.0 {
        eprintln!(
            "error: machine `{}` is a positioning machine (`task position`): its axes are corrected, not its readings (`kin compensate`)",
            m.name
        );
        return Err(Failed::INPUT);
    }
    let points = match load::observations(&a.points, &compiled, true, &a.ignore)? {
        Observations::Points(p) => p,
        Observations::Lengths(_) => {
            eprintln!(
                "error: `{}` is a length file: `kin correct` corrects points (one pose per row)",
                a.points.display()
            );
            return Err(Failed::INPUT);
        }
    };
    let fail = |e: simulate::SimulateError| {
        eprintln!("error: `{}`: {e}", a.points.display());
        Failed::INPUT
    };
    let poses = Observations::Points(points);
    // The reported error (measured − true) with the exact transforms, as `kin simulate`
    // computes it for the fitted coefficients without noise.
    let predicted = simulate::simulate(
        m,
        &m.beta,
        &poses,
        &simulate::Options {
            observe: POSITION,
            ..simulate::Options::default()
        },
    )
    .map_err(fail)?;
    let fit = load::fit_report(&a.fit)?;
    let Uncertainty::Points(u) =
        simulate::uncertainty(m, &fit, &poses, POSITION, kin_model::engine::Engine::Interp)
            .map_err(fail)?
    else {
        return Err(Failed::INPUT);
    };
    let Observations::Points(mut out) = predicted else {
        return Err(Failed::INPUT);
    };
    // The measured coordinates: where the machine believes the probe is (nominal kinematics).
    let states = States::new(m, &out.rows, &out.pose, "").map_err(|e| {
        eprintln!("error: `{}`: {e}", a.points.display());
        Failed::INPUT
    })?;
    let mut it = Interpreter::new(m).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let mut measured: [Vec<f64>; 3] = Default::default();
    for r in 0..states.len() {
        let p = it.nominal_position(&states.get(r)).map_err(|e| {
            let line = states.line.get(r).copied().unwrap_or(0);
            eprintln!("error: `{}`, line {line}: {e}", a.points.display());
            Failed::INPUT
        })?;
        for (col, v) in measured.iter_mut().zip(p) {
            col.push(v);
        }
    }
    let names = ["x", "y", "z"];
    let mut extra = Vec::new();
    for (k, name) in names.iter().enumerate() {
        extra.push(ExtraColumn {
            name: (*name).to_string(),
            quantity: ExtraQuantity::Length,
            values: measured[k].clone(),
        });
    }
    for (k, name) in names.iter().enumerate() {
        let error = out.observed[k].clone().unwrap_or_default();
        extra.push(ExtraColumn {
            name: format!("{name}_corrected"),
            quantity: ExtraQuantity::Length,
            values: measured[k].iter().zip(&error).map(|(p, e)| p - e).collect(),
        });
    }
    for (k, name) in names.iter().enumerate() {
        extra.push(ExtraColumn {
            name: format!("u_{name}"),
            quantity: ExtraQuantity::Error,
            values: u[k].clone().unwrap_or_default(),
        });
    }
    for slot in out.observed.iter_mut().skip(3) {
        *slot = None;
    }
    let options = WriteOptions {
        comments: vec![
            format!(
                "corrected by kin with `{}` and the fit `{}`, from `{}`",
                a.machine.display(),
                a.fit.display(),
                a.points.display()
            ),
            "ex ey ez: predicted error (measured − true) in the workpiece frame; x y z: measured coordinates (nominal kinematics); x_corrected …: measured minus predicted error; u_x …: standard uncertainty (k = 1) of the correction from the fit's covariance (eq. 4.12)".into(),
        ],
        extra,
        ..WriteOptions::default()
    };
    let n = states.len();
    data::write_file(&a.output, m, &Observations::Points(out), &options).map_err(|e| {
        eprintln!("error: {e}");
        Failed::USAGE
    })?;
    eprintln!("{n} points corrected into `{}`", a.output.display());
    Ok(())
}
