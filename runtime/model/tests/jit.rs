//! Two engines, one truth: the JIT against the interpreter on randomly generated machines and
//! error models (random `.kin` source, compiled by the real compiler) and on every example.
//!
//! Agreement is measured relative to the magnitude of what is compared, per output row:
//! a Jacobian row against its largest entry, an error component against `|fixed| + Σ|J·β|`
//! (entries of a row cancel, so the result itself can be ~0 while its parts are not).

use kin_bench::baseline_5axis as baseline;
use kin_compiler::ir::{JointKind, Machine};
use kin_model::engine::Evaluator;
use kin_model::interp::{EvalError, Interpreter, State};
use kin_model::jit::{self, BatchError, JitModel, Observed, StateRows};
use nalgebra::Vector6;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const TOLERANCE: f64 = 1e-12;

/// Counts this thread's allocations, so a test can check that evaluation allocates nothing
/// (other tests run on other threads meanwhile).
struct Counting;

thread_local! {
    static ALLOCATIONS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

// SAFETY: forwards every call unchanged to the system allocator; the counter is a
// const-initialised thread-local `Cell`, which neither allocates nor blocks.
unsafe impl std::alloc::GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: the caller's contract is the system allocator's.
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: as above.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(|c| c.get())
}

fn example(name: &str) -> Machine {
    let path = format!("{}/../../examples/{name}.kin", env!("CARGO_MANIFEST_DIR"));
    let src = std::fs::read_to_string(&path).expect("example readable");
    compile_source(&src)
}

fn compile_source(src: &str) -> Machine {
    let out = kin_compiler::compile(src);
    match out.compiled {
        Some(c) => c.machine,
        None => panic!("does not compile:\n{src}\n{:#?}", out.diagnostics),
    }
}

/// Owned storage for one random state.
#[derive(Clone)]
struct OwnedState {
    q: Vec<f64>,
    inputs: Vec<f64>,
    lags: Vec<f64>,
    dirs: Vec<f64>,
    time: f64,
    tool: usize,
    tool_offset: Option<[f64; 3]>,
}

impl OwnedState {
    fn get(&self) -> State<'_> {
        State {
            q: &self.q,
            inputs: &self.inputs,
            lags: &self.lags,
            time: self.time,
            dirs: &self.dirs,
            tool: self.tool,
            tool_offset: self.tool_offset,
        }
    }
}

/// A state anywhere near the declared ranges: a little outside them (extrapolation), and
/// continuous axes over several turns (the basis factors reduce them modulo 2π).
fn random_state(rng: &mut StdRng, m: &Machine) -> OwnedState {
    let q = m
        .axes
        .iter()
        .map(|a| {
            if a.continuous {
                rng.random_range(-4.0 * std::f64::consts::PI..6.0 * std::f64::consts::PI)
            } else {
                let span = a.range[1] - a.range[0];
                rng.random_range(a.range[0] - 0.1 * span..a.range[1] + 0.1 * span)
            }
        })
        .collect();
    let inputs: Vec<f64> = m
        .inputs
        .iter()
        .map(|i| {
            if i.absolute {
                rng.random_range(288.0..298.0)
            } else {
                rng.random_range(0.0..1000.0)
            }
        })
        .collect();
    let lags = m
        .lags
        .iter()
        .map(|l| l.steady(inputs.get(l.input).copied().unwrap_or(0.0)) * rng.random_range(0.5..1.0))
        .collect();
    let dirs = m
        .axes
        .iter()
        .map(|_| if rng.random_bool(0.5) { 1.0 } else { -1.0 })
        .collect();
    let tool = rng.random_range(0..m.tools.len());
    let tool_offset = rng
        .random_bool(0.3)
        .then(|| [0, 1, 2].map(|_| rng.random_range(-0.3..0.3)));
    OwnedState {
        q,
        inputs,
        lags,
        dirs,
        time: rng.random_range(0.0..5000.0),
        tool,
        tool_offset,
    }
}

/// The largest relative difference so far, for the report.
#[derive(Default, Debug)]
struct Worst {
    error: f64,
    jacobian: f64,
    nominal: f64,
    length: f64,
}

/// `max_r max_j |a − b| / scale_r` over a `rows × cols` row-major block.
fn row_relative(a: &[f64], b: &[f64], rows: usize, scale: impl Fn(usize) -> f64) -> f64 {
    let cols = a.len() / rows.max(1);
    let mut worst: f64 = 0.0;
    for r in 0..rows {
        let s = scale(r);
        for j in 0..cols {
            let d = (a[r * cols + j] - b[r * cols + j]).abs();
            let rel = if s > 0.0 {
                d / s
            } else if d == 0.0 {
                0.0
            } else {
                f64::INFINITY
            };
            worst = worst.max(rel);
        }
    }
    worst
}

/// Compares the JIT with the interpreter on `states`, returning the worst relative differences.
fn compare(
    m: &Machine,
    model: &JitModel,
    states: &[OwnedState],
    rng: &mut StdRng,
    label: &str,
) -> Worst {
    let n = m.coefficients.len();
    let axes = m.axes.len();
    let mut it = Interpreter::new(m).expect("interpreter");
    let mut ev = model.evaluator();
    // Random non-linear parameters (fitted wavelengths move), the same in both engines.
    let nonlinear: Vec<f64> = m
        .nonlinear
        .iter()
        .map(|p| p.value * rng.random_range(0.8..1.25))
        .collect();
    it.set_nonlinear(&nonlinear).expect("set");
    ev.set_nonlinear(&nonlinear).expect("set");
    let beta: Vec<f64> = (0..n).map(|_| rng.random_range(-1e-5..1e-5)).collect();
    let zero = vec![0.0; n];
    let (mut ji, mut jj) = (vec![0.0; 6 * n], vec![0.0; 6 * n]);
    let (mut ei, mut ej, mut e0) = ([0.0; 6], [0.0; 6], [0.0; 6]);
    let mut worst = Worst::default();
    for (k, s) in states.iter().enumerate() {
        let st = s.get();
        let ctx = || format!("{label}, state {k}");
        it.error_and_jacobian(&st, &zero, &mut e0, &mut ji)
            .unwrap_or_else(|e| panic!("{}: {e}", ctx()));
        it.error_and_jacobian(&st, &beta, &mut ei, &mut ji)
            .unwrap_or_else(|e| panic!("{}: {e}", ctx()));
        // Poison the JIT's buffer: every entry must be written.
        jj.fill(f64::NAN);
        ev.error_and_jacobian(&st, &beta, &mut ej, &mut jj)
            .unwrap_or_else(|e| panic!("{}: {e}", ctx()));
        let jac_scale = |r: usize| (0..n).map(|j| ji[r * n + j].abs()).fold(0.0, f64::max);
        let dj = row_relative(&ji, &jj, 6, jac_scale);
        assert!(dj <= TOLERANCE, "{}: Jacobian differs by {dj:e}", ctx());
        let err_scale =
            |r: usize| e0[r].abs() + (0..n).map(|j| (ji[r * n + j] * beta[j]).abs()).sum::<f64>();
        let de = row_relative(&ei, &ej, 6, err_scale);
        assert!(
            de <= TOLERANCE,
            "{}: error differs by {de:e}: {ei:?} vs {ej:?}",
            ctx()
        );
        // The error-only function and the plain interpreter path.
        let plain_i = it.error(&st, &beta).expect("interp error");
        let plain_j = ev.error(&st, &beta).expect("jit error");
        let dp = row_relative(&plain_i, &plain_j, 6, err_scale);
        assert!(dp <= TOLERANCE, "{}: error-only differs by {dp:e}", ctx());
        worst.jacobian = worst.jacobian.max(dj);
        worst.error = worst.error.max(de).max(dp);

        // Nominal location and joint Jacobian.
        let mut vi = vec![Vector6::zeros(); axes];
        let mut vj = vec![f64::NAN; 6 * axes];
        let li = it.nominal_jacobian(&st, &mut vi).expect("interp nominal");
        let lj = model.nominal_jacobian(&st, &mut vj).expect("jit nominal");
        let flat: Vec<f64> = vi.iter().flat_map(|v| v.iter().copied()).collect();
        // Per row of (dp/dq, ω): scale by the largest entry of that row over all axes, or the
        // machine size for a position.
        let size = li.position.norm().max(1.0);
        let dn = row_relative(&flat, &vj, axes, |_| {
            flat.iter().fold(size, |a, v| a.max(v.abs()))
        });
        let dpos = (li.position - lj.position).amax() / size;
        let drot = (li.rotation - lj.rotation).amax();
        assert!(
            dn.max(dpos).max(drot) <= TOLERANCE,
            "{}: nominal differs: {dn:e} {dpos:e} {drot:e}",
            ctx()
        );
        worst.nominal = worst.nominal.max(dn).max(dpos).max(drot);
    }
    // Length rows between consecutive states of the same tool (eq. 4.5).
    for pair in states.windows(2) {
        let s1 = pair[0].get();
        let mut second = pair[1].get();
        second.tool = s1.tool;
        second.tool_offset = s1.tool_offset;
        let (mut ri, mut rj) = (vec![0.0; n], vec![0.0; n]);
        let li = it.length_and_row(&s1, &second, &beta, &mut ri);
        let lj = ev.length_and_row(&s1, &second, &beta, &mut rj);
        let (li, lj) = match (li, lj) {
            (Ok(a), Ok(b)) => (a, b),
            (Err(a), Err(b)) => {
                assert_eq!(a, b);
                continue;
            }
            (a, b) => panic!("{label}: length {a:?} vs {b:?}"),
        };
        // The length error is u·(Δp₂ − Δp₁) and its row u·(J₂ − J₁): differences of the two
        // poses' values, which cancel when the poses see the same error. Rounding is relative
        // to the magnitudes that cancel, not to their difference, so the scales are built from
        // the interpreter's Jacobians at both poses (a row of 1e-17 left by cancellation is
        // rounding, and so is a length of 1e-22 computed from it).
        let (cancelling, fixed) = {
            let (mut j1, mut j2) = (vec![0.0; 6 * n], vec![0.0; 6 * n]);
            let (mut f1, mut f2) = ([0.0; 6], [0.0; 6]);
            it.error_and_jacobian(&s1, &zero, &mut f1, &mut j1)
                .expect("error at the first pose");
            it.error_and_jacobian(&second, &zero, &mut f2, &mut j2)
                .expect("error at the second pose");
            let magnitude = |j: usize| -> f64 {
                (0..3)
                    .map(|r| j1[r * n + j].abs() + j2[r * n + j].abs())
                    .sum()
            };
            let fixed: f64 = (0..3).map(|r| f1[r].abs() + f2[r].abs()).sum();
            ((0..n).map(magnitude).collect::<Vec<f64>>(), fixed)
        };
        let mut r0 = vec![0.0; n];
        let l0 = it
            .length_and_row(&s1, &second, &zero, &mut r0)
            .expect("length");
        let row_scale = cancelling.iter().fold(0.0, |a: f64, v| a.max(*v));
        let dr = row_relative(&ri, &rj, 1, |_| row_scale);
        let l_scale = l0.abs()
            + fixed
            + cancelling
                .iter()
                .zip(&beta)
                .map(|(m, b)| m * b.abs())
                .sum::<f64>();
        let dl = if l_scale > 0.0 {
            (li - lj).abs() / l_scale
        } else {
            (li - lj).abs()
        };
        assert!(
            dr.max(dl) <= TOLERANCE,
            "{label}: length row {dr:e}, length {dl:e}"
        );
        worst.length = worst.length.max(dr).max(dl);
    }
    worst
}

