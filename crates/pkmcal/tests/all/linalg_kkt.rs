//! Tests of `pkmcal::linalg::kkt`.

use nalgebra::DMatrix;
use pkmcal::linalg::kkt::*;
use pkmcal::linalg::solve::solve_scaled_in_place;
use rand::{RngExt, SeedableRng};

/// Agreement of the two routes on well-conditioned random systems
/// (each block, `x` and `y`, relative to its own size).
const AGREE: f64 = 1e-9;
/// Backward error of the null-space solution: `‖A z − b‖∞` relative to
/// `‖A‖∞ ‖z‖∞ + ‖b‖∞` (the whole LU's is about `ε`; the products with
/// `S` lose up to `cond(G_D)` of it, which Newton steps afford: the
/// equilibrium's accuracy is set by its residual, not by its steps).
const BACKWARD: f64 = 1e-11;

/// A random KKT system: `W` symmetric with a stiff diagonal on some
/// joints, `G` with entries of a few hundred (mm), `G_D` well away from
/// singular.
fn system(
    rng: &mut rand::rngs::StdRng,
    nq: usize,
    m: usize,
    k: usize,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = nq + m;
    let mut a = DMatrix::zeros(n, n);
    for i in 0..nq {
        for j in 0..=i {
            let v = rng.random_range(-50.0..50.0);
            a[(i, j)] = v;
            a[(j, i)] = v;
        }
        a[(i, i)] += if i % 2 == 0 { 3e5 } else { 1e3 };
    }
    for r in 0..m {
        for c in 0..nq {
            let v = rng.random_range(-300.0..300.0);
            a[(nq + r, c)] = v;
            a[(c, nq + r)] = v;
        }
    }
    let b = DMatrix::from_fn(n, k, |_, _| rng.random_range(-1.0..1.0));
    (a, b)
}

#[test]
fn the_null_space_solve_agrees_with_the_whole_lu() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let mut used = 0;
    for &(nq, m, k) in &[(5, 3, 1), (12, 9, 1), (12, 9, 3), (14, 8, 6), (9, 6, 2)] {
        for _ in 0..50 {
            let (a, b) = system(&mut rng, nq, m, k);
            let independent: Vec<usize> = (m..nq).collect();
            let mut whole = (a.clone(), b.clone());
            assert!(solve_scaled_in_place(&mut whole.0, &mut whole.1));
            let mut ns = b.clone();
            let fast = KktWork::default().null_space(&a, &mut ns, nq, &independent);
            used += usize::from(fast);
            if !fast {
                continue;
            }
            for (block, rows) in [("x", 0..nq), ("y", nq..nq + m)] {
                let size = whole.1.rows(rows.start, rows.len()).amax();
                let diff =
                    (ns.rows(rows.start, rows.len()) - whole.1.rows(rows.start, rows.len())).amax();
                assert!(
                    diff <= AGREE * size,
                    "{nq}+{m}, {block}: differ by {diff:e} (size {size:e})"
                );
            }
            let norm_a = a.row_iter().map(|r| r.abs().sum()).fold(0.0, f64::max);
            let residual = (&a * &ns - &b).amax();
            assert!(
                residual <= BACKWARD * (norm_a * ns.amax() + b.amax()),
                "{nq}+{m}: residual {residual:e}"
            );
            // And through the public entry: the null-space route where
            // it pays, else the whole LU.
            let mut a2 = a.clone();
            let mut b2 = b.clone();
            assert!(solve_kkt_in_place(
                &mut a2,
                &mut b2,
                nq,
                &independent,
                &mut KktWork::default()
            ));
            if null_space_pays(nq, m) {
                assert_eq!(b2, ns);
            } else {
                assert_eq!(b2, whole.1);
            }
        }
    }
    assert!(used > 200, "null-space route taken {used} times of 250");
}

/// The route by size, as measured: the 4-RRR's system (12 joints, 9
/// constraints) on the null space; the reference's (5 + 3) and an 8-leg
/// platform's (14 + 8) by the whole LU.
#[test]
fn the_null_space_route_is_taken_where_it_pays() {
    assert!(null_space_pays(12, 9));
    assert!(!null_space_pays(5, 3));
    assert!(!null_space_pays(14, 8));
}

#[test]
fn a_singular_dependent_block_goes_to_the_whole_lu() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let (nq, m) = (5, 2);
    let (mut a, b) = system(&mut rng, nq, m, 1);
    // G's columns of joints 0 and 1 (the dependent ones) made parallel:
    // G_D singular, the whole system not.
    for r in 0..m {
        let v = a[(nq + r, 0)];
        a[(nq + r, 1)] = 2.0 * v;
        a[(1, nq + r)] = 2.0 * v;
    }
    let independent = [2, 3, 4];
    let mut ns = b.clone();
    assert!(!KktWork::default().null_space(&a, &mut ns, nq, &independent));
    assert_eq!(ns, b, "nothing written");
    let mut whole = (a.clone(), b.clone());
    assert!(solve_scaled_in_place(&mut whole.0, &mut whole.1));
    let mut via = (a.clone(), b.clone());
    assert!(solve_kkt_in_place(
        &mut via.0,
        &mut via.1,
        nq,
        &independent,
        &mut KktWork::default()
    ));
    assert_eq!(via.1, whole.1);
    // A singular system stays singular.
    let mut s = a.clone();
    for r in 0..m {
        s[(nq + r, 2)] = 0.0;
        s[(nq + r, 3)] = 0.0;
        s[(nq + r, 4)] = 0.0;
        s[(2, nq + r)] = 0.0;
        s[(3, nq + r)] = 0.0;
        s[(4, nq + r)] = 0.0;
    }
    let mut rhs = b.clone();
    assert!(!solve_kkt_in_place(
        &mut s,
        &mut rhs,
        nq,
        &independent,
        &mut KktWork::default()
    ));
}
