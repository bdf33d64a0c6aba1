//! Gough–Stewart platforms with `n ≥ 6` prismatic legs (general `n`-`n`
//! geometry; with 7 or more legs the platform is redundantly actuated). Its
//! target points, measured by a laser tracker, are the measurement model
//! [`crate::measurement::Instrument::Targets`]. (A long file: the platform's
//! builder and its exact leg derivatives are one job.)
//!
//! Conventions (docs/mechanisms.md):
//!
//! - Joints `q = [L1 … Ln, x, y, z, rx, ry, rz]`: the leg lengths (mm, actuated,
//!   distance between the joint centres) and the platform pose (mm, rad).
//!   The orientation is `R = Rz(rz) · Ry(ry) · Rx(rx)` (rotations about the
//!   fixed base axes x, then y, then z); the platform frame's origin is at
//!   `(x, y, z)` in the base (measurement) frame.
//! - Loop closure, one equation per leg (docs/model.md eq. 3):
//!   `g_i = |p + R b_i − a_i| − L_i = 0`.
//! - Parameters: base joint centres `a{i}x a{i}y a{i}z` (base frame), platform
//!   joint centres `b{i}x b{i}y b{i}z` (platform frame), leg length offsets
//!   `dL{i}` (actual minus reported, mm), axial leg stiffness `kL{i}` (N/mm;
//!   `k` and the joint's name, as on every kind; `k{i}`, its name before, is
//!   still accepted).
//! - Tool: the pose `x y z rx ry rz`. The first six legs are the independent
//!   joints (the rigid model drives them).

use crate::error::{Error, Result};
use crate::kinds::build::{Built, Joints, Parts, assemble, finish};
use crate::kinds::description::{Names, Value};
use crate::linalg::pose::{rotation, transform};
use crate::mechanism::{Mechanism, Scalar, Spec};
use crate::units::Unit;
use serde::Deserialize;
use std::collections::BTreeMap;

/// Gauss–Newton steps on the platform pose that bring a stored
/// configuration nearer the commanded leg lengths before forward kinematics
/// starts from it ([`GoughStewart::refine_guess`]).
const GUESS_STEPS: usize = 3;

/// Names of the pose coordinates, in order.
pub const POSE_AXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];

/// Units of the pose coordinates, in order.
pub const POSE_UNITS: [Unit; 6] = [
    Unit::Millimetre,
    Unit::Millimetre,
    Unit::Millimetre,
    Unit::Radian,
    Unit::Radian,
    Unit::Radian,
];

/// One leg: joint centres and axial stiffness.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leg {
    /// Base joint centre in the base frame (mm).
    pub base: [f64; 3],
    /// Platform joint centre in the platform frame (mm).
    pub platform: [f64; 3],
    /// Axial stiffness (N/mm).
    pub stiffness: f64,
}

/// The reference pose of a Gough–Stewart platform.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoughStewartAssembly {
    /// `[x, y, z, rx, ry, rz]` (mm, rad): forward kinematics starts from it,
    /// so it fixes the assembly mode.
    pub pose: [f64; 6],
}

/// A Gough–Stewart platform as a user describes it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoughStewartDescription {
    /// Human-readable name.
    #[serde(default)]
    pub name: Option<String>,
    /// The legs (at least six).
    #[serde(rename = "leg")]
    pub legs: Vec<Leg>,
    /// The reference pose (assembly mode).
    pub assembly: GoughStewartAssembly,
    /// Box `[min, max]` per pose axis.
    pub workspace: BTreeMap<String, [f64; 2]>,
    /// Parameters identified by default (base and platform joint centres and
    /// leg offsets if left out).
    #[serde(default)]
    pub free: Option<Vec<String>>,
}

/// A Gough–Stewart platform.
#[derive(Debug, Clone, PartialEq)]
pub struct GoughStewart {
    spec: Spec,
    n: usize,
    atlas: crate::engine::atlas::Atlas,
    /// Sign of the forward-kinematics determinant at the reference pose.
    branch: i8,
}