#[test]
fn examples_agree_with_the_interpreter() {
    let mut rng = StdRng::seed_from_u64(1);
    for name in ["milling_5axis", "bridge_cmm", "robot_6axis"] {
        let m = example(name);
        let model = jit::compile(&m).expect("compiles");
        let states: Vec<OwnedState> = (0..40).map(|_| random_state(&mut rng, &m)).collect();
        let w = compare(&m, &model, &states, &mut rng, name);
        eprintln!(
            "{name}: {w:?}, {} nodes, compiled in {:?}",
            model.nodes(),
            model.compile_time()
        );
    }
}

/// Random `.kin` sources: chains of 0–4 elements each side, moving/fixed, revolute/prismatic
/// in random directions, shapes with rotations, several tools, both tasks, and error models
/// drawing on every factor family, products, known scalings and fixed terms.
struct Gen {
    rng: StdRng,
    /// Also `fourier(V, …, wavelength λ)` along a variable that is not an angle. Off where a
    /// test's random stream (and so its machines) must stay as it was.
    fourier_along: bool,
    /// Also definitions with several targets (`A0.tx, A1.ry += …`), sharing their fitted
    /// wavelengths and time constants. Off where a test's random stream must stay as it was.
    shared: bool,
    /// Also heat sources and cascades (`lag(pow(S0 / 10000 rpm, 1.5), …, from 0 rpm)`,
    /// `lag(lag(T0, …), …)`) and the speed input they need. Off where a test's random stream
    /// must stay as it was.
    heat: bool,
    /// While generating the value of a definition whose targets mix translations and
    /// rotations: no fixed term (it cannot have both dimensions).
    no_fixed: bool,
}

#[derive(Clone)]
struct AxisDecl {
    name: String,
    revolute: bool,
    /// Range in the declared unit (mm or deg).
    lo: f64,
    hi: f64,
}

