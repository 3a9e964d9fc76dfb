//! The first-order kinematic model (thesis §2.3, eq. 2.15–2.28 with the shape/joint split of
//! eq. 2.35–2.38): for one pose, the 6×6 matrices `F_k` that map the parametric errors of every
//! frame to the error of the tool frame `tl` relative to the workpiece reference `wr`.
//!
//! # Conventions (spec/kinematics.md)
//!
//! * Every 6-vector is ordered translations first: a frame's parametric errors are
//!   `(tx, ty, tz, rx, ry, rz)` in the frame's own axes, and a tool-location error is
//!   `(ex, ey, ez, erx, ery, erz)`. The thesis (eq. 2.25/2.26) puts rotations first; here the
//!   blocks are swapped so that both vectors index like [`Component`].
//! * The tool-location error is as spec/kinematics.md defines it: position error = translation of the actual
//!   `T(wr→tl)` minus the nominal one, in *wr* axes; rotation error `r` in *wr* axes with
//!   `R_act ≈ (I + [r]×) R_nom`. The thesis expresses `wr E_tl` in the nominal *tl* axes
//!   (eq. 2.11/2.12); its closing remark under eq. 2.28 says that premultiplying both blocks of
//!   `tl F_k` by `wr R_tl` moves them to another frame, which is what is done here.
//! * Errors are *positioning* errors (actual − nominal); [`Task::sign`] turns them into the
//!   reported error of a measuring machine.
//!
//! # Derivation of `F_k` in wr axes
//!
//! Write the nominal location as `T(wr→tl) = M · N` with `M = T(wr→k)` (rotation `R`, origin
//! `p_k`) and `N = T(k→tl)` (tool origin `t` in frame-k axes). An error of frame k inserts
//! `I + δ` between them (eq. 2.9), `δ = [[e]×, d; 0, 0]` in frame-k axes, so to first order
//! the actual location is `M N + M δ N`:
//!
//! * rotation part: `R [e]× R(k→tl) = [R e]× R_nom`, so `Δr = R e`;
//! * translation part: `R (e × t + d)`, so `Δp = R d + (R e) × a`, with `a = R t = p_tl − p_k`
//!   the Abbe arm from the origin of frame k to the tool, in wr axes.
//!
//! Hence `F_k = [[R, −[a]× R], [0, R]]`, which is eq. 2.27/2.28 premultiplied by `wr R_tl`. For
//! the workpiece chain `T(0→wr)` is inverted, so `(I + δ)` becomes `(I − δ)` and the same
//! matrix enters with a minus sign (eq. 2.15/2.24), where `M = T(wr→bk) = T(0→wr)⁻¹ T(0→bk)`.
//! The end frames are the special cases `tl` (`M = T(wr→tl)`, `a = 0`: errors are merely
//! rotated to wr axes) and `wr` (`M = I`, `a` = tool position in wr, minus sign).
//!
//! # Nominal chain
//!
//! The moving/fixed rule (eq. 2.35–2.38) only decides on which side of the joint motion `J_k`
//! frame k sits: the product of a chain from the base is always `S_1 J_1 S_2 J_2 … S_n J_n S_end`,
//! and frame k is located at `G_{k-1} S_k J_k` when moving and at `G_{k-1} S_k` when fixed,
//! with `G_k = S_1 J_1 … S_k J_k`. (The exact simulator in [`crate::exact`] applies the table
//! literally; the agreement tests check the two against each other.)

use std::fmt;

use kin_compiler::ir::{Component, FrameKind, FrameRef, JointKind, Machine, Shape, Task};
use nalgebra::{Matrix3, Matrix4, Matrix6, Vector3, Vector6};
use thiserror::Error;

/// Which serial chain an element belongs to, for error messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chain {
    Tool,
    Workpiece,
}

impl fmt::Display for Chain {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Chain::Tool => "tool",
            Chain::Workpiece => "workpiece",
        })
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum KinematicsError {
    #[error("the pose gives {got} joint positions but the machine has {expected} axes")]
    JointCount { expected: usize, got: usize },
    #[error("tool {index} does not exist: the machine has {count} tools")]
    ToolIndex { index: usize, count: usize },
    #[error("the machine has no tool")]
    NoTool,
    #[error(
        "element {element} of the {chain} chain uses axis {axis}, but the machine has {count} axes"
    )]
    AxisIndex {
        chain: Chain,
        element: usize,
        axis: usize,
        count: usize,
    },
    #[error("the {chain} chain has {expected} elements but {got} error vectors were given")]
    ErrorCount {
        chain: Chain,
        expected: usize,
        got: usize,
    },
    #[error("the output buffer holds {got} entries but {expected} are needed")]
    BufferSize { expected: usize, got: usize },
    #[error("the two ends of a length observation have the same nominal position")]
    ZeroLength,
}

/// One pose of the machine: what the first-order model and the exact simulator evaluate.
#[derive(Debug, Clone, Copy)]
pub struct Pose<'a> {
    /// Joint positions indexed like `Machine::axes`, in m or rad.
    pub q: &'a [f64],
    /// Index into `Machine::tools`.
    pub tool: usize,
    /// Replaces the translation of the selected tool's offset (spec/data.md `tool_x/y/z`).
    pub tool_offset: Option<[f64; 3]>,
}

/// The parametric errors of every frame at one pose, `(tx, ty, tz, rx, ry, rz)` in the frame's
/// own axes (spec/kinematics.md), in m and rad.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameErrors {
    pub tool_chain: Vec<[f64; 6]>,
    pub workpiece_chain: Vec<[f64; 6]>,
    /// Errors of the selected tool's frame `tl`: the caller adds the `ToolEnd(None)` and
    /// `ToolEnd(Some(tool))` contributions.
    pub tool_end: [f64; 6],
    /// Errors of the workpiece reference frame `wr`.
    pub workpiece_end: [f64; 6],
}

impl FrameErrors {
    /// All errors zero, sized for `machine`.
    pub fn zeros(machine: &Machine) -> Self {
        FrameErrors {
            tool_chain: vec![[0.0; 6]; machine.tool_chain.len()],
            workpiece_chain: vec![[0.0; 6]; machine.workpiece_chain.len()],
            tool_end: [0.0; 6],
            workpiece_end: [0.0; 6],
        }
    }

    /// The error vector of `frame`; every `ToolEnd` maps to the one `tool_end` slot because
    /// only the selected tool's frame exists in a pose.
    pub fn get(&self, frame: FrameRef) -> Option<&[f64; 6]> {
        match frame {
            FrameRef::Tool(k) => self.tool_chain.get(k),
            FrameRef::Workpiece(k) => self.workpiece_chain.get(k),
            FrameRef::ToolEnd(_) => Some(&self.tool_end),
            FrameRef::WorkpieceEnd => Some(&self.workpiece_end),
        }
    }

