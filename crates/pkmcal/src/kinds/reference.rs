//! The reference mechanism of docs/model.md §10 (paper §3): a planar 2-DOF parallel
//! mechanism with three actuated base revolute joints (Jeong & Kim).
//!
//! (A long file: the reference mechanism, its closed forms and its
//! hand-written derivatives are one job.)
//!
//! Joints `q1..q5`: `q1, q2, q3` actuated at `B1, B2, B3`; `q4, q5` the passive
//! elbows of legs 1 and 2; leg 3 is a single link. With `e(a) = (cos a, sin a)`:
//!
//! ```text
//! P1 = B1 + l11 e(q1) + l12 e(q1 + q4)
//! P2 = B2 + l21 e(q2) + l22 e(q2 + q5)
//! P3 = B3 + l31 e(q3)
//! g  = (|P1−P2|² − D1², |P2−P3|² − D2², |P3−P1|² − D3²)      (paper eq. 13–14)
//! Pt = P1 + Ptx·x̂ + Pty·ŷ,  x̂ = (P2−P1)/|P2−P1|,  ŷ = x̂ turned +90°
//! ```

use crate::error::{Error, Result};
use crate::mechanism::{Mechanism, Scalar, Spec};
use crate::units::Unit;

/// Geometric parameter names of the reference mechanism, in vector order.
pub const GEOMETRIC: [&str; 16] = [
    "l11", "l12", "l21", "l22", "l31", "B1x", "B1y", "B2x", "B2y", "B3x", "B3y", "D1", "D2", "D3",
    "Ptx", "Pty",
];

/// The parameters the paper identifies (its Table 1): all but `B1x B1y B2x`.
pub const PAPER_FREE: [&str; 16] = [
    "l11", "l12", "l21", "l22", "l31", "B2y", "B3x", "B3y", "D1", "D2", "D3", "Ptx", "Pty", "dq1",
    "dq2", "dq3",
];

/// Nominal values (paper Tables 2 and 3), in [`GEOMETRIC`] order, mm.
pub fn nominal_geometric() -> [f64; 16] {
    let side = 215.0;
    [
        280.0,
        280.0,
        280.0,
        280.0,
        280.0,
        -300.0,
        0.0,
        300.0,
        0.0,
        150.0,
        420.0,
        side,
        side,
        side,
        side / 2.0,
        side / (2.0 * 3f64.sqrt()),
    ]
}

/// Nominal stiffness of the three actuated joints (paper Table 3), N·m/rad.
pub const NOMINAL_STIFFNESS: [f64; 3] = [8360.0, 7750.0, 8390.0];

/// Reference configuration (tool at (−30, 165) mm), degrees, docs/model.md §10.
pub const REFERENCE_Q_DEG: [f64; 5] = [83.735, 204.025, -148.618, -135.209, -124.275];

/// The reference mechanism. Holds its [`Spec`]; the nominal values may be
/// overridden (e.g. from a mechanism file) with [`JeongKim2Dof::with_spec`].
#[derive(Debug, Clone)]
pub struct JeongKim2Dof {
    spec: Spec,
}

impl Default for JeongKim2Dof {
    fn default() -> Self {
        Self::new()
    }
}

impl JeongKim2Dof {
    /// The built-in reference with the paper's nominal values.
    pub fn new() -> Self {
        Self {
            spec: Self::default_spec(),
        }
    }

