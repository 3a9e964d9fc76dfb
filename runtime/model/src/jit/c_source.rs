//! The model's evaluator as C source (`kin export c`): the expression graphs the JIT compiles
//! (`lower::build`), written as C for an embedder's own compiler.
//!
//! Why: an embedder that knows its machine when it builds its program can compile the model in
//! — no JIT, no kin library, no per-call checks but the tool's index — instead of calling the C
//! ABI's JIT (spec/performance.md, "The evaluator as C source"; GCC's code of these graphs is
//! not reliably faster than Cranelift's: "Where the code lands").
//!
//! What the file holds: for each graph one `static` function of the JIT's arguments (the state's
//! arrays, β, the non-linear parameters, the tool's transform, the outputs), each node one
//! `const double`, emitted where a store first needs it — a value read back from `out` (the
//! running sum a piece before left there, `lower`) is read at the start of its piece, as the
//! JIT reads it; and three public functions — the error, the error with the six-row Jacobian,
//! the position rows — that pick the tool's transform, default β to the exported values and
//! call the pieces in order. The operations are the graph's, in its order, so the results are
//! the JIT's except for `sin` and `cos`, which come from the C library the program links
//! (kin's engines take a Rust port of musl's): a few units in the last place.

use std::fmt::Write as _;

use kin_compiler::ir::Machine;

use super::graph::{Cmp, Dst, Effect, Graph, Id, Node, Src};
use super::lower::{self, Kind};
use super::{common_rotation, tool_transforms, JitError, Observed};

/// The C source of `machine`'s evaluator, its functions named after the machine (a C
/// identifier made of its name); the machine's bound β (its `params`) and non-linear
/// parameter values are the defaults the file carries.
pub fn c_source(machine: &Machine) -> Result<String, JitError> {
    lower::validate(machine)?;
    let tools = tool_transforms(machine);
    let rotation = common_rotation(&tools);
    let p = prefix(&machine.name);
    let n = machine.coefficients.len();
    let mut c = String::new();
    header(&mut c, machine, &p);
    let array = |c: &mut String, name: &str, values: &[f64]| {
        // ISO C has no arrays of length 0: a model without any keeps one unread zero.
        let values = if values.is_empty() {
            &[0.0][..]
        } else {
            values
        };
        let _ = write!(c, "static const double {p}_{name}[{}] = {{", values.len());
        for (i, v) in values.iter().enumerate() {
            let sep = if i % 4 == 0 { "\n    " } else { " " };
            let _ = write!(c, "{sep}{},", literal(*v));
        }
        let _ = writeln!(c, "\n}};\n");
    };
    // The machine's bound values when it has them all, else zeros: the nominal machine.
    let beta = if machine.beta.len() == n {
        machine.beta.clone()
    } else {
        vec![0.0; n]
    };
    array(&mut c, "beta", &beta);
    let nonlinear: Vec<f64> = machine.nonlinear.iter().map(|q| q.value).collect();
    array(&mut c, "nonlinear", &nonlinear);
    let flat: Vec<f64> = tools.iter().flatten().copied().collect();
    array(&mut c, "tools", &flat);
    let functions = [
        ("error", Kind::Error, Observed::FULL, 6),
        ("jacobian", Kind::Jacobian, Observed::FULL, 6),
        ("jacobian_position", Kind::Jacobian, Observed::POSITION, 3),
    ];
    for (name, kind, observed, rows) in functions {
        let pieces = lower::build(machine, kind, rotation, observed);
        for (i, g) in pieces.iter().enumerate() {
            piece(&mut c, &format!("{p}_{name}_{i}"), g);
        }
        public(&mut c, &p, name, pieces.len(), rows, kind == Kind::Jacobian);
    }
    Ok(c)
}

/// A C identifier from the machine's name: other characters become `_`, a leading digit gets
/// a `kin_` before it.
fn prefix(name: &str) -> String {
    let mut p: String = name
        .chars()
        .map(|ch| if ch.is_ascii_alphanumeric() { ch } else { '_' })
        .collect();
    if p.is_empty() || p.starts_with(|ch: char| ch.is_ascii_digit()) {
        p.insert_str(0, "kin_");
    }
    p
}

/// A double as C reads it back to the same bits: the shortest decimal that round-trips (C's
/// `strtod` rounds correctly), the infinities and NaN by name.
fn literal(v: f64) -> String {
    if v.is_nan() {
        "NAN".into()
    } else if v.is_infinite() {
        if v > 0.0 { "INFINITY" } else { "-INFINITY" }.into()
    } else {
        format!("{v:?}")
    }
}

