//! DH import: a Denavit–Hartenberg table, standard or modified, as a `.kin` machine
//! (`kin import dh`, spec/urdf.md "Denavit–Hartenberg tables").
//!
//! Each row is a joint: `a`, `alpha`, `d`, `theta` (the joint's zero offset) and its type, in
//! one of the two conventions robot makers publish:
//!
//! - **standard** (Denavit–Hartenberg 1955, as in most robot manuals): link i is
//!   `Rz(θᵢ + qᵢ) · Tz(dᵢ) · Tx(aᵢ) · Rx(αᵢ)` (a prismatic joint adds qᵢ to dᵢ);
//! - **modified** (Craig 1986): link i is `Rx(αᵢ₋₁) · Tx(aᵢ₋₁) · Rz(θᵢ + qᵢ) · Tz(dᵢ)`, the
//!   row of joint i holding `aᵢ₋₁` and `αᵢ₋₁`.
//!
//! Either way the chain is a product of fixed transforms and motions about or along each
//! joint's z, which is what a URDF chain is: the table is written as one (every joint's
//! `<origin>` the fixed transforms since the previous joint's motion, its axis z, exactly, each
//! number in its shortest round-trip text) and imported by [`crate::urdf`], so a DH robot gets
//! the same frames, shapes and default error model as a URDF one. A last row of type `fixed`
//! is the flange or tool, in the same convention.

use std::path::Path;

mod export;
pub use export::{export, link, text, DhExportError, Row as ExportedRow, Table, PARALLEL};

use kin_compiler::units::{Dim, Unit};
use nalgebra::{Matrix4, Rotation3, Vector3};

use crate::urdf::{self, origin_text, Imported, Options, UrdfError};

/// Which Denavit–Hartenberg convention a table follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Convention {
    Standard,
    Modified,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Revolute,
    Prismatic,
    Fixed,
}

/// One row of the table, SI.
#[derive(Debug, Clone)]
struct Row {
    name: String,
    kind: Kind,
    a: f64,
    alpha: f64,
    d: f64,
    theta: f64,
    /// Hayati's tilt about y at the end of a standard link (0 when not given).
    beta: f64,
    limits: Option<(f64, f64)>,
}

/// Reads the DH table at `path` (at most 64 MiB of UTF-8) and imports it.
pub fn import_file(
    path: &Path,
    convention: Convention,
    options: &Options,
) -> Result<Imported, UrdfError> {
    let text = urdf::read_text(path)?;
    import(&text, path, convention, options)
}

/// Imports the DH table `text`; `path` names it in messages and in the model's header.
pub fn import(
    text: &str,
    path: &Path,
    convention: Convention,
    options: &Options,
) -> Result<Imported, UrdfError> {
    let rows = read_rows(text, path)?;
    if convention == Convention::Modified {
        if let Some(r) = rows.iter().find(|r| r.beta != 0.0) {
            return Err(invalid(
                path,
                1,
                1,
                format!(
                    "joint `{}` has a `beta` (Hayati's tilt), which kin reads in the standard convention only (--convention standard)",
                    r.name
                ),
            ));
        }
    }
    let frames = read_frames(text, path)?;
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "robot".into());
    let urdf_text = as_urdf(&rows, convention, &name, &frames);
    let mut imported = urdf::import(&urdf_text, path, options)?;
    imported.source = with_header(&imported.source, path, convention, rows.len());
    Ok(imported)
}

/// The model's header comment for a DH table, in place of the URDF importer's.
fn with_header(source: &str, path: &Path, convention: Convention, rows: usize) -> String {
    let file = path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    );
    let body: String = source
        .lines()
        .skip_while(|l| l.starts_with("//"))
        .map(|l| format!("{l}\n"))
        .collect();
    format!(
        "// Imported by `kin import dh` from {file}: {rows} rows of a {} Denavit–Hartenberg table,\n\
         // each joint about (or along) the z of its own frame. Lengths in mm, angles in deg; each\n\
         // element's shape is the fixed part of the table between its joint and the one before.\n{body}",
        match convention {
            Convention::Standard => "standard",
            Convention::Modified => "modified (Craig)",
        }
    )
}

