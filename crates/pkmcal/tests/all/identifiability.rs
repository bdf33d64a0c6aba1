//! Tests of `pkmcal::identify::identifiability`.

use nalgebra::DMatrix;
use pkmcal::identify::identifiability::*;
use rand::RngExt;
use rand::SeedableRng;
use rand::rngs::StdRng;

/// Relative agreement of the singular values found through the QR with
/// those of the scaled matrix itself (both backward stable: rounding
/// times the condition number at most).
const SVD_AGREE: f64 = 1e-12;

/// [`scaled_svd`] through the QR gives the singular values and right
/// singular vectors of the scaled matrix: on random tall matrices with
/// columns of very different sizes, a zero column and two nearly
/// dependent columns, and on a wide one (the zero-row path).
#[test]
fn the_svd_through_the_qr_is_that_of_the_scaled_matrix() {
    let mut rng = StdRng::seed_from_u64(11);
    for (m, n) in [(60, 7), (120, 12), (7, 7), (4, 6)] {
        let mut a = DMatrix::from_fn(m, n, |_, c| {
            rng.random_range(-1.0..1.0) * 10f64.powi(c as i32 % 5 - 2)
        });
        a.column_mut(1).fill(0.0);
        let c3 = a.column(3).into_owned();
        a.column_mut(4).copy_from(&(c3 * 2.0));
        a[(0, 4)] += 1e-6;
        let norms: Vec<f64> = (0..n).map(|k| a.column(k).norm()).collect();
        let (sv, vt, _) = scaled_svd(&a, &norms);
        let mut scaled = a.clone();
        for (k, s) in norms.iter().enumerate() {
            if *s > 0.0 {
                scaled.column_mut(k).unscale_mut(*s);
            }
        }
        let direct = scaled.clone().svd(false, false).singular_values;
        let mut ours = sv.clone();
        let mut theirs: Vec<f64> = direct.iter().copied().collect();
        ours.sort_by(|a, b| b.total_cmp(a));
        theirs.sort_by(|a, b| b.total_cmp(a));
        for (o, t) in ours.iter().zip(&theirs) {
            assert!(
                (o - t).abs() <= SVD_AGREE * theirs[0],
                "{m}x{n}: {o} vs {t}"
            );
        }
        // Each right vector: ‖scaled v‖ is its singular value, v a unit vector.
        for (i, s) in sv.iter().enumerate() {
            let v = vt.row(i).transpose();
            assert!(
                (v.norm() - 1.0).abs() < SVD_AGREE,
                "{m}x{n}: |v| = {}",
                v.norm()
            );
            let image = (&scaled * &v).norm();
            assert!(
                (image - s).abs() <= SVD_AGREE * theirs[0],
                "{m}x{n}: {image} vs {s}"
            );
        }
    }
}