    /// Mutable access with the same mapping as [`FrameErrors::get`].
    pub fn get_mut(&mut self, frame: FrameRef) -> Option<&mut [f64; 6]> {
        match frame {
            FrameRef::Tool(k) => self.tool_chain.get_mut(k),
            FrameRef::Workpiece(k) => self.workpiece_chain.get_mut(k),
            FrameRef::ToolEnd(_) => Some(&mut self.tool_end),
            FrameRef::WorkpieceEnd => Some(&mut self.workpiece_end),
        }
    }

    /// Checks that the chains have one error vector per element of `machine`.
    pub fn check(&self, machine: &Machine) -> Result<(), KinematicsError> {
        check_count(Chain::Tool, machine.tool_chain.len(), self.tool_chain.len())?;
        check_count(
            Chain::Workpiece,
            machine.workpiece_chain.len(),
            self.workpiece_chain.len(),
        )
    }
}

fn check_count(chain: Chain, expected: usize, got: usize) -> Result<(), KinematicsError> {
    if expected == got {
        Ok(())
    } else {
        Err(KinematicsError::ErrorCount {
            chain,
            expected,
            got,
        })
    }
}

/// Checks a pose against a machine; shared with the exact simulator so both reject alike.
pub(crate) fn check_pose(machine: &Machine, pose: &Pose<'_>) -> Result<(), KinematicsError> {
    if pose.q.len() != machine.axes.len() {
        return Err(KinematicsError::JointCount {
            expected: machine.axes.len(),
            got: pose.q.len(),
        });
    }
    if pose.tool >= machine.tools.len() {
        return Err(KinematicsError::ToolIndex {
            index: pose.tool,
            count: machine.tools.len(),
        });
    }
    Ok(())
}

/// The nominal location of the tool frame `tl` in the workpiece reference frame `wr`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolLocation {
    /// Origin of `tl` in wr coordinates.
    pub position: Vector3<f64>,
    /// `R(wr→tl)`: its columns are the axes of `tl` in wr coordinates.
    pub rotation: Matrix3<f64>,
}

impl ToolLocation {
    /// The homogeneous transform `T(wr→tl)` (eq. 2.2).
    pub(crate) fn to_matrix(self) -> Matrix4<f64> {
        let mut t = Matrix4::identity();
        t.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation);
        t.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.position);
        t
    }
}

/// A chain element with its constant parts evaluated once.
#[derive(Debug, Clone)]
struct Link {
    axis: usize,
    kind: JointKind,
    direction: Vector3<f64>,
    frame: FrameKind,
    shape: Rigid,
}

/// A rigid transform kept as its rotation block and translation column: half the work of a
/// 4×4 product, and the bottom row of a homogeneous transform (eq. 2.2) is never needed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rigid {
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
}

impl Rigid {
    const IDENTITY: Rigid = Rigid {
        rotation: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        translation: Vector3::new(0.0, 0.0, 0.0),
    };

    /// `self · other` in homogeneous form.
    fn then(&self, other: &Rigid) -> Rigid {
        Rigid {
            rotation: self.rotation * other.rotation,
            translation: self.translation + self.rotation * other.translation,
        }
    }
}

/// A machine prepared for the first-order model: shape transforms evaluated once so that the
/// per-pose pass does only joint trigonometry and matrix products.
#[derive(Debug, Clone)]
pub struct FirstOrderModel {
    axes: usize,
    tool_chain: Vec<Link>,
    workpiece_chain: Vec<Link>,
    tools: Vec<Rigid>,
    workpiece: Rigid,
}

/// The per-pose output of [`FirstOrderModel::evaluate`]: the F-matrices of every frame and the
/// nominal tool location. Allocate once with [`FirstOrderModel::sensitivities`] and reuse.
#[derive(Debug, Clone)]
pub struct Sensitivities {
    tool_chain: Vec<Matrix6<f64>>,
    workpiece_chain: Vec<Matrix6<f64>>,
    tool_end: Matrix6<f64>,
    workpiece_end: Matrix6<f64>,
    tool: usize,
    location: ToolLocation,
    /// Scratch: base-frame locations of the chain frames, kept here so a pose allocates nothing.
    tool_frames: Vec<Rigid>,
    workpiece_frames: Vec<Rigid>,
}

impl FirstOrderModel {
    /// Prepares `machine`, checking the indices the per-pose pass relies on.
    pub fn new(machine: &Machine) -> Result<Self, KinematicsError> {
        if machine.tools.is_empty() {
            return Err(KinematicsError::NoTool);
        }
        let links = |chain: Chain, elements: &[kin_compiler::ir::Element]| {
            elements
                .iter()
                .enumerate()
                .map(|(k, e)| {
                    let axis = machine.axes.get(e.axis).ok_or(KinematicsError::AxisIndex {
                        chain,
                        element: k,
                        axis: e.axis,
                        count: machine.axes.len(),
                    })?;
                    Ok(Link {
                        axis: e.axis,
                        kind: axis.kind,
                        direction: Vector3::from(axis.direction),
                        frame: e.frame,
                        shape: shape_transform(&e.shape),
                    })
                })
                .collect::<Result<Vec<_>, KinematicsError>>()
        };
        Ok(FirstOrderModel {
            axes: machine.axes.len(),
            tool_chain: links(Chain::Tool, &machine.tool_chain)?,
            workpiece_chain: links(Chain::Workpiece, &machine.workpiece_chain)?,
            tools: machine
                .tools
                .iter()
                .map(|t| shape_transform(&t.offset))
                .collect(),
            workpiece: shape_transform(&machine.workpiece),
        })
    }

    /// An output buffer sized for this machine.
    pub fn sensitivities(&self) -> Sensitivities {
        Sensitivities {
            tool_chain: vec![Matrix6::zeros(); self.tool_chain.len()],
            workpiece_chain: vec![Matrix6::zeros(); self.workpiece_chain.len()],
            tool_end: Matrix6::zeros(),
            workpiece_end: Matrix6::zeros(),
            tool: 0,
            location: ToolLocation {
                position: Vector3::zeros(),
                rotation: Matrix3::identity(),
            },
            tool_frames: vec![Rigid::IDENTITY; self.tool_chain.len()],
            workpiece_frames: vec![Rigid::IDENTITY; self.workpiece_chain.len()],
        }
    }

    fn check(&self, pose: &Pose<'_>) -> Result<(), KinematicsError> {
        if pose.q.len() != self.axes {
            return Err(KinematicsError::JointCount {
                expected: self.axes,
                got: pose.q.len(),
            });
        }
        if pose.tool >= self.tools.len() {
            return Err(KinematicsError::ToolIndex {
                index: pose.tool,
                count: self.tools.len(),
            });
        }
        Ok(())
    }

    fn tool_shape(&self, pose: &Pose<'_>) -> Result<Rigid, KinematicsError> {
        let mut shape = *self
            .tools
            .get(pose.tool)
            .ok_or(KinematicsError::ToolIndex {
                index: pose.tool,
                count: self.tools.len(),
            })?;
        if let Some(t) = pose.tool_offset {
            // S_tl = Trans(t)·R, so overriding t leaves the rotation block as declared.
            shape.translation = Vector3::from(t);
        }
        Ok(shape)
    }

