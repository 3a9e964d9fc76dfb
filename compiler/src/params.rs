//! Binding parameter values (`params { … }`) to a compiled machine.
//!
//! Coefficients are addressed as `FRAME.comp[i]` (index among that component's coefficients,
//! in order of appearance) or all at once as `FRAME.comp = [ … ] unit`; non-linear parameters by
//! their name (`Z.tz.tau`). Values are stored in SI; units must match the derived dimension.

use crate::diagnostic::{suggest, Diagnostic, Span};
use crate::ir;
use crate::resolve::{constant, parse_unit, Sink};
use crate::syntax::ast::{self, ParamValue};
use crate::units::Unit;

/// Binds every definition of `params` into `machine.beta` (zeros where not given) and the
/// non-linear parameter values. Returns the diagnostics.
pub(crate) fn bind(machine: &mut ir::Machine, params: &ast::ParamsBlock) -> Vec<Diagnostic> {
    let mut sink = Sink::default();
    if machine.beta.len() != machine.coefficients.len() {
        machine.beta = vec![0.0; machine.coefficients.len()];
    }
    let mut bound = Bound::default();
    for def in &params.defs {
        if let Some(add) = def.add {
            sink.push(
                Diagnostic::error("E0501", "parameter values are set with `=`, not `+=`", add)
                    .with_label("not an assignment of a value"),
            );
            continue;
        }
        bind_one(machine, def, &mut bound, &mut sink);
    }
    sink.diagnostics
}

/// Where each coefficient and non-linear parameter was first set, to refuse a second value.
#[derive(Default)]
struct Bound {
    coefficients: std::collections::HashMap<usize, Span>,
    nonlinear: std::collections::HashMap<usize, Span>,
}

impl Bound {
    fn claim(
        map: &mut std::collections::HashMap<usize, Span>,
        k: usize,
        name: &str,
        span: Span,
        sink: &mut Sink,
    ) -> bool {
        if let Some(first) = map.get(&k) {
            sink.push(
                Diagnostic::error("E0102", format!("`{name}` is given a value twice"), span)
                    .with_label("second value")
                    .with_secondary(*first, "first set here"),
            );
            return false;
        }
        map.insert(k, span);
        true
    }
}