impl GoughStewart {
    /// Build the platform from its description.
    pub fn new(d: &GoughStewartDescription) -> Result<Self> {
        let n = d.legs.len();
        let bad = |m: String| Err(Error::InvalidMechanism(m));
        if n < 6 {
            return bad(format!(
                "a Gough–Stewart platform needs at least 6 legs ([[leg]] tables), got {n}"
            ));
        }
        crate::mechanism::check_size(n, 0)?;
        for (i, l) in d.legs.iter().enumerate() {
            if l.base.iter().chain(&l.platform).any(|v| !v.is_finite()) {
                return bad(format!("leg {}: joint centres must be finite", i + 1));
            }
            if !(l.stiffness.is_finite() && l.stiffness > 0.0) {
                return bad(format!(
                    "leg {}: `stiffness` must be a positive axial stiffness in N/mm",
                    i + 1
                ));
            }
        }
        if d.assembly.pose.iter().any(|v| !v.is_finite()) {
            return bad(
                "[assembly]: `pose` must be six finite numbers [x, y, z, rx, ry, rz]".into(),
            );
        }
        // The parameters: base joint centres, then platform ones.
        let none = BTreeMap::new();
        let mut names = Names::new(&none);
        for (prefix, side) in [("a", 0), ("b", 1)] {
            for (i, l) in d.legs.iter().enumerate() {
                let centre = if side == 0 { l.base } else { l.platform };
                for (c, v) in ["x", "y", "z"].iter().zip(centre) {
                    let name = format!("{prefix}{}{c}", i + 1);
                    names.add(&Value::Number(v), name, Unit::Millimetre)?;
                }
            }
        }
        let mut joints = Joints::default();
        for (i, l) in d.legs.iter().enumerate() {
            let q = joints.push(&format!("L{}", i + 1), Unit::Millimetre);
            joints.actuate(q, l.stiffness, false);
        }
        for (a, u) in POSE_AXES.iter().zip(POSE_UNITS) {
            joints.push(a, u);
        }
        // A rotation of one radian moves the platform joints by about their
        // mean distance from the platform origin.
        let radius = (d
            .legs
            .iter()
            .map(|l| l.platform.iter().map(|v| v * v).sum::<f64>().sqrt())
            .sum::<f64>()
            / n as f64)
            .max(1.0);
        // The stiffness was `k{i}` before it followed the rule of every kind.
        let renamed: BTreeMap<String, String> = (1..=n)
            .map(|i| (format!("k{i}"), format!("kL{i}")))
            .collect();
        let spec = assemble(Parts {
            name: d
                .name
                .clone()
                .unwrap_or_else(|| format!("Gough–Stewart platform, {n} legs")),
            parameters: names,
            work_scale: joints.work_scale()?,
            joints,
            n_constraints: n,
            tool_axes: POSE_AXES.iter().map(|s| s.to_string()).collect(),
            tool_units: POSE_UNITS.to_vec(),
            tool_layout: crate::mechanism::tool::ToolLayout::SpatialPose,
            workspace: &d.workspace,
            free: &d.free,
            joint_scale: std::iter::repeat_n(1.0, n + 3).chain([radius; 3]).collect(),
            axis_scale: vec![1.0, 1.0, 1.0, radius, radius, radius],
            renamed: &renamed,
        })?;
        let mut gs = GoughStewart {
            spec,
            n,
            atlas: Default::default(),
            branch: 0,
        };
        let rho = gs.spec.nominal[..6 * n].to_vec();
        gs.spec.reference_q = gs.ik(&d.assembly.pose, &rho)?;
        // The first six legs must determine the pose at the reference.
        finish(
            gs,
            Some(&|_: &Spec| {
                "the reference pose is singular for the first six legs; move it or reorder the legs"
                    .into()
            }),
        )
    }

    /// Number of legs.
    pub fn legs(&self) -> usize {
        self.n
    }