    /// Computes the F-matrices of every frame and the nominal tool location for `pose` into
    /// `out`, without allocating.
    pub fn evaluate(
        &self,
        pose: &Pose<'_>,
        out: &mut Sensitivities,
    ) -> Result<(), KinematicsError> {
        self.check(pose)?;
        out.fit(self);
        let tool_base = chain_frames(&self.tool_chain, pose.q, &mut out.tool_frames)?
            .then(&self.tool_shape(pose)?);
        let wr_base = chain_frames(&self.workpiece_chain, pose.q, &mut out.workpiece_frames)?
            .then(&self.workpiece);

        let wr_rot_t = wr_base.rotation.transpose();
        let tool_origin = tool_base.translation;
        let tool_rot = wr_rot_t * tool_base.rotation;
        let tool_in_wr = wr_rot_t * (tool_origin - wr_base.translation);

        let frame_f = |frame: &Rigid, sign: f64, f: &mut Matrix6<f64>| {
            let rotation = wr_rot_t * frame.rotation;
            let arm = wr_rot_t * (tool_origin - frame.translation);
            propagation(&rotation, &arm, sign, f);
        };
        for (frame, f) in out.tool_frames.iter().zip(out.tool_chain.iter_mut()) {
            frame_f(frame, 1.0, f);
        }
        for (frame, f) in out
            .workpiece_frames
            .iter()
            .zip(out.workpiece_chain.iter_mut())
        {
            frame_f(frame, -1.0, f);
        }
        propagation(&tool_rot, &Vector3::zeros(), 1.0, &mut out.tool_end);
        propagation(
            &Matrix3::identity(),
            &tool_in_wr,
            -1.0,
            &mut out.workpiece_end,
        );

        out.tool = pose.tool;
        out.location = ToolLocation {
            position: tool_in_wr,
            rotation: tool_rot,
        };
        Ok(())
    }

    /// The nominal location of `tl` in `wr` at `pose`, and the Jacobian of that location with
    /// respect to the joint positions: `jacobian[j] = (dp/dq_j, ω_j)` in wr axes, where `ω_j` is
    /// the angular velocity of `tl` relative to `wr` per unit `q_j`. `out` is used as scratch and
    /// left holding this pose's F-matrices.
    ///
    /// A joint motion `dq` of element k is an error of frame k equal to `u·dq` (a translation for
    /// a prismatic joint, a rotation about the frame's origin for a revolute one), in frame-k
    /// axes, for both moving (`… S_k J_k(q) J_k(dq)`) and fixed (`… S_k J_k(dq) J_k(q) …`)
    /// frames, because motions along one axis commute and leave `u` fixed. So column j is
    /// `Σ F_k·(u, 0)` or `Σ F_k·(0, u)` over the elements driven by axis j.
    pub fn nominal_jacobian(
        &self,
        pose: &Pose<'_>,
        out: &mut Sensitivities,
        jacobian: &mut [Vector6<f64>],
    ) -> Result<ToolLocation, KinematicsError> {
        if jacobian.len() != self.axes {
            return Err(KinematicsError::BufferSize {
                expected: self.axes,
                got: jacobian.len(),
            });
        }
        self.evaluate(pose, out)?;
        jacobian.fill(Vector6::zeros());
        let chains = [
            (&self.tool_chain, &out.tool_chain),
            (&self.workpiece_chain, &out.workpiece_chain),
        ];
        for (links, fs) in chains {
            for (link, f) in links.iter().zip(fs.iter()) {
                let column = match link.kind {
                    JointKind::Prismatic => f.fixed_view::<6, 3>(0, 0) * link.direction,
                    JointKind::Revolute => f.fixed_view::<6, 3>(0, 3) * link.direction,
                };
                if let Some(j) = jacobian.get_mut(link.axis) {
                    *j += column;
                }
            }
        }
        Ok(out.location)
    }
}

/// Runs one chain from the base, storing each frame's base location (eq. 2.35–2.38 via the
/// `G_k` form in the module docs) and returning `G_n`, the location before the end shape.
fn chain_frames(links: &[Link], q: &[f64], frames: &mut [Rigid]) -> Result<Rigid, KinematicsError> {
    let mut g = Rigid::IDENTITY;
    for (link, frame) in links.iter().zip(frames.iter_mut()) {
        let qk = *q.get(link.axis).ok_or(KinematicsError::JointCount {
            expected: link.axis + 1,
            got: q.len(),
        })?;
        let before_joint = g.then(&link.shape);
        g = before_joint;
        apply_joint(&mut g, link.kind, &link.direction, qk);
        *frame = match link.frame {
            FrameKind::Moving => g,
            FrameKind::Fixed => before_joint,
        };
    }
    Ok(g)
}

impl Sensitivities {
    /// Resizes to `model`'s chains; a no-op (no allocation) when already the right size.
    fn fit(&mut self, model: &FirstOrderModel) {
        self.tool_chain
            .resize(model.tool_chain.len(), Matrix6::zeros());
        self.workpiece_chain
            .resize(model.workpiece_chain.len(), Matrix6::zeros());
        self.tool_frames
            .resize(model.tool_chain.len(), Rigid::IDENTITY);
        self.workpiece_frames
            .resize(model.workpiece_chain.len(), Rigid::IDENTITY);
    }

    /// The nominal location of `tl` in `wr` at the evaluated pose.
    pub fn location(&self) -> &ToolLocation {
        &self.location
    }

    /// The tool the pose used.
    pub fn tool(&self) -> usize {
        self.tool
    }

    /// The axes of a chain frame in the base frame at the evaluated pose (the rotation of
    /// `G_{k−1} S_k J_k` when moving, `G_{k−1} S_k` when fixed); `None` for the end frames and
    /// frames that do not exist. Controller tables state errors in machine (base) axes.
    pub fn base_rotation(&self, frame: FrameRef) -> Option<Matrix3<f64>> {
        match frame {
            FrameRef::Tool(k) => self.tool_frames.get(k).map(|f| f.rotation),
            FrameRef::Workpiece(k) => self.workpiece_frames.get(k).map(|f| f.rotation),
            FrameRef::ToolEnd(_) | FrameRef::WorkpieceEnd => None,
        }
    }

    /// F-matrices of the tool-chain frames, in chain order (sign +, eq. 2.24).
    pub fn tool_chain(&self) -> &[Matrix6<f64>] {
        &self.tool_chain
    }

    /// F-matrices of the workpiece-chain frames, in chain order, already negated (eq. 2.24).
    pub fn workpiece_chain(&self) -> &[Matrix6<f64>] {
        &self.workpiece_chain
    }

