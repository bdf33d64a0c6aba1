//! Tests of `pkmcal::linalg::lu`.

use nalgebra::{DMatrix, DVector};
use pkmcal::linalg::lu::*;
use rand::{RngExt, SeedableRng};

/// Factors, solutions and determinants equal nalgebra's bit for bit, on
/// random matrices with and without zero columns and repeated pivots.
#[test]
fn same_bits_as_nalgebra() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    for trial in 0..400 {
        let n = 1 + trial % 14;
        let mut a = DMatrix::from_fn(n, n, |_, _| rng.random_range(-3.0..3.0));
        if trial % 7 == 3 {
            a.column_mut(n / 2).fill(0.0);
        }
        if trial % 5 == 1 && n > 1 {
            let r = a.row(0).into_owned();
            a.row_mut(n - 1).copy_from(&r);
        }
        if trial % 4 == 2 {
            a.iter_mut().for_each(|v: &mut f64| *v = f64::round(*v));
        }
        let b = DVector::from_fn(n, |_, _| rng.random_range(-1.0..1.0));
        let bm = DMatrix::from_fn(n, 3, |_, _| rng.random_range(-1.0..1.0));
        let ours = Lu::new(a.clone());
        let theirs = a.clone().lu();
        assert_eq!(ours.lu, *theirs.lu_internal(), "factors, trial {trial}");
        assert_eq!(
            ours.determinant().to_bits(),
            theirs.determinant().to_bits(),
            "determinant, trial {trial}"
        );
        assert_eq!(determinant(a.clone()).to_bits(), a.determinant().to_bits());
        assert_eq!(ours.solve(&b), theirs.solve(&b), "solve, trial {trial}");
        assert_eq!(ours.solve_matrix(&bm), theirs.solve(&bm), "trial {trial}");
        let (mut a2, mut b2) = (a.clone(), b.clone());
        let solved = solve_in_place(&mut a2, b2.as_mut_slice());
        assert_eq!(
            solved.then_some(b2),
            theirs.solve(&b),
            "in place, trial {trial}"
        );
    }
}
