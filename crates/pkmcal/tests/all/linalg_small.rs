//! Tests of `pkmcal::linalg::small`.

use pkmcal::linalg::small::*;

/// A rotation about an axis keeps the axis, is orthonormal, and turns
/// a perpendicular vector by its angle; the basis about an axis is
/// orthonormal whatever the axis.
#[test]
fn rotations_and_bases_are_orthonormal() {
    let u = normalized([1.0, -2.0, 0.5]);
    let r = rotation_about(u, 0.7);
    let rt = [0, 1, 2].map(|i| column(&r, i));
    let i3 = mat_mul(&r, &rt);
    for (a, row) in i3.iter().enumerate() {
        for (b, v) in row.iter().enumerate() {
            let want: f64 = if a == b { 1.0 } else { 0.0 };
            assert!((v - want).abs() < 1e-15, "{i3:?}");
        }
    }
    assert!(norm(sub(apply(&r, u), u)) < 1e-15);
    let p = normalized(cross(u, [0.0, 0.0, 1.0]));
    assert!((dot(apply(&r, p), p) - 0.7f64.cos()).abs() < 1e-15);
    assert!(norm(sub(apply_transposed(&r, apply(&r, p)), p)) < 1e-15);
    for axis in [[0.0, 0.0, 3.0], [1.0, 2.0, 3.0], [0.0, 1.0, 0.0]] {
        let b = axis_basis(axis);
        for (i, j) in [(0, 1), (0, 2), (1, 2)] {
            assert!(dot(b[i], b[j]).abs() < 1e-15);
        }
        assert!(b.iter().all(|v| (norm(*v) - 1.0).abs() < 1e-15));
    }
    assert_eq!(
        identity::<f64>(),
        mat_mul(&identity::<f64>(), &identity::<f64>())
    );
}