    /// The default description (names, nominal values, assembly mode).
    pub fn default_spec() -> Spec {
        let mut nominal = nominal_geometric().to_vec();
        nominal.extend([0.0; 3]);
        nominal.extend(NOMINAL_STIFFNESS);
        Spec {
            name: "Jeong-Kim planar 2-DOF, 3 actuators".into(),
            joints: ["q1", "q2", "q3", "q4", "q5"].map(String::from).to_vec(),
            actuated: vec![0, 1, 2],
            independent: vec![0, 1],
            n_constraints: 3,
            geometric: GEOMETRIC.map(String::from).to_vec(),
            offsets: ["dq1", "dq2", "dq3"].map(String::from).to_vec(),
            stiffness: ["k1", "k2", "k3"].map(String::from).to_vec(),
            tool_axes: vec!["x".into(), "y".into()],
            joint_units: vec![Unit::Radian; 5],
            geometric_units: vec![Unit::Millimetre; GEOMETRIC.len()],
            tool_units: vec![Unit::Millimetre; 2],
            tool_layout: crate::mechanism::tool::ToolLayout::PlanarPoint,
            nominal,
            reference_q: REFERENCE_Q_DEG.map(f64::to_radians).to_vec(),
            default_free: PAPER_FREE.map(String::from).to_vec(),
            workspace_box: vec![[-140.0, 250.0], [0.0, 420.0]],
            work_scale: crate::units::MM_TO_M,
            joint_scale: vec![],
            axis_scale: vec![],
            min_conditioning: crate::engine::atlas::MIN_CONDITIONING,
            renamed: vec![],
        }
    }

    /// A reference mechanism with another description (same structure, other
    /// nominal values, reference configuration or workspace box).
    pub fn with_spec(spec: Spec) -> Result<Self> {
        let d = Self::default_spec();
        if spec.joints != d.joints
            || spec.geometric != d.geometric
            || spec.actuated != d.actuated
            || spec.n_constraints != d.n_constraints
        {
            return Err(Error::InvalidMechanism(
                "the jeong-kim-2dof structure has fixed joints and parameter names".into(),
            ));
        }
        spec.validate()?;
        Ok(Self { spec })
    }

    /// The three platform points and the tool point, generic.
    fn points<D: Scalar>(q: &[D], r: &[D]) -> [[D; 2]; 3] {
        let (s1, c1) = q[0].sin_cos();
        let (s14, c14) = (q[0] + q[3]).sin_cos();
        let (s2, c2) = q[1].sin_cos();
        let (s25, c25) = (q[1] + q[4]).sin_cos();
        let (s3, c3) = q[2].sin_cos();
        let p1 = [r[5] + r[0] * c1 + r[1] * c14, r[6] + r[0] * s1 + r[1] * s14];
        let p2 = [r[7] + r[2] * c2 + r[3] * c25, r[8] + r[2] * s2 + r[3] * s25];
        let p3 = [r[9] + r[4] * c3, r[10] + r[4] * s3];
        [p1, p2, p3]
    }

    /// Branch indicators: sin q4, sin q5, z of (P3−B3)×(Pt−P3), and z of
    /// (P2−P1)×(P3−P1) (the platform the right way up: P3 on its +y side).
    fn branch(&self, q: &[f64], rho: &[f64]) -> [f64; 4] {
        let [p1, p2, p3] = Self::points(q, rho);
        let up = (p2[0] - p1[0]) * (p3[1] - p1[1]) - (p2[1] - p1[1]) * (p3[0] - p1[0]);
        let mut t = [0.0; 2];
        self.tool(q, rho, &mut t);
        let a = [p3[0] - rho[9], p3[1] - rho[10]];
        let b = [t[0] - p3[0], t[1] - p3[1]];
        [q[3].sin(), q[4].sin(), a[0] * b[1] - a[1] * b[0], up]
    }
}

fn dist2<D: Scalar>(a: &[D; 2], b: &[D; 2]) -> D {
    let dx = a[0] - b[0];
    let dy = a[1] - b[1];
    dx * dx + dy * dy
}

/// Wrap `a` to within π of `near`.
pub(crate) fn wrap_near(a: f64, near: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    near + (a - near + PI).rem_euclid(TAU) - PI
}

impl Mechanism for JeongKim2Dof {
    fn spec(&self) -> &Spec {
        &self.spec
    }