fn header(c: &mut String, m: &Machine, p: &str) {
    let names = |v: Vec<&str>| {
        if v.is_empty() {
            "none".to_string()
        } else {
            v.join(", ")
        }
    };
    let axes = names(m.axes.iter().map(|a| a.name.as_str()).collect());
    let inputs = names(m.inputs.iter().map(|a| a.name.as_str()).collect());
    let lags = m.lags.len();
    let tools = names(m.tools.iter().map(|t| t.name.as_str()).collect());
    let n = m.coefficients.len();
    let upper = p.to_ascii_uppercase();
    let _ = writeln!(
        c,
        "/* The evaluator of machine `{name}`, written by kin {version} (`kin export c`).
 *
 * Axes ({na}, in this order in q and dirs): {axes}. Inputs ({ni}): {inputs}. Lag states: {lags}.
 * Tools (index for `tool`): {tools}. Coefficients: {n}. Everything in SI: m, rad, s, K, N.
 *
 *   int {p}_error(q, inputs, lags, dirs, time, tool, beta, err)              err: 6
 *   int {p}_jacobian(q, inputs, lags, dirs, time, tool, beta, err, jac)      err: 6, jac: 6 x {n}
 *   int {p}_jacobian_position(q, inputs, lags, dirs, time, tool, beta, err, jac)
 *                                                                            err: 3, jac: 3 x {n}
 *
 * err receives the tool-location error ex, ey, ez, erx, ery, erz with the task's sign (the
 * position rows: ex, ey, ez), jac the Jacobian with respect to beta, row-major (row r is error
 * component r): err = fixed + jac * beta. beta NULL: the values this file was exported with.
 * dirs holds each axis' direction of motion (+1, -1, 0); inputs and lags the values the model's
 * terms read. Each returns 0, or -1 when tool is not a tool's index (nothing written).
 *
 * Nothing else is checked: a value the model reads that is NaN or infinite (an input not given)
 * gives NaN or infinite results where kin's own interfaces name it, and no output may overlap
 * an input. The functions allocate nothing and share no state: any thread may call them.
 *
 * The same operations as kin's JIT in the same order: compiled without contracting a*b + c
 * into fused operations (GCC and Clang: -ffp-contract=off) the results are kin's to the last
 * bit except where sin and cos of the C library differ from kin's by a unit in the last place.
 * For speed, -O2 or -O3 and the target's instruction set (-march=native). GCC 12 was seen to
 * fuse a product and a sum in spite of -ffp-contract=off when it vectorises straight-line code
 * for a processor with FMA; -fno-tree-slp-vectorize keeps every rounding.
 */
#include <math.h>
#include <stddef.h>

#define {upper}_AXES {na}
#define {upper}_INPUTS {ni}
#define {upper}_LAGS {lags}
#define {upper}_TOOLS {nt}
#define {upper}_COEFFICIENTS {n}
",
        name = m.name,
        version = env!("CARGO_PKG_VERSION"),
        na = m.axes.len(),
        ni = m.inputs.len(),
        nt = m.tools.len(),
    );
}