fn bind_one(machine: &mut ir::Machine, def: &ast::ParamDef, bound: &mut Bound, sink: &mut Sink) {
    let path: Vec<&str> = def.path.iter().map(|n| n.node.as_str()).collect();
    let (full, location) = match canonical(machine, &path) {
        Ok(found) => found,
        Err(e) => {
            let first = def.path.first().map(|n| n.span).unwrap_or(def.span);
            sink.push(
                Diagnostic::error("E0107", e.to_string(), first)
                    .with_label("an ISO 230-1 location name this machine cannot carry")
                    .with_help(e.help()),
            );
            return;
        }
    };
    let first = def.path.first().map(|n| n.span).unwrap_or(def.span);
    let last = def.path.last().map(|n| n.span).unwrap_or(def.span);
    let path_span = first.to(last);

    // A non-linear parameter, by its full name (with an optional index).
    let nl_name = match &def.index {
        Some(i) if i.node > 0 => format!("{full}[{}]", i.node),
        _ => full.clone(),
    };
    if let Some(k) = machine.nonlinear.iter().position(|p| p.name == nl_name) {
        if !Bound::claim(&mut bound.nonlinear, k, &nl_name, def.span, sink) {
            return;
        }
        let Some(p) = machine.nonlinear.get(k) else {
            return;
        };
        let unit = p.unit.clone();
        if let Some(v) = scalar_value(&def.value, &unit, sink) {
            if v <= 0.0 {
                sink.push(
                    Diagnostic::error("E0501", format!("`{nl_name}` must be positive"), def.span)
                        .with_label("not positive"),
                );
            } else if let Some(p) = machine.nonlinear.get_mut(k) {
                p.value = v;
            }
        }
        return;
    }

    // Coefficients of one error component.
    let members: Vec<usize> = machine
        .coefficients
        .iter()
        .enumerate()
        .filter(|(_, c)| c.name.rsplit_once('[').map(|(base, _)| base) == Some(full.as_str()))
        .map(|(i, _)| i)
        .collect();
    if members.is_empty() {
        let mut names: Vec<String> = machine
            .coefficients
            .iter()
            .filter_map(|c| c.name.rsplit_once('[').map(|(b, _)| b.to_string()))
            .chain(machine.nonlinear.iter().map(|p| p.name.clone()))
            .collect();
        names.dedup();
        let mut d = Diagnostic::error("E0501", format!("`{full}` has no parameters"), path_span)
            .with_label("no coefficient or non-linear parameter of this name");
        if let Some(s) = suggest(&full, names.iter().map(String::as_str)) {
            d = d.with_help(format!("did you mean `{s}`?"));
        }
        sink.push(d);
        return;
    }
    // A location or squareness name (`EC0Y`) is the constant of its component, not the
    // component: `X.rz = spline(X, knots 2) + const` holds the squareness in its `const` term,
    // and `EC0Y[0]` must not bind the spline's first coefficient.
    let members = match location {
        Some(_) => {
            let constants = constant_members(machine, &members);
            match constants.len() {
                1 => constants,
                n => {
                    let first_name = def.path.first().map_or("", |p| p.node.as_str());
                    sink.push(
                        Diagnostic::error(
                            "E0501",
                            if n == 0 {
                                format!("`{first_name}` is a constant of `{full}`, which has no constant term")
                            } else {
                                format!("`{first_name}` is a constant of `{full}`, which has {n} constant terms")
                            },
                            path_span,
                        )
                        .with_label(format!("`{first_name}` is `{full}`'s constant (ISO 230-1)"))
                        .with_help(if n == 0 {
                            format!("add `{first_name} = const` to the errors block, or bind `{full}[k]` by its index")
                        } else {
                            format!("bind the one meant by its index, `{full}[k]`")
                        }),
                    );
                    return;
                }
            }
        }
        None => members,
    };
    match (&def.index, &def.value) {
        // A location name holds one value: `EC0Y = 15 urad`.
        (None, ParamValue::Scalar(_)) if location.is_some() => {
            let Some(&k) = members.first() else {
                return;
            };
            bind_scalar(machine, def, bound, k, location, sink);
        }
        (Some(i), _) => {
            let Some(&k) = usize::try_from(i.node).ok().and_then(|i| members.get(i)) else {
                sink.push(
                    Diagnostic::error(
                        "E0501",
                        format!(
                            "`{full}` has {} coefficient{}; index {} is out of range",
                            members.len(),
                            if members.len() == 1 { "" } else { "s" },
                            i.node
                        ),
                        i.span,
                    )
                    .with_label(format!(
                        "valid indices: 0..{}",
                        members.len().saturating_sub(1)
                    )),
                );
                return;
            };
            bind_scalar(machine, def, bound, k, location, sink);
        }
        (None, ParamValue::List { values, unit, span }) => {
            if values.len() != members.len() {
                sink.push(
                    Diagnostic::error(
                        "E0501",
                        format!(
                            "`{full}` has {} coefficient{}, but {} value{} given",
                            members.len(),
                            if members.len() == 1 { "" } else { "s" },
                            values.len(),
                            if values.len() == 1 { " is" } else { "s are" }
                        ),
                        *span,
                    )
                    .with_label("wrong number of values"),
                );
                return;
            }
            let given = match unit {
                Some(u) => match parse_unit(u, sink) {
                    Some(parsed) => Some((parsed, u.span)),
                    None => return,
                },
                None => None,
            };
            for k in &members {
                let name = machine
                    .coefficients
                    .get(*k)
                    .map(|c| c.name.clone())
                    .unwrap_or_default();
                if !Bound::claim(&mut bound.coefficients, *k, &name, def.span, sink) {
                    return;
                }
            }
            for (k, v) in members.iter().zip(values) {
                let Some(coef) = machine.coefficients.get(*k) else {
                    continue;
                };
                let unit = match &given {
                    Some((u, uspan)) => {
                        if u.dim != coef.unit.dim {
                            sink.push(unit_mismatch(&coef.name, &coef.unit, u, *uspan));
                            return;
                        }
                        u.clone()
                    }
                    None => coef.unit.clone(),
                };
                let sign = location.map_or(1.0, |s| s * scale_sign(machine, *k));
                if let Some(b) = machine.beta.get_mut(*k) {
                    *b = sign * unit.to_si(*v);
                }
            }
        }
        (None, ParamValue::Scalar(e)) => {
            let (label, help) = if members.len() == 1 {
                (
                    "a value without an index",
                    format!("write `{full}[0] = …`, or a list `{full} = [ … ] unit`"),
                )
            } else {
                (
                    "a single value for several coefficients",
                    format!("give them all, `{full} = [ … ] unit`, or one, `{full}[0] = …`"),
                )
            };
            sink.push(
                Diagnostic::error(
                    "E0501",
                    format!(
                        "`{full}` has {} coefficient{}",
                        members.len(),
                        if members.len() == 1 { "" } else { "s" }
                    ),
                    e.span,
                )
                .with_label(label)
                .with_help(help),
            );
        }
    }
}