    /// Link lengths `l…` and platform sides `D…` must be positive.
    fn check_params(&self, rho: &[f64]) -> crate::Result<()> {
        for (name, &v) in self.spec.geometric.iter().zip(rho) {
            if (name.starts_with('l') || name.starts_with('D')) && v <= 0.0 {
                return Err(crate::Error::InvalidParameter {
                    name: name.clone(),
                    value: v,
                    reason: "a length must be positive".into(),
                });
            }
        }
        Ok(())
    }

    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]) {
        let [p1, p2, p3] = Self::points(q, rho);
        g[0] = dist2(&p1, &p2) - rho[11] * rho[11];
        g[1] = dist2(&p2, &p3) - rho[12] * rho[12];
        g[2] = dist2(&p3, &p1) - rho[13] * rho[13];
    }

    fn tool<D: Scalar>(&self, q: &[D], rho: &[D], x: &mut [D]) {
        let [p1, p2, _] = Self::points(q, rho);
        let d = [p2[0] - p1[0], p2[1] - p1[1]];
        let len = dist2(&p1, &p2).sqrt();
        let ux = [d[0] / len, d[1] / len];
        x[0] = p1[0] + rho[14] * ux[0] - rho[15] * ux[1];
        x[1] = p1[1] + rho[14] * ux[1] + rho[15] * ux[0];
    }

    fn inverse_kinematics_closed(&self, target: &[f64], rho: &[f64]) -> Option<Result<Vec<f64>>> {
        Some(self.ik(target, rho))
    }

    fn configuration_guess(&self, c: &[f64], r: &[f64]) -> Option<Vec<f64>> {
        // P3 is fixed by q3; P1 and P2 lie where their elbow circles meet the
        // circles of radius D3 and D2 around P3. Of the (up to) four
        // combinations on the elbow branches, keep the one whose |P1 − P2| is
        // closest to D1 with the platform the right way up.
        let reference = self.branch(&self.spec.reference_q, &self.spec.nominal);
        let p3 = [r[9] + r[4] * c[2].cos(), r[10] + r[4] * c[2].sin()];
        let mut legs: [Vec<(f64, [f64; 2])>; 2] = [vec![], vec![]];
        for (leg, (base, la, lb, d, sign)) in [
            ([r[5], r[6]], r[0], r[1], r[13], reference[0]),
            ([r[7], r[8]], r[2], r[3], r[12], reference[1]),
        ]
        .into_iter()
        .enumerate()
        {
            let e = [base[0] + la * c[leg].cos(), base[1] + la * c[leg].sin()];
            let (dx, dy) = (p3[0] - e[0], p3[1] - e[1]);
            let dist = dx.hypot(dy);
            let a = (lb * lb - d * d + dist * dist) / (2.0 * dist);
            let h2 = lb * lb - a * a;
            if h2.is_nan() || h2 < 0.0 {
                return None;
            }
            let h = h2.sqrt();
            let mid = [e[0] + a * dx / dist, e[1] + a * dy / dist];
            for s in [1.0, -1.0] {
                let p = [mid[0] - s * h * dy / dist, mid[1] + s * h * dx / dist];
                let elbow = wrap_near((p[1] - e[1]).atan2(p[0] - e[0]) - c[leg], 0.0);
                if elbow.sin() * sign > 0.0 {
                    legs[leg].push((elbow, p));
                }
            }
        }
        let mut best: Option<(f64, f64, f64)> = None;
        for &(e1, p1) in &legs[0] {
            for &(e2, p2) in &legs[1] {
                let up = (p2[0] - p1[0]) * (p3[1] - p1[1]) - (p2[1] - p1[1]) * (p3[0] - p1[0]);
                let miss = ((p2[0] - p1[0]).hypot(p2[1] - p1[1]) - r[11]).abs();
                if up * reference[3] > 0.0 && best.is_none_or(|b| miss < b.0) {
                    best = Some((miss, e1, e2));
                }
            }
        }
        let (_, e1, e2) = best?;
        Some(vec![
            c[0],
            c[1],
            c[2],
            wrap_near(e1, self.spec.reference_q[3]),
            wrap_near(e2, self.spec.reference_q[4]),
        ])
    }

    /// Closed form through the platform points: `∂g_k/∂v = 2 (P_i − P_j) ·
    /// (∂P_i/∂v − ∂P_j/∂v)` (less `2 D_k` on `D_k`), and the tool
    /// `P1 + (Ptx I + Pty J) u`, `u = (P2 − P1)/|P2 − P1|`, through
    /// `∂u = (I − u uᵀ) ∂(P2 − P1) / |P2 − P1|` (`J` turns by +90°).
    fn first_derivatives(
        &self,
        q: &[f64],
        r: &[f64],
        cols: std::ops::Range<usize>,
    ) -> Option<crate::mechanism::autodiff::Jacobians> {
        Some(closed_form_jacobians(q, r, cols))
    }

    fn first_derivatives_into(
        &self,
        q: &[f64],
        r: &[f64],
        cols: std::ops::Range<usize>,
        out: &mut crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        closed_form_jacobians_into(q, r, cols, out);
        true
    }

    /// Analytic second derivatives by the chain rule through the platform
    /// points `P = (P1, P2, P3)`: `∇²φ = Aᵀ ∇²_P φ̃ A + Σ_c ∂φ̃/∂P_c ∇²P_c`
    /// plus the tool offsets' mixed terms, with `A = ∂P/∂[q; ρ]`.
    fn weighted_hessian(
        &self,
        q: &[f64],
        r: &[f64],
        lambda: &[f64],
        mu: &[f64],
    ) -> nalgebra::DMatrix<f64> {
        analytic_weighted_hessian(q, r, lambda, mu)
    }

    fn joint_hessians(&self, q: &[f64], r: &[f64]) -> Vec<nalgebra::DMatrix<f64>> {
        // The points' derivatives once, weighted per output; joint columns only.
        let points = PointDerivatives::new(q, r);
        (0..5)
            .map(|o| {
                let mut w = [0.0; 5];
                w[o] = 1.0;
                points.weighted_hessian(r, &w[..3], &w[3..], 5)
            })
            .collect()
    }

    fn on_branch(&self, q: &[f64], rho: &[f64]) -> bool {
        let now = self.branch(q, rho);
        let reference = self.branch(&self.spec.reference_q, &self.spec.nominal);
        now.iter().zip(reference).all(|(a, b)| a * b > 0.0)
    }
}