    /// The F-matrix of `frame`, or `None` when the frame does not act in this pose (the end
    /// frame of another tool) or does not exist.
    pub fn get(&self, frame: FrameRef) -> Option<&Matrix6<f64>> {
        match frame {
            FrameRef::Tool(k) => self.tool_chain.get(k),
            FrameRef::Workpiece(k) => self.workpiece_chain.get(k),
            FrameRef::ToolEnd(None) => Some(&self.tool_end),
            FrameRef::ToolEnd(Some(i)) if i == self.tool => Some(&self.tool_end),
            FrameRef::ToolEnd(Some(_)) => None,
            FrameRef::WorkpieceEnd => Some(&self.workpiece_end),
        }
    }

    /// The effect on the tool-location error of a unit error `component` of `frame`: a column
    /// of its F-matrix, or zero when the frame does not act in this pose.
    pub fn column(&self, frame: FrameRef, component: Component) -> Vector6<f64> {
        self.get(frame)
            .map_or_else(Vector6::zeros, |f| f.column(component.index()).into_owned())
    }

    /// The first-order positioning error `Σ F_k E_k` (eq. 2.24) of the evaluated pose, with
    /// `errors` in the frames' own axes.
    pub fn first_order_error(&self, errors: &FrameErrors) -> Result<Vector6<f64>, KinematicsError> {
        check_count(Chain::Tool, self.tool_chain.len(), errors.tool_chain.len())?;
        check_count(
            Chain::Workpiece,
            self.workpiece_chain.len(),
            errors.workpiece_chain.len(),
        )?;
        let mut total = self.tool_end * Vector6::from(errors.tool_end)
            + self.workpiece_end * Vector6::from(errors.workpiece_end);
        for (f, e) in self.tool_chain.iter().zip(&errors.tool_chain) {
            total += f * Vector6::from(*e);
        }
        for (f, e) in self.workpiece_chain.iter().zip(&errors.workpiece_chain) {
            total += f * Vector6::from(*e);
        }
        Ok(total)
    }
}

/// The reported error of a task from a positioning error (eq. 2.31 / 2.34: a measuring machine
/// reports the negated positioning error).
pub fn task_error(task: Task, positioning: &Vector6<f64>) -> Vector6<f64> {
    positioning * task.sign()
}

/// Tool-location error sensitivity of one frame, eq. 2.27/2.28 premultiplied by `R(wr→tl)`
/// (see the module docs): `F = sign·[[R, −[a]× R], [0, R]]` with `R = R(wr→k)` and `a` the
/// arm from the origin of frame k to the tool origin, both in wr axes; `sign` is −1 for the
/// workpiece side (eq. 2.24).
fn propagation(rotation: &Matrix3<f64>, arm: &Vector3<f64>, sign: f64, f: &mut Matrix6<f64>) {
    let r = rotation * sign;
    let abbe = -(arm.cross_matrix() * r);
    f.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    f.fixed_view_mut::<3, 3>(0, 3).copy_from(&abbe);
    f.fixed_view_mut::<3, 3>(3, 0).fill(0.0);
    f.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
}

/// Shape transform `S = Trans(t)·Rot_x(rx)·Rot_y(ry)·Rot_z(rz)` (spec/kinematics.md, the form of
/// eq. 2.8), with the rotation product written out in closed form.
fn shape_transform(shape: &Shape) -> Rigid {
    let [rx, ry, rz] = shape.rotation;
    let [tx, ty, tz] = shape.translation;
    let (sa, ca) = (libm::sin(rx), libm::cos(rx));
    let (sb, cb) = (libm::sin(ry), libm::cos(ry));
    let (sc, cc) = (libm::sin(rz), libm::cos(rz));
    Rigid {
        rotation: Matrix3::new(
            cb * cc,
            -cb * sc,
            sb,
            ca * sc + sa * sb * cc,
            ca * cc - sa * sb * sc,
            -sa * cb,
            sa * sc - ca * sb * cc,
            sa * cc + ca * sb * sc,
            ca * cb,
        ),
        translation: Vector3::new(tx, ty, tz),
    }
}

/// Postmultiplies `g` by the joint transform `J_k(q)` (spec/kinematics.md): a translation `q·u`, or a
/// rotation by `q` about the unit axis `u` through the frame origin by Rodrigues' formula
/// `cI + s[u]× + (1−c)uuᵀ`. Done in place because either joint leaves half of `g` untouched.
fn apply_joint(g: &mut Rigid, kind: JointKind, u: &Vector3<f64>, q: f64) {
    match kind {
        JointKind::Prismatic => {
            g.translation += g.rotation * (u * q);
        }
        JointKind::Revolute => {
            let (s, c) = (libm::sin(q), libm::cos(q));
            let r =
                Matrix3::identity() * c + u.cross_matrix() * s + (u * u.transpose()) * (1.0 - c);
            g.rotation *= r;
        }
    }
}

/// Unit vector `u` from nominal point 1 to nominal point 2 of a length observation (eq. 4.5).
pub(crate) fn length_direction(
    p1: &Vector3<f64>,
    p2: &Vector3<f64>,
) -> Result<Vector3<f64>, KinematicsError> {
    let d = p2 - p1;
    let n = d.norm();
    if n > 0.0 {
        Ok(d / n)
    } else {
        Err(KinematicsError::ZeroLength)
    }
}

/// First-order length error `dL = u·(Δp_2 − Δp_1)` (eq. 4.5, spec/data.md), with `Δp` the
/// position errors of the two ends in wr axes.
pub fn length_error(u: &Vector3<f64>, dp1: &Vector3<f64>, dp2: &Vector3<f64>) -> f64 {
    u.dot(&(dp2 - dp1))
}

/// The sensitivity of `u·Δp` to a frame's six parametric errors: `uᵀ` times the position rows
/// of its F-matrix. A length row is this at pose 2 minus this at pose 1 (eq. 4.5). The engines
/// fold it into their own passes; the tests check them against it.
#[cfg(test)]
pub(crate) fn length_row(u: &Vector3<f64>, f: &Matrix6<f64>) -> Vector6<f64> {
    f.fixed_view::<3, 6>(0, 0).tr_mul(u)
}

/// The weight of rotation rows: one tilt unit counts as much as one error unit (µrad as µm
/// with the default units), so a fit or a compensation mixing both does not depend on SI's
/// choice of metre and radian.
pub fn rotation_weight(m: &Machine) -> f64 {
    m.units.error.scale / m.units.tilt.scale
}

#[cfg(test)]
pub(crate) mod testing {
    //! Hand-built machines for the tests of this module and of `exact`.

    use kin_compiler::ir::{
        Axis, DisplayUnits, Element, FrameKind, JointKind, Machine, Shape, Task, Tool,
    };
    use kin_compiler::units::{Dim, Unit};
    use rand::rngs::StdRng;
    use rand::Rng;

    use super::{FrameErrors, Pose};

    fn unit() -> Unit {
        Unit {
            name: "1".into(),
            dim: Dim::default(),
            scale: 1.0,
            offset: 0.0,
        }
    }

