//! DH export: a calibrated serial robot as a standard Denavit–Hartenberg table with Hayati's
//! angle for nearly parallel joints, and its base and tool frames (`kin export dh`, spec/urdf.md
//! "Export").
//!
//! The chain is the one the URDF export writes (every constant error folded into rigid
//! transforms, [`crate::urdf::calibrated`]). At q = 0 each joint's motion is about (or along) a
//! line in the base: its point and direction. A DH table is that sequence of lines, each frame's
//! z on the next joint's line, written link by link as
//!
//! `A_i = Rz(θ_i + q_i) · Tz(d_i) · Tx(a_i) · Rx(α_i) · Ry(β_i)`
//!
//! (a prismatic joint adds q_i to d_i). Between lines that are not nearly parallel, x_i lies on
//! their common normal, `z_{i−1} × z_i`, and β_i = 0: the standard convention. Between nearly
//! parallel lines the common normal runs off to infinity (a calibrated tilt of microradians
//! between two parallel shoulder joints puts it kilometres away, and d with it): there, after
//! Hayati and Mirmirani (1985), d_i = 0, frame i's origin is where line i meets the plane of x_{i−1}
//! and y_{i−1}, and the small tilt is β_i about y. Every A_i turns about its own line, as the
//! joint does, so the table's forward kinematics equal the calibrated chain's at every q —
//! the base frame (base → frame 0) and each tool's frame (frame n → tool) carry what a DH
//! table cannot (a robot's mounting, its flange and tool offsets).

use kin_compiler::ir::{JointKind, Machine};
use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};
use thiserror::Error;

use crate::urdf::{self, CalibratedJoint, ExportError};

/// Consecutive joint lines closer to parallel than this (rad) are written with Hayati's β.
/// Beyond it the standard form's d stays within the lines' distance over sin(1°), some 60 times
/// their gap; below it the common normal's foot moves with the tilt and d would carry it.
pub const PARALLEL: f64 = 1.0 * std::f64::consts::PI / 180.0;

#[derive(Debug, Error)]
pub enum DhExportError {
    #[error(transparent)]
    Chain(#[from] ExportError),
    #[error(
        "the workpiece chain moves ({0}): a DH table describes one serial chain; export the URDF \
         (`kin export urdf`) for a robot with a positioner"
    )]
    WorkpieceMoves(String),
    #[error("the machine's tool chain has no joint")]
    NoJoint,
    #[error("a folded transform is not finite (a coefficient far too large): {0}")]
    NotFinite(String),
}

/// One row of the table (SI), joint i.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub name: String,
    pub kind: JointKind,
    pub theta: f64,
    pub d: f64,
    pub a: f64,
    pub alpha: f64,
    /// Hayati's tilt about y, non-zero only between nearly parallel joints (then d = 0).
    pub beta: f64,
    /// The joint's limits; `None` for a continuous joint.
    pub limits: Option<[f64; 2]>,
}

/// A calibrated robot as a DH table.
#[derive(Debug, Clone)]
pub struct Table {
    pub rows: Vec<Row>,
    /// The world → frame 0 (whose z is the first joint's line). The world is kin's workpiece
    /// frame, where the tool's location is measured: a robot's base errors are in it.
    pub base: Matrix4<f64>,
    /// Each tool: frame n (after the last joint's motion) → the tool.
    pub tools: Vec<(String, Matrix4<f64>)>,
    pub folded: usize,
    pub left_out: Vec<String>,
}

/// A line of motion at q = 0: a point and a unit direction, in the base.
struct Line {
    point: Vector3<f64>,
    dir: Vector3<f64>,
}

fn rotation(t: &Matrix4<f64>) -> Matrix3<f64> {
    t.fixed_view::<3, 3>(0, 0).into_owned()
}

fn translation(t: &Matrix4<f64>) -> Vector3<f64> {
    t.fixed_view::<3, 1>(0, 3).into_owned()
}

fn frame(x: Vector3<f64>, z: Vector3<f64>, origin: Vector3<f64>) -> Matrix4<f64> {
    let y = z.cross(&x);
    let mut t = Matrix4::identity();
    t.fixed_view_mut::<3, 1>(0, 0).copy_from(&x);
    t.fixed_view_mut::<3, 1>(0, 1).copy_from(&y);
    t.fixed_view_mut::<3, 1>(0, 2).copy_from(&z);
    t.fixed_view_mut::<3, 1>(0, 3).copy_from(&origin);
    t
}

/// The inverse of a rigid transform.
fn inverse(t: &Matrix4<f64>) -> Matrix4<f64> {
    let r = rotation(t).transpose();
    let p = -(r * translation(t));
    let mut out = Matrix4::identity();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    out.fixed_view_mut::<3, 1>(0, 3).copy_from(&p);
    out
}

/// The signed angle from `from` to `to` about `axis` (all unit, both normal to `axis`).
fn angle_about(from: &Vector3<f64>, to: &Vector3<f64>, axis: &Vector3<f64>) -> f64 {
    from.cross(to).dot(axis).atan2(from.dot(to))
}