/// Binds coefficient `k` to the definition's single value (with a location name's sign).
fn bind_scalar(
    machine: &mut ir::Machine,
    def: &ast::ParamDef,
    bound: &mut Bound,
    k: usize,
    location: Option<f64>,
    sink: &mut Sink,
) {
    let name = machine
        .coefficients
        .get(k)
        .map(|c| c.name.clone())
        .unwrap_or_default();
    if !Bound::claim(&mut bound.coefficients, k, &name, def.span, sink) {
        return;
    }
    let unit = machine
        .coefficients
        .get(k)
        .map(|c| c.unit.clone())
        .unwrap_or_else(Unit::dimensionless);
    let sign = location.map_or(1.0, |s| s * scale_sign(machine, k));
    if let Some(v) = scalar_value(&def.value, &unit, sink) {
        if let Some(b) = machine.beta.get_mut(k) {
            *b = sign * v;
        }
    }
}

/// The term coefficient `k` belongs to.
fn term_of(machine: &ir::Machine, k: usize) -> Option<&ir::Term> {
    machine
        .coefficients
        .get(k)
        .and_then(|c| machine.errors.get(c.error))
        .and_then(|e| {
            e.terms
                .iter()
                .find(|t| t.first <= k && k < t.first + t.coefficients)
        })
}

/// The coefficients among `members` that are a constant term of their component (`const`
/// with a plain-number scale, no factor that varies): where a location or squareness is held.
fn constant_members(machine: &ir::Machine, members: &[usize]) -> Vec<usize> {
    members
        .iter()
        .copied()
        .filter(|&k| {
            term_of(machine, k).is_some_and(|t| {
                t.coefficients == 1
                    && matches!(t.scale, ir::Scalar::Num(_))
                    && t.factors
                        .iter()
                        .all(|f| matches!(f.basis, crate::basis::Basis::Const))
            })
        })
        .collect()
}

/// The name `path` stands for, and for a location name the sign relating its value to the
/// component's (`None` for any other name): itself when the machine has
/// parameters of that name, else with an ISO 230-1 or VDI 2617 alias in front expanded
/// (`EAX[0]` is `X.rx[0]`, `xtx.wavelength` is `X.tx.wavelength`, `EC0Y[0]` may be
/// `−X.rz[0]`), as the `errors` block accepts them.
fn canonical(
    machine: &ir::Machine,
    path: &[&str],
) -> Result<(String, Option<f64>), ir::AliasError> {
    let given = path.join(".");
    let known = |name: &str| {
        machine.nonlinear.iter().any(|p| {
            p.name == name
                || p.name
                    .strip_prefix(name)
                    .is_some_and(|rest| rest.starts_with('['))
        }) || machine
            .coefficients
            .iter()
            .any(|c| c.name.rsplit_once('[').map(|(base, _)| base) == Some(name))
    };
    if known(&given) {
        return Ok((given, None));
    }
    Ok(match path.split_first() {
        Some((first, rest)) => match ir::alias(first, machine.layout())? {
            Some(a) => (
                std::iter::once(format!("{}.{}", a.axis, a.component.name()))
                    .chain(rest.iter().map(|s| s.to_string()))
                    .collect::<Vec<_>>()
                    .join("."),
                // A component alias binds coefficients as they are; only a location name binds
                // an error value (see `scale_sign`), and never a non-linear parameter.
                (rest.is_empty() && ir::is_location(first)).then_some(a.sign),
            ),
            None => (given, None),
        },
        None => (given, None),
    })
}