impl Gen {
    fn f(&mut self, lo: f64, hi: f64) -> f64 {
        self.rng.random_range(lo..hi)
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.rng.random_range(0..items.len())]
    }

    fn chance(&mut self, p: f64) -> bool {
        self.rng.random_bool(p)
    }

    fn vector(&mut self, scale: f64) -> String {
        let v: Vec<String> = (0..3)
            .map(|_| format!("{:.3}", self.f(-scale, scale)))
            .collect();
        format!("({})", v.join(", "))
    }

    fn placement(&mut self) -> String {
        let mut p = String::new();
        if self.chance(0.8) {
            p += &format!(" at {} mm", self.vector(400.0));
        }
        if self.chance(0.4) {
            p += &format!(" rot {} deg", self.vector(90.0));
        }
        p
    }

    fn direction(&mut self) -> String {
        if self.chance(0.5) {
            let sign = self.pick(&["", "-", "+"]).to_string();
            let axis = self.pick(&["x", "y", "z"]).to_string();
            format!("{sign}{axis}")
        } else {
            loop {
                let v = [0, 1, 2].map(|_| self.f(-1.0, 1.0));
                if v.iter().map(|x| x * x).sum::<f64>() > 0.1 {
                    return format!("({:.3}, {:.3}, {:.3})", v[0], v[1], v[2]);
                }
            }
        }
    }

    fn machine(&mut self, index: usize) -> String {
        let tool_len = self.rng.random_range(0..=4);
        let wp_len = self.rng.random_range(0..=4);
        let mut axes = Vec::new();
        let mut src = format!("machine random_{index} {{\n");
        src += &format!(
            "    task {}\n",
            if self.chance(0.5) {
                "position"
            } else {
                "measure"
            }
        );
        for k in 0..tool_len + wp_len {
            let revolute = self.chance(0.45);
            let name = format!("A{k}");
            let dir = self.direction();
            let decl = if revolute {
                if self.chance(0.35) {
                    src += &format!("    axis {name} revolute about {dir} continuous\n");
                    AxisDecl {
                        name,
                        revolute,
                        lo: 0.0,
                        hi: 360.0,
                    }
                } else {
                    let lo = self.f(-180.0, 30.0);
                    let hi = lo + self.f(60.0, 300.0);
                    src += &format!(
                        "    axis {name} revolute about {dir} range {lo:.2} deg .. {hi:.2} deg\n"
                    );
                    AxisDecl {
                        name,
                        revolute,
                        lo: (lo * 100.0).round() / 100.0,
                        hi: (hi * 100.0).round() / 100.0,
                    }
                }
            } else {
                let lo = self.f(-500.0, 200.0);
                let hi = lo + self.f(100.0, 900.0);
                src += &format!(
                    "    axis {name} prismatic along {dir} range {lo:.2} mm .. {hi:.2} mm\n"
                );
                AxisDecl {
                    name,
                    revolute,
                    lo: (lo * 100.0).round() / 100.0,
                    hi: (hi * 100.0).round() / 100.0,
                }
            };
            axes.push(decl);
        }
        src += "    input T0 : temperature rise range 0 degC .. 5 degC\n";
        src += "    input Tabs : temperature absolute range 15 degC .. 25 degC\n";
        src += "    input F0 : force range 0 N .. 1000 N\n";
        if self.heat {
            src += "    input S0 : speed range 0 rpm .. 12000 rpm\n";
        }
        let tools: Vec<String> = (0..self.rng.random_range(1..=3))
            .map(|i| format!("t{i}"))
            .collect();
        src += "    tool chain {\n";
        for a in axes.iter().take(tool_len) {
            let kind = if self.chance(0.5) { "moving" } else { "fixed" };
            src += &format!("        {} {kind}{}\n", a.name, self.placement());
        }
        for t in &tools {
            src += &format!("        tool {t}{}\n", self.placement());
        }
        src += "    }\n    workpiece chain {\n";
        for a in axes.iter().skip(tool_len) {
            let kind = if self.chance(0.5) { "moving" } else { "fixed" };
            src += &format!("        {} {kind}{}\n", a.name, self.placement());
        }
        if self.chance(0.7) {
            src += &format!("        workpiece{}\n", self.placement());
        }
        src += "    }\n    errors {\n";
        let mut frames: Vec<String> = axes.iter().map(|a| a.name.clone()).collect();
        frames.extend(tools.iter().cloned());
        frames.push("tool".into());
        frames.push("workpiece".into());
        let mut defined = std::collections::HashSet::new();
        for _ in 0..self.rng.random_range(1..=8) {
            let frame = self.pick(&frames).clone();
            let comp = *self.pick(&["tx", "ty", "tz", "rx", "ry", "rz"]);
            let mut targets = vec![(frame, comp)];
            if self.shared && self.chance(0.4) {
                for _ in 0..self.rng.random_range(1..=2) {
                    let t = (
                        self.pick(&frames).clone(),
                        *self.pick(&["tx", "ty", "tz", "rx", "ry", "rz"]),
                    );
                    if !targets.contains(&t) {
                        targets.push(t);
                    }
                }
            }
            let fresh = targets.iter().all(|t| !defined.contains(t));
            defined.extend(targets.iter().cloned());
            let op = if fresh { "=" } else { "+=" };
            let rotation = comp.starts_with('r');
            self.no_fixed = targets.iter().any(|t| t.1.starts_with('r') != rotation);
            let expr = self.expr(&axes, rotation);
            self.no_fixed = false;
            let names: Vec<String> = targets.iter().map(|(f, c)| format!("{f}.{c}")).collect();
            src += &format!("        {} {op} {expr}\n", names.join(", "));
        }
        src += "    }\n}\n";
        src
    }

    /// A variable for a ranged family: an axis or the ranged inputs.
    fn ranged_var(&mut self, axes: &[AxisDecl]) -> (String, f64, &'static str) {
        if axes.is_empty() || self.chance(0.15) {
            return match self.rng.random_range(0..3) {
                0 => ("T0".into(), 5.0, "degC"),
                1 => ("Tabs".into(), 10.0, "degC"),
                _ => ("F0".into(), 1000.0, "N"),
            };
        }
        let a = self.pick(axes).clone();
        (a.name, a.hi - a.lo, if a.revolute { "deg" } else { "mm" })
    }

    /// One basis-factor call. `avoid` holds the variables already used in the product.
    fn family(&mut self, axes: &[AxisDecl], avoid: &mut Vec<String>) -> Option<String> {
        let revolute: Vec<AxisDecl> = axes
            .iter()
            .filter(|a| a.revolute && !avoid.contains(&a.name))
            .cloned()
            .collect();
        for _ in 0..20 {
            let kind = self.rng.random_range(0..10);
            let call = match kind {
                0 => "const".to_string(),
                1 | 2 => {
                    let (v, _, _) = self.ranged_var(axes);
                    if avoid.contains(&v) {
                        continue;
                    }
                    avoid.push(v.clone());
                    match kind {
                        1 => format!("linear({v})"),
                        _ => format!("poly({v}, degree {})", self.rng.random_range(1..=5)),
                    }
                }
                3 | 4 => {
                    let (v, span, unit) = self.ranged_var(axes);
                    if avoid.contains(&v) {
                        continue;
                    }
                    let degree = self.rng.random_range(1..=4u32);
                    let smooth = self.rng.random_range(0..degree);
                    let knots = self.rng.random_range(0..=3usize);
                    let straight = kind == 4;
                    if straight && degree + knots as u32 * (degree - smooth) < 2 {
                        continue;
                    }
                    // `knots at (…) degC` on an absolute temperature is rejected by the checker (it compares
                    // the knots as differences against an absolute range), so positions are only given
                    // for the other variables.
                    let knot_text = if knots > 0 && v != "Tabs" && self.chance(0.4) {
                        let lo = axes
                            .iter()
                            .find(|a| a.name == v)
                            .map_or(if v == "Tabs" { 15.0 } else { 0.0 }, |a| a.lo);
                        let mut ts: Vec<f64> = (0..knots)
                            .map(|k| (k as f64 + 0.3 + 0.4 * self.f(0.0, 1.0)) / knots as f64)
                            .collect();
                        ts.sort_by(f64::total_cmp);
                        let list: Vec<String> =
                            ts.iter().map(|t| format!("{:.3}", lo + t * span)).collect();
                        format!("knots at ({}) {unit}", list.join(", "))
                    } else {
                        format!("knots {knots}")
                    };
                    avoid.push(v.clone());
                    let family = if straight { "straightness" } else { "spline" };
                    format!("{family}({v}, {knot_text}, degree {degree}, smooth {smooth})")
                }
                5 if !revolute.is_empty() => {
                    let a = self.pick(&revolute).clone();
                    if avoid.contains(&a.name) {
                        continue;
                    }
                    avoid.push(a.name.clone());
                    format!(
                        "spline({}, knots {}, no_once_per_rev)",
                        a.name,
                        self.rng.random_range(1..=3)
                    )
                }
                6 if !revolute.is_empty() => {
                    let a = self.pick(&revolute).clone();
                    if avoid.contains(&a.name) {
                        continue;
                    }
                    avoid.push(a.name.clone());
                    let h = match self.rng.random_range(0..3) {
                        0 => {
                            let lo = self.rng.random_range(1..4);
                            format!("{lo}..{}", lo + self.rng.random_range(0..3))
                        }
                        1 => format!(
                            "({}, {})",
                            self.rng.random_range(1..5),
                            self.rng.random_range(5..200)
                        ),
                        _ => format!("{}", self.rng.random_range(1..50)),
                    };
                    format!("fourier({}, harmonics {h})", a.name)
                }
                7 => {
                    let (v, span, unit) = self.ranged_var(axes);
                    if avoid.contains(&v) {
                        continue;
                    }
                    let degree = self.rng.random_range(1..=4u32);
                    let smooth = self.rng.random_range(0..degree);
                    let knots = self.rng.random_range(0..=3u32);
                    if (knots + 1) * (degree - smooth) < 2 {
                        continue;
                    }
                    avoid.push(v.clone());
                    let lambda = span / f64::from(self.rng.random_range(2..9u32));
                    let fit = if self.chance(0.5) { "fit " } else { "" };
                    // A revolute axis' harmonics are per revolution, never at a wavelength.
                    if self.fourier_along && unit != "deg" && self.chance(0.3) {
                        // The Fourier series of a fundamental along a variable that is not an angle.
                        let top = self.rng.random_range(1..5u32);
                        return Some(format!(
                            "fourier({v}, harmonics 1..{top}, wavelength {fit}{lambda:.4} {unit})"
                        ));
                    }
                    let phase = if self.chance(0.4) {
                        format!(", phase {:.3} {unit}", self.f(0.0, lambda))
                    } else {
                        String::new()
                    };
                    format!("periodic({v}, wavelength {fit}{lambda:.4} {unit}, knots {knots}, degree {degree}, smooth {smooth}{phase})")
                }
                8 if !axes.is_empty() => {
                    let a = self.pick(axes).clone();
                    let dir = format!("dir_{}", a.name);
                    if avoid.contains(&dir) {
                        continue;
                    }
                    avoid.push(dir);
                    format!(
                        "{}({})",
                        if self.chance(0.5) {
                            "backlash"
                        } else {
                            "direction"
                        },
                        a.name
                    )
                }
                _ => continue,
            };
            return Some(call);
        }
        None
    }

    /// A known scalar that scales a term (any dimension).
    fn known_scale(&mut self, axes: &[AxisDecl]) -> String {
        let revolute: Vec<&AxisDecl> = axes.iter().filter(|a| a.revolute).collect();
        let cases = if self.heat { 10 } else { 7 };
        match self.rng.random_range(0..cases) {
            0 if !revolute.is_empty() => format!("sin({})", self.pick(&revolute).name),
            1 if revolute.len() >= 2 => format!("cos({} + {})", revolute[0].name, revolute[1].name),
            2 if !revolute.is_empty() => format!("cos(2 * {} - 10 deg)", self.pick(&revolute).name),
            3 => "F0 / 500 N".into(),
            4 => format!(
                "lag(T0, tau {}{:.1} s)",
                if self.chance(0.5) { "fit " } else { "" },
                self.f(10.0, 500.0)
            ),
            5 => "time / 1000 s".into(),
            6 if self.heat => format!(
                "lag(pow(S0 / 10000 rpm, {}), tau {}{:.1} min{})",
                self.pick(&["1.5", "2", "0.8"]),
                if self.chance(0.5) { "fit " } else { "" },
                self.f(1.0, 60.0),
                if self.chance(0.5) { ", from 0 rpm" } else { "" }
            ),
            7 if self.heat => format!(
                "lag(lag(T0, tau {}{:.1} s), tau {}{:.1} min)",
                if self.chance(0.5) { "fit " } else { "" },
                self.f(10.0, 500.0),
                if self.chance(0.5) { "fit " } else { "" },
                self.f(10.0, 200.0)
            ),
            8 if self.heat => format!(
                "warmup(time, tau {}{:.1} min)",
                if self.chance(0.5) { "fit " } else { "" },
                self.f(1.0, 60.0)
            ),
            _ => format!("{:.3}", self.f(-3.0, 3.0)),
        }
    }

    /// A known fixed error of the component's dimension (length or angle).
    fn fixed(&mut self, axes: &[AxisDecl], rotation: bool) -> String {
        let unit = if rotation { "urad" } else { "um" };
        let revolute: Vec<&AxisDecl> = axes.iter().filter(|a| a.revolute).collect();
        let prismatic: Vec<&AxisDecl> = axes.iter().filter(|a| !a.revolute).collect();
        match self.rng.random_range(0..6) {
            0 => format!("{:.3} {unit}/K * (Tabs - 20 degC)", self.f(-10.0, 10.0)),
            1 if !revolute.is_empty() => format!(
                "{:.3} {unit} * sin({})",
                self.f(-5.0, 5.0),
                self.pick(&revolute).name
            ),
            2 if !prismatic.is_empty() => format!(
                "{:.3} {unit}/mm * {}",
                self.f(-0.01, 0.01),
                self.pick(&prismatic).name
            ),
            3 => format!("{:.3} {unit}/K * T0", self.f(-2.0, 2.0)),
            4 => format!("{:.3} {unit}/N * F0 * cos(30 deg)", self.f(-0.01, 0.01)),
            _ => format!("{:.3} {unit}", self.f(-5.0, 5.0)),
        }
    }

    fn term(&mut self, axes: &[AxisDecl], rotation: bool) -> String {
        let mut avoid = Vec::new();
        match self.rng.random_range(0..8) {
            0 if !self.no_fixed => self.fixed(axes, rotation),
            1 => format!(
                "{} * {}",
                self.known_scale(axes),
                self.family(axes, &mut avoid).unwrap_or("const".into())
            ),
            2 | 3 => {
                let a = self.family(axes, &mut avoid).unwrap_or("const".into());
                let b = self.family(axes, &mut avoid).unwrap_or("const".into());
                format!("{a} * {b}")
            }
            4 => {
                let a = self.family(axes, &mut avoid).unwrap_or("const".into());
                let b = self.family(axes, &mut avoid).unwrap_or("const".into());
                let c = self.family(axes, &mut avoid).unwrap_or("const".into());
                format!("({a} + {:.2} * {b}) * {c}", self.f(0.5, 2.0))
            }
            5 => format!(
                "{} / {:.2}",
                self.family(axes, &mut avoid).unwrap_or("const".into()),
                self.f(1.0, 4.0)
            ),
            _ => self.family(axes, &mut avoid).unwrap_or("const".into()),
        }
    }

    fn expr(&mut self, axes: &[AxisDecl], rotation: bool) -> String {
        let mut e = self.term(axes, rotation);
        for _ in 0..self.rng.random_range(0..3) {
            let op = if self.chance(0.7) { "+" } else { "-" };
            e = format!("{e}\n            {op} {}", self.term(axes, rotation));
        }
        if self.chance(0.1) {
            e = format!("-({e})");
        }
        e
    }
}

