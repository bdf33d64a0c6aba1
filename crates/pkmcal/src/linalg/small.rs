//! Vectors and 3×3 matrices as plain arrays, generic over the scalar
//! ([`Scalar`]: `f64` or a dual number), for the closed forms of the
//! spatial kinds: products, cross products, Rodrigues' rotation. Each sum
//! is written out in index order, so that a result is the same to the bit
//! wherever it is computed (nalgebra's fixed-size types would need a
//! conversion at every joint of a leg, and do not take dual numbers).

use crate::linalg::Scalar;

/// A 3×3 matrix, row-major.
pub type Mat3<D> = [[D; 3]; 3];

/// The identity matrix.
pub fn identity<D: Scalar>() -> Mat3<D> {
    let (o, l) = (D::from(0.0), D::from(1.0));
    [[l, o, o], [o, l, o], [o, o, l]]
}

/// The product `a b`.
pub fn mat_mul<D: Scalar>(a: &Mat3<D>, b: &Mat3<D>) -> Mat3<D> {
    let mut c = [[D::from(0.0); 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    c
}

/// The product `r v`.
pub fn apply<D: Scalar>(r: &Mat3<D>, v: [D; 3]) -> [D; 3] {
    [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

/// The product `rᵀ v` (a vector of the frame `r` maps from).
pub fn apply_transposed<D: Scalar>(r: &Mat3<D>, v: [D; 3]) -> [D; 3] {
    [0, 1, 2].map(|i| r[0][i] * v[0] + r[1][i] * v[1] + r[2][i] * v[2])
}

/// Column `c` of `m`.
pub fn column<D: Scalar>(m: &Mat3<D>, c: usize) -> [D; 3] {
    [m[0][c], m[1][c], m[2][c]]
}

/// Rotation by `t` about the unit axis `u` (Rodrigues).
pub fn rotation_about<D: Scalar>(u: [D; 3], t: D) -> Mat3<D> {
    let (s, c) = t.sin_cos();
    let v = D::from(1.0) - c;
    [
        [
            c + u[0] * u[0] * v,
            u[0] * u[1] * v - u[2] * s,
            u[0] * u[2] * v + u[1] * s,
        ],
        [
            u[1] * u[0] * v + u[2] * s,
            c + u[1] * u[1] * v,
            u[1] * u[2] * v - u[0] * s,
        ],
        [
            u[2] * u[0] * v - u[1] * s,
            u[2] * u[1] * v + u[0] * s,
            c + u[2] * u[2] * v,
        ],
    ]
}

/// `a · b`.
pub fn dot<D: Scalar>(a: [D; 3], b: [D; 3]) -> D {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a − b`.
pub fn sub<D: Scalar>(a: [D; 3], b: [D; 3]) -> [D; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a × b`.
pub fn cross<D: Scalar>(a: [D; 3], b: [D; 3]) -> [D; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `|v|`.
pub fn norm<D: Scalar>(v: [D; 3]) -> D {
    dot(v, v).sqrt()
}

/// `v / |v|`.
pub fn normalized<D: Scalar>(v: [D; 3]) -> [D; 3] {
    let n = norm(v);
    v.map(|c| c / n)
}

/// An orthonormal frame about an axis: `n` (the axis normalised),
/// `e1 = n × z` normalised (`x` when `n` is along `z`) and `e2 = n × e1`,
/// the two directions a spatial joint's axis tilts towards.
pub fn axis_basis(axis: [f64; 3]) -> Mat3<f64> {
    let n = normalized(axis);
    let c = cross(n, [0.0, 0.0, 1.0]);
    let e1 = if dot(c, c) < 1e-12 {
        [1.0, 0.0, 0.0]
    } else {
        normalized(c)
    };
    [n, e1, cross(n, e1)]
}