impl JeongKim2Dof {
    fn ik(&self, t: &[f64], r: &[f64]) -> Result<Vec<f64>> {
        let unreachable = |reason: &str| Error::Unreachable {
            target: t.to_vec(),
            reason: reason.to_string(),
        };
        if t.len() != 2 || t.iter().any(|v| !v.is_finite()) {
            return Err(unreachable("a target needs two finite coordinates (x, y)"));
        }
        let reference = self.branch(&self.spec.reference_q, &self.spec.nominal);
        let (d1, d2, d3) = (r[11], r[12], r[13]);
        // Platform points in the platform frame, relative to the tool point.
        let a = (d1 * d1 + d3 * d3 - d2 * d2) / (2.0 * d1);
        let b2 = d3 * d3 - a * a;
        if b2 <= 0.0 {
            return Err(Error::InvalidMechanism(
                "platform side lengths D1, D2, D3 do not form a triangle".into(),
            ));
        }
        let local = [[0.0, 0.0], [d1, 0.0], [a, b2.sqrt()]].map(|p| [p[0] - r[14], p[1] - r[15]]);
        // Leg 3: |t + R(φ) v − B3| = l31, i.e. A cos φ + B sin φ = C.
        let v = local[2];
        let d = [t[0] - r[9], t[1] - r[10]];
        let big_a = d[0] * v[0] + d[1] * v[1];
        let big_b = d[1] * v[0] - d[0] * v[1];
        let c = (r[4] * r[4] - (d[0] * d[0] + d[1] * d[1]) - (v[0] * v[0] + v[1] * v[1])) / 2.0;
        let rr = big_a.hypot(big_b);
        if rr == 0.0 || c.abs() > rr {
            return Err(unreachable("leg 3 cannot reach the platform"));
        }
        let psi = big_b.atan2(big_a);
        let delta = (c / rr).acos();
        for phi in [psi + delta, psi - delta] {
            let (s, co) = phi.sin_cos();
            let world = local.map(|p| [t[0] + co * p[0] - s * p[1], t[1] + s * p[0] + co * p[1]]);
            let p3 = world[2];
            let a3 = [p3[0] - r[9], p3[1] - r[10]];
            let b3 = [t[0] - p3[0], t[1] - p3[1]];
            if (a3[0] * b3[1] - a3[1] * b3[0]) * reference[2] <= 0.0 {
                continue;
            }
            let mut q = [0.0; 5];
            q[2] = a3[1].atan2(a3[0]);
            for (leg, (base, la, lb, sign)) in [
                ([r[5], r[6]], r[0], r[1], reference[0]),
                ([r[7], r[8]], r[2], r[3], reference[1]),
            ]
            .into_iter()
            .enumerate()
            {
                let w = [world[leg][0] - base[0], world[leg][1] - base[1]];
                let l2 = w[0] * w[0] + w[1] * w[1];
                let ce = (l2 - la * la - lb * lb) / (2.0 * la * lb);
                if ce.abs() > 1.0 {
                    return Err(unreachable(&format!(
                        "leg {} cannot reach the platform",
                        leg + 1
                    )));
                }
                let elbow = ce.acos().copysign(sign);
                q[3 + leg] = elbow;
                q[leg] = w[1].atan2(w[0]) - (lb * elbow.sin()).atan2(la + lb * elbow.cos());
            }
            let q: Vec<f64> = q
                .iter()
                .zip(&self.spec.reference_q)
                .map(|(&a, &n)| wrap_near(a, n))
                .collect();
            return Ok(q);
        }
        Err(unreachable(
            "no platform orientation on the assembly branch",
        ))
    }
}