    /// The stored configuration (nearest the commands) moved nearer the
    /// commanded leg lengths: up to [`GUESS_STEPS`] Gauss–Newton steps on
    /// the platform pose (the legs' lengths are linear in it to first
    /// order, their gradients the unit leg vectors), each followed by the
    /// closed-form inverse kinematics so that the configuration stays
    /// assembled, each kept only while the largest length mismatch shrinks;
    /// the stored configuration itself where the result has left the
    /// reference's assembly mode. Forward kinematics then starts one short
    /// continuation stage away instead of several: the same solution on the
    /// same branch, found in fewer Newton iterations.
    fn refine_guess(&self, stored: Vec<f64>, commands: &[f64], rho: &[f64]) -> Vec<f64> {
        use nalgebra::{Matrix6, Vector6};
        let n = self.n;
        if commands.len() != n || stored.len() != n + 6 {
            return stored;
        }
        let mut q = stored.clone();
        let mismatch = |q: &[f64]| {
            q[..n]
                .iter()
                .zip(commands)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        };
        let mut worst = mismatch(&q);
        // Not `engine::newton::run`: a step is kept only while the mismatch
        // shrinks, and there is no tolerance to converge to.
        for _ in 0..GUESS_STEPS {
            if worst.is_nan() || worst <= 0.0 {
                break;
            }
            let Some(j) = self.first_derivatives(&q, rho, n..n + 6) else {
                break;
            };
            // Normal equations of J Δp = c − L (J: n × 6, ∂|w_i|/∂pose).
            let mut jtj = Matrix6::<f64>::zeros();
            let mut jtr = Vector6::<f64>::zeros();
            for i in 0..n {
                let row = Vector6::from_fn(|k, _| j.dg[(i, k)]);
                jtj += row * row.transpose();
                jtr += row * (commands[i] - q[i]);
            }
            let Some(step) = jtj.lu().solve(&jtr) else {
                break;
            };
            let pose: Vec<f64> = (0..6).map(|k| q[n + k] + step[k]).collect();
            let Ok(next) = self.ik(&pose, rho) else {
                break;
            };
            let m = mismatch(&next);
            if m.is_nan() || m >= worst {
                break;
            }
            (q, worst) = (next, m);
        }
        if q != stored && !self.on_branch(&q, rho) {
            return stored;
        }
        q
    }

    /// Inverse kinematics in closed form: leg lengths for a pose.
    fn ik(&self, pose: &[f64], rho: &[f64]) -> Result<Vec<f64>> {
        let n = self.n;
        let mut q = Vec::with_capacity(n + 6);
        for i in 0..n {
            let b = [
                rho[3 * n + 3 * i],
                rho[3 * n + 3 * i + 1],
                rho[3 * n + 3 * i + 2],
            ];
            let w = transform(pose, b);
            let d = (0..3)
                .map(|k| (w[k] - rho[3 * i + k]).powi(2))
                .sum::<f64>()
                .sqrt();
            if d < 1e-9 {
                return Err(Error::Unreachable {
                    target: pose.to_vec(),
                    reason: format!("leg {} would have zero length", i + 1),
                });
            }
            q.push(d);
        }
        q.extend_from_slice(pose);
        Ok(q)
    }
}

/// The rotation `R = Rz(c) Ry(b) Rx(a)` with its first and second
/// derivatives in the pose angles, for closed-form leg derivatives.
struct RotationDerivatives {
    r: nalgebra::Matrix3<f64>,
    d: [nalgebra::Matrix3<f64>; 3],
    dd: [[nalgebra::Matrix3<f64>; 3]; 3],
}

impl RotationDerivatives {
    /// `R`, its first derivatives and, with `second`, its second ones
    /// (zero otherwise: the first derivatives of the legs need none).
    fn new(a: f64, b: f64, c: f64, second: bool) -> Self {
        use nalgebra::Matrix3;
        let (sa, ca) = a.sin_cos();
        let (sb, cb) = b.sin_cos();
        let (sc, cc) = c.sin_cos();
        let x = [
            Matrix3::new(1.0, 0.0, 0.0, 0.0, ca, -sa, 0.0, sa, ca),
            Matrix3::new(0.0, 0.0, 0.0, 0.0, -sa, -ca, 0.0, ca, -sa),
            Matrix3::new(0.0, 0.0, 0.0, 0.0, -ca, sa, 0.0, -sa, -ca),
        ];
        let y = [
            Matrix3::new(cb, 0.0, sb, 0.0, 1.0, 0.0, -sb, 0.0, cb),
            Matrix3::new(-sb, 0.0, cb, 0.0, 0.0, 0.0, -cb, 0.0, -sb),
            Matrix3::new(-cb, 0.0, -sb, 0.0, 0.0, 0.0, sb, 0.0, -cb),
        ];
        let z = [
            Matrix3::new(cc, -sc, 0.0, sc, cc, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(-sc, -cc, 0.0, cc, -sc, 0.0, 0.0, 0.0, 0.0),
            Matrix3::new(-cc, sc, 0.0, -sc, -cc, 0.0, 0.0, 0.0, 0.0),
        ];
        // Derivative orders of (a, b, c) for each product.
        let prod = |oa: usize, ob: usize, oc: usize| z[oc] * y[ob] * x[oa];
        let order = |j: usize| -> [usize; 3] {
            let mut o = [0; 3];
            o[j] += 1;
            o
        };
        let d = [0, 1, 2].map(|j| {
            let o = order(j);
            prod(o[0], o[1], o[2])
        });
        let dd = [0, 1, 2].map(|j| {
            [0, 1, 2].map(|k| {
                if !second {
                    return Matrix3::zeros();
                }
                let mut o = order(j);
                o[k] += 1;
                prod(o[0], o[1], o[2])
            })
        });
        Self {
            r: prod(0, 0, 0),
            d,
            dd,
        }
    }
}

/// Closed-form second derivatives of each leg's constraint
/// `g_i = |w_i| − L_i`, `w_i = p + R b_i − a_i`, over its twelve variables
/// `z = (p, θ, a_i, b_i)`: `∇²g = Wᵀ (I − u uᵀ)/|w| W + Σ_m u_m ∇²w_m` with
/// `W = ∂w/∂z = [I, (∂R/∂θ_j) b, −I, R]` and `u = w/|w|`.
struct LegHessians<'a> {
    q: &'a [f64],
    rho: &'a [f64],
    n: usize,
    rot: RotationDerivatives,
}