#[test]
fn random_machines_agree_with_the_interpreter() {
    let mut gen = Gen {
        rng: StdRng::seed_from_u64(20240601),
        fourier_along: true,
        shared: false,
        heat: true,
        no_fixed: false,
    };
    let mut rng = StdRng::seed_from_u64(99);
    let mut worst = Worst::default();
    let mut coefficients = 0;
    let mut revolute = 0;
    const MACHINES: usize = 200;
    for index in 0..MACHINES {
        let src = gen.machine(index);
        let m = compile_source(&src);
        coefficients += m.coefficients.len();
        revolute += m
            .axes
            .iter()
            .filter(|a| a.kind == JointKind::Revolute)
            .count();
        let model = jit::compile(&m).unwrap_or_else(|e| panic!("{src}\n{e}"));
        let states: Vec<OwnedState> = (0..6).map(|_| random_state(&mut rng, &m)).collect();
        let w = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            compare(&m, &model, &states, &mut rng, &format!("machine {index}"))
        }));
        let w = match w {
            Ok(w) => w,
            Err(e) => {
                eprintln!("failing source:\n{src}");
                std::panic::resume_unwind(e);
            }
        };
        worst.error = worst.error.max(w.error);
        worst.jacobian = worst.jacobian.max(w.jacobian);
        worst.nominal = worst.nominal.max(w.nominal);
        worst.length = worst.length.max(w.length);
    }
    eprintln!("{MACHINES} random machines, {coefficients} coefficients, {revolute} revolute axes; worst relative differences {worst:?}");
    assert!(
        coefficients > 10 * MACHINES,
        "the generator makes too small models"
    );
}

#[test]
fn fourier_along_an_axis_agrees_with_the_interpreter() {
    let mut gen = Gen {
        rng: StdRng::seed_from_u64(20261123),
        fourier_along: true,
        shared: false,
        heat: true,
        no_fixed: false,
    };
    let mut rng = StdRng::seed_from_u64(7);
    // Machines with a Fourier series at a fixed and at a fitted wavelength.
    let (mut fixed, mut fitted) = (0, 0);
    for index in 0..120 {
        let src = gen.machine(index);
        let along = |fit: &str| {
            src.split("fourier(")
                .skip(1)
                .any(|t| t.split(')').next().is_some_and(|a| a.contains(fit)))
        };
        fixed += usize::from(along("wavelength "));
        fitted += usize::from(along("wavelength fit"));
        let m = compile_source(&src);
        let model = jit::compile(&m).unwrap_or_else(|e| panic!("{src}\n{e}"));
        let states: Vec<OwnedState> = (0..6).map(|_| random_state(&mut rng, &m)).collect();
        let w = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            compare(&m, &model, &states, &mut rng, &format!("machine {index}"))
        }));
        if let Err(e) = w {
            eprintln!("failing source:\n{src}");
            std::panic::resume_unwind(e);
        }
    }
    assert!(fixed > fitted && fitted > 0, "{fixed} {fitted}");
}

#[test]
fn shared_targets_agree_with_the_interpreter() {
    let mut gen = Gen {
        rng: StdRng::seed_from_u64(20261125),
        fourier_along: true,
        shared: true,
        heat: true,
        no_fixed: false,
    };
    let mut rng = StdRng::seed_from_u64(11);
    // Machines where a fitted wavelength or time constant is shared by several targets.
    let mut shared = 0;
    for index in 0..120 {
        let src = gen.machine(index);
        shared += usize::from(src.lines().any(|l| {
            l.split(" = ")
                .next()
                .and_then(|t| t.split(" += ").next())
                .is_some_and(|t| t.contains(", "))
                && l.contains(" fit ")
        }));
        let m = compile_source(&src);
        let model = jit::compile(&m).unwrap_or_else(|e| panic!("{src}\n{e}"));
        let states: Vec<OwnedState> = (0..6).map(|_| random_state(&mut rng, &m)).collect();
        let w = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            compare(&m, &model, &states, &mut rng, &format!("machine {index}"))
        }));
        if let Err(e) = w {
            eprintln!("failing source:\n{src}");
            std::panic::resume_unwind(e);
        }
    }
    assert!(
        shared > 5,
        "only {shared} machines share a fitted parameter"
    );
}

#[test]
fn every_family_is_generated() {
    // The generator's reach, checked on its text so a change cannot quietly drop a family.
    let mut gen = Gen {
        rng: StdRng::seed_from_u64(20240601),
        fourier_along: true,
        shared: false,
        heat: true,
        no_fixed: false,
    };
    let text: String = (0..200).map(|i| gen.machine(i)).collect();
    for needle in [
        "const",
        "linear(",
        "poly(",
        "spline(",
        "straightness(",
        "no_once_per_rev",
        "fourier(",
        "periodic(",
        "wavelength fit",
        "phase",
        "backlash(",
        "direction(",
        "lag(",
        "lag(lag(",
        "warmup(",
        "pow(",
        "from 0 rpm",
        "tau fit",
        "sin(",
        "cos(",
        "knots at",
        "moving",
        "fixed",
        "revolute",
        "prismatic",
        "continuous",
        "rot (",
        "task measure",
        "task position",
        "tool.",
        "workpiece.",
        "t1.",
        "time /",
        "+=",
        "Tabs - 20 degC",
    ] {
        assert!(
            text.contains(needle),
            "no `{needle}` in the generated sources"
        );
    }
}

#[test]
fn evaluation_does_not_allocate() {
    let m = example("milling_5axis");
    let model = jit::compile(&m).expect("compiles");
    let n = m.coefficients.len();
    let mut rng = StdRng::seed_from_u64(4);
    let states: Vec<OwnedState> = (0..20).map(|_| random_state(&mut rng, &m)).collect();
    let beta = vec![1e-6; n];
    let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let mut ev = model.evaluator();
    let (mut jac, mut joint, mut row) =
        (vec![0.0; 6 * n], vec![0.0; 6 * m.axes.len()], vec![0.0; n]);
    let mut err = [0.0; 6];
    // A subset's code is compiled at its first use (lengths use the position rows' code).
    model.prepare(Observed::POSITION);
    let (mut perr, mut pjac) = ([0.0; 3], vec![0.0; 3 * n]);
    let before = allocations();
    for pair in states.windows(2) {
        let (s1, mut s2) = (pair[0].get(), pair[1].get());
        s2.tool = s1.tool;
        s2.tool_offset = s1.tool_offset;
        model
            .error_and_jacobian(&s1, &beta, &nl, &mut err, &mut jac)
            .expect("eval");
        std::hint::black_box(model.error(&s1, &beta, &nl).expect("eval"));
        model.nominal_jacobian(&s1, &mut joint).expect("eval");
        ev.error_and_jacobian(&s1, &beta, &mut err, &mut jac)
            .expect("eval");
        std::hint::black_box(ev.length_and_row(&s1, &s2, &beta, &mut row).expect("eval"));
        std::hint::black_box(ev.nominal_position(&s1).expect("eval"));
        ev.observed_error_and_jacobian(&s1, &beta, Observed::POSITION, &mut perr, &mut pjac)
            .expect("eval");
    }
    assert_eq!(allocations(), before, "an evaluation allocated");
}