/// Parameter errors of the size the paper reports (about 1.4 mm of tool error
/// before calibration over the workspace): a fixed, documented scenario for the
/// demo, tests and benchmarks. Sub-millimetre length errors, milliradian
/// encoder offsets.
pub const DEMO_ERRORS: [(&str, f64); 16] = [
    ("l11", 0.42),
    ("l12", -0.32),
    ("l21", 0.26),
    ("l22", 0.37),
    ("l31", -0.29),
    ("B2y", 0.35),
    ("B3x", -0.47),
    ("B3y", 0.42),
    ("D1", 0.18),
    ("D2", -0.23),
    ("D3", 0.21),
    ("Ptx", 0.29),
    ("Pty", -0.23),
    ("dq1", 1.15e-3),
    ("dq2", -0.95e-3),
    ("dq3", 1.42e-3),
];

/// The demo's true parameters: nominal plus [`DEMO_ERRORS`].
pub fn demo_truth() -> crate::Params {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let mut p = crate::Params::nominal(spec);
    for (name, err) in DEMO_ERRORS {
        let i = spec.param_index(name).expect("demo names are valid");
        p.values[i] += err;
    }
    p
}

/// See [`Mechanism::weighted_hessian`] for [`JeongKim2Dof`]. Columns: the five
/// joints, then the 16 geometric parameters.
/// [`JeongKim2Dof::first_derivatives`].
fn closed_form_jacobians(
    q: &[f64],
    r: &[f64],
    cols: std::ops::Range<usize>,
) -> crate::mechanism::autodiff::Jacobians {
    let mut out = crate::mechanism::autodiff::Jacobians::empty();
    closed_form_jacobians_into(q, r, cols, &mut out);
    out
}