/// `A_i` of a row at joint value `q` (the convention of this module's header).
pub fn link(row: &Row, q: f64) -> Matrix4<f64> {
    let (theta, d) = match row.kind {
        JointKind::Revolute => (row.theta + q, row.d),
        JointKind::Prismatic => (row.theta, row.d + q),
    };
    Rotation3::from_axis_angle(&Vector3::z_axis(), theta).to_homogeneous()
        * Matrix4::new_translation(&Vector3::new(row.a, 0.0, d))
        * Rotation3::from_axis_angle(&Vector3::x_axis(), row.alpha).to_homogeneous()
        * Rotation3::from_axis_angle(&Vector3::y_axis(), row.beta).to_homogeneous()
}

/// The calibrated tool chain of `m` (its bound β) as a DH table.
pub fn export(m: &Machine) -> Result<Table, DhExportError> {
    let c = urdf::calibrated(m)?;
    if let Some(j) = c.workpiece_chain.first() {
        return Err(DhExportError::WorkpieceMoves(j.name.clone()));
    }
    if c.tool_chain.is_empty() {
        return Err(DhExportError::NoJoint);
    }
    // Each joint's frame at q = 0 in the base, and its line of motion.
    let mut at = Matrix4::<f64>::identity();
    let mut lines = Vec::with_capacity(c.tool_chain.len());
    for j in &c.tool_chain {
        at *= j.origin;
        let dir = rotation(&at) * Vector3::from(j.axis).normalize();
        lines.push(Line {
            point: translation(&at),
            dir,
        });
    }
    let last = at;
    // Frame 0: z on the first line, x the base's x made normal to it (or y when x is the line).
    let first = &lines[0];
    let seed = if first.dir.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let x0 = (seed - first.dir * first.dir.dot(&seed)).normalize();
    let base = frame(x0, first.dir, first.point);
    let mut frames = vec![base];
    let mut rows = Vec::with_capacity(c.tool_chain.len());
    for (i, joint) in c.tool_chain.iter().enumerate() {
        let prev = frames[i];
        let (x_prev, z_prev, o_prev) = (
            rotation(&prev).column(0).into_owned(),
            rotation(&prev).column(2).into_owned(),
            translation(&prev),
        );
        let row = match lines.get(i + 1) {
            Some(next) => to_next_line(joint, &x_prev, &z_prev, &o_prev, next),
            // The last frame: the joint's motion alone (the tools' frames carry the rest).
            None => Row::motion(joint),
        };
        frames.push(prev * link(&row, 0.0));
        rows.push(row);
    }
    let end = frames.last().copied().unwrap_or(base);
    let to_end = inverse(&end) * last;
    let tools = c
        .tools
        .iter()
        .map(|(name, t)| (name.clone(), to_end * t))
        .collect::<Vec<_>>();
    // kin locates the tool relative to the workpiece (the world of the measurements).
    let base = inverse(&c.workpiece) * base;
    let finite = |t: &Matrix4<f64>| t.iter().all(|v| v.is_finite());
    if !finite(&base) || !tools.iter().all(|(_, t)| finite(t)) {
        return Err(DhExportError::NotFinite("the base or a tool frame".into()));
    }
    if let Some(r) = rows.iter().find(|r| {
        ![r.theta, r.d, r.a, r.alpha, r.beta]
            .iter()
            .all(|v| v.is_finite())
    }) {
        return Err(DhExportError::NotFinite(r.name.clone()));
    }
    Ok(Table {
        rows,
        base,
        tools,
        folded: c.folded,
        left_out: c.left_out,
    })
}

impl Row {
    /// The joint's motion alone (every parameter 0), with its name, kind and limits.
    fn motion(j: &CalibratedJoint) -> Row {
        Row {
            name: j.name.clone(),
            kind: j.kind,
            theta: 0.0,
            d: 0.0,
            a: 0.0,
            alpha: 0.0,
            beta: 0.0,
            limits: (!j.continuous).then_some(j.range),
        }
    }
}