#[test]
fn the_model_is_shared_between_threads() {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<JitModel>();
    fn send<T: Send>() {}
    send::<jit::JitEvaluator>();
    let m = example("milling_5axis");
    let model = jit::compile(&m).expect("compiles");
    let n = m.coefficients.len();
    let mut rng = StdRng::seed_from_u64(5);
    let states: Vec<OwnedState> = (0..64).map(|_| random_state(&mut rng, &m)).collect();
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j as f64).sin()).collect();
    let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let reference: Vec<[f64; 6]> = states
        .iter()
        .map(|s| model.error(&s.get(), &beta, &nl).expect("eval"))
        .collect();
    std::thread::scope(|scope| {
        for t in 0..4 {
            let (model, states, beta, nl, reference) = (&model, &states, &beta, &nl, &reference);
            scope.spawn(move || {
                let mut jac = vec![0.0; 6 * n];
                let mut err = [0.0; 6];
                for round in 0..50 {
                    let k = (t * 17 + round * 5) % states.len();
                    model
                        .error_and_jacobian(&states[k].get(), beta, nl, &mut err, &mut jac)
                        .expect("eval");
                    assert_eq!(err, reference[k]);
                }
            });
        }
    });
}

#[test]
fn batch_rows_match_single_calls() {
    let m = example("bridge_cmm");
    let model = jit::compile(&m).expect("compiles");
    let n = m.coefficients.len();
    let mut rng = StdRng::seed_from_u64(8);
    let states: Vec<OwnedState> = (0..25).map(|_| random_state(&mut rng, &m)).collect();
    let flat =
        |f: &dyn Fn(&OwnedState) -> Vec<f64>| -> Vec<f64> { states.iter().flat_map(f).collect() };
    let q = flat(&|s| s.q.clone());
    let inputs = flat(&|s| s.inputs.clone());
    let lags = flat(&|s| s.lags.clone());
    let dirs = flat(&|s| s.dirs.clone());
    let time: Vec<f64> = states.iter().map(|s| s.time).collect();
    let tool: Vec<usize> = states.iter().map(|s| s.tool).collect();
    let tool_offset: Vec<Option<[f64; 3]>> = states.iter().map(|s| s.tool_offset).collect();
    let rows = StateRows {
        q: &q,
        inputs: &inputs,
        lags: &lags,
        time: &time,
        dirs: &dirs,
        tool: &tool,
        tool_offset: &tool_offset,
    };
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j as f64).cos()).collect();
    let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let mut err = vec![0.0; 6 * rows.len()];
    let mut jac = vec![0.0; 6 * n * rows.len()];
    model
        .error_and_jacobian_rows(&rows, &beta, &nl, &mut err, &mut jac)
        .expect("batch");
    let mut plain = vec![0.0; 6 * rows.len()];
    model
        .error_rows(&rows, &beta, &nl, &mut plain)
        .expect("batch");
    let mut one = vec![0.0; 6 * n];
    let mut e = [0.0; 6];
    for (r, s) in states.iter().enumerate() {
        model
            .error_and_jacobian(&s.get(), &beta, &nl, &mut e, &mut one)
            .expect("single");
        assert_eq!(&err[6 * r..6 * r + 6], &e[..]);
        assert_eq!(&jac[6 * n * r..6 * n * (r + 1)], &one[..]);
        assert_eq!(
            model.error(&s.get(), &beta, &nl).expect("single"),
            <[f64; 6]>::try_from(&plain[6 * r..6 * r + 6]).expect("6")
        );
    }
    // Wrong sizes are errors, not panics or overruns.
    assert!(matches!(
        model.error_and_jacobian_rows(&rows, &beta, &nl, &mut err, &mut jac[1..]),
        Err(BatchError::Size { .. })
    ));
    let short = StateRows { q: &q[1..], ..rows };
    assert!(matches!(
        model.error_rows(&short, &beta, &nl, &mut plain),
        Err(BatchError::Size { what: "q", .. })
    ));
    let mut bad_tool = tool.clone();
    bad_tool[3] = 99;
    let bad = StateRows {
        tool: &bad_tool,
        ..rows
    };
    assert!(matches!(
        model.error_rows(&bad, &beta, &nl, &mut plain),
        Err(BatchError::Row { row: 3, .. })
    ));
}

/// Every subset of the components, per pose and in batches, on random machines: the rows
/// of the code compiled for a subset are the full evaluation's rows bit for bit (the same
/// operations in the same order, only fewer of them), and the interpreter's generic path
/// picks out the same rows.
#[test]
fn observed_rows_are_the_full_rows_bit_for_bit() {
    let mut gen = Gen {
        rng: StdRng::seed_from_u64(7071),
        fourier_along: true,
        shared: false,
        heat: true,
        no_fixed: false,
    };
    let mut rng = StdRng::seed_from_u64(5);
    let mut subsets = std::collections::HashSet::new();
    for index in 0..40 {
        let src = gen.machine(index);
        let m = compile_source(&src);
        let model = jit::compile(&m).unwrap_or_else(|e| panic!("{src}\n{e}"));
        let n = m.coefficients.len();
        let states: Vec<OwnedState> = (0..5).map(|_| random_state(&mut rng, &m)).collect();
        let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j as f64 * 0.7).sin()).collect();
        let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let mut interp = Interpreter::new(&m).expect("interpreter");
        interp.set_nonlinear(&nl).expect("nonlinear");
        // The two common subsets on every machine, and one random one.
        let random = Observed::from_flags(std::array::from_fn(|_| rng.random_bool(0.5)));
        for observed in [Observed::POSITION, Observed::FULL, random] {
            subsets.insert(observed);
            let k = observed.rows();
            let (mut full_err, mut full) = ([0.0; 6], vec![0.0; 6 * n]);
            let (mut err, mut jac) = (vec![0.0; k], vec![f64::NAN; k * n]);
            let (mut ierr, mut ijac) = (vec![0.0; k], vec![0.0; k * n]);
            let (mut ferr, mut fjac) = ([0.0; 6], vec![0.0; 6 * n]);
            for s in &states {
                let s = s.get();
                model
                    .error_and_jacobian(&s, &beta, &nl, &mut full_err, &mut full)
                    .expect("full");
                model
                    .observed_error_and_jacobian(&s, &beta, &nl, observed, &mut err, &mut jac)
                    .expect("observed");
                interp
                    .observed_error_and_jacobian(&s, &beta, observed, &mut ierr, &mut ijac)
                    .expect("interpreter");
                interp
                    .error_and_jacobian(&s, &beta, &mut ferr, &mut fjac)
                    .expect("interpreter");
                for (row, c) in observed.components().enumerate() {
                    assert_eq!(observed.row(c), Some(row));
                    let what = format!("machine {index}, {observed}, component {c}");
                    assert_eq!(err[row].to_bits(), full_err[c].to_bits(), "{what}");
                    assert_eq!(ierr[row].to_bits(), ferr[c].to_bits(), "{what}");
                    for j in 0..n {
                        assert_eq!(
                            jac[row * n + j].to_bits(),
                            full[c * n + j].to_bits(),
                            "{what}, coefficient {j}\n{src}"
                        );
                        assert_eq!(ijac[row * n + j].to_bits(), fjac[c * n + j].to_bits());
                    }
                }
            }
            // The batch call gives the single calls' rows.
            let rows = jit_rows(&states);
            let r = rows.rows();
            let mut berr = vec![0.0; k * states.len()];
            let mut bjac = vec![0.0; k * n * states.len()];
            model
                .observed_error_and_jacobian_rows(&r, &beta, &nl, observed, &mut berr, &mut bjac)
                .expect("batch");
            let mut eonly = vec![0.0; k * states.len()];
            model
                .observed_error_rows(&r, &beta, &nl, observed, &mut eonly)
                .expect("batch");
            for (i, s) in states.iter().enumerate() {
                model
                    .observed_error_and_jacobian(&s.get(), &beta, &nl, observed, &mut err, &mut jac)
                    .expect("observed");
                assert_eq!(&berr[k * i..k * (i + 1)], &err[..]);
                assert_eq!(&bjac[k * n * i..k * n * (i + 1)], &jac[..]);
                let e = model.error(&s.get(), &beta, &nl).expect("error");
                for (row, c) in observed.components().enumerate() {
                    assert_eq!(eonly[k * i + row].to_bits(), e[c].to_bits());
                }
            }
            // Wrong sizes are errors.
            assert!(matches!(
                model.observed_error_and_jacobian_rows(
                    &r,
                    &beta,
                    &nl,
                    observed,
                    &mut berr,
                    &mut vec![0.0; bjac.len() + 1]
                ),
                Err(BatchError::Size { .. })
            ));
        }
    }
    assert!(
        subsets.len() >= 10,
        "too few subsets tried: {}",
        subsets.len()
    );
}

/// A batch large enough to be written out with streaming stores (more than 32 MiB of
/// Jacobian) gives exactly the single calls' rows, at every position in the buffer.
#[test]
fn a_large_batch_streams_the_same_rows() {
    let m = example("milling_5axis");
    let model = jit::compile(&m).expect("compiles");
    let n = m.coefficients.len();
    let mut rng = StdRng::seed_from_u64(31);
    let states: Vec<OwnedState> = (0..4200).map(|_| random_state(&mut rng, &m)).collect();
    assert!(6 * n * states.len() * 8 > 32 << 20, "the batch must stream");
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 5) as f64 - 2.0)).collect();
    let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let rows = jit_rows(&states);
    let mut err = vec![0.0; 6 * states.len()];
    // One value more in front, so that the blocks start 8 bytes off a 16-byte boundary.
    let mut buffer = vec![f64::NAN; 6 * n * states.len() + 1];
    model
        .error_and_jacobian_rows(&rows.rows(), &beta, &nl, &mut err, &mut buffer[1..])
        .expect("batch");
    assert!(buffer[0].is_nan());
    let (mut e, mut one) = ([0.0; 6], vec![0.0; 6 * n]);
    for (i, s) in states.iter().enumerate() {
        model
            .error_and_jacobian(&s.get(), &beta, &nl, &mut e, &mut one)
            .expect("single");
        assert_eq!(&err[6 * i..6 * i + 6], &e[..]);
        assert_eq!(
            &buffer[1 + 6 * n * i..1 + 6 * n * (i + 1)],
            &one[..],
            "row {i}"
        );
    }
}