    pub fn shape(translation: [f64; 3], rotation: [f64; 3]) -> Shape {
        Shape {
            translation,
            rotation,
        }
    }

    pub fn axis(name: &str, kind: JointKind, direction: [f64; 3]) -> Axis {
        Axis {
            name: name.into(),
            kind,
            direction,
            range: [-1.0, 1.0],
            continuous: false,
        }
    }

    pub fn element(axis: usize, frame: FrameKind, shape: Shape) -> Element {
        Element { axis, frame, shape }
    }

    pub fn tool(name: &str, offset: Shape) -> Tool {
        Tool {
            name: name.into(),
            offset,
        }
    }

    pub fn machine(
        task: Task,
        axes: Vec<Axis>,
        tool_chain: Vec<Element>,
        workpiece_chain: Vec<Element>,
        tools: Vec<Tool>,
        workpiece: Shape,
    ) -> Machine {
        Machine {
            name: "test".into(),
            task,
            gravity: kin_compiler::ir::GRAVITY,
            axes,
            inputs: vec![],
            lags: vec![],
            nonlinear: vec![],
            tool_chain,
            workpiece_chain,
            tools,
            workpiece,
            errors: vec![],
            coefficients: vec![],
            beta: vec![],
            units: DisplayUnits {
                length: unit(),
                angle: unit(),
                error: unit(),
                tilt: unit(),
                time: unit(),
                temperature: unit(),
                force: unit(),
            },
        }
    }

    fn unit_vector(rng: &mut StdRng) -> [f64; 3] {
        loop {
            let v: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if n > 0.1 && n <= 1.0 {
                return v.map(|x| x / n);
            }
        }
    }

    fn random_shape(rng: &mut StdRng) -> Shape {
        shape(
            std::array::from_fn(|_| rng.random_range(-0.5..0.5)),
            std::array::from_fn(|_| rng.random_range(-3.0..3.0)),
        )
    }

    /// A random machine: 0–4 elements per chain, each on its own axis of random kind and
    /// direction, random moving/fixed frames and shapes, 1–3 tools.
    pub(crate) fn random_machine(rng: &mut StdRng) -> Machine {
        let mut axes = vec![];
        let chain = |rng: &mut StdRng, axes: &mut Vec<Axis>| {
            let n = rng.random_range(0..=4);
            (0..n)
                .map(|_| {
                    let kind = if rng.random_bool(0.5) {
                        JointKind::Prismatic
                    } else {
                        JointKind::Revolute
                    };
                    axes.push(axis("A", kind, unit_vector(rng)));
                    let frame = if rng.random_bool(0.5) {
                        FrameKind::Moving
                    } else {
                        FrameKind::Fixed
                    };
                    element(axes.len() - 1, frame, random_shape(rng))
                })
                .collect::<Vec<_>>()
        };
        let tool_chain = chain(rng, &mut axes);
        let workpiece_chain = chain(rng, &mut axes);
        let tools = (0..rng.random_range(1..=3))
            .map(|_| tool("T", random_shape(rng)))
            .collect();
        let workpiece = random_shape(rng);
        machine(
            Task::Position,
            axes,
            tool_chain,
            workpiece_chain,
            tools,
            workpiece,
        )
    }

    /// Random joint positions (m within ±0.5, rad within ±3) for `machine`.
    pub(crate) fn random_q(rng: &mut StdRng, machine: &Machine) -> Vec<f64> {
        machine
            .axes
            .iter()
            .map(|a| match a.kind {
                JointKind::Prismatic => rng.random_range(-0.5..0.5),
                JointKind::Revolute => rng.random_range(-3.0..3.0),
            })
            .collect()
    }

    /// A random pose (tool, and an offset override half the time) using `q`.
    pub(crate) fn random_pose<'a>(rng: &mut StdRng, machine: &Machine, q: &'a [f64]) -> Pose<'a> {
        Pose {
            q,
            tool: rng.random_range(0..machine.tools.len()),
            tool_offset: if rng.random_bool(0.5) {
                Some(std::array::from_fn(|_| rng.random_range(-0.3..0.3)))
            } else {
                None
            },
        }
    }

    /// Every error of every frame uniform in `±scale` (m and rad alike).
    pub(crate) fn random_errors(rng: &mut StdRng, machine: &Machine, scale: f64) -> FrameErrors {
        let mut v = || -> [f64; 6] { std::array::from_fn(|_| rng.random_range(-scale..scale)) };
        FrameErrors {
            tool_chain: (0..machine.tool_chain.len()).map(|_| v()).collect(),
            workpiece_chain: (0..machine.workpiece_chain.len()).map(|_| v()).collect(),
            tool_end: v(),
            workpiece_end: v(),
        }
    }

    pub fn scaled(errors: &FrameErrors, factor: f64) -> FrameErrors {
        let s = |e: &[f64; 6]| e.map(|x| x * factor);
        FrameErrors {
            tool_chain: errors.tool_chain.iter().map(s).collect(),
            workpiece_chain: errors.workpiece_chain.iter().map(s).collect(),
            tool_end: s(&errors.tool_end),
            workpiece_end: s(&errors.workpiece_end),
        }
    }
}

#[cfg(test)]
mod tests {
    use kin_compiler::ir::{Component, FrameKind, FrameRef, JointKind, Machine, Task};
    use nalgebra::{Matrix3, Vector3, Vector6};
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    use super::testing::*;
    use super::*;
    use crate::exact;

    const X: [f64; 3] = [1.0, 0.0, 0.0];
    const Y: [f64; 3] = [0.0, 1.0, 0.0];
    const Z: [f64; 3] = [0.0, 0.0, 1.0];
    const ZERO: [f64; 3] = [0.0; 3];

    fn first_order(machine: &Machine, pose: &Pose<'_>, errors: &FrameErrors) -> Vector6<f64> {
        let model = FirstOrderModel::new(machine).unwrap();
        let mut sens = model.sensitivities();
        model.evaluate(pose, &mut sens).unwrap();
        sens.first_order_error(errors).unwrap()
    }

