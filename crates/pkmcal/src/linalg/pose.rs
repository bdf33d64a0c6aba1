//! The pose convention, in one place: a spatial orientation is the Euler
//! angles `(rx, ry, rz)` of `R = Rz(rz) Ry(ry) Rx(rx)`, and a pose
//! `[x, y, z, rx, ry, rz]` maps a point `v` of its body to `p + R v`.

use crate::linalg::Scalar;
use crate::linalg::small::apply;

/// `R = Rz(c) Ry(b) Rx(a)`, row-major.
pub fn rotation<D: Scalar>(a: D, b: D, c: D) -> [[D; 3]; 3] {
    let (sa, ca) = a.sin_cos();
    let (sb, cb) = b.sin_cos();
    let (sc, cc) = c.sin_cos();
    [
        [cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa],
        [sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa],
        [-sb, cb * sa, cb * ca],
    ]
}

/// `p + R v` for a pose `[x, y, z, rx, ry, rz]`.
pub(crate) fn transform<D: Scalar>(pose: &[D], v: [D; 3]) -> [D; 3] {
    let rv = apply(&rotation(pose[3], pose[4], pose[5]), v);
    [0, 1, 2].map(|i| pose[i] + rv[i])
}

/// The base-frame axes `ω_x, ω_y, ω_z` the Euler angles `rx, ry, rz` of
/// `R = Rz(c) Ry(b) Rx(a)` turn about (`ω_z = z`, `ω_y = Rz y`,
/// `ω_x = Rz Ry x`), so that `∂(R v)/∂(angle k) = ω_k × R v`: the
/// platform's angular derivatives, and the moments a tool torque gives
/// each angle. They do not depend on `a`.
pub(crate) fn euler_axes(b: f64, c: f64) -> [[f64; 3]; 3] {
    let (sb, cb) = b.sin_cos();
    let (sc, cc) = c.sin_cos();
    [[cc * cb, sc * cb, -sb], [-sc, cc, 0.0], [0.0, 0.0, 1.0]]
}

pub(crate) fn euler(m: &dyn Fn(usize, usize) -> f64) -> (f64, f64, f64) {
    (
        m(2, 1).atan2(m(2, 2)),
        (-m(2, 0)).clamp(-1.0, 1.0).asin(),
        m(1, 0).atan2(m(0, 0)),
    )
}
