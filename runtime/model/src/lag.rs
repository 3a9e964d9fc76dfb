//! First-order lag states of inputs over a run of observations (thesis eq. 3.41–3.48).
//!
//! Each lag follows `dx/dt = (u − x)/τ` (the state-space model of eq. 3.42 with one mode,
//! normalised to unit steady-state gain). Between consecutive rows the input is linear in time
//! (spec/data.md), for which the update is exact:
//! `x₁ = u₁ − aτ + (x₀ − u₀ + aτ)·e^{−Δt/τ}`, `a = (u₁ − u₀)/Δt`;
//! the particular solution of a ramp is `u − aτ`, and the difference from it decays with `e^{−Δt/τ}`.
//! A run starts in steady state with its first input value, or with the value the model says
//! was held before the run (`from`).
//!
//! A lag of a lag (two stages in cascade, a slow structure warmed by a faster one) is
//! integrated exactly the same way, both states together: see `lag2_step`.

use kin_compiler::ir::Lag;

/// One lag update over `dt` with the input moving linearly from `u0` to `u1`.
pub(crate) fn lag_step(x0: f64, u0: f64, u1: f64, dt: f64, tau: f64) -> f64 {
    if !(dt > 0.0) {
        // No time passes: the state cannot move, whatever the input did.
        return x0;
    }
    let a = (u1 - u0) / dt;
    let decay = libm::exp(-dt / tau);
    u1 - a * tau + (x0 - u0 + a * tau) * decay
}

/// Lag states for one run: `times` in time order, `inputs` the input at each row.
/// Writes one state per row into `out`. The reference the tests hold `run`'s states to.
#[cfg(test)]
pub(crate) fn lag_run(times: &[f64], inputs: &[f64], tau: f64, out: &mut [f64]) {
    let x0 = inputs.first().copied().unwrap_or(0.0);
    lag_run_from(times, inputs, x0, tau, out);
}

/// Lag states for one run that starts in the state `x0` at its first row.
pub(crate) fn lag_run_from(times: &[f64], inputs: &[f64], x0: f64, tau: f64, out: &mut [f64]) {
    let mut x = x0;
    let mut prev: Option<(f64, f64)> = None;
    for ((t, u), slot) in times.iter().zip(inputs).zip(out.iter_mut()) {
        if let Some((t0, u0)) = prev {
            x = lag_step(x, u0, *u, t - t0, tau);
        }
        *slot = x;
        prev = Some((*t, *u));
    }
}

/// `(e^z − 1)/z`, 1 at 0, for `z ≤ 0`: accurate near 0 (through `expm1`) and bounded.
fn phi(z: f64) -> f64 {
    if z == 0.0 {
        1.0
    } else {
        libm::expm1(z) / z
    }
}

/// One update over `dt` of two lags in cascade, `dx₁/dt = (u − x₁)/τ₁`,
/// `dx₂/dt = (x₁ − x₂)/τ₂` (the state-space model of thesis eq. 3.42 with two modes in
/// series), the input moving linearly from `u0` to `u1`. Exact:
///
/// with `a = (u₁ − u₀)/Δt`, the ramp's particular solutions are `p₁ = u − aτ₁` and
/// `p₂ = u − a(τ₁ + τ₂)`; the deviations `e₁ = x₁ − p₁`, `e₂ = x₂ − p₂` obey `e₁' = −e₁/τ₁`,
/// `e₂' = (e₁ − e₂)/τ₂`, so over a step `h`
///
/// `e₁(h) = e₁ e^{−h/τ₁}`,
/// `e₂(h) = e₂ e^{−h/τ₂} + e₁ (h/τ₂) e^{−h/τ_slow} φ(−h·|1/τ₁ − 1/τ₂|)`, `φ(z) = (e^z − 1)/z`,
///
/// where `τ_slow` is the larger time constant (the convolution `∫ e^{−(h−s)/τ₂} e^{−s/τ₁} ds / τ₂`
/// written with a non-positive argument of φ, so that equal time constants give the limit
/// `e₁ (h/τ) e^{−h/τ}` and very different ones neither overflow nor cancel).
pub(crate) fn lag2_step(x: [f64; 2], u0: f64, u1: f64, dt: f64, tau1: f64, tau2: f64) -> [f64; 2] {
    if !(dt > 0.0) {
        return x;
    }
    let a = (u1 - u0) / dt;
    let e1 = x[0] - (u0 - a * tau1);
    let e2 = x[1] - (u0 - a * (tau1 + tau2));
    let d1 = libm::exp(-dt / tau1);
    let d2 = libm::exp(-dt / tau2);
    let slow = tau1.max(tau2);
    let coupling = (dt / tau2) * libm::exp(-dt / slow) * phi(-dt * (1.0 / tau1 - 1.0 / tau2).abs());
    [
        u1 - a * tau1 + e1 * d1,
        u1 - a * (tau1 + tau2) + e2 * d2 + e1 * coupling,
    ]
}