/// [`closed_form_jacobians`] into `out`'s buffers.
fn closed_form_jacobians_into(
    q: &[f64],
    r: &[f64],
    cols: std::ops::Range<usize>,
    out: &mut crate::mechanism::autodiff::Jacobians,
) {
    const NQ: usize = 5;
    const NV: usize = 21;
    let rho = |k: usize| NQ + k;
    // Each angle's sine and cosine once (as in `JeongKim2Dof::points`):
    // unit vectors `e(a) = (cos a, sin a)` and `e'(a) = (−sin a, cos a)`.
    let sc = |a: f64| {
        let (s, c) = a.sin_cos();
        ([c, s], [-s, c])
    };
    let (ea1, epa1) = sc(q[0]);
    let (eb1, epb1) = sc(q[0] + q[3]);
    let (ea2, epa2) = sc(q[1]);
    let (eb2, epb2) = sc(q[1] + q[4]);
    let (ea3, epa3) = sc(q[2]);
    let p1 = [
        r[5] + r[0] * ea1[0] + r[1] * eb1[0],
        r[6] + r[0] * ea1[1] + r[1] * eb1[1],
    ];
    let p2 = [
        r[7] + r[2] * ea2[0] + r[3] * eb2[0],
        r[8] + r[2] * ea2[1] + r[3] * eb2[1],
    ];
    let p3 = [r[9] + r[4] * ea3[0], r[10] + r[4] * ea3[1]];
    // ∂P_i/∂v, dense over the 21 variables (zeros elsewhere).
    let mut a = [[[0.0; 2]; NV]; 3];
    let comb =
        |x: [f64; 2], s: f64, y: [f64; 2], t: f64| [x[0] * s + y[0] * t, x[1] * s + y[1] * t];
    a[0][0] = comb(epa1, r[0], epb1, r[1]);
    a[0][3] = epb1.map(|c| c * r[1]);
    a[0][rho(0)] = ea1;
    a[0][rho(1)] = eb1;
    a[0][rho(5)] = [1.0, 0.0];
    a[0][rho(6)] = [0.0, 1.0];
    a[1][1] = comb(epa2, r[2], epb2, r[3]);
    a[1][4] = epb2.map(|c| c * r[3]);
    a[1][rho(2)] = ea2;
    a[1][rho(3)] = eb2;
    a[1][rho(7)] = [1.0, 0.0];
    a[1][rho(8)] = [0.0, 1.0];
    a[2][2] = epa3.map(|c| c * r[4]);
    a[2][rho(4)] = ea3;
    a[2][rho(9)] = [1.0, 0.0];
    a[2][rho(10)] = [0.0, 1.0];
    let p = [p1, p2, p3];
    out.resize(3, 2, cols.len());
    let crate::mechanism::autodiff::Jacobians { g, x, dg, dx } = out;
    for (k, (i, j)) in [(0usize, 1usize), (1, 2), (2, 0)].into_iter().enumerate() {
        let d = [p[i][0] - p[j][0], p[i][1] - p[j][1]];
        g[k] = d[0] * d[0] + d[1] * d[1] - r[11 + k] * r[11 + k];
        for (c, v) in cols.clone().enumerate() {
            let mut val =
                2.0 * (d[0] * (a[i][v][0] - a[j][v][0]) + d[1] * (a[i][v][1] - a[j][v][1]));
            if v == rho(11 + k) {
                val -= 2.0 * r[11 + k];
            }
            dg[(k, c)] = val;
        }
    }
    let d = [p2[0] - p1[0], p2[1] - p1[1]];
    let n = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let u = [d[0] / n, d[1] / n];
    let ju = [-u[1], u[0]];
    x[0] = p1[0] + r[14] * u[0] + r[15] * ju[0];
    x[1] = p1[1] + r[14] * u[1] + r[15] * ju[1];
    for (c, v) in cols.clone().enumerate() {
        let dd = [a[1][v][0] - a[0][v][0], a[1][v][1] - a[0][v][1]];
        let along = u[0] * dd[0] + u[1] * dd[1];
        let du = [(dd[0] - u[0] * along) / n, (dd[1] - u[1] * along) / n];
        // (Ptx I + Pty J) du, J du = (−du_y, du_x).
        let mut col = [
            a[0][v][0] + r[14] * du[0] - r[15] * du[1],
            a[0][v][1] + r[14] * du[1] + r[15] * du[0],
        ];
        if v == rho(14) {
            col[0] += u[0];
            col[1] += u[1];
        }
        if v == rho(15) {
            col[0] += ju[0];
            col[1] += ju[1];
        }
        dx[(0, c)] = col[0];
        dx[(1, c)] = col[1];
    }
}

