//! Tests of `pkmcal::engine::load`.

use pkmcal::ToolLayout;
use pkmcal::engine::load::*;
use pkmcal::linalg::pose::rotation;

/// The work of a moment over a small rotation equals `Q·δ(angles)`.
#[test]
fn euler_generalised_forces_do_the_work_of_the_moment() {
    let x = [1.0, 2.0, 700.0, 0.1, -0.2, 0.3];
    let load = [0.0, 0.0, 0.0, 2.0, -1.0, 3.0];
    let q = generalized_forces(ToolLayout::SpatialPose, &x, &load);
    let h = 1e-6;
    for k in 0..3 {
        let mut y = x;
        y[3 + k] += h;
        let r0 = rotation(x[3], x[4], x[5]);
        let r1 = rotation(y[3], y[4], y[5]);
        // Small rotation vector ω h = vee(R1 R0ᵀ − I).
        let m = |i: usize, j: usize| (0..3).map(|l| r1[i][l] * r0[j][l]).sum::<f64>();
        let w = [
            (m(2, 1) - m(1, 2)) / 2.0,
            (m(0, 2) - m(2, 0)) / 2.0,
            (m(1, 0) - m(0, 1)) / 2.0,
        ];
        let work = 1e3 * (w[0] * load[3] + w[1] * load[4] + w[2] * load[5]);
        assert!(
            (work / h - q[3 + k]).abs() < 1e-4,
            "{k}: {} vs {}",
            work / h,
            q[3 + k]
        );
    }
}
