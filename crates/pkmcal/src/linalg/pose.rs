//! The pose convention, in one place: a spatial orientation is the Euler
//! angles `(rx, ry, rz)` of `R = Rz(rz) Ry(ry) Rx(rx)`, and a pose
//! `[x, y, z, rx, ry, rz]` maps a point `v` of its body to `p + R v`.

use crate::linalg::Scalar;

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
    let r = rotation(pose[3], pose[4], pose[5]);
    let mut out = [pose[0], pose[1], pose[2]];
    for (i, o) in out.iter_mut().enumerate() {
        *o += r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2];
    }
    out
}

pub(crate) fn euler(m: &dyn Fn(usize, usize) -> f64) -> (f64, f64, f64) {
    (
        m(2, 1).atan2(m(2, 2)),
        (-m(2, 0)).clamp(-1.0, 1.0).asin(),
        m(1, 0).atan2(m(0, 0)),
    )
}