/// Second-stage states of a two-stage lag over one run that starts with both stages at `x0`.
pub(crate) fn lag2_run_from(
    times: &[f64],
    inputs: &[f64],
    x0: f64,
    tau1: f64,
    tau2: f64,
    out: &mut [f64],
) {
    let mut x = [x0, x0];
    let mut prev: Option<(f64, f64)> = None;
    for ((t, u), slot) in times.iter().zip(inputs).zip(out.iter_mut()) {
        if let Some((t0, u0)) = prev {
            x = lag2_step(x, u0, *u, t - t0, tau1, tau2);
        }
        *slot = x[1];
        prev = Some((*t, *u));
    }
}

/// The states of `lag` over one run: `inputs` are the input values (SI) at `times`, `tau` the
/// values of the machine's non-linear parameters. The heat-source relation is applied at each
/// row and the drive taken as linear between rows (exact for the input itself).
pub fn run(lag: &Lag, nonlinear: &[f64], times: &[f64], inputs: &[f64], out: &mut [f64]) {
    let tau1 = nonlinear.get(lag.tau.index).copied().unwrap_or(f64::NAN);
    // A warm-up is the step response: the constant drive 1 from rest at the run's first row.
    let drive: Vec<f64> = if lag.warmup {
        vec![1.0; times.len()]
    } else {
        inputs.iter().map(|&u| lag.source.drive(u)).collect()
    };
    let x0 = match lag.from {
        _ if lag.warmup => 0.0,
        Some(held) => lag.steady(held),
        None => drive.first().copied().unwrap_or(0.0),
    };
    match lag.tau2 {
        None => lag_run_from(times, &drive, x0, tau1, out),
        Some(t2) => {
            let tau2 = nonlinear.get(t2.index).copied().unwrap_or(f64::NAN);
            lag2_run_from(times, &drive, x0, tau1, tau2, out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_response_matches_the_exponential() {
        // A step held constant: x approaches u as 1 − e^{−t/τ}.
        let tau = 100.0;
        let times = [0.0, 0.0, 50.0, 100.0, 400.0];
        let inputs = [0.0, 1.0, 1.0, 1.0, 1.0];
        let mut out = [0.0; 5];
        lag_run(&times, &inputs, tau, &mut out);
        assert_eq!(out[0], 0.0);
        assert_eq!(out[1], 0.0, "no time passed");
        assert!((out[2] - (1.0 - (-0.5f64).exp())).abs() < 1e-12);
        assert!((out[3] - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
        assert!((out[4] - (1.0 - (-4.0f64).exp())).abs() < 1e-12);
    }

    #[test]
    fn a_warm_up_is_the_step_response_from_rest_in_each_run() {
        let lag = Lag {
            input: 0,
            tau: kin_compiler::ir::NonLinear { index: 0 },
            source: kin_compiler::ir::LagSource::default(),
            tau2: None,
            from: None,
            warmup: true,
        };
        // Irregular times from a start at 1000 s; the inputs are not read.
        let times = [1000.0, 1000.0, 1060.0, 1300.0, 5000.0];
        let mut out = [f64::NAN; 5];
        run(&lag, &[600.0], &times, &[f64::NAN; 5], &mut out);
        for (t, x) in times.iter().zip(out) {
            let w = 1.0 - (-(t - 1000.0) / 600.0f64).exp();
            assert!((x - w).abs() < 1e-12, "t {t}: {x} against {w}");
        }
        assert_eq!(lag.steady(0.0), 1.0, "warm once settled");
    }

    #[test]
    fn ramp_is_exact_against_fine_integration() {
        let tau = 30.0;
        let (u0, u1, dt) = (2.0, 5.0, 45.0);
        let exact = lag_step(u0, u0, u1, dt, tau);
        // Integrate dx/dt = (u − x)/τ with many small RK4 steps.
        let n = 20_000;
        let h = dt / n as f64;
        let u = |t: f64| u0 + (u1 - u0) * t / dt;
        let f = |t: f64, x: f64| (u(t) - x) / tau;
        let mut x = u0;
        for i in 0..n {
            let t = i as f64 * h;
            let k1 = f(t, x);
            let k2 = f(t + h / 2.0, x + h / 2.0 * k1);
            let k3 = f(t + h / 2.0, x + h / 2.0 * k2);
            let k4 = f(t + h, x + h * k3);
            x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
        }
        assert!((x - exact).abs() < 1e-10, "{x} vs {exact}");
    }

    #[test]
    fn steady_input_stays_put() {
        let mut out = [0.0; 3];
        lag_run(&[0.0, 10.0, 20.0], &[3.0, 3.0, 3.0], 5.0, &mut out);
        assert_eq!(out, [3.0, 3.0, 3.0]);
    }

    /// RK4 with many small steps over one ramp step, both stages.
    fn fine2(x: [f64; 2], u0: f64, u1: f64, dt: f64, t1: f64, t2: f64) -> [f64; 2] {
        let n = 20_000;
        let h = dt / n as f64;
        let u = |t: f64| u0 + (u1 - u0) * t / dt;
        let f = |t: f64, x: [f64; 2]| [(u(t) - x[0]) / t1, (x[0] - x[1]) / t2];
        let add = |x: [f64; 2], k: [f64; 2], s: f64| [x[0] + s * k[0], x[1] + s * k[1]];
        let mut x = x;
        for i in 0..n {
            let t = i as f64 * h;
            let k1 = f(t, x);
            let k2 = f(t + h / 2.0, add(x, k1, h / 2.0));
            let k3 = f(t + h / 2.0, add(x, k2, h / 2.0));
            let k4 = f(t + h, add(x, k3, h));
            x = [
                x[0] + h / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
                x[1] + h / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            ];
        }
        x
    }

    #[test]
    fn cascade_step_response_matches_the_closed_form() {
        // A unit step into two stages: x₂ = 1 − (τ₁e^{−t/τ₁} − τ₂e^{−t/τ₂})/(τ₁ − τ₂), and
        // 1 − (1 + t/τ)e^{−t/τ} for equal time constants.
        for (t1, t2) in [(600.0, 7200.0), (7200.0, 600.0), (900.0, 900.0)] {
            let times = [0.0, 0.0, 300.0, 1000.0, 5000.0, 20000.0];
            let inputs = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0];
            let mut out = [0.0; 6];
            lag2_run_from(&times, &inputs, 0.0, t1, t2, &mut out);
            for (t, x) in times.iter().zip(out).skip(1) {
                let closed = if t1 == t2 {
                    1.0 - (1.0 + t / t1) * (-t / t1).exp()
                } else {
                    1.0 - (t1 * (-t / t1).exp() - t2 * (-t / t2).exp()) / (t1 - t2)
                };
                assert!(
                    (x - closed).abs() < 1e-13,
                    "τ {t1} {t2} t {t}: {x} vs {closed}"
                );
            }
        }
    }

    #[test]
    fn cascade_ramp_is_exact_against_fine_integration() {
        for (t1, t2) in [
            (30.0, 200.0),
            (200.0, 30.0),
            (50.0, 50.0),
            (50.0, 50.000001),
            (1.0, 1e4),
        ] {
            let x0 = [1.5, -0.5];
            let exact = lag2_step(x0, 2.0, 5.0, 45.0, t1, t2);
            let fine = fine2(x0, 2.0, 5.0, 45.0, t1, t2);
            for k in 0..2 {
                assert!(
                    (exact[k] - fine[k]).abs() < 1e-9,
                    "τ {t1} {t2} stage {k}: {exact:?} vs {fine:?}"
                );
            }
        }
    }

    #[test]
    fn cascade_of_a_steady_input_stays_put_and_extreme_steps_stay_finite() {
        let mut out = [0.0; 3];
        lag2_run_from(
            &[0.0, 10.0, 20.0],
            &[3.0, 3.0, 3.0],
            3.0,
            5.0,
            50.0,
            &mut out,
        );
        assert_eq!(out, [3.0, 3.0, 3.0]);
        let x = lag2_step([0.0, 0.0], 0.0, 1.0, 1e9, 1e-3, 1e6);
        assert!(x.iter().all(|v| v.is_finite()), "{x:?}");
    }

    #[test]
    fn first_stage_of_a_cascade_is_the_single_lag() {
        let (t1, t2) = (40.0, 400.0);
        let times = [0.0, 13.0, 50.0, 51.0, 300.0];
        let inputs = [0.0, 2.0, -1.0, 4.0, 4.0];
        let mut single = [0.0; 5];
        lag_run_from(&times, &inputs, 0.5, t1, &mut single);
        let mut x = [0.5, 0.5];
        for i in 1..5 {
            x = lag2_step(x, inputs[i - 1], inputs[i], times[i] - times[i - 1], t1, t2);
            assert!((x[0] - single[i]).abs() < 1e-14);
        }
    }
}