/// One graph as a `static` function of the JIT's arguments.
fn piece(c: &mut String, name: &str, g: &Graph) {
    let _ = writeln!(
        c,
        "static void {name}(const double *restrict q, const double *restrict inputs,
    const double *restrict lags, const double *restrict dirs, const double *restrict beta,
    const double *restrict nonlinear, const double *restrict tool_tf, double *restrict out,
    double *restrict jac, double time, size_t tool)
{{
    (void)q; (void)inputs; (void)lags; (void)dirs; (void)beta; (void)nonlinear;
    (void)tool_tf; (void)out; (void)jac; (void)time; (void)tool;"
    );
    let mut emitted = vec![false; g.nodes().len()];
    let dst = |d: Dst| match d {
        Dst::Out => "out",
        Dst::Jac => "jac",
    };
    for effect in g.effects() {
        match *effect {
            Effect::Store(d, at, v) => {
                need(c, g, &mut emitted, v);
                let _ = writeln!(c, "    {}[{at}] = v{};", dst(d), v.index());
            }
            // A column that is zero whatever the pose: zeros, as the JIT stores them (`+0`,
            // where the product with a negative value would be `-0`).
            Effect::Pair(d, at, col, ..) if g.value(col) == Some(0.0) => {
                let d = dst(d);
                let _ = writeln!(c, "    {d}[{at}] = 0.0;\n    {d}[{}] = 0.0;", at + 1);
            }
            Effect::Pair(d, at, col, a, b) => {
                for v in [col, a, b] {
                    need(c, g, &mut emitted, v);
                }
                let (d, col, a, b) = (dst(d), col.index(), a.index(), b.index());
                let _ = writeln!(
                    c,
                    "    {d}[{at}] = v{col} * v{a};\n    {d}[{}] = v{col} * v{b};",
                    at + 1
                );
            }
            Effect::AddTo(d, at, v) => {
                need(c, g, &mut emitted, v);
                let _ = writeln!(c, "    {}[{at}] += v{};", dst(d), v.index());
            }
            // Where the JIT brings a running sum up to date (a register's schedule); the C
            // compiler schedules for itself. Written there, the 5-axis example's functions
            // measured (GCC 12, -O3 -march=native, both forms in one program): six rows 2.2–2.3
            // against 3.2–3.4 M poses/s, the error 6.2–6.4 against 6.9, the position rows
            // 4.2–4.4 against 4.1–4.2.
            Effect::Eval(_) => {}
        }
    }
    let _ = writeln!(c, "}}\n");
}

/// The operands of a node, in no particular order.
fn operands(node: Node) -> Vec<Id> {
    match node {
        Node::Const(_) | Node::Load(..) => Vec::new(),
        Node::Neg(a)
        | Node::Floor(a)
        | Node::Sin(a)
        | Node::Cos(a)
        | Node::PosPart(a)
        | Node::IfTool(_, a) => vec![a],
        Node::Add(a, b)
        | Node::Sub(a, b)
        | Node::Mul(a, b)
        | Node::Div(a, b)
        | Node::Fmod(a, b) => {
            vec![a, b]
        }
        Node::Select(_, a, b, t, f) => vec![a, b, t, f],
    }
}

/// Writes the definitions of `id` and of whatever it depends on that is not written yet,
/// operands first (without recursion: a graph's chains can be long).
fn need(c: &mut String, g: &Graph, emitted: &mut [bool], id: Id) {
    let mut stack = vec![(id, false)];
    while let Some((id, ready)) = stack.pop() {
        let i = id.index();
        if emitted.get(i).copied().unwrap_or(true) {
            continue;
        }
        let node = g.node(id);
        if !ready {
            stack.push((id, true));
            stack.extend(operands(node).into_iter().map(|o| (o, false)));
            continue;
        }
        if let Some(done) = emitted.get_mut(i) {
            *done = true;
        }
        let _ = writeln!(c, "    const double v{i} = {};", expression(node));
    }
}

/// The C expression of a node over the `v` values of its operands.
fn expression(node: Node) -> String {
    let v = |id: Id| format!("v{}", id.index());
    match node {
        Node::Const(bits) => literal(f64::from_bits(bits)),
        Node::Load(src, at) => match src {
            Src::Q => format!("q[{at}]"),
            Src::Inputs => format!("inputs[{at}]"),
            Src::Lags => format!("lags[{at}]"),
            Src::Dirs => format!("dirs[{at}]"),
            Src::Beta => format!("beta[{at}]"),
            Src::Nonlinear => format!("nonlinear[{at}]"),
            Src::ToolTf => format!("tool_tf[{at}]"),
            Src::Time => "time".into(),
            Src::Out => format!("out[{at}]"),
        },
        Node::Add(a, b) => format!("{} + {}", v(a), v(b)),
        Node::Sub(a, b) => format!("{} - {}", v(a), v(b)),
        Node::Mul(a, b) => format!("{} * {}", v(a), v(b)),
        Node::Div(a, b) => format!("{} / {}", v(a), v(b)),
        Node::Neg(a) => format!("-{}", v(a)),
        Node::Floor(a) => format!("floor({})", v(a)),
        Node::Sin(a) => format!("sin({})", v(a)),
        Node::Cos(a) => format!("cos({})", v(a)),
        // The graph's positive part as the JIT computes it: `a` where `0 < a`, else +0.
        Node::PosPart(a) => format!("0.0 < {} ? {} : 0.0", v(a), v(a)),
        Node::Fmod(a, b) => format!("fmod({}, {})", v(a), v(b)),
        // A comparison with a NaN is false in C as in the graph.
        Node::Select(cmp, a, b, t, f) => {
            let op = match cmp {
                Cmp::Gt => ">",
                Cmp::Ge => ">=",
            };
            format!("{} {op} {} ? {} : {}", v(a), v(b), v(t), v(f))
        }
        Node::IfTool(tool, x) => format!("tool == {tool} ? {} : 0.0", v(x)),
    }
}

/// A public function: the tool's transform, β by default, the pieces in order, the observed
/// error out of `out` (component c at `out[c]`, as `JitModel` reads it).
fn public(c: &mut String, p: &str, name: &str, pieces: usize, rows: usize, jacobian: bool) {
    let (jac_param, jac_arg) = if jacobian {
        (", double *jac", "jac")
    } else {
        ("", "NULL")
    };
    let upper = p.to_ascii_uppercase();
    let _ = writeln!(
        c,
        "int {p}_{name}(const double *q, const double *inputs, const double *lags,
    const double *dirs, double time, size_t tool, const double *beta, double *err{jac_param})
{{
    double out[12] = {{0}};
    const double *tool_tf;
    if (tool >= {upper}_TOOLS)
        return -1;
    tool_tf = {p}_tools + 12 * tool;
    if (beta == NULL)
        beta = {p}_beta;"
    );
    for i in 0..pieces {
        let _ = writeln!(
            c,
            "    {p}_{name}_{i}(q, inputs, lags, dirs, beta, {p}_nonlinear, tool_tf, out, {jac_arg}, time, tool);"
        );
    }
    let _ = writeln!(
        c,
        "    for (size_t k = 0; k < {rows}; k++)
        err[k] = out[k];
    return 0;
}}
"
    );
}