/// A model past one piece (`lower::PIECE`) is several functions handing running sums on; the
/// code of a subset of the components cuts and hands on the same way.
#[test]
fn observed_rows_of_a_model_in_pieces_are_the_full_rows() {
    let m = compile_source(&large_model(2_000));
    let model = jit::compile(&m).expect("compiles");
    let n = m.coefficients.len();
    let mut rng = StdRng::seed_from_u64(12);
    let beta: Vec<f64> = (0..n).map(|j| 1e-7 * (j as f64).cos()).collect();
    let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let observed = Observed::from_flags([true, false, true, false, true, true]);
    let (mut full_err, mut full) = ([0.0; 6], vec![0.0; 6 * n]);
    let (mut err, mut jac) = (vec![0.0; 4], vec![0.0; 4 * n]);
    let states: Vec<OwnedState> = (0..3).map(|_| random_state(&mut rng, &m)).collect();
    for s in &states {
        model
            .error_and_jacobian(&s.get(), &beta, &nl, &mut full_err, &mut full)
            .expect("full");
        model
            .observed_error_and_jacobian(&s.get(), &beta, &nl, observed, &mut err, &mut jac)
            .expect("observed");
        for (row, c) in observed.components().enumerate() {
            assert_eq!(err[row].to_bits(), full_err[c].to_bits());
            assert_eq!(&jac[row * n..(row + 1) * n], &full[c * n..(c + 1) * n]);
        }
    }
    // The batches of errors (two poses a call, then one) hand the pieces on the same way.
    let rows = jit_rows(&states);
    let mut all = vec![0.0; 6 * states.len()];
    let mut some = vec![0.0; 4 * states.len()];
    model
        .error_rows(&rows.rows(), &beta, &nl, &mut all)
        .expect("batch");
    model
        .observed_error_rows(&rows.rows(), &beta, &nl, observed, &mut some)
        .expect("batch");
    for (i, s) in states.iter().enumerate() {
        let e = model.error(&s.get(), &beta, &nl).expect("error");
        for (c, v) in e.iter().enumerate() {
            assert_eq!(
                all[6 * i + c].to_bits(),
                v.to_bits(),
                "row {i}, component {c}"
            );
        }
        for (row, c) in observed.components().enumerate() {
            assert_eq!(some[4 * i + row].to_bits(), e[c].to_bits(), "row {i}, {c}");
        }
    }
}

/// Owned row-major storage of `states` for the batch calls.
struct JitRows {
    q: Vec<f64>,
    inputs: Vec<f64>,
    lags: Vec<f64>,
    dirs: Vec<f64>,
    time: Vec<f64>,
    tool: Vec<usize>,
    tool_offset: Vec<Option<[f64; 3]>>,
}

impl JitRows {
    fn rows(&self) -> StateRows<'_> {
        StateRows {
            q: &self.q,
            inputs: &self.inputs,
            lags: &self.lags,
            time: &self.time,
            dirs: &self.dirs,
            tool: &self.tool,
            tool_offset: &self.tool_offset,
        }
    }
}

fn jit_rows(states: &[OwnedState]) -> JitRows {
    let flat = |f: &dyn Fn(&OwnedState) -> &[f64]| -> Vec<f64> {
        states.iter().flat_map(|s| f(s).iter().copied()).collect()
    };
    JitRows {
        q: flat(&|s| &s.q),
        inputs: flat(&|s| &s.inputs),
        lags: flat(&|s| &s.lags),
        dirs: flat(&|s| &s.dirs),
        time: states.iter().map(|s| s.time).collect(),
        tool: states.iter().map(|s| s.tool).collect(),
        tool_offset: states.iter().map(|s| s.tool_offset).collect(),
    }
}

#[test]
fn bad_calls_are_errors_like_the_interpreter() {
    let m = example("milling_5axis");
    let model = jit::compile(&m).expect("compiles");
    let mut it = Interpreter::new(&m).expect("interpreter");
    let n = m.coefficients.len();
    let mut rng = StdRng::seed_from_u64(3);
    let s = random_state(&mut rng, &m);
    let beta = vec![0.0; n];
    let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];
    let mut ev = model.evaluator();
    let check = |a: Result<(), EvalError>, b: Result<(), EvalError>| assert_eq!(a, b);

    // Short state, β, Jacobian, non-linear parameters.
    let q = &s.q[1..];
    let short = State { q, ..s.get() };
    check(
        ev.error_and_jacobian(&short, &beta, &mut err, &mut jac),
        it.error_and_jacobian(&short, &beta, &mut err, &mut jac),
    );
    check(
        ev.error_and_jacobian(&s.get(), &beta[1..], &mut err, &mut jac),
        it.error_and_jacobian(&s.get(), &beta[1..], &mut err, &mut jac),
    );
    let mut short_jac = vec![0.0; 6 * n - 1];
    check(
        ev.error_and_jacobian(&s.get(), &beta, &mut err, &mut short_jac),
        it.error_and_jacobian(&s.get(), &beta, &mut err, &mut short_jac),
    );
    assert!(model.error(&s.get(), &beta, &nl[1..]).is_err());
    assert_eq!(ev.set_nonlinear(&[]), it.set_nonlinear(&[]));
    let mut joint = vec![0.0; 6 * m.axes.len() + 1];
    assert!(model.nominal_jacobian(&s.get(), &mut joint).is_err());

    // A tool that does not exist.
    let bad_tool = State { tool: 7, ..s.get() };
    check(
        ev.error_and_jacobian(&bad_tool, &beta, &mut err, &mut jac),
        it.error_and_jacobian(&bad_tool, &beta, &mut err, &mut jac),
    );

    // A variable the model needs and the state does not give: named, as by the interpreter.
    for input in 0..m.inputs.len() {
        let mut inputs = s.inputs.clone();
        inputs[input] = f64::NAN;
        let missing = State {
            inputs: &inputs,
            ..s.get()
        };
        check(
            ev.error_and_jacobian(&missing, &beta, &mut err, &mut jac),
            it.error_and_jacobian(&missing, &beta, &mut err, &mut jac),
        );
        assert_eq!(
            ev.error(&missing, &beta).map(|_| ()),
            it.error(&missing, &beta).map(|_| ())
        );
    }
    let dirs = vec![f64::NAN; m.axes.len()];
    let no_dirs = State {
        dirs: &dirs,
        ..s.get()
    };
    let e = ev.error(&no_dirs, &beta).unwrap_err();
    assert_eq!(e, it.error(&no_dirs, &beta).unwrap_err());
}

#[test]
fn only_the_selected_tool_reads_its_variables() {
    // `t1.tx` reads the load; a row measured with t0 need not give it (as in the interpreter).
    let src = "machine tools {
        task position
        axis X prismatic along x range 0 mm .. 500 mm
        input F0 : force range 0 N .. 1000 N
        tool chain { X moving tool t0 at (0, 0, -100) mm tool t1 at (0, 0, -150) mm rot (0, 10, 0) deg }
        errors { X.tx = spline(X, knots 2) t1.tx = F0 / 1000 N * const t1.rz = const }
    }";
    let m = compile_source(src);
    let model = jit::compile(&m).expect("compiles");
    let mut it = Interpreter::new(&m).expect("interpreter");
    let n = m.coefficients.len();
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j + 1) as f64).collect();
    let inputs = [f64::NAN];
    let q = [0.2];
    let dirs = [1.0];
    let s = State {
        q: &q,
        inputs: &inputs,
        lags: &[],
        time: 0.0,
        dirs: &dirs,
        tool: 0,
        tool_offset: None,
    };
    let (mut ei, mut ej) = ([0.0; 6], [0.0; 6]);
    let (mut ji, mut jj) = (vec![0.0; 6 * n], vec![f64::NAN; 6 * n]);
    it.error_and_jacobian(&s, &beta, &mut ei, &mut ji)
        .expect("interp");
    model
        .error_and_jacobian(&s, &beta, &[], &mut ej, &mut jj)
        .expect("jit");
    assert_eq!(ji, jj);
    assert!(ei
        .iter()
        .zip(&ej)
        .all(|(a, b)| (a - b).abs() <= 1e-12 * a.abs().max(1e-9)));
    let t1 = State { tool: 1, ..s };
    assert!(model.error(&t1, &beta, &[]).is_err());
}