fn analytic_weighted_hessian(
    q: &[f64],
    r: &[f64],
    lambda: &[f64],
    mu: &[f64],
) -> nalgebra::DMatrix<f64> {
    PointDerivatives::new(q, r).weighted_hessian(r, lambda, mu, 21)
}

/// The platform points `P1, P2, P3` at a configuration with their first and
/// second derivatives (`A = ∂P/∂[q; ρ]` and `∇²P`, sparse), shared by every
/// weighting of [`analytic_weighted_hessian`].
struct PointDerivatives {
    p: [nalgebra::Vector2<f64>; 3],
    /// Per point: (column of `[q; ρ]`, derivative) ([`Self::first`]; in
    /// arrays, not vectors: this is made for every sensitivity).
    first: (FirstOf<6>, FirstOf<6>, FirstOf<4>),
    /// Per point: (joint row, column, second derivative) ([`Self::second`]).
    second: (SecondOf<7>, SecondOf<7>, SecondOf<2>),
}

/// A point's `n` first derivatives: (column of `[q; ρ]`, derivative).
type FirstOf<const N: usize> = [(usize, nalgebra::Vector2<f64>); N];

/// A point's `n` second derivatives: (joint row, column, derivative).
type SecondOf<const N: usize> = [(usize, usize, nalgebra::Vector2<f64>); N];

impl PointDerivatives {
    /// Per point: (column of `[q; ρ]`, derivative).
    fn first(&self) -> [&[(usize, nalgebra::Vector2<f64>)]; 3] {
        [&self.first.0, &self.first.1, &self.first.2]
    }

    /// Per point: (joint row, column, second derivative).
    fn second(&self) -> [&[(usize, usize, nalgebra::Vector2<f64>)]; 3] {
        [&self.second.0, &self.second.1, &self.second.2]
    }

    fn new(q: &[f64], r: &[f64]) -> Self {
        use nalgebra::Vector2;
        const NQ: usize = 5;
        let e = |a: f64| Vector2::new(a.cos(), a.sin());
        let ep = |a: f64| Vector2::new(-a.sin(), a.cos());
        // Indices into v = [q1..q5, ρ].
        let rho = |k: usize| NQ + k;
        let [p1, p2, p3] = JeongKim2Dof::points(q, r).map(|p| Vector2::new(p[0], p[1]));
        // A = ∂P/∂v: per point, a list of (column, derivative).
        let (a1, b1) = (q[0], q[0] + q[3]);
        let (a2, b2) = (q[1], q[1] + q[4]);
        let a3 = q[2];
        let first = (
            [
                (0, ep(a1) * r[0] + ep(b1) * r[1]),
                (3, ep(b1) * r[1]),
                (rho(0), e(a1)),
                (rho(1), e(b1)),
                (rho(5), Vector2::new(1.0, 0.0)),
                (rho(6), Vector2::new(0.0, 1.0)),
            ],
            [
                (1, ep(a2) * r[2] + ep(b2) * r[3]),
                (4, ep(b2) * r[3]),
                (rho(2), e(a2)),
                (rho(3), e(b2)),
                (rho(7), Vector2::new(1.0, 0.0)),
                (rho(8), Vector2::new(0.0, 1.0)),
            ],
            [
                (2, ep(a3) * r[4]),
                (rho(4), e(a3)),
                (rho(9), Vector2::new(1.0, 0.0)),
                (rho(10), Vector2::new(0.0, 1.0)),
            ],
        );
        // Second derivatives of each point, rows in q: (row, column, value).
        let second = (
            [
                (0, 0, -(e(a1) * r[0] + e(b1) * r[1])),
                (0, 3, -e(b1) * r[1]),
                (3, 0, -e(b1) * r[1]),
                (3, 3, -e(b1) * r[1]),
                (0, rho(0), ep(a1)),
                (0, rho(1), ep(b1)),
                (3, rho(1), ep(b1)),
            ],
            [
                (1, 1, -(e(a2) * r[2] + e(b2) * r[3])),
                (1, 4, -e(b2) * r[3]),
                (4, 1, -e(b2) * r[3]),
                (4, 4, -e(b2) * r[3]),
                (1, rho(2), ep(a2)),
                (1, rho(3), ep(b2)),
                (4, rho(3), ep(b2)),
            ],
            [(2, 2, -e(a3) * r[4]), (2, rho(4), ep(a3))],
        );
        Self {
            p: [p1, p2, p3],
            first,
            second,
        }
    }

