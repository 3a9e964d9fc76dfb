//! Beam bending candidates: the stress-free thermal deformation of a structure along a
//! prismatic axis (thesis §3.4.3, eq. 3.56–3.62, the `beam(…)` factor of spec/factors.md)
//! where a temperature difference across it bends it. Two sources:
//!
//! - a beam the model already declares with a gradient (`upper`, `lower`, `gap`, `across`) on
//!   some of the components it moves: the same call on the others it moves but the model does
//!   not give it (a bed whose expansion is modelled but whose bending is not);
//! - two temperature inputs (rises, or absolute ones as differences from 20 °C) that every file
//!   carries: for each prismatic axis with no declared gradient, each pair as the upper and the
//!   lower face of a beam along the axis' travel, bending across each direction across it.
//!
//! Only the bending is proposed (the deflection along the gradient and the rotation about the
//! normal): the expansion along the axis is the `thermal-scale` row's. The data fix the
//! curvature per kelvin of difference, `α/gap`, not α and the gap apart: a pair of inputs is
//! proposed with `gap 1 m`, so the fitted coefficient is α times 1 m over the real distance
//! between the faces (with that distance as `gap` it is α itself).

use std::collections::BTreeSet;

use kin_compiler::ir::{Component, JointKind, Machine};
use kin_compiler::syntax::ast::{Arg, Expr, ExprKind, Item, OptionValue};
use kin_compiler::units::Dim;

use super::library::{axis_frames, frame_name, push, Available, Proposal, Term};
use super::Family;

/// A `beam(…)` call with a gradient, as the model's source writes it.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Declared {
    /// The axis the beam runs along.
    pub axis: String,
    /// The call on one line, comments and line breaks removed.
    pub call: String,
}

/// What the model's source says about beams: the calls with a gradient, and the targets
/// (`X.tz`) a beam already defines.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Beams {
    pub declared: Vec<Declared>,
    pub defined: BTreeSet<String>,
}

impl Beams {
    /// The beams of a model's source; none when it does not parse (the candidates from pairs of
    /// inputs need no source).
    pub fn of(source: &str) -> Beams {
        let mut out = Beams::default();
        let Ok(file) = kin_compiler::syntax::parse_file(source) else {
            return out;
        };
        for item in &file.machine.items {
            let Item::Errors(errors) = item else { continue };
            for def in &errors.defs {
                let mut calls = Vec::new();
                beam_calls(&def.value, &mut calls);
                if calls.is_empty() {
                    continue;
                }
                for t in &def.targets {
                    if let Some(c) = &t.component {
                        out.defined.insert(format!("{}.{}", t.frame.node, c.node));
                    }
                }
                for call in calls {
                    let ExprKind::Call { args, .. } = &call.kind else {
                        continue;
                    };
                    let gradient = args
                        .iter()
                        .any(|a| matches!(a, Arg::Option(o) if o.name.node == "across"));
                    let axis = args.iter().find_map(|a| match a {
                        Arg::Positional(Expr {
                            kind: ExprKind::Name(n),
                            ..
                        }) => Some(n.clone()),
                        _ => None,
                    });
                    let text = source.get(call.span.start..call.span.end);
                    if let (true, Some(axis), Some(text)) = (gradient, axis, text) {
                        let d = Declared {
                            axis,
                            call: one_line(text),
                        };
                        if !out.declared.contains(&d) {
                            out.declared.push(d);
                        }
                    }
                }
            }
        }
        out
    }
}

/// Every `beam(…)` call inside an expression.
fn beam_calls<'a>(e: &'a Expr, out: &mut Vec<&'a Expr>) {
    match &e.kind {
        ExprKind::Call { name, args } => {
            if name.node == "beam" {
                out.push(e);
            }
            for a in args {
                match a {
                    Arg::Positional(x) => beam_calls(x, out),
                    Arg::Option(o) => match &o.value {
                        OptionValue::Expr(x) => beam_calls(x, out),
                        OptionValue::At { items, .. } => {
                            items.iter().for_each(|x| beam_calls(x, out))
                        }
                        OptionValue::IntRange { .. } | OptionValue::IntList { .. } => {}
                    },
                }
            }
        }
        ExprKind::Neg(a) => beam_calls(a, out),
        ExprKind::Binary(_, a, b) => {
            beam_calls(a, out);
            beam_calls(b, out);
        }
        ExprKind::Quantity { .. } | ExprKind::Const | ExprKind::Name(_) => {}
    }
}

/// A call's source text on one line: comments removed (the language has no strings, so `//`
/// and `/*` always open one), runs of whitespace as one space, none inside brackets.
fn one_line(text: &str) -> String {
    let mut plain = String::with_capacity(text.len());
    let mut rest = text;
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix("//") {
            rest = after.find('\n').map_or("", |k| &after[k..]);
        } else if let Some(after) = rest.strip_prefix("/*") {
            rest = after.find("*/").map_or("", |k| &after[k + 2..]);
            plain.push(' ');
        } else {
            let mut chars = rest.chars();
            if let Some(c) = chars.next() {
                plain.push(c);
            }
            rest = chars.as_str();
        }
    }
    let joined = plain.split_whitespace().collect::<Vec<_>>().join(" ");
    joined
        .replace("( ", "(")
        .replace(" )", ")")
        .replace(" ,", ",")
}