// The baseline is benchmark code (kin-bench, a dev-dependency of these tests only).
#[test]
fn the_hand_written_baseline_agrees_with_the_interpreter() {
    let m = example("milling_5axis");
    let n = m.coefficients.len();
    let mut it = Interpreter::new(&m).expect("interpreter");
    for trig in [baseline::Trig::Exact, baseline::Trig::Recurrence] {
        let mut base = baseline::Baseline::new(&m, trig).expect("the 5-axis example");
        let mut rng = StdRng::seed_from_u64(12);
        let beta: Vec<f64> = (0..n).map(|_| rng.random_range(-1e-5..1e-5)).collect();
        let zero = vec![0.0; n];
        let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let (mut ji, mut jb) = (vec![0.0; 6 * n], vec![f64::NAN; 6 * n]);
        let (mut ei, mut eb, mut e0) = ([0.0; 6], [0.0; 6], [0.0; 6]);
        let mut worst: f64 = 0.0;
        for _ in 0..300 {
            let s = random_state(&mut rng, &m);
            let st = s.get();
            it.error_and_jacobian(&st, &zero, &mut e0, &mut ji)
                .expect("interp");
            it.error_and_jacobian(&st, &beta, &mut ei, &mut ji)
                .expect("interp");
            base.error_and_jacobian(&st, &beta, &nl, &mut eb, &mut jb);
            let dj = row_relative(&ji, &jb, 6, |r| {
                (0..n).map(|j| ji[r * n + j].abs()).fold(0.0, f64::max)
            });
            let de = row_relative(&ei, &eb, 6, |r| {
                e0[r].abs() + (0..n).map(|j| (ji[r * n + j] * beta[j]).abs()).sum::<f64>()
            });
            assert!(
                dj <= TOLERANCE && de <= TOLERANCE,
                "baseline {trig:?}: Jacobian {dj:e}, error {de:e}: {ei:?} vs {eb:?}"
            );
            worst = worst.max(dj).max(de);
        }
        eprintln!("baseline ({trig:?}) vs interpreter: worst relative difference {worst:e}");
    }
}

#[test]
fn clif_dump_names_the_three_functions() {
    let m = example("robot_6axis");
    let text = jit::dump_clif(&m).expect("dump");
    for f in ["; error\n", "; error_jacobian\n", "; nominal\n"] {
        assert!(text.contains(f), "{f}");
    }
    assert!(text.contains("call fn"), "sin/cos are calls");
}

/// `fneg` and `fabs` build their sign mask in a general register and move it over (three
/// instructions on x86-64): a negation is emitted as a product by −1 from the constant pool and
/// a positive part as the compare and select the backend makes one `maxsd` of, so the only
/// `fabs` left is the `|a|` of each `fmod`'s first-turn test (the one call with a result).
#[test]
fn negations_and_positive_parts_build_no_sign_mask() {
    for name in ["milling_5axis", "bridge_cmm", "robot_6axis"] {
        let text = jit::dump_clif(&example(name)).expect("dump");
        let count = |needle: &str| text.matches(needle).count();
        assert_eq!(count("= fneg "), 0, "{name}");
        assert_eq!(count("= fabs "), count("= call fn"), "{name}");
        if cfg!(target_arch = "x86_64") && name != "robot_6axis" {
            assert!(
                count("vmaxsd") > 0,
                "{name}: splines' positive parts are `maxsd`"
            );
        }
    }
}

#[test]
fn inconsistent_ir_is_rejected_at_compile_time() {
    let mut m = example("bridge_cmm");
    m.coefficients.pop();
    assert!(matches!(jit::compile(&m), Err(jit::JitError::Model { .. })));
    let mut m = example("bridge_cmm");
    m.tool_chain[0].axis = 17;
    assert!(matches!(jit::compile(&m), Err(jit::JitError::Model { .. })));
}

/// A model of `coefficients` coefficients: X, Y, Z prismatic and C revolute, splines on the
/// linear axes and long Fourier series on C (the shape of the scale benchmark, smaller).
fn large_model(coefficients: usize) -> String {
    use std::fmt::Write as _;
    let mut errors = String::new();
    let mut total = 0;
    for axis in ["X", "Y", "Z"] {
        for e in ["tx", "ty", "tz", "rx", "ry", "rz"] {
            if total + 51 <= coefficients {
                let _ = writeln!(errors, "{axis}.{e} = spline({axis}, knots 50, degree 1)");
                total += 51;
            }
        }
    }
    for e in ["tx", "ty", "tz", "rx", "ry", "rz"] {
        let harmonics = ((coefficients - total) / 2).min(200);
        if harmonics == 0 {
            break;
        }
        let _ = writeln!(errors, "C.{e} = fourier(C, harmonics 1..{harmonics})");
        total += 2 * harmonics;
    }
    format!(
        "machine large {{
    task position
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Y prismatic along y range 0 mm .. 800 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    axis C revolute about z continuous
    workpiece chain {{ Y fixed  C fixed  workpiece }}
    tool chain {{ X moving  Z moving at (0, 0, 500) mm  tool a at (30, 20, -100) mm }}
    errors {{
{errors}    }}
}}
"
    )
}

/// Past 1 024 coefficients the error and Jacobian are emitted as several functions called in
/// turn (compile time linear in the model), one component's running sum handed from one to
/// the next; together they must still compute what the interpreter computes, every entry
/// written (`compare` poisons the Jacobian first).
#[test]
fn a_large_model_compiles_and_agrees_with_the_interpreter() {
    let m = compile_source(&large_model(2_000));
    assert!(m.coefficients.len() >= 1_900, "{}", m.coefficients.len());
    let model = jit::compile(&m).expect("compiles");
    let mut rng = StdRng::seed_from_u64(7);
    let states: Vec<OwnedState> = (0..6).map(|_| random_state(&mut rng, &m)).collect();
    let w = compare(&m, &model, &states, &mut rng, "large");
    eprintln!(
        "large ({} coefficients): {w:?}, compiled in {:?}",
        m.coefficients.len(),
        model.compile_time()
    );
}

/// The servo compensation by the JIT and by the interpreter on random positioning machines:
/// the same iteration on engines that agree to 1e-12 of their terms. Compared: the effect of
/// the two corrections on the tool and the predicted errors, relative to the error compensated;
/// the corrections themselves per axis kind (an angle and a length each by its own scale).
#[test]
fn random_machines_compensate_alike_in_both_engines() {
    use kin_model::compensate::{Divergence, Options as CompOptions, ServoError};
    let mut gen = Gen {
        rng: StdRng::seed_from_u64(20251125),
        fourier_along: true,
        // The machines this test was measured on: no shared-target definitions.
        shared: false,
        heat: false,
        no_fixed: false,
    };
    let mut rng = StdRng::seed_from_u64(7);
    let (mut worst_dq, mut worst_error) = (0.0_f64, 0.0_f64);
    let (mut compared, mut identical, mut diverged) = (0, 0, 0);
    let mut smallest_diverging = f64::INFINITY;
    for index in 0..120 {
        // Compensation is for positioning machines: every generated machine is made one.
        let src = gen
            .machine(index)
            .replacen("task measure", "task position", 1);
        let mut model = kin_model::Model::compile(&src).unwrap_or_else(|e| panic!("{src}\n{e}"));
        let n = model.coefficients();
        let beta: Vec<f64> = (0..n).map(|_| rng.random_range(-1e-5..1e-5)).collect();
        model.set_beta(&beta).expect("β");
        let nonlinear: Vec<f64> = model
            .nonlinear()
            .iter()
            .map(|v| v * rng.random_range(0.8..1.25))
            .collect();
        model.set_nonlinear(&nonlinear).expect("values");
        let m = model.machine().clone();
        let options = CompOptions::pose(&m);
        let comp = model.compensator(options).expect("compensator");
        let mut it = comp.interpreter().expect("interpreter");
        let axes = m.axes.len();
        let (mut a, mut b) = (vec![0.0; axes], vec![0.0; axes]);
        for _ in 0..4 {
            let mut s = random_state(&mut rng, &m);
            // Commands inside the declared ranges (compensation refuses others).
            for (q, axis) in s.q.iter_mut().zip(&m.axes) {
                if !axis.continuous {
                    *q = q.clamp(axis.range[0], axis.range[1]);
                }
            }
            let st = s.get();
            let ca = comp.compensate(&st, &mut a);
            let cb = comp.compensate_interp(&mut it, &st, &mut b);
            let (ca, cb) = match (ca, cb) {
                (Ok(x), Ok(y)) => (x, y),
                (Err(x), Err(y)) => {
                    // The one refusal a command inside the ranges may meet: a random model's
                    // errors can be far from small (a polynomial of a continuous axis over
                    // several turns), and then the linearised iteration diverges. Both engines
                    // must say so at the same step, with the same numbers.
                    assert_eq!(x, y, "machine {index}\n{src}");
                    assert!(
                        matches!(
                            x,
                            ServoError::Diverges(
                                Divergence::Grows { .. } | Divergence::Overflows { .. }
                            )
                        ),
                        "machine {index}: {x}\n{src}"
                    );
                    let e = it.error(&st, comp.model().beta()).expect("error");
                    let size = e.iter().fold(0.0_f64, |s, x| s.max(x.abs()));
                    smallest_diverging = smallest_diverging.min(size);
                    diverged += 1;
                    continue;
                }
                (x, y) => panic!("machine {index}: {x:?} vs {y:?}\n{src}"),
            };
            assert_eq!(ca.rank, cb.rank, "machine {index}\n{src}");
            assert_eq!(ca.iterations, cb.iterations, "machine {index}\n{src}");
            if ca == cb && a == b {
                identical += 1;
            }
            // Relative differences: of the predicted errors (before and after) against the
            // largest component of the error before, ‖e_a − e_b‖∞ / ‖e_before‖∞; of the
            // corrections against the largest correction of the same kind (a length and an
            // angle are not compared), ‖δq_a − δq_b‖∞ / ‖δq_a‖∞.
            let norm = |v: &[f64]| v.iter().fold(0.0_f64, |s, x| s.max(x.abs()));
            let scale = norm(&ca.before).max(f64::MIN_POSITIVE);
            for (x, y) in ca
                .after
                .iter()
                .zip(&cb.after)
                .chain(ca.before.iter().zip(&cb.before))
            {
                worst_error = worst_error.max((x - y).abs() / scale);
            }
            for kind in [JointKind::Prismatic, JointKind::Revolute] {
                let pick = |v: &[f64]| -> Vec<f64> {
                    v.iter()
                        .zip(&m.axes)
                        .filter(|(_, axis)| axis.kind == kind)
                        .map(|(x, _)| *x)
                        .collect()
                };
                let (pa, pb) = (pick(&a), pick(&b));
                let scale = norm(&pa);
                for (x, y) in pa.iter().zip(&pb) {
                    if scale > 0.0 {
                        worst_dq = worst_dq.max((x - y).abs() / scale);
                    }
                }
            }
            compared += 1;
        }
    }
    eprintln!(
        "{compared} compensations compared ({identical} bit for bit), {diverged} diverged alike in both engines (predicted errors of {smallest_diverging:.3e} m or rad and more); worst relative differences: the predicted errors {worst_error:e}, the corrections {worst_dq:e}"
    );
    assert!(
        compared >= 450,
        "too few compensations compared: {compared}"
    );
    // The engines sum every error in the same order with the same association (the models by
    // frame, each model's terms as one running sum), take the same libm sin/cos and share the
    // solve, so their corrections agree to the last bit (measured: all of them); the bound is
    // the one issue #12 sets.
    assert!(worst_error <= TOLERANCE, "errors differ by {worst_error:e}");
    assert!(worst_dq <= TOLERANCE, "corrections differ by {worst_dq:e}");
    // Only models whose errors are far outside the first-order regime diverge.
    assert!(
        smallest_diverging > 1e-3,
        "a model with errors of {smallest_diverging:e} diverged"
    );
}