    /// `Σ λ_k ∇²g_k + Σ μ_i ∇²x_i`, rows the joints, the first `nv` columns of
    /// `[q; ρ]` (5: the joints only; 21: every column).
    fn weighted_hessian(
        &self,
        r: &[f64],
        lambda: &[f64],
        mu: &[f64],
        nv: usize,
    ) -> nalgebra::DMatrix<f64> {
        use nalgebra::{DMatrix, Matrix2, Vector2};
        const NQ: usize = 5;
        let rho = |k: usize| NQ + k;
        let (first, second) = (self.first(), self.second());
        let p = self.p;
        let [p1, p2, _] = p;
        // Outer function φ̃(P, D, Pt): gradient and Hessian in P (2×2 blocks).
        let mut grad = [Vector2::zeros(); 3];
        let mut hess = [[Matrix2::zeros(); 3]; 3];
        for (k, (i, j)) in [(0usize, 1usize), (1, 2), (2, 0)].into_iter().enumerate() {
            let d = p[i] - p[j];
            grad[i] += d * (2.0 * lambda[k]);
            grad[j] -= d * (2.0 * lambda[k]);
            let h = Matrix2::identity() * (2.0 * lambda[k]);
            hess[i][i] += h;
            hess[j][j] += h;
            hess[i][j] -= h;
            hess[j][i] -= h;
        }
        // Tool: μ·Pt = μ·P1 + z·u, u = (P2 − P1)/n, z = Ptx μ + Pty Rᵀμ.
        let w = Vector2::new(mu[0], mu[1]);
        let rt_w = Vector2::new(w[1], -w[0]);
        let z = w * r[14] + rt_w * r[15];
        let d = p2 - p1;
        let n = d.norm();
        let u = d / n;
        let proj = (Matrix2::identity() - u * u.transpose()) / n;
        let gz = proj * z;
        grad[0] += w - gz;
        grad[1] += gz;
        let zu = z.dot(&u);
        let hz = -(u * z.transpose() + z * u.transpose() + Matrix2::identity() * zu
            - u * u.transpose() * (3.0 * zu))
            / (n * n);
        hess[0][0] += hz;
        hess[1][1] += hz;
        hess[0][1] -= hz;
        hess[1][0] -= hz;
        // Mixed P–Pt terms: ∂(∇_P φ̃)/∂Ptx = ∓ proj μ, ∂/∂Pty = ∓ proj Rᵀμ.
        let gx = proj * w;
        let gy = proj * rt_w;
        let mut out = DMatrix::zeros(NQ, nv);
        // Aᵀ H A, rows restricted to joints.
        for (i, fi) in first.iter().enumerate() {
            for (j, fj) in first.iter().enumerate() {
                let h = hess[i][j];
                if h == Matrix2::zeros() {
                    continue;
                }
                for &(ri, ai) in fi.iter().filter(|(c, _)| *c < NQ) {
                    for &(cj, aj) in fj.iter().filter(|(c, _)| *c < nv) {
                        out[(ri, cj)] += ai.dot(&(h * aj));
                    }
                }
            }
        }
        // Σ ∂φ̃/∂P ∇²P.
        for (k, list) in second.iter().enumerate() {
            for &(ri, cj, v) in list.iter().filter(|(_, c, _)| *c < nv) {
                out[(ri, cj)] += grad[k].dot(&v);
            }
        }
        if nv <= rho(15) {
            return out;
        }
        // Pt columns.
        for (k, sign) in [(0usize, -1.0), (1, 1.0)] {
            for &(ri, ai) in first[k].iter().filter(|(c, _)| *c < NQ) {
                out[(ri, rho(14))] += sign * ai.dot(&gx);
                out[(ri, rho(15))] += sign * ai.dot(&gy);
            }
        }
        out
    }
}