/// The row of joint i: from frame i−1 (x_prev, z_prev on joint i's line, origin o_prev) to
/// frame i with z on `next`, joint i+1's line.
fn to_next_line(
    joint: &CalibratedJoint,
    x_prev: &Vector3<f64>,
    z_prev: &Vector3<f64>,
    o_prev: &Vector3<f64>,
    next: &Line,
) -> Row {
    let z = next.dir;
    let normal = z_prev.cross(&z);
    let sin = normal.norm();
    let mut row = Row::motion(joint);
    // Parallel or antiparallel within PARALLEL: the sine of the angle between the lines.
    if sin > PARALLEL.sin() {
        // The common normal: x along z_{i−1} × z_i; its feet on both lines.
        let x = normal / sin;
        let w = next.point - o_prev;
        // Feet: o_prev + s z_prev and next.point + t z, with (feet difference) ∥ x.
        let b = z_prev.dot(&z);
        let (dp, dq) = (z_prev.dot(&w), z.dot(&w));
        let denom = 1.0 - b * b;
        let s = (dp - b * dq) / denom;
        let t = (b * dp - dq) / denom;
        let foot_prev = o_prev + z_prev * s;
        let foot = next.point + z * t;
        row.d = s;
        row.a = (foot - foot_prev).dot(&x);
        row.theta = angle_about(x_prev, &x, z_prev);
        row.alpha = angle_about(z_prev, &z, &x);
    } else {
        // Hayati: where line i+1 meets the plane of x_{i−1}, y_{i−1} through o_prev.
        let along = z.dot(z_prev);
        let t = (o_prev - next.point).dot(z_prev) / along;
        let origin = next.point + z * t;
        let v = origin - o_prev;
        let a = v.norm();
        let x1 = if a > 1e-15 { v / a } else { *x_prev };
        row.a = a;
        row.theta = angle_about(x_prev, &x1, z_prev);
        // z_i in the frame (x1, y1, z_prev): Rx(α)·Ry(β)·e_z = (sin β, −sin α cos β, cos α cos β).
        let y1 = z_prev.cross(&x1);
        let (tx, ty, tz) = (z.dot(&x1), z.dot(&y1), z.dot(z_prev));
        row.beta = tx.clamp(-1.0, 1.0).asin();
        row.alpha = (-ty).atan2(tz);
    }
    row
}

/// `x y z roll pitch yaw` of a rigid transform in mm and degrees (URDF's fixed-axis angles,
/// `R = Rz(yaw)·Ry(pitch)·Rx(roll)`), each number to 10⁻⁹ of its unit.
pub(crate) fn pose_text(t: &Matrix4<f64>) -> String {
    let r = Rotation3::from_matrix_unchecked(rotation(t));
    let (roll, pitch, yaw) = r.euler_angles();
    let p = translation(t) * 1e3;
    [
        p.x,
        p.y,
        p.z,
        roll.to_degrees(),
        pitch.to_degrees(),
        yaw.to_degrees(),
    ]
    .map(number)
    .join(" ")
}

/// A value in mm or degrees to 10⁻⁹ of its unit (a picometre, 17 prad): what rounding leaves
/// below that (`1.1e-14`, `115.70000000000002`) is noise a reader should not have to parse.
fn number(v: f64) -> String {
    let r = (v * 1e9).round() / 1e9;
    // `+ 0.0` writes a negative zero as 0.
    format!("{}", if r.is_finite() { r } else { v } + 0.0)
}

/// The table as a CSV `kin import dh` reads back: comment lines stating the convention, what was
/// folded and left out, then the base and tool frames (`# base [mm, deg]: x y z roll pitch
/// yaw`, `# tool NAME [mm, deg]: …`), then a row per joint.
pub fn text(table: &Table, machine: &str) -> String {
    let mut out =
        format!(
        "# Written by kin export dh from machine `{machine}`: the calibrated robot as a standard \
         Denavit-Hartenberg table, link i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) \
         Ry(beta_i) (d_i + q_i for a prismatic joint); beta is Hayati's tilt, used only between \
         joints within 1 deg of parallel (there d = 0).\n\
         # {} constant coefficients folded; {}.\n\
         # The base frame (world -> frame 0, whose z is the first joint's axis; the world is the \
         frame the tool is measured in, kin's workpiece) and each tool's frame (frame n -> tool), \
         as x y z in mm and roll pitch yaw in deg (URDF's fixed axes):\n",
        table.folded,
        if table.left_out.is_empty() {
            "no term varies with the pose".to_string()
        } else {
            format!("left out as varying with the pose: {}", table.left_out.join(", "))
        }
    );
    out.push_str(&format!("# base [mm, deg]: {}\n", pose_text(&table.base)));
    for (name, t) in &table.tools {
        out.push_str(&format!("# tool {name} [mm, deg]: {}\n", pose_text(t)));
    }
    out.push_str("joint,type,a[mm],alpha[deg],d[mm],theta[deg],beta[deg],lower,upper\n");
    for r in &table.rows {
        let (kind, limit) = match r.kind {
            JointKind::Revolute => ("revolute", 180.0 / std::f64::consts::PI),
            JointKind::Prismatic => ("prismatic", 1e3),
        };
        let (lower, upper) = match r.limits {
            Some([lo, hi]) => (number(lo * limit), number(hi * limit)),
            None => (String::new(), String::new()),
        };
        let v = number;
        out.push_str(&format!(
            "{},{kind},{},{},{},{},{},{lower},{upper}\n",
            r.name,
            v(r.a * 1e3),
            v(r.alpha.to_degrees()),
            v(r.d * 1e3),
            v(r.theta.to_degrees()),
            v(r.beta.to_degrees()),
        ));
    }
    out
}