impl<'a> LegHessians<'a> {
    fn new(q: &'a [f64], rho: &'a [f64], n: usize) -> Self {
        let pose = &q[n..n + 6];
        Self {
            q,
            rho,
            n,
            rot: RotationDerivatives::new(pose[3], pose[4], pose[5], true),
        }
    }

    /// The indices of `z` in `[q; ρ]` and `∇²g_i` over them.
    fn leg(&self, i: usize) -> ([usize; 12], nalgebra::SMatrix<f64, 12, 12>) {
        use nalgebra::{Matrix3, SMatrix, Vector3};
        let (n, nq) = (self.n, self.n + 6);
        let (q, rho, rot) = (self.q, self.rho, &self.rot);
        let p = Vector3::new(q[n], q[n + 1], q[n + 2]);
        let a = Vector3::new(rho[3 * i], rho[3 * i + 1], rho[3 * i + 2]);
        let b = Vector3::new(
            rho[3 * n + 3 * i],
            rho[3 * n + 3 * i + 1],
            rho[3 * n + 3 * i + 2],
        );
        let w = p + rot.r * b - a;
        let len = w.norm();
        let mut idx = [0usize; 12];
        for k in 0..3 {
            idx[k] = n + k;
            idx[3 + k] = n + 3 + k;
            idx[6 + k] = nq + 3 * i + k;
            idx[9 + k] = nq + 3 * n + 3 * i + k;
        }
        let mut h = SMatrix::<f64, 12, 12>::zeros();
        if len <= 0.0 {
            return (idx, h);
        }
        let u = w / len;
        let mut wz = SMatrix::<f64, 3, 12>::zeros();
        wz.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        for j in 0..3 {
            wz.fixed_view_mut::<3, 1>(0, 3 + j)
                .copy_from(&(rot.d[j] * b));
        }
        wz.fixed_view_mut::<3, 3>(0, 6)
            .copy_from(&(-Matrix3::identity()));
        wz.fixed_view_mut::<3, 3>(0, 9).copy_from(&rot.r);
        let proj = (Matrix3::identity() - u * u.transpose()) / len;
        h += wz.transpose() * proj * wz;
        for j in 0..3 {
            for k in 0..3 {
                h[(3 + j, 3 + k)] += u.dot(&(rot.dd[j][k] * b));
            }
            let c = rot.d[j].transpose() * u;
            for l in 0..3 {
                h[(3 + j, 9 + l)] += c[l];
                h[(9 + l, 3 + j)] += c[l];
            }
        }
        (idx, h)
    }

