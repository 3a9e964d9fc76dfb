//! First-order lag states of inputs over a run of observations (thesis eq. 3.41–3.48).
//!
//! Each lag follows `dx/dt = (u − x)/τ` (the state-space model of eq. 3.42 with one mode,
//! normalised to unit steady-state gain). Between consecutive rows the input is linear in time
//! (spec/data.md), for which the update is exact:
//! `x₁ = u₁ − aτ + (x₀ − u₀ + aτ)·e^{−Δt/τ}`, `a = (u₁ − u₀)/Δt`;
//! the particular solution of a ramp is `u − aτ`, and the difference from it decays with `e^{−Δt/τ}`.
//! A run starts in steady state with its first input value.

/// One lag update over `dt` with the input moving linearly from `u0` to `u1`.
pub fn lag_step(x0: f64, u0: f64, u1: f64, dt: f64, tau: f64) -> f64 {
    if !(dt > 0.0) {
        // No time passes: the state cannot move, whatever the input did.
        return x0;
    }
    let a = (u1 - u0) / dt;
    let decay = libm::exp(-dt / tau);
    u1 - a * tau + (x0 - u0 + a * tau) * decay
}

/// Lag states for one run: `times` in time order, `inputs` the input at each row.
/// Writes one state per row into `out`.
pub fn lag_run(times: &[f64], inputs: &[f64], tau: f64, out: &mut [f64]) {
    let mut x = inputs.first().copied().unwrap_or(0.0);
    let mut prev: Option<(f64, f64)> = None;
    for ((t, u), slot) in times.iter().zip(inputs).zip(out.iter_mut()) {
        if let Some((t0, u0)) = prev {
            x = lag_step(x, u0, *u, t - t0, tau);
        }
        *slot = x;
        prev = Some((*t, *u));
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
}