/// The bending components of a beam along `u` with its gradient along frame axis `g`: the
/// translation along `g` (the deflection) and the rotations about `g × u`.
fn bending(u: [f64; 3], g: usize) -> Vec<Component> {
    let e = |k: usize| {
        let mut v = [0.0; 3];
        v[k] = 1.0;
        v
    };
    let gv = e(g);
    let n = [
        gv[1] * u[2] - gv[2] * u[1],
        gv[2] * u[0] - gv[0] * u[2],
        gv[0] * u[1] - gv[1] * u[0],
    ];
    let mut out = vec![[Component::Tx, Component::Ty, Component::Tz][g]];
    for (k, c) in [Component::Rx, Component::Ry, Component::Rz]
        .into_iter()
        .enumerate()
    {
        if n[k].abs() > 1e-12 {
            out.push(c);
        }
    }
    out
}

/// Appends the beam bending candidates (module docs) for `m`, whose source's beams are `beams`.
pub(super) fn propose(m: &Machine, available: &Available, beams: &Beams, out: &mut Vec<Proposal>) {
    let length = &m.units.length;
    let number = |v: f64| (length.from_si(v) * 1e9).round() / 1e9;
    // The temperatures every file carries, as the known scalar a beam takes.
    let temperatures: Vec<String> = m
        .inputs
        .iter()
        .enumerate()
        .filter(|(i, input)| {
            input.unit.dim == Dim::TEMPERATURE && available.inputs.get(*i).copied().unwrap_or(false)
        })
        .map(|(_, input)| {
            if input.absolute {
                format!("({} - 20 degC)", input.name)
            } else {
                input.name.clone()
            }
        })
        .collect();
    for (a, frame) in axis_frames(m) {
        let (Some(axis), Some(name)) = (m.axes.get(a), frame_name(m, frame)) else {
            continue;
        };
        // A bending grows with the square of the position along the axis: it takes three
        // positions to tell it from an offset and a tilt.
        let seen = available
            .sampled
            .get(a)
            .copied()
            .flatten()
            .is_some_and(|s| s.distinct >= 3);
        if axis.kind != JointKind::Prismatic || !seen {
            continue;
        }
        let u = axis.direction;
        let across: Vec<usize> = (0..3).filter(|&k| u[k].abs() <= 1e-9).collect();
        let declared: Vec<&Declared> = beams
            .declared
            .iter()
            .filter(|d| d.axis == axis.name)
            .collect();
        let mut add = |comp: Component, call: &str, explanation: String| {
            let target = format!("{name}.{}", comp.name());
            if beams.defined.contains(&target) {
                return;
            }
            push(
                out,
                Family::Thermal,
                target.clone(),
                vec![Term::new(format!("{call} * const"))],
                explanation,
                Some(format!("beam {target}")),
            );
        };
        if !declared.is_empty() {
            // The declared beam's own gradient: its `across` names the direction, whose
            // bending components are the only ones the call moves besides the expansion (the
            // compiler refuses it on the others).
            for d in declared {
                for &g in &across {
                    if !d.call.contains(&format!("across {}", ["x", "y", "z"][g])) {
                        continue;
                    }
                    for comp in bending(u, g) {
                        add(
                            comp,
                            &d.call,
                            format!(
                                "the beam along {} that the model declares also bends: its {} follows the gradient through the same temperatures (thesis §3.4.3)",
                                axis.name,
                                comp.name()
                            ),
                        );
                    }
                }
            }
            continue;
        }
        let (lo, hi) = (number(axis.range[0]), number(axis.range[1]));
        if !(hi > lo) {
            continue;
        }
        let gap = number(1.0);
        for (k, upper) in temperatures.iter().enumerate() {
            for lower in temperatures.iter().skip(k + 1) {
                for &g in &across {
                    let dir = ["x", "y", "z"][g];
                    let call = format!(
                        "beam({}, ends at ({lo}, {hi}) {unit}, upper at ({upper}, {upper}), lower at ({lower}, {lower}), gap {gap} {unit}, across {dir})",
                        axis.name,
                        unit = length.name
                    );
                    for comp in bending(u, g) {
                        add(
                            comp,
                            &call,
                            format!(
                                "the structure along {} bends with the difference between {upper} and {lower} across {dir} (a stress-free beam, thesis §3.4.3): put the beam's real ends and the distance between the two sensors as `gap`, the coefficient is then its expansion coefficient",
                                axis.name
                            ),
                        );
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::library::Sampling;
    use super::*;

    const SRC: &str = r#"
machine bed {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    input T_top0 : temperature rise
    input T_top1 : temperature rise
    input T_low0 : temperature rise
    input T_low1 : temperature rise
    input T_room : temperature absolute
    tool chain { Y moving  tool t at (0, 0, -100) mm }
    workpiece chain { X moving  workpiece at (0, 0, 50) mm }
    errors {
        X.tx = 11.5 um/m/K * beam(X, ends at (-100, 1100) mm,
                                  upper at (T_top0, T_top1), // the sunlit face
                                  lower at (T_low0, T_low1), gap 250 mm, across z)
        Y.ty = linear(Y)
    }
}
"#;

    fn machine(src: &str) -> Machine {
        match kin_compiler::compile(src).compiled {
            Some(c) => c.machine,
            None => panic!("{:?}", kin_compiler::compile(src).diagnostics),
        }
    }

    fn available(m: &Machine) -> Available {
        Available {
            directions: vec![false; m.axes.len()],
            inputs: vec![true; m.inputs.len()],
            time: false,
            sampled: m
                .axes
                .iter()
                .map(|a| Sampling::of((0..=10).map(|k| a.range[0] + a.range[1] * k as f64 / 10.0)))
                .collect(),
            reversals: Vec::new(),
        }
    }

    fn texts(src: &str) -> Vec<String> {
        let m = machine(src);
        let mut out = Vec::new();
        propose(&m, &available(&m), &Beams::of(src), &mut out);
        out.into_iter().map(|p| p.candidate.text).collect()
    }

    #[test]
    fn a_declared_beam_is_offered_on_the_components_it_bends() {
        let beams = Beams::of(SRC);
        assert_eq!(beams.declared.len(), 1);
        assert_eq!(
            beams.declared[0].call,
            "beam(X, ends at (-100, 1100) mm, upper at (T_top0, T_top1), lower at (T_low0, T_low1), gap 250 mm, across z)"
        );
        assert!(beams.defined.contains("X.tx"));
        let t = texts(SRC);
        let call = &beams.declared[0].call;
        // Across z along x: the deflection along z and the rotation about z × x = y.
        assert!(t.contains(&format!("X.tz += {call} * const")), "{t:#?}");
        assert!(t.contains(&format!("X.ry += {call} * const")), "{t:#?}");
        // Y has no beam declared: pairs of the five temperatures (the absolute one as a rise
        // from 20 °C), across x and z, each bending two components.
        let y: Vec<&String> = t.iter().filter(|s| s.starts_with("Y.")).collect();
        assert_eq!(y.len(), 10 * 2 * 2, "{y:#?}");
        let expected = "Y.tz += beam(Y, ends at (0, 400) mm, upper at (T_top0, T_top0), lower at ((T_room - 20 degC), (T_room - 20 degC)), gap 1000 mm, across z) * const";
        assert!(y.iter().any(|s| s.as_str() == expected), "{y:#?}");
        // Each, added to the model, checks clean.
        for line in &t {
            let last = "        Y.ty = linear(Y)\n";
            let src = SRC.replace(last, &format!("{last}        {line}\n"));
            let c = kin_compiler::compile(&src);
            assert!(c.compiled.is_some(), "{line}: {:?}", c.diagnostics);
        }
    }

    #[test]
    fn nothing_without_two_temperatures_or_where_a_beam_is_defined() {
        let one = r#"
machine one {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    input T : temperature rise
    tool chain { X moving  tool t at (0, 0, 0) mm }
    errors { X.tx = linear(X) }
}
"#;
        assert!(texts(one).is_empty());
        let both = SRC.replace(
            "        Y.ty = linear(Y)\n",
            "        Y.ty = linear(Y)\n        X.tz = beam(X, ends at (-100, 1100) mm, upper at (T_top0, T_top1), lower at (T_low0, T_low1), gap 250 mm, across z) * const\n",
        );
        let t = texts(&both);
        assert!(!t.iter().any(|s| s.starts_with("X.tz")), "{t:#?}");
        assert!(t.iter().any(|s| s.starts_with("X.ry")), "{t:#?}");
        // A temperature missing from a file takes it out of the pairs.
        let m = machine(SRC);
        let mut a = available(&m);
        a.inputs = vec![true, false, false, false, true];
        let mut out = Vec::new();
        propose(&m, &a, &Beams::of(SRC), &mut out);
        assert_eq!(
            out.iter()
                .filter(|p| p.candidate.target.starts_with("Y."))
                .count(),
            4
        );
        // Nor along an axis the data hold at two positions.
        let mut a = available(&m);
        a.sampled[1] = Sampling::of([0.0, 0.4].into_iter());
        let mut out = Vec::new();
        propose(&m, &a, &Beams::of(SRC), &mut out);
        assert!(out.iter().all(|p| !p.candidate.target.starts_with("Y.")));
    }

    #[test]
    fn comments_and_line_breaks_leave_a_call_on_one_line() {
        assert_eq!(
            one_line("beam(X,\n  ends at ( 0, 1 ) mm, /* hot */ mean at (A , B) // end\n)"),
            "beam(X, ends at (0, 1) mm, mean at (A, B))"
        );
    }
}