#[test]
fn compensation_does_not_allocate_and_serves_many_threads() {
    use kin_model::compensate::Options as CompOptions;
    let path = format!(
        "{}/../../examples/milling_5axis.kin",
        env!("CARGO_MANIFEST_DIR")
    );
    let src = std::fs::read_to_string(&path).expect("example readable");
    let mut model = kin_model::Model::compile(&src).expect("compiles");
    let n = model.coefficients();
    let beta: Vec<f64> = (0..n).map(|j| 2e-6 * ((j % 5) as f64 - 2.0)).collect();
    model.set_beta(&beta).expect("β");
    let comp = model
        .compensator(CompOptions::pose(model.machine()))
        .expect("compensator");
    let states = kin_model::states::States::sample(model.machine(), 64, 5);
    let axes = model.axes();
    let mut dq = vec![0.0; axes];
    comp.compensate(&states.get(0), &mut dq).expect("warm-up");
    let before = allocations();
    for r in 0..states.len() {
        std::hint::black_box(
            comp.compensate(&states.get(r), &mut dq)
                .expect("compensates"),
        );
    }
    assert_eq!(allocations(), before, "a compensation allocated");
    // Four threads on one compensator at once, each its own output: what one thread alone gives.
    let alone: Vec<Vec<f64>> = (0..states.len())
        .map(|r| {
            let mut dq = vec![0.0; axes];
            comp.compensate(&states.get(r), &mut dq)
                .expect("compensates");
            dq
        })
        .collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..4)
            .map(|t| {
                let (comp, states, alone) = (&comp, &states, &alone);
                scope.spawn(move || {
                    let mut dq = vec![0.0; axes];
                    for round in 0..20 {
                        for r in 0..states.len() {
                            let r = (r + 7 * t + round) % states.len();
                            comp.compensate(&states.get(r), &mut dq)
                                .expect("compensates");
                            assert_eq!(dq, alone[r], "thread {t}, pose {r}");
                        }
                    }
                })
            })
            .collect();
        for h in handles {
            h.join().expect("thread");
        }
    });
}

/// A beam's bending (known α and fitted) on a table that carries a rotary axis, with lagged
/// face temperatures and a heat source: both engines agree on the beam's polynomial in the
/// axis position and the temperatures, propagated through the chain.
#[test]
fn a_heated_beam_agrees_with_the_interpreter() {
    let src = r#"
machine beam_table {
    task position
    units { length mm, angle deg, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis C revolute about z continuous
    input T0 : temperature rise
    input T1 : temperature rise
    input T2 : temperature rise
    input S0 : speed
    tool chain {
        Y moving
        tool t at (0, 0, -80) mm
    }
    workpiece chain {
        X moving
        C moving at (0, 0, 120) mm
        workpiece at (30, 0, 10) mm
    }
    errors {
        X.tx = 11.5 um/m/K * beam(X, ends at (-50, 1050) mm, upper at (T0, T1), lower at (T2, lag(T2, tau 30 min)), gap 200 mm, across z)
        X.tz = beam(X, ends at (-50, 1050) mm, upper at (T0, T1), lower at (T2, lag(T2, tau 30 min)), gap 200 mm, across z) * const
        X.ry = beam(X, ends at (-50, 1050) mm, upper at (T0, T1), lower at (T2, 0 K), gap 200 mm, across z) * spline(X, knots 1)
        Y.tx = beam(Y, ends at (0, 600) mm, upper at (T0, T1), lower at (T1, T0), gap 80 mm, across x) * const
        Y.rz = 11.5 um/m/K * beam(Y, ends at (0, 600) mm, upper at (T0, T1), lower at (T1, T0), gap 80 mm, across x)
        C.tz = lag(lag(pow(S0 / 10000 rpm, 1.5), tau 5 min, from 0 rpm), tau fit 40 min) * const
    }
}
"#;
    let out = kin_compiler::compile(src);
    let m = out
        .compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
        .machine;
    let model = jit::compile(&m).expect("compiles");
    let mut rng = StdRng::seed_from_u64(16);
    let states: Vec<OwnedState> = (0..60).map(|_| random_state(&mut rng, &m)).collect();
    let w = compare(&m, &model, &states, &mut rng, "beam_table");
    eprintln!("beam_table: {w:?}");
}

/// A turntable whose only errors are functions of its continuous angle, measured at the
/// origin: each Jacobian entry is a basis value (the frame's column is exact), so the two
/// engines agree exactly. The generated code reduces the angle to one turn with a call
/// only outside the first turn, and inside it takes the joint's own `sincos` for the
/// harmonics' fundamental; on both sides of every boundary that must give the interpreter's
/// numbers exactly (the spline's once-per-revolution trend calls for its own angle).
#[test]
fn a_continuous_axis_agrees_exactly_on_and_off_its_first_turn() {
    let m = compile_source(
        "machine turntable {
    task position
    axis C revolute about z continuous
    workpiece chain {
        C moving at (0, 0, 0) mm
        workpiece at (0, 0, 0) mm
    }
    tool chain {
        tool probe at (0, 0, 0) mm
    }
    errors {
        C.tz = fourier(C, harmonics 1..3) + fourier(C, harmonics (90, 180)) + spline(C, knots 4)
    }
}
",
    );
    let model = jit::compile(&m).expect("compiles");
    let n = m.coefficients.len();
    let mut it = Interpreter::new(&m).expect("interpreter");
    let mut ev = model.evaluator();
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j as f64 + 1.0)).collect();
    let tau = std::f64::consts::TAU;
    let below = |x: f64| f64::from_bits(x.to_bits() - 1);
    let angles = [
        0.0,
        -0.0,
        f64::MIN_POSITIVE,
        -f64::MIN_POSITIVE,
        1.0,
        std::f64::consts::PI,
        below(tau),
        tau,
        tau + 1.0,
        -1.0,
        -tau,
        7.5,
        -123.456,
        1e6,
    ];
    let mut rng = StdRng::seed_from_u64(9);
    let template = random_state(&mut rng, &m);
    let (mut ji, mut jj) = (vec![0.0; 6 * n], vec![0.0; 6 * n]);
    let (mut ei, mut ej) = ([0.0; 6], [0.0; 6]);
    for c in angles {
        let mut s = template.clone();
        s.q[0] = c;
        s.tool_offset = None;
        it.error_and_jacobian(&s.get(), &beta, &mut ei, &mut ji)
            .expect("interpreter");
        ev.error_and_jacobian(&s.get(), &beta, &mut ej, &mut jj)
            .expect("jit");
        // Equal as numbers: the rows the table's errors do not reach are a zero whose sign
        // differs between the engines (−0 from a product in one, +0 in the other).
        assert_eq!(ji, jj, "Jacobian at C = {c:e}");
        assert_eq!(ei, ej, "error at C = {c:e}");
        let plain = ev.error(&s.get(), &beta).expect("jit error");
        assert_eq!(plain, ei, "error alone at C = {c:e}");
    }
}