#[cfg(test)]
mod tests {
    use std::ffi::c_int;
    use std::process::Command;

    use super::*;
    use crate::jit::tests::{example, large_machine, EXAMPLES};
    use crate::states::States;

    type Error = unsafe extern "C" fn(
        *const f64,
        *const f64,
        *const f64,
        *const f64,
        f64,
        usize,
        *const f64,
        *mut f64,
    ) -> c_int;
    type Jacobian = unsafe extern "C" fn(
        *const f64,
        *const f64,
        *const f64,
        *const f64,
        f64,
        usize,
        *const f64,
        *mut f64,
        *mut f64,
    ) -> c_int;

    /// The largest difference relative to `1 + |b|`, infinite for a NaN on either side.
    fn worst(a: &[f64], b: &[f64]) -> f64 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| {
                let d = (x - y).abs() / (1.0 + y.abs());
                if d.is_nan() {
                    f64::INFINITY
                } else {
                    d
                }
            })
            .fold(0.0, f64::max)
    }

    /// Each example's C source (and a model in pieces) compiled by the system's C compiler
    /// with every warning an error, loaded, and its three functions compared with the JIT at
    /// 200 sampled poses, with the exported β (NULL) and with β given; a tool index past the
    /// last refused. sin and cos come from the C library, so agreement is to rounding.
    #[test]
    fn the_c_source_compiles_clean_and_evaluates_as_the_jit() {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let mut machines: Vec<Machine> = EXAMPLES.iter().map(|name| example(name)).collect();
        machines.push(large_machine());
        for m in &machines {
            let source = c_source(m).expect("C source");
            let p = prefix(&m.name);
            let file = dir.path().join(format!("{p}.c"));
            let lib = dir.path().join(format!("lib{p}.so"));
            std::fs::write(&file, &source).expect("written");
            let status = Command::new("cc")
                .args([
                    "-std=c99",
                    "-O1",
                    "-Wall",
                    "-Wextra",
                    "-Werror",
                    "-pedantic",
                    "-ffp-contract=off",
                    "-fPIC",
                    "-shared",
                    "-o",
                ])
                .arg(&lib)
                .arg(&file)
                .arg("-lm")
                .status()
                .expect("the C compiler runs");
            assert!(
                status.success(),
                "{}: the C source does not compile",
                m.name
            );
            // SAFETY: the library just compiled from kin's C source; its functions have the
            // signatures of `Error` and `Jacobian` (the file's header states them).
            let lib = unsafe { libloading::Library::new(&lib) }.expect("loads");
            let symbol = |name: &str| format!("{p}_{name}");
            // SAFETY: as above.
            let (error, six, position) = unsafe {
                (
                    *lib.get::<Error>(symbol("error").as_bytes()).expect("error"),
                    *lib.get::<Jacobian>(symbol("jacobian").as_bytes())
                        .expect("jacobian"),
                    *lib.get::<Jacobian>(symbol("jacobian_position").as_bytes())
                        .expect("jacobian_position"),
                )
            };
            let call_error =
                |st: &crate::interp::State, tool: usize, beta: *const f64, e: &mut [f64; 6]| {
                    // SAFETY: the state's arrays have the machine's sizes, β (when not null) its
                    // coefficients, and `e` the six values the function writes.
                    unsafe {
                        error(
                            st.q.as_ptr(),
                            st.inputs.as_ptr(),
                            st.lags.as_ptr(),
                            st.dirs.as_ptr(),
                            st.time,
                            tool,
                            beta,
                            e.as_mut_ptr(),
                        )
                    }
                };
            let jit = crate::jit::compile(m).expect("compiles");
            let n = m.coefficients.len();
            let nonlinear: Vec<f64> = m.nonlinear.iter().map(|q| q.value).collect();
            let bound = if m.beta.len() == n {
                m.beta.clone()
            } else {
                vec![0.0; n]
            };
            let given: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 5) as f64 - 2.0)).collect();
            let states = States::sample(m, 200, 7);
            let mut d: f64 = 0.0;
            // Per Jacobian entry: +0 from the JIT at every pose (a column that is zero
            // whatever the pose), and -0 from C at some pose.
            let (mut always_zero, mut minus_zero) = (vec![true; 6 * n], vec![false; 6 * n]);
            for r in 0..states.len() {
                let st = states.get(r);
                for (beta, pass) in [(&bound, std::ptr::null()), (&given, given.as_ptr())] {
                    let (mut e, mut j) = ([0.0; 6], vec![0.0; 6 * n]);
                    jit.error_and_jacobian(&st, beta, &nonlinear, &mut e, &mut j)
                        .expect("JIT");
                    let (mut ce, mut cj) = ([0.0; 6], vec![0.0; 6 * n]);
                    let call = |f: Jacobian, e: &mut [f64], j: &mut [f64]| {
                        // SAFETY: arrays of the machine's sizes, outputs of the rows' sizes.
                        unsafe {
                            f(
                                st.q.as_ptr(),
                                st.inputs.as_ptr(),
                                st.lags.as_ptr(),
                                st.dirs.as_ptr(),
                                st.time,
                                st.tool,
                                pass,
                                e.as_mut_ptr(),
                                j.as_mut_ptr(),
                            )
                        }
                    };
                    assert_eq!(call(six, &mut ce, &mut cj), 0);
                    d = d.max(worst(&ce, &e)).max(worst(&cj, &j));
                    for (k, (x, y)) in j.iter().zip(&cj).enumerate() {
                        always_zero[k] &= x.to_bits() == 0;
                        minus_zero[k] |= y.to_bits() == (-0.0f64).to_bits();
                    }
                    let (mut pe, mut pj) = ([0.0; 3], vec![0.0; 3 * n]);
                    assert_eq!(call(position, &mut pe, &mut pj), 0);
                    d = d.max(worst(&pe, &e[..3])).max(worst(&pj, &j[..3 * n]));
                    let mut ee = [0.0; 6];
                    assert_eq!(call_error(&st, st.tool, pass, &mut ee), 0);
                    let je = jit.error(&st, beta, &nonlinear).expect("JIT error");
                    d = d.max(worst(&ee, &je));
                }
            }
            assert!(d <= 1e-12, "{}: C and JIT differ by {d:e}", m.name);
            // Such entries are +0 in C too, not the -0 of a product with a negative value;
            // elsewhere a zero's sign may follow the C library's sin and cos.
            let signs = always_zero
                .iter()
                .zip(&minus_zero)
                .filter(|(a, b)| **a && **b);
            assert_eq!(signs.count(), 0, "{}: zero entries' signs", m.name);
            // A tool index past the last is refused before anything is read or written.
            let mut e = [7.0; 6];
            let code = call_error(&states.get(0), m.tools.len(), std::ptr::null(), &mut e);
            assert_eq!(
                (code, e),
                (-1, [7.0; 6]),
                "{}: a tool past the last",
                m.name
            );
        }
    }

    #[test]
    fn a_machine_name_becomes_a_c_identifier() {
        assert_eq!(prefix("milling_5axis"), "milling_5axis");
        assert_eq!(prefix("5axis"), "kin_5axis");
        assert_eq!(prefix("a-b c"), "a_b_c");
        assert_eq!(prefix("fräse"), "fr_se");
        assert_eq!(prefix(""), "kin_");
    }

    #[test]
    fn every_double_is_written_to_read_back_the_same() {
        for v in [
            0.0,
            -0.0,
            1.0,
            0.1,
            1e-300,
            5e-324,
            f64::MAX,
            -2.5e17,
            1.0 / 3.0,
        ] {
            assert_eq!(literal(v).parse::<f64>().map(f64::to_bits), Ok(v.to_bits()));
        }
        assert_eq!(literal(f64::NAN), "NAN");
        assert_eq!(literal(f64::NEG_INFINITY), "-INFINITY");
    }
}