/// The sign of the plain-number scale of coefficient `k`'s term, +1 for any other: a location
/// name binds the error's value, `scale × β`, and `EC0Y = const` written where `EC0Y` is
/// `−X.rz` makes a term of scale −1 whose coefficient is EC0Y itself.
fn scale_sign(machine: &ir::Machine, k: usize) -> f64 {
    term_of(machine, k)
        .map(|t| match t.scale {
            ir::Scalar::Num(v) if v < 0.0 => -1.0,
            _ => 1.0,
        })
        .unwrap_or(1.0)
}

fn unit_mismatch(name: &str, expected: &Unit, given: &Unit, span: Span) -> Diagnostic {
    Diagnostic::error(
        "E0501",
        format!(
            "`{name}` is in {} ({}), but `{}` is {}",
            expected.name,
            expected.dim.describe(),
            given.name,
            given.dim.describe()
        ),
        span,
    )
    .with_label(format!("expected {}", expected.dim.describe()))
}

/// A single value: a quantity of the expected dimension, or a bare number in `unit`.
fn scalar_value(value: &ParamValue, unit: &Unit, sink: &mut Sink) -> Option<f64> {
    match value {
        ParamValue::Scalar(e) => {
            let c = constant(e, false, sink)?;
            if c.bare {
                return Some(unit.to_si(c.value));
            }
            if c.dim != unit.dim {
                sink.push(
                    Diagnostic::error(
                        "E0501",
                        format!(
                            "expected {} (e.g. `{}`), but this is {}",
                            unit.dim.describe(),
                            unit.name,
                            c.dim.describe()
                        ),
                        e.span,
                    )
                    .with_label(format!("expected {}", unit.dim.describe())),
                );
                return None;
            }
            Some(c.value)
        }
        ParamValue::List { span, .. } => {
            sink.push(
                Diagnostic::error("E0501", "expected one value, not a list", *span)
                    .with_label("a list"),
            );
            None
        }
    }
}