    /// [`LegHessians::leg`]'s block on the platform's six joints `(p, θ)`
    /// alone (its first six rows and columns), computed without the rest:
    /// the same products in the same order, so the same numbers (a large
    /// calibration computes these for each equilibrium).
    fn platform(&self, i: usize) -> nalgebra::SMatrix<f64, 6, 6> {
        use nalgebra::{Matrix3, SMatrix, Vector3};
        let n = self.n;
        let (q, rho, rot) = (self.q, self.rho, &self.rot);
        let p = Vector3::new(q[n], q[n + 1], q[n + 2]);
        let a = Vector3::new(rho[3 * i], rho[3 * i + 1], rho[3 * i + 2]);
        let b = Vector3::new(
            rho[3 * n + 3 * i],
            rho[3 * n + 3 * i + 1],
            rho[3 * n + 3 * i + 2],
        );
        let w = p + rot.r * b - a;
        let len = w.norm();
        let mut h = SMatrix::<f64, 6, 6>::zeros();
        if len <= 0.0 {
            return h;
        }
        let u = w / len;
        let mut wz = SMatrix::<f64, 3, 6>::zeros();
        wz.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        for j in 0..3 {
            wz.fixed_view_mut::<3, 1>(0, 3 + j)
                .copy_from(&(rot.d[j] * b));
        }
        let proj = (Matrix3::identity() - u * u.transpose()) / len;
        h += wz.transpose() * proj * wz;
        for j in 0..3 {
            for k in 0..3 {
                h[(3 + j, 3 + k)] += u.dot(&(rot.dd[j][k] * b));
            }
        }
        h
    }
}

impl Built for GoughStewart {
    const ATLAS_POINTS: usize = 800;
    fn spec_mut(&mut self) -> &mut Spec {
        &mut self.spec
    }
    /// The forward sign alone, the one its branch checks compare.
    fn keep_reference(&mut self, signs: [i8; 2]) {
        self.branch = signs[0];
    }
    fn atlas_mut(&mut self) -> Option<&mut crate::engine::atlas::Atlas> {
        Some(&mut self.atlas)
    }
}

impl Mechanism for GoughStewart {
    fn spec(&self) -> &Spec {
        &self.spec
    }

