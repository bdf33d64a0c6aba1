//! Tests of `pkmcal::linalg::solve`.

use nalgebra::{DMatrix, DVector};
use pkmcal::linalg::solve::*;
use rand::{RngExt, SeedableRng, rngs::StdRng};

/// The scaled solve's maxima are `f64::max`'s sequential folds, bit for
/// bit: NaN entries skipped, signed zeros, every length and remainder.
#[test]
fn lane_maxima_are_the_sequential_folds() {
    let mut rng = StdRng::seed_from_u64(11);
    for len in 0..40 {
        for case in 0..4 {
            let v: Vec<f64> = (0..len)
                .map(|i| match (case, i % 5) {
                    (1, 0) => f64::NAN,
                    (2, _) => -0.0,
                    (3, 1) => f64::INFINITY,
                    _ => rng.random_range(-1e3..1e3),
                })
                .collect();
            let sequential = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert_eq!(
                largest_magnitude(&v).to_bits(),
                sequential.to_bits(),
                "{v:?}"
            );
            let running = v.iter().fold(0.0f64, |m, x| larger(m, x.abs()));
            assert_eq!(running.to_bits(), sequential.to_bits());
        }
    }
}

/// The scaled LU kept and solved later agrees with the one-pass scaled
/// solve to rounding (several sizes, mixed units, right-hand sides
/// solved in turn with one factorisation), refuses the same singular
/// systems, and scales by powers of two only.
#[test]
fn kept_scaled_factors_solve_as_the_one_pass_solve() {
    let mut rng = StdRng::seed_from_u64(5);
    let mut lu = ScaledLu::default();
    for n in 1..=12 {
        for case in 0..3 {
            let mut a = DMatrix::from_fn(n, n, |_, _| rng.random_range(-3.0..3.0));
            // Mixed units: a stiff block beside small entries.
            for i in 0..n / 2 {
                a[(i, i)] *= 1e4;
            }
            if case == 1 {
                a.column_mut(n - 1).fill(0.0);
            }
            if case == 2 {
                a[(0, n - 1)] = f64::NAN;
            }
            let factored = lu.factor(a.as_slice(), n);
            for v in lu.rows.iter().chain(&lu.cols).filter(|_| factored) {
                assert_eq!(v.to_bits() << 12, 0, "{v} is a power of two");
            }
            for _ in 0..3 {
                let b = DMatrix::from_fn(n, 1, |_, _| rng.random_range(-3.0..3.0));
                let (mut a1, mut b1) = (a.clone(), b.clone());
                let solved = solve_scaled_in_place(&mut a1, &mut b1);
                assert_eq!(solved, factored, "n {n} case {case}");
                if solved {
                    let mut b2 = b.as_slice().to_vec();
                    lu.solve(&mut b2);
                    // (A NaN entry that passes the test gives NaN
                    // solutions in both, which the callers reject.)
                    let size = b1.amax();
                    for (x, y) in b1.iter().zip(&b2) {
                        let close = (x - y).abs() <= 1e-10 * size;
                        assert!(close || (x.is_nan() && y.is_nan()), "n {n}: {x} {y}");
                    }
                }
            }
        }
    }
    // Largest magnitudes outside the normal range are refused.
    assert_eq!(unit_factor(3.0), Some(0.5));
    assert_eq!(unit_factor(1.0), Some(1.0));
    assert_eq!(unit_factor(0.75), Some(2.0));
    for m in [
        0.0,
        f64::MIN_POSITIVE / 2.0,
        f64::MAX,
        f64::INFINITY,
        f64::NAN,
    ] {
        assert_eq!(unit_factor(m), None, "{m}");
    }
    assert!(!lu.factor(&[f64::MAX, 1.0, 1.0, 1.0], 2));
}

/// The in-place solve is [`checked_lu`] then its solve, bit for bit,
/// singular systems included (a zero column, a tiny pivot, a NaN entry).
#[test]
fn square_solves_in_place_are_the_allocating_ones() {
    let mut rng = StdRng::seed_from_u64(7);
    for n in 1..=14 {
        for case in 0..4 {
            let mut a = DMatrix::from_fn(n, n, |_, _| rng.random_range(-3.0..3.0));
            let b = DVector::from_fn(n, |_, _| rng.random_range(-3.0..3.0));
            match case {
                1 => a.column_mut(n / 2).fill(0.0),
                2 => {
                    // The last column nearly the first (a tiny pivot).
                    let c = a.column(0) + a.column(n - 1) * 1e-12;
                    a.column_mut(n - 1).copy_from(&c);
                }
                3 => a[(n - 1, 0)] = f64::NAN,
                _ => {}
            }
            let expected = checked_lu(a.clone()).and_then(|lu| lu.solve(&b));
            let (mut a2, mut x) = (a.clone(), b.as_slice().to_vec());
            let solved = solve_square_in_place(&mut a2, &mut x);
            assert_eq!(solved, expected.is_some(), "n {n} case {case}");
            if let Some(e) = expected {
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(e.as_slice()), bits(&x), "n {n} case {case}");
            }
        }
    }
}