#[cfg(test)]
mod tests {
    const MACHINE: &str = "machine m {
        task position
        units { length mm, error um, tilt urad }
        axis X prismatic along x range 0 mm .. 500 mm
        tool chain { X moving  tool t at (0, 0, -100) mm }
        errors {
            X.rx = spline(X, knots 2)
            X.tx = periodic(X, wavelength fit 10 mm, knots 2)
        }
    }";

    fn bound(params: &str) -> (crate::ir::Machine, Vec<String>) {
        let mut m = crate::compile(MACHINE)
            .compiled
            .expect("the machine compiles")
            .machine;
        let diagnostics = crate::bind_params(&mut m, params);
        (m, diagnostics.into_iter().map(|d| d.message).collect())
    }

    #[test]
    fn iso_and_vdi_names_bind_like_canonical_ones() {
        let (m, errors) = bound(
            "params { EAX[0] = 1.5 urad  xrx[1] = -2 urad  xtx.wavelength = 12.5 mm  EXX = [0.5, 0.25] um }",
        );
        assert_eq!(errors, Vec::<String>::new());
        let value = |name: &str| {
            m.coefficients
                .iter()
                .position(|c| c.name == name)
                .and_then(|j| m.beta.get(j).copied())
                .unwrap_or(f64::NAN)
        };
        assert!((value("X.rx[0]") - 1.5e-6).abs() < 1e-18);
        assert!((value("X.rx[1]") + 2e-6).abs() < 1e-18);
        assert!((value("X.tx[1]") - 0.25e-6).abs() < 1e-18);
        let tau = m.nonlinear.iter().find(|p| p.name == "X.tx.wavelength");
        assert!(
            tau.is_some_and(|p| (p.value - 0.0125).abs() < 1e-15),
            "{tau:?}"
        );
    }

    #[test]
    fn an_unknown_alias_is_still_an_error() {
        let (_, errors) = bound("params { EAY[0] = 1 urad }");
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(errors[0].contains("EAY"), "{errors:?}");
    }

    #[test]
    fn a_squareness_name_binds_its_component_with_its_sign() {
        let mut m = crate::compile(
            "machine m { task position
                units { tilt urad }
                axis Y prismatic along y range 0 mm .. 500 mm
                axis X prismatic along x range 0 mm .. 500 mm
                workpiece chain { Y moving  X moving }
                tool chain { tool t }
                errors { Y.rz = const } }",
        )
        .compiled
        .expect("the machine compiles")
        .machine;
        // Y moving carries X: Y's constant yaw turns X against Y, i.e. Y against X the other
        // way: EC0Y is −Y.rz.
        let diagnostics = crate::bind_params(&mut m, "params { EC0Y[0] = 12 urad }");
        assert!(diagnostics.is_empty(), "{diagnostics:?}");
        assert!((m.beta[0] + 12e-6).abs() < 1e-18, "{:?}", m.beta);
        // Written through the alias, the term has scale −1 and its coefficient is EC0Y itself.
        let mut m = crate::compile(
            "machine m { task position
                units { tilt urad }
                axis Y prismatic along y range 0 mm .. 500 mm
                axis X prismatic along x range 0 mm .. 500 mm
                workpiece chain { Y moving  X moving }
                tool chain { tool t }
                errors { EC0Y = const } }",
        )
        .compiled
        .expect("the machine compiles")
        .machine;
        let diagnostics = crate::bind_params(&mut m, "params { EC0Y[0] = 12 urad }");
        assert!(diagnostics.is_empty(), "{diagnostics:?}");
        assert!((m.beta[0] - 12e-6).abs() < 1e-18, "{:?}", m.beta);
        let diagnostics = crate::bind_params(&mut m, "params { EY0X[0] = 1 um }");
        assert_eq!(diagnostics.len(), 1);
        assert_eq!(diagnostics[0].code, "E0107", "{diagnostics:?}");
    }

    /// `EC0Y` is the squareness, the constant of its component: beside a yaw spline it binds
    /// the `const` term, never the spline's first coefficient; without a constant term it is
    /// an error that says so.
    #[test]
    fn a_squareness_name_binds_the_constant_not_the_component() {
        let machine = |errors: &str| {
            crate::compile(&format!(
                "machine m {{ task position
                    units {{ tilt urad }}
                    axis Y prismatic along y range 0 mm .. 500 mm
                    axis X prismatic along x range 0 mm .. 500 mm
                    workpiece chain {{ Y moving  X moving }}
                    tool chain {{ tool t }}
                    errors {{ {errors} }} }}"
            ))
            .compiled
            .expect("the machine compiles")
            .machine
        };
        let mut m = machine("Y.rz = spline(Y, knots 2) + const");
        let diagnostics = crate::bind_params(&mut m, "params { EC0Y = 15 urad }");
        assert!(diagnostics.is_empty(), "{diagnostics:?}");
        let constant = m
            .coefficients
            .iter()
            .position(|c| c.label.is_empty() || !c.label.contains("spline"))
            .expect("the const coefficient");
        for (j, b) in m.beta.iter().enumerate() {
            if j == constant {
                assert!((b + 15e-6).abs() < 1e-18, "{:?}", m.beta);
            } else {
                assert_eq!(*b, 0.0, "the spline is untouched: {:?}", m.beta);
            }
        }
        let mut m = machine("Y.rz = spline(Y, knots 2) + const");
        let diagnostics = crate::bind_params(&mut m, "params { EC0Y[0] = 15 urad }");
        assert!(diagnostics.is_empty(), "{diagnostics:?}");
        assert!((m.beta[constant] + 15e-6).abs() < 1e-18, "{:?}", m.beta);
        let mut m = machine("Y.rz = spline(Y, knots 2)");
        let diagnostics = crate::bind_params(&mut m, "params { EC0Y = 15 urad }");
        assert_eq!(diagnostics.len(), 1, "{diagnostics:?}");
        assert!(
            diagnostics[0].message.contains("no constant term"),
            "{diagnostics:?}"
        );
        assert!(m.beta.iter().all(|b| *b == 0.0));
    }
}