    /// `g_i = |p + R b_i − a_i| − L_i` (docs/model.md eq. 3, one per leg).
    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]) {
        let n = self.n;
        let pose = &q[n..n + 6];
        let r = rotation(pose[3], pose[4], pose[5]);
        for i in 0..n {
            let b = &rho[3 * n + 3 * i..3 * n + 3 * i + 3];
            let a = &rho[3 * i..3 * i + 3];
            let mut s = D::from(0.0);
            for k in 0..3 {
                let w = pose[k] + r[k][0] * b[0] + r[k][1] * b[1] + r[k][2] * b[2] - a[k];
                s += w * w;
            }
            g[i] = s.sqrt() - q[i];
        }
    }

    /// The platform pose.
    fn tool<D: Scalar>(&self, q: &[D], _rho: &[D], x: &mut [D]) {
        x.copy_from_slice(&q[self.n..self.n + 6]);
    }

    /// Closed form: with `w_i = p + R b_i − a_i` and `u_i = w_i/|w_i|`,
    /// `g_i = |w_i| − L_i` has `∂g_i/∂L_i = −1`, `∂g_i/∂p = u_i`,
    /// `∂g_i/∂θ_j = u_iᵀ (∂R/∂θ_j) b_i`, `∂g_i/∂a_i = −u_i`,
    /// `∂g_i/∂b_i = Rᵀu_i`; the tool map is the pose itself.
    fn first_derivatives(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
    ) -> Option<crate::mechanism::autodiff::Jacobians> {
        use nalgebra::{DMatrix, Vector3};
        let n = self.n;
        let nq = n + 6;
        let pose = &q[n..nq];
        let RotationDerivatives { r, d: dr, .. } =
            RotationDerivatives::new(pose[3], pose[4], pose[5], false);
        let p = Vector3::new(pose[0], pose[1], pose[2]);
        let (c0, width) = (cols.start, cols.len());
        let mut g = vec![0.0; n];
        let mut dg = DMatrix::zeros(n, width);
        let mut dx = DMatrix::zeros(6, width);
        let put = |m: &mut DMatrix<f64>, row: usize, col: usize, v: f64| {
            if col >= cols.start && col < cols.end {
                m[(row, col - c0)] = v;
            }
        };
        for i in 0..n {
            let a = Vector3::new(rho[3 * i], rho[3 * i + 1], rho[3 * i + 2]);
            let b = Vector3::new(
                rho[3 * n + 3 * i],
                rho[3 * n + 3 * i + 1],
                rho[3 * n + 3 * i + 2],
            );
            let w = p + r * b - a;
            let len = w.norm();
            g[i] = len - q[i];
            let u = if len > 0.0 { w / len } else { Vector3::zeros() };
            put(&mut dg, i, i, -1.0);
            for k in 0..3 {
                put(&mut dg, i, n + k, u[k]);
                put(&mut dg, i, n + 3 + k, u.dot(&(dr[k] * b)));
                put(&mut dg, i, nq + 3 * i + k, -u[k]);
            }
            let rtu = r.transpose() * u;
            for k in 0..3 {
                put(&mut dg, i, nq + 3 * n + 3 * i + k, rtu[k]);
            }
        }
        for k in 0..6 {
            put(&mut dx, k, n + k, 1.0);
        }
        Some(crate::mechanism::autodiff::Jacobians {
            g,
            x: pose.to_vec(),
            dg,
            dx,
        })
    }

    fn weighted_hessian(
        &self,
        q: &[f64],
        rho: &[f64],
        lambda: &[f64],
        _mu: &[f64],
    ) -> nalgebra::DMatrix<f64> {
        // The tool map is linear in q: only the constraints curve.
        let (n, nq) = (self.n, self.n + 6);
        let mut h = nalgebra::DMatrix::zeros(nq, nq + rho.len());
        let legs = LegHessians::new(q, rho, n);
        for (i, &l) in lambda.iter().enumerate().take(n) {
            if l == 0.0 {
                continue;
            }
            let (idx, hi) = legs.leg(i);
            for (r, &vr) in idx.iter().enumerate() {
                if vr >= nq {
                    continue;
                }
                for (c, &vc) in idx.iter().enumerate() {
                    h[(vr, vc)] += l * hi[(r, c)];
                }
            }
        }
        h
    }

    fn joint_hessians(&self, q: &[f64], rho: &[f64]) -> Vec<nalgebra::DMatrix<f64>> {
        let (n, nq) = (self.n, self.n + 6);
        let legs = LegHessians::new(q, rho, n);
        let mut out = Vec::with_capacity(n + 6);
        for i in 0..n {
            let (idx, hi) = legs.leg(i);
            let mut m = nalgebra::DMatrix::zeros(nq, nq);
            for r in 0..6 {
                for c in 0..6 {
                    m[(idx[r], idx[c])] = hi[(r, c)];
                }
            }
            out.push(m);
        }
        out.extend(std::iter::repeat_n(nalgebra::DMatrix::zeros(nq, nq), 6));
        out
    }

    fn joint_hessians_cheap(&self) -> bool {
        true
    }

    fn joint_hessian_blocks(
        &self,
        q: &[f64],
        rho: &[f64],
        out: &mut dyn FnMut(&[usize], &[f64]),
    ) -> bool {
        // Each leg's on the platform's six joints, as `joint_hessians`
        // places them; the tool coordinates are joints (no curvature).
        let n = self.n;
        let legs = LegHessians::new(q, rho, n);
        let platform: [usize; 6] = std::array::from_fn(|k| n + k);
        for i in 0..n {
            out(&platform, legs.platform(i).as_slice());
        }
        for _ in 0..6 {
            out(&[], &[]);
        }
        true
    }

    fn inverse_kinematics_closed(&self, target: &[f64], rho: &[f64]) -> Option<Result<Vec<f64>>> {
        Some(self.ik(target, rho))
    }

    fn configuration_guess(&self, commands: &[f64], rho: &[f64]) -> Option<Vec<f64>> {
        let q = self.atlas.nearest(commands)?;
        Some(self.refine_guess(q, commands, rho))
    }

    /// The assembly mode of the reference pose: the same sign of the forward
    /// kinematics determinant ([`crate::engine::kinematics::branch_signs`]).
    fn on_branch(&self, q: &[f64], rho: &[f64]) -> bool {
        // The forward sign alone ([`crate::engine::kinematics::branch_signs`]'s
        // first), without the inverse one's 12 × 12 determinant.
        self.branch == 0 || {
            let j = crate::mechanism::autodiff::jacobians(self, q, rho, 0..q.len());
            crate::engine::kinematics::forward_branch_sign_of(&self.spec, &j) == self.branch
        }
    }

    fn on_branch_near(
        &self,
        _q: &[f64],
        _rho: &[f64],
        jac: &crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        self.branch == 0
            || crate::engine::kinematics::forward_branch_sign_of(&self.spec, jac) == self.branch
    }
}