    fn pose(q: &[f64]) -> Pose<'_> {
        Pose {
            q,
            tool: 0,
            tool_offset: None,
        }
    }

    /// The 2-D CMM of thesis §4.4 (fig. 4.2): X on the base, Y carried by X, moving frames at
    /// the origin, no probe offset, a measuring machine.
    fn cmm_2d() -> Machine {
        machine(
            Task::Measure,
            vec![
                axis("X", JointKind::Prismatic, X),
                axis("Y", JointKind::Prismatic, Y),
            ],
            vec![
                element(0, FrameKind::Moving, shape(ZERO, ZERO)),
                element(1, FrameKind::Moving, shape(ZERO, ZERO)),
            ],
            vec![],
            vec![tool("probe", shape(ZERO, ZERO))],
            shape(ZERO, ZERO),
        )
    }

    /// Parametric errors of eq. 4.15–4.17 at `(x, y)`: `X.rz = β1` (squareness),
    /// `X.tx = β2·x`, `Y.ty = β3·y` (scales).
    fn cmm_errors(machine: &Machine, beta: [f64; 3], x: f64, y: f64) -> FrameErrors {
        let mut e = FrameErrors::zeros(machine);
        e.tool_chain[0][Component::Rz.index()] = beta[0];
        e.tool_chain[0][Component::Tx.index()] = beta[1] * x;
        e.tool_chain[1][Component::Ty.index()] = beta[2] * y;
        e
    }

    #[test]
    fn first_order_agrees_with_exact_to_second_order() {
        let mut rng = StdRng::seed_from_u64(0x5eed_2024);
        let eps = 1e-5;
        let mut checked = 0;
        let mut worst = (4.0f64, 4.0f64);
        for _ in 0..400 {
            let machine = random_machine(&mut rng);
            let q = random_q(&mut rng, &machine);
            let pose = random_pose(&mut rng, &machine, &q);
            let errors = random_errors(&mut rng, &machine, eps);
            let half = scaled(&errors, 0.5);
            let gap = |e: &FrameErrors| {
                (exact::positioning_error(&machine, &pose, e).unwrap()
                    - first_order(&machine, &pose, e))
                .norm()
            };
            let (g1, g2) = (gap(&errors), gap(&half));
            // Second order in ε on a machine of a few metres: far below ε itself.
            assert!(g1 < 100.0 * eps * eps, "gap {g1} not second order");
            if g1 < 1e-12 {
                continue;
            }
            let ratio = g1 / g2;
            worst = (worst.0.min(ratio), worst.1.max(ratio));
            assert!(
                (3.9..=4.1).contains(&ratio),
                "gap ratio {ratio} (gaps {g1:e}, {g2:e}) for {machine:?} at {q:?}"
            );
            checked += 1;
        }
        assert!(checked > 350, "only {checked} cases above rounding");
        eprintln!("gap ratios within [{}, {}]", worst.0, worst.1);
    }

    #[test]
    fn first_order_model_is_linear_and_matches_exact_nominal() {
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let machine = random_machine(&mut rng);
            let q = random_q(&mut rng, &machine);
            let pose = random_pose(&mut rng, &machine, &q);
            let model = FirstOrderModel::new(&machine).unwrap();
            let mut sens = model.sensitivities();
            model.evaluate(&pose, &mut sens).unwrap();
            let nominal = exact::nominal_transform(&machine, &pose).unwrap();
            assert!((sens.location().to_matrix() - nominal).amax() < 1e-12);
            // A unit error of a single component gives exactly that column.
            let mut errors = FrameErrors::zeros(&machine);
            errors.workpiece_end[Component::Ry.index()] = 1.0;
            let e = sens.first_order_error(&errors).unwrap();
            assert_eq!(e, sens.column(FrameRef::WorkpieceEnd, Component::Ry));
        }
    }

    #[test]
    fn rz_and_pitch_errors_of_an_x_carriage_act_through_the_probe_offset() {
        // Probe at (0, l, h) from the X carriage frame. A small rotation e about the carriage
        // origin moves the probe tip by e × (0, l, h):
        //   rz: (0, 0, rz) × (0, l, h) = (−l·rz, 0, 0)
        //   rx: (rx, 0, 0) × (0, l, h) = (0, −h·rx, l·rx)
        //   ry: (0, ry, 0) × (0, l, h) = (h·ry, 0, 0)
        // and rotates the probe by the same vector; the workpiece sits on the base.
        let (l, h) = (0.2, -0.15);
        let m = machine(
            Task::Position,
            vec![axis("X", JointKind::Prismatic, X)],
            vec![element(0, FrameKind::Moving, shape([0.1, 0.0, 0.5], ZERO))],
            vec![],
            vec![tool("probe", shape([0.0, l, h], ZERO))],
            shape(ZERO, ZERO),
        );
        let q = [0.37];
        let model = FirstOrderModel::new(&m).unwrap();
        let mut sens = model.sensitivities();
        model.evaluate(&pose(&q), &mut sens).unwrap();
        let x = FrameRef::Tool(0);
        let expect = |c: Component, v: [f64; 6]| {
            let got = sens.column(x, c);
            assert!((got - Vector6::from(v)).amax() < 1e-15, "{c:?}: {got}");
        };
        expect(Component::Rz, [-l, 0.0, 0.0, 0.0, 0.0, 1.0]);
        expect(Component::Rx, [0.0, -h, l, 1.0, 0.0, 0.0]);
        expect(Component::Ry, [h, 0.0, 0.0, 0.0, 1.0, 0.0]);
        expect(Component::Tx, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);

        let rz = 1e-6;
        let mut errors = FrameErrors::zeros(&m);
        errors.tool_chain[0][Component::Rz.index()] = rz;
        let e = exact::positioning_error(&m, &pose(&q), &errors).unwrap();
        assert!((e - Vector6::new(-l * rz, 0.0, 0.0, 0.0, 0.0, rz)).amax() < 1e-12);
    }

    #[test]
    fn squareness_of_the_2d_cmm_is_eq_4_13() {
        // Eq. 4.13/4.18: e = −[[−y, x, 0], [0, 0, y]]·β for a *measured* position, i.e. the
        // positioning error is −y·β1 in x (the Y carriage, at arm y from the X frame, swings
        // with X.rz) plus the scale errors.
        let m = cmm_2d();
        let beta = [3e-6, -2e-6, 5e-6];
        for (x, y) in [(0.4, 0.3), (-0.2, 0.7), (0.0, -0.5)] {
            let q = [x, y];
            let errors = cmm_errors(&m, beta, x, y);
            let expected = [y * beta[0] - x * beta[1], -y * beta[2]];
            let fo = task_error(m.task, &first_order(&m, &pose(&q), &errors));
            let ex = task_error(
                m.task,
                &exact::positioning_error(&m, &pose(&q), &errors).unwrap(),
            );
            for (got, tol) in [(fo, 1e-18), (ex, 1e-10)] {
                assert!((got[0] - expected[0]).abs() < tol, "{got} vs {expected:?}");
                assert!((got[1] - expected[1]).abs() < tol, "{got} vs {expected:?}");
                assert!(got[2].abs() < tol);
            }
            // The squareness also turns the probe: positioning rz = β1, reported −β1.
            assert!((fo[5] + beta[0]).abs() < 1e-18);
        }
    }

    #[test]
    fn length_error_of_the_2d_cmm_is_eq_4_21() {
        // Eq. 4.21: ΔL = L·[cos α sin α, −cos²α, −sin²α]·β, independent of where the length lies.
        let m = cmm_2d();
        let beta = [3e-6, -2e-6, 5e-6];
        let model = FirstOrderModel::new(&m).unwrap();
        let (mut s1, mut s2) = (model.sensitivities(), model.sensitivities());
        for (x1, y1, len, alpha) in [
            (0.1, 0.2, 0.4, 0.3),
            (-0.3, 0.1, 0.4, 2.0),
            (0.2, -0.4, 0.25, -1.1),
        ] {
            let (c, s) = (f64::cos(alpha), f64::sin(alpha));
            let q1 = [x1, y1];
            let q2 = [x1 + len * c, y1 + len * s];
            let (e1, e2) = (
                cmm_errors(&m, beta, q1[0], q1[1]),
                cmm_errors(&m, beta, q2[0], q2[1]),
            );
            model.evaluate(&pose(&q1), &mut s1).unwrap();
            model.evaluate(&pose(&q2), &mut s2).unwrap();
            let u = length_direction(&s1.location().position, &s2.location().position).unwrap();
            let expected = len * (c * s * beta[0] - c * c * beta[1] - s * s * beta[2]);

            let dp = |s: &Sensitivities, e: &FrameErrors| -> Vector3<f64> {
                s.first_order_error(e)
                    .unwrap()
                    .fixed_rows::<3>(0)
                    .into_owned()
            };
            let dl = m.task.sign() * length_error(&u, &dp(&s1, &e1), &dp(&s2, &e2));
            assert!((dl - expected).abs() < 1e-18, "{dl} vs {expected}");

            // The same through per-frame rows, as a fit assembles it.
            let mut by_rows = 0.0;
            for k in 0..2 {
                let row1 = length_row(&u, &s1.tool_chain()[k]);
                let row2 = length_row(&u, &s2.tool_chain()[k]);
                by_rows += row2.dot(&Vector6::from(e2.tool_chain[k]))
                    - row1.dot(&Vector6::from(e1.tool_chain[k]));
            }
            assert!((m.task.sign() * by_rows - expected).abs() < 1e-18);

            let exact_dl =
                m.task.sign() * exact::length_error(&m, &pose(&q1), &e1, &pose(&q2), &e2).unwrap();
            assert!(
                (exact_dl - expected).abs() < 1e-10,
                "{exact_dl} vs {expected}"
            );
        }
    }

    /// A rotary table C about z carrying the workpiece, whose reference sits at radius `a` on
    /// the table; a fixed spindle with its tool at `(b, 0, 0)` on the base.
    fn rotary_table(frame: FrameKind, a: f64, b: f64) -> Machine {
        machine(
            Task::Position,
            vec![axis("C", JointKind::Revolute, Z)],
            vec![],
            vec![element(0, frame, shape(ZERO, ZERO))],
            vec![tool("t", shape([b, 0.0, 0.0], ZERO))],
            shape([a, 0.0, 0.0], ZERO),
        )
    }

    #[test]
    fn revolute_table_with_fixed_frame() {
        // Fixed frame: T(0→c) = S_c = I and T(c→wr) = J_c·S_wr = Rot_z(q)·Trans(a, 0, 0), so wr
        // sits at (a cos q, a sin q, 0) turned by q, and the tool at (b, 0, 0) is at
        // Rot_z(−q)·((b, 0, 0) − (a cos q, a sin q, 0)) = (b cos q − a, −b sin q, 0) in wr.
        let (a, b) = (0.1, 0.3);
        let q = [std::f64::consts::FRAC_PI_2];
        let expected = Vector3::new(-a, -b, 0.0);
        let expected_rot = Matrix3::new(0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        for frame in [FrameKind::Fixed, FrameKind::Moving] {
            // The nominal location does not depend on where the frame sits relative to J_c.
            let m = rotary_table(frame, a, b);
            let model = FirstOrderModel::new(&m).unwrap();
            let mut sens = model.sensitivities();
            model.evaluate(&pose(&q), &mut sens).unwrap();
            assert!((sens.location().position - expected).amax() < 1e-15);
            assert!((sens.location().rotation - expected_rot).amax() < 1e-15);
            let t = exact::nominal_transform(&m, &pose(&q)).unwrap();
            assert!((t.fixed_view::<3, 1>(0, 3) - expected).amax() < 1e-15);
            assert!((t.fixed_view::<3, 3>(0, 0) - expected_rot).amax() < 1e-15);
        }
        // A tx error of the table frame shifts the workpiece along base x when the frame is
        // fixed, along the turned table x (= base y at q = 90°) when moving. The tool moves the
        // opposite way relative to wr; in wr axes (Rot_z(−90°)) that is (0, e, 0) and (−e, 0, 0).
        let e = 1e-6;
        for (frame, expected) in [
            (FrameKind::Fixed, [0.0, e, 0.0]),
            (FrameKind::Moving, [-e, 0.0, 0.0]),
        ] {
            let m = rotary_table(frame, a, b);
            let mut errors = FrameErrors::zeros(&m);
            errors.workpiece_chain[0][0] = e;
            let fo = first_order(&m, &pose(&q), &errors);
            let ex = exact::positioning_error(&m, &pose(&q), &errors).unwrap();
            for got in [fo, ex] {
                assert!(
                    (got.fixed_rows::<3>(0) - Vector3::from(expected)).amax() < 1e-15,
                    "{frame:?}: {got}"
                );
                assert!(got.fixed_rows::<3>(3).amax() < 1e-15);
            }
        }
    }

    #[test]
    fn task_sign_negates_for_measuring_machines() {
        let v = Vector6::new(1.0, -2.0, 3.0, -4.0, 5.0, -6.0);
        assert_eq!(task_error(Task::Position, &v), v);
        assert_eq!(task_error(Task::Measure, &v), -v);
        assert_eq!(exact::task_error(Task::Measure, &v), -v);
    }

    #[test]
    fn several_tools_and_offset_override() {
        let m = machine(
            Task::Position,
            vec![
                axis("Z", JointKind::Prismatic, Z),
                axis("B", JointKind::Revolute, Y),
            ],
            vec![
                element(0, FrameKind::Moving, shape([0.0, 0.0, 0.8], ZERO)),
                element(1, FrameKind::Fixed, shape([0.0, 0.0, -0.2], ZERO)),
            ],
            vec![],
            vec![
                tool("short", shape([0.0, 0.0, -0.1], ZERO)),
                tool("long", shape([0.0, 0.0, -0.3], [0.0, 0.0, 0.5])),
            ],
            shape([0.1, 0.2, 0.0], ZERO),
        );
        let q = [0.05, 0.3];
        let model = FirstOrderModel::new(&m).unwrap();
        let mut sens = model.sensitivities();
        let locate = |p: Pose<'_>, sens: &mut Sensitivities| {
            model.evaluate(&p, sens).unwrap();
            let t = exact::nominal_transform(&m, &p).unwrap();
            assert!((sens.location().to_matrix() - t).amax() < 1e-15);
            sens.location().position
        };
        let short = locate(pose(&q), &mut sens);
        let long = locate(
            Pose {
                q: &q,
                tool: 1,
                tool_offset: None,
            },
            &mut sens,
        );
        // B turns the tools about y at the fixed frame: the tips lie along the turned −z.
        let down = Vector3::new(-f64::sin(0.3), 0.0, -f64::cos(0.3));
        assert!((long - short - down * 0.2).amax() < 1e-15);
        assert_eq!(sens.tool(), 1);
        assert_eq!(
            sens.column(FrameRef::ToolEnd(Some(0)), Component::Tx),
            Vector6::zeros()
        );
        assert_ne!(
            sens.column(FrameRef::ToolEnd(Some(1)), Component::Tx),
            Vector6::zeros()
        );
        assert_ne!(
            sens.column(FrameRef::ToolEnd(None), Component::Tx),
            Vector6::zeros()
        );
        // The tl errors are in the tool's own (turned) axes.
        let tl_rz = sens.column(FrameRef::ToolEnd(None), Component::Rz);
        let tool_z = sens.location().rotation.column(2).into_owned();
        assert!((tl_rz.fixed_rows::<3>(3) - tool_z).amax() < 1e-15);

        let overridden = locate(
            Pose {
                q: &q,
                tool: 1,
                tool_offset: Some([0.0, 0.0, -0.5]),
            },
            &mut sens,
        );
        assert!((overridden - short - down * 0.4).amax() < 1e-15);
        // The override keeps the declared rotation of the tool.
        let rz = Matrix3::new(
            f64::cos(0.5),
            -f64::sin(0.5),
            0.0,
            f64::sin(0.5),
            f64::cos(0.5),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        let b = Matrix3::new(
            f64::cos(0.3),
            0.0,
            f64::sin(0.3),
            0.0,
            1.0,
            0.0,
            -f64::sin(0.3),
            0.0,
            f64::cos(0.3),
        );
        assert!((sens.location().rotation - b * rz).amax() < 1e-15);
    }

    #[test]
    fn empty_chains() {
        // Nothing but the tool and workpiece offsets: T(wr→tl) = S_wr⁻¹·S_tl.
        let m = machine(
            Task::Measure,
            vec![],
            vec![],
            vec![],
            vec![tool("t", shape([0.1, 0.2, 0.3], [0.0, 0.0, 0.0]))],
            shape([0.5, 0.0, 0.0], [0.0, 0.0, std::f64::consts::FRAC_PI_2]),
        );
        let model = FirstOrderModel::new(&m).unwrap();
        let mut sens = model.sensitivities();
        model.evaluate(&pose(&[]), &mut sens).unwrap();
        // Tool at (0.1, 0.2, 0.3) in base; wr at (0.5, 0, 0) turned 90° about z.
        let expected = Vector3::new(0.2, 0.4, 0.3);
        assert!((sens.location().position - expected).amax() < 1e-15);
        assert!(sens.tool_chain().is_empty() && sens.workpiece_chain().is_empty());
        // A wr rotation error about its z turns the workpiece under the tool: −[p]×… enters
        // with the minus sign, so the tool moves by −(0, 0, rz) × p in wr.
        let col = sens.column(FrameRef::WorkpieceEnd, Component::Rz);
        let moved = -Vector3::z().cross(&expected);
        assert!((col.fixed_rows::<3>(0) - moved).amax() < 1e-15);
        assert_eq!(col.fixed_rows::<3>(3), -Vector3::z());

        let mut rng = StdRng::seed_from_u64(3);
        let errors = random_errors(&mut rng, &m, 1e-6);
        let gap = exact::positioning_error(&m, &pose(&[]), &errors).unwrap()
            - sens.first_order_error(&errors).unwrap();
        assert!(gap.amax() < 1e-11);
    }

    #[test]
    fn nominal_jacobian_matches_central_differences() {
        let mut rng = StdRng::seed_from_u64(11);
        let h = 1e-6;
        for _ in 0..200 {
            let machine = random_machine(&mut rng);
            let q = random_q(&mut rng, &machine);
            let p = random_pose(&mut rng, &machine, &q);
            let model = FirstOrderModel::new(&machine).unwrap();
            let mut sens = model.sensitivities();
            let mut jac = vec![Vector6::zeros(); machine.axes.len()];
            let loc = model.nominal_jacobian(&p, &mut sens, &mut jac).unwrap();
            assert_eq!(loc, *sens.location());
            for j in 0..q.len() {
                let at = |d: f64| {
                    let mut qq = q.clone();
                    qq[j] += d;
                    let mut s = model.sensitivities();
                    model.evaluate(&Pose { q: &qq, ..p }, &mut s).unwrap();
                    *s.location()
                };
                let (plus, minus) = (at(h), at(-h));
                let dp = (plus.position - minus.position) / (2.0 * h);
                let w = exact::rotation_vector(&(plus.rotation * minus.rotation.transpose()))
                    / (2.0 * h);
                let fd = Vector6::new(dp[0], dp[1], dp[2], w[0], w[1], w[2]);
                assert!((fd - jac[j]).amax() < 1e-7, "axis {j}: {fd} vs {}", jac[j]);
            }
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let m = cmm_2d();
        let model = FirstOrderModel::new(&m).unwrap();
        let mut sens = model.sensitivities();
        assert_eq!(
            model.evaluate(&pose(&[0.0]), &mut sens),
            Err(KinematicsError::JointCount {
                expected: 2,
                got: 1
            })
        );
        let q = [0.0, 0.0];
        let bad_tool = Pose {
            q: &q,
            tool: 1,
            tool_offset: None,
        };
        assert!(matches!(
            model.evaluate(&bad_tool, &mut sens),
            Err(KinematicsError::ToolIndex { index: 1, count: 1 })
        ));
        assert!(matches!(
            exact::nominal_transform(&m, &bad_tool),
            Err(KinematicsError::ToolIndex { index: 1, count: 1 })
        ));
        model.evaluate(&pose(&q), &mut sens).unwrap();
        let mut errors = FrameErrors::zeros(&m);
        errors.tool_chain.pop();
        assert!(matches!(
            sens.first_order_error(&errors),
            Err(KinematicsError::ErrorCount {
                chain: Chain::Tool,
                expected: 2,
                got: 1
            })
        ));
        assert!(exact::positioning_error(&m, &pose(&q), &errors).is_err());
        let mut jac = vec![Vector6::zeros(); 1];
        assert!(matches!(
            model.nominal_jacobian(&pose(&q), &mut sens, &mut jac),
            Err(KinematicsError::BufferSize {
                expected: 2,
                got: 1
            })
        ));
        let p = Vector3::new(1.0, 2.0, 3.0);
        assert_eq!(length_direction(&p, &p), Err(KinematicsError::ZeroLength));

        let mut broken = m.clone();
        broken.tool_chain[1].axis = 7;
        assert!(matches!(
            FirstOrderModel::new(&broken),
            Err(KinematicsError::AxisIndex { axis: 7, .. })
        ));
        assert!(matches!(
            exact::nominal_transform(&broken, &pose(&q)),
            Err(KinematicsError::AxisIndex { axis: 7, .. })
        ));
    }
}