fn invalid(path: &Path, line: u32, column: u32, message: impl Into<String>) -> UrdfError {
    UrdfError::Invalid {
        path: path.to_path_buf(),
        line,
        column,
        message: message.into(),
    }
}

/// The columns a table may hold: name, the unit dimension of its numbers, its default unit.
const COLUMNS: [(&str, Option<Dim>); 9] = [
    ("joint", None),
    ("type", None),
    ("a", Some(Dim::LENGTH)),
    ("alpha", Some(Dim::ANGLE)),
    ("d", Some(Dim::LENGTH)),
    ("theta", Some(Dim::ANGLE)),
    ("beta", Some(Dim::ANGLE)),
    ("lower", None),
    ("upper", None),
];

fn read_rows(text: &str, path: &Path) -> Result<Vec<Row>, UrdfError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (u32::try_from(i + 1).unwrap_or(u32::MAX), l))
        .filter(|(_, l)| {
            let t = l.trim();
            !t.is_empty() && !t.starts_with('#')
        });
    let Some((header_line, header)) = lines.next() else {
        return Err(invalid(
            path,
            1,
            1,
            "the table has no header (a, alpha, d, theta, …)",
        ));
    };
    let sep = [',', ';', '\t']
        .into_iter()
        .max_by_key(|c| header.matches(*c).count())
        .filter(|c| header.contains(*c));
    let split = |l: &str| -> Vec<(u32, String)> {
        let mut out = Vec::new();
        let mut column = 1u32;
        let cells: Vec<&str> = match sep {
            Some(c) => l.split(c).collect(),
            None => l.split_whitespace().collect(),
        };
        for cell in cells {
            out.push((column, cell.trim().trim_matches('"').to_string()));
            column = column.saturating_add(u32::try_from(cell.chars().count() + 1).unwrap_or(0));
        }
        out
    };
    // Per column of the file: which field and its unit.
    let mut fields: Vec<Option<(usize, Option<Unit>)>> = Vec::new();
    for (column, cell) in split(header) {
        let (name, unit) = match cell.split_once('[') {
            Some((n, u)) => (
                n.trim().to_lowercase(),
                Some(u.trim_end_matches(']').trim().to_string()),
            ),
            None => (cell.trim().to_lowercase(), None),
        };
        let Some(k) = COLUMNS.iter().position(|(n, _)| *n == name) else {
            return Err(invalid(
                path,
                header_line,
                column,
                format!("unknown column `{cell}`: a DH table has joint, type, a, alpha, d, theta, beta, lower, upper"),
            ));
        };
        if fields.iter().flatten().any(|(j, _)| *j == k) {
            return Err(invalid(
                path,
                header_line,
                column,
                format!("column `{name}` is given twice"),
            ));
        }
        let unit = match unit {
            Some(u) => {
                let parsed = Unit::parse(&u)
                    .map_err(|e| invalid(path, header_line, column, format!("unit `{u}`: {e}")))?;
                if let Some((_, Some(dim))) = COLUMNS.get(k) {
                    if parsed.dim != *dim {
                        return Err(invalid(
                            path,
                            header_line,
                            column,
                            format!(
                                "`{name}` is {}, not in `{u}`",
                                if *dim == Dim::LENGTH {
                                    "a length"
                                } else {
                                    "an angle"
                                }
                            ),
                        ));
                    }
                }
                Some(parsed)
            }
            None => None,
        };
        fields.push(Some((k, unit)));
    }
    for required in ["a", "alpha", "d", "theta"] {
        let k = COLUMNS
            .iter()
            .position(|(n, _)| *n == required)
            .unwrap_or(0);
        if !fields.iter().flatten().any(|(j, _)| *j == k) {
            return Err(invalid(
                path,
                header_line,
                1,
                format!(
                    "the table has no `{required}` column (a DH table needs a, alpha, d, theta)"
                ),
            ));
        }
    }
    let mm = Unit::parse("mm").map_err(|e| invalid(path, header_line, 1, e.to_string()))?;
    let deg = Unit::parse("deg").map_err(|e| invalid(path, header_line, 1, e.to_string()))?;
    let mut rows: Vec<Row> = Vec::new();
    for (line, text) in lines {
        let cells = split(text);
        if cells.len() != fields.len() {
            return Err(invalid(
                path,
                line,
                1,
                format!(
                    "{} cells, but the header has {} columns",
                    cells.len(),
                    fields.len()
                ),
            ));
        }
        let mut row = Row {
            name: format!("J{}", rows.len() + 1),
            kind: Kind::Revolute,
            a: 0.0,
            alpha: 0.0,
            d: 0.0,
            theta: 0.0,
            beta: 0.0,
            limits: None,
        };
        let mut lower = None;
        let mut upper = None;
        for ((column, cell), field) in cells.iter().zip(&fields) {
            let Some((k, unit)) = field else { continue };
            let name = COLUMNS.get(*k).map(|c| c.0).unwrap_or("");
            match name {
                "joint" => {
                    let ok = !cell.is_empty()
                        && cell
                            .chars()
                            .next()
                            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                        && cell.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
                    if !ok {
                        return Err(invalid(path, line, *column, format!("joint name `{cell}`: letters, digits and `_`, starting with a letter")));
                    }
                    row.name = cell.clone();
                }
                "type" => {
                    row.kind = match cell.to_lowercase().as_str() {
                        "" | "revolute" | "r" => Kind::Revolute,
                        "prismatic" | "p" => Kind::Prismatic,
                        "fixed" => Kind::Fixed,
                        _ => {
                            return Err(invalid(
                                path,
                                line,
                                *column,
                                format!("type `{cell}`: revolute, prismatic or fixed"),
                            ))
                        }
                    }
                }
                // An empty limit is no limit (a continuous joint, a tool row).
                "lower" | "upper" if cell.is_empty() => {}
                _ => {
                    let v: f64 = match cell.parse::<f64>() {
                        Ok(v) if v.is_finite() => v,
                        _ => {
                            return Err(invalid(
                                path,
                                line,
                                *column,
                                format!("`{cell}` is not a finite number"),
                            ))
                        }
                    };
                    let of = |default: &Unit| unit.as_ref().unwrap_or(default).to_si(v);
                    match name {
                        "a" => row.a = of(&mm),
                        "alpha" => row.alpha = of(&deg),
                        "d" => row.d = of(&mm),
                        "theta" => row.theta = of(&deg),
                        "beta" => row.beta = of(&deg),
                        "lower" => lower = Some((v, unit.clone(), *column)),
                        _ => upper = Some((v, unit.clone(), *column)),
                    }
                    if (name == "a" || name == "d") && row_abs(&row, name) > 1e4 {
                        return Err(invalid(
                            path,
                            line,
                            *column,
                            format!("`{name}` = {cell} is beyond any robot (10 km)"),
                        ));
                    }
                }
            }
        }
        // Limits are angles for a revolute joint, lengths for a prismatic one.
        let limit = |l: Option<(f64, Option<Unit>, u32)>| -> Result<Option<f64>, UrdfError> {
            let Some((v, unit, column)) = l else {
                return Ok(None);
            };
            let default = if row.kind == Kind::Prismatic {
                &mm
            } else {
                &deg
            };
            let unit = unit.as_ref().unwrap_or(default);
            if unit.dim != default.dim {
                return Err(invalid(path, line, column, "a limit has the joint's dimension: an angle for a revolute joint, a length for a prismatic one"));
            }
            Ok(Some(unit.to_si(v)))
        };
        row.limits = match (limit(lower)?, limit(upper)?) {
            (Some(lo), Some(hi)) if lo < hi => Some((lo, hi)),
            (None, None) => None,
            _ => {
                return Err(invalid(
                    path,
                    line,
                    1,
                    "give both limits, lower below upper, or neither",
                ))
            }
        };
        if row.kind == Kind::Prismatic && row.limits.is_none() {
            return Err(invalid(
                path,
                line,
                1,
                "a prismatic joint needs its limits (lower and upper)",
            ));
        }
        if rows.iter().any(|r| r.kind == Kind::Fixed) {
            return Err(invalid(
                path,
                line,
                1,
                "only the last row may be `fixed` (the flange or tool)",
            ));
        }
        if rows.iter().any(|r| r.name == row.name) {
            return Err(invalid(
                path,
                line,
                1,
                format!("joint `{}` is named twice", row.name),
            ));
        }
        rows.push(row);
    }
    let joints = rows.iter().filter(|r| r.kind != Kind::Fixed).count();
    if joints == 0 {
        return Err(invalid(path, header_line, 1, "the table has no joint"));
    }
    if joints > urdf::MAX_JOINTS {
        return Err(invalid(
            path,
            header_line,
            1,
            format!(
                "{joints} joints: kin imports chains of at most {}",
                urdf::MAX_JOINTS
            ),
        ));
    }
    Ok(rows)
}

fn row_abs(row: &Row, name: &str) -> f64 {
    if name == "a" {
        row.a.abs()
    } else {
        row.d.abs()
    }
}

fn rz(t: f64) -> Matrix4<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), t).to_homogeneous()
}

fn rx(t: f64) -> Matrix4<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), t).to_homogeneous()
}

fn ry(t: f64) -> Matrix4<f64> {
    Rotation3::from_axis_angle(&Vector3::y_axis(), t).to_homogeneous()
}

/// The frames a table's comment lines may state (what `kin export dh` writes): `# base [mm,
/// deg]: x y z roll pitch yaw`, the base → frame 0, and `# tool NAME [mm, deg]: …`, frame n →
/// tool, in mm and degrees (URDF's fixed-axis roll, pitch, yaw).
struct Frames {
    base: Matrix4<f64>,
    tools: Vec<(String, Matrix4<f64>)>,
}

fn read_frames(text: &str, path: &Path) -> Result<Frames, UrdfError> {
    let mut frames = Frames {
        base: Matrix4::identity(),
        tools: Vec::new(),
    };
    for (i, l) in text.lines().enumerate() {
        let line = u32::try_from(i + 1).unwrap_or(u32::MAX);
        let Some(comment) = l.trim().strip_prefix('#') else {
            continue;
        };
        let Some((key, values)) = comment.split_once(':') else {
            continue;
        };
        let key = key.trim();
        let Some(key) = key.strip_suffix("[mm, deg]").map(str::trim) else {
            continue;
        };
        let tool = match key.split_once(char::is_whitespace) {
            Some(("tool", name)) => Some(name.trim()),
            None if key == "base" => None,
            _ => continue,
        };
        let numbers: Vec<f64> = values
            .split_whitespace()
            .map(|v| v.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .filter(|v: &Vec<f64>| v.len() == 6)
            .ok_or_else(|| {
                invalid(
                    path,
                    line,
                    1,
                    "a frame is six finite numbers: x y z in mm, roll pitch yaw in deg",
                )
            })?;
        if numbers[..3].iter().any(|v| v.abs() > 1e7) {
            return Err(invalid(
                path,
                line,
                1,
                "a frame's offset is beyond any robot (10 km)",
            ));
        }
        let t = trans(numbers[0] * 1e-3, numbers[1] * 1e-3, numbers[2] * 1e-3)
            * Rotation3::from_euler_angles(
                numbers[3].to_radians(),
                numbers[4].to_radians(),
                numbers[5].to_radians(),
            )
            .to_homogeneous();
        match tool {
            None => frames.base = t,
            Some(name) => {
                let ok = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
                    && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
                if !ok || frames.tools.iter().any(|(n, _)| n == name) {
                    return Err(invalid(
                        path,
                        line,
                        1,
                        format!("tool `{name}`: a new name of letters, digits and `_`"),
                    ));
                }
                frames.tools.push((name.to_string(), t));
            }
        }
    }
    Ok(frames)
}

fn trans(x: f64, y: f64, z: f64) -> Matrix4<f64> {
    Matrix4::new_translation(&Vector3::new(x, y, z))
}

/// The table as a URDF chain: joint i's origin is every fixed transform since joint i−1's
/// motion, its axis z; the fixed remainder after the last joint is a fixed joint to `flange`.
fn as_urdf(rows: &[Row], convention: Convention, name: &str, frames: &Frames) -> String {
    let mut xml = format!("<robot name=\"{name}\">\n  <link name=\"base\"/>\n");
    let mut pending = frames.base;
    let mut parent = "base".to_string();
    for row in rows {
        match convention {
            // Rz(θ + q) Tz(d) Tx(a) Rx(α): the motion right after Rz(θ), the rest after it.
            Convention::Standard => {
                let origin = pending * rz(row.theta);
                let after =
                    trans(0.0, 0.0, row.d) * trans(row.a, 0.0, 0.0) * rx(row.alpha) * ry(row.beta);
                if row.kind == Kind::Fixed {
                    pending = origin * after;
                    break;
                }
                joint(&mut xml, row, &parent, &origin);
                parent = format!("{}_link", row.name);
                pending = after;
            }
            // Rx(α) Tx(a) Rz(θ + q) Tz(d): Rz(q) commutes with Tz(d), so the motion ends it.
            Convention::Modified => {
                let origin = pending
                    * rx(row.alpha)
                    * trans(row.a, 0.0, 0.0)
                    * rz(row.theta)
                    * trans(0.0, 0.0, row.d);
                if row.kind == Kind::Fixed {
                    pending = origin;
                    break;
                }
                joint(&mut xml, row, &parent, &origin);
                parent = format!("{}_link", row.name);
                pending = Matrix4::identity();
            }
        }
    }
    let flange = [("flange".to_string(), Matrix4::identity())];
    let tools = if frames.tools.is_empty() {
        &flange[..]
    } else {
        &frames.tools[..]
    };
    for (tool, t) in tools {
        xml.push_str(&format!("  <link name=\"{tool}\"/>\n"));
        xml.push_str(&format!(
            "  <joint name=\"{tool}_joint\" type=\"fixed\">\n    <parent link=\"{parent}\"/>\n    <child link=\"{tool}\"/>\n{}  </joint>\n",
            origin_text(&(pending * t)).unwrap_or_default()
        ));
    }
    xml.push_str("</robot>\n");
    xml
}

fn joint(xml: &mut String, row: &Row, parent: &str, origin: &Matrix4<f64>) {
    let kind = match (row.kind, row.limits) {
        (Kind::Prismatic, _) => "prismatic",
        (_, None) => "continuous",
        _ => "revolute",
    };
    xml.push_str(&format!(
        "  <link name=\"{n}_link\"/>\n  <joint name=\"{n}\" type=\"{kind}\">\n    <parent link=\"{parent}\"/>\n    <child link=\"{n}_link\"/>\n{}    <axis xyz=\"0 0 1\"/>\n",
        origin_text(origin).unwrap_or_default(),
        n = row.name
    ));
    if let Some((lo, hi)) = row.limits {
        xml.push_str(&format!(
            "    <limit lower=\"{lo}\" upper=\"{hi}\" effort=\"0\" velocity=\"0\"/>\n"
        ));
    }
    xml.push_str("  </joint>\n");
}
