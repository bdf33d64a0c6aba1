//! Tests of `pkmcal::apply::screening`.

use nalgebra::DMatrix;
use pkmcal::apply::planning::Candidates;
use pkmcal::apply::screening::*;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// Agreement of kept gains with gains computed afresh (relative to the
/// gain, plus an absolute part for gains near 0).
const GAIN_TOL: f64 = 1e-9;

fn candidates(seed: u64, count: usize, nx: usize, n: usize) -> Candidates {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let rows = (0..count)
        .map(|_| {
            DMatrix::from_fn(nx, n, |_, j| {
                let g: f64 = StandardNormal.sample(&mut rng);
                g * 10f64.powi(j as i32 % 3 - 1)
            })
        })
        .collect();
    Candidates {
        points: vec![],
        rows,
    }
}

/// `log det(I + A (m + reg·I)⁻¹ Aᵀ)` of every candidate, directly.
fn direct(c: &Candidates, m: &DMatrix<f64>, reg: f64) -> Vec<f64> {
    let n = m.nrows();
    let inv = (m + DMatrix::identity(n, n) * reg)
        .try_inverse()
        .expect("positive definite");
    c.rows
        .iter()
        .map(|a| {
            let s = DMatrix::identity(a.nrows(), a.nrows()) + a * &inv * a.transpose();
            s.determinant().ln()
        })
        .collect()
}

fn info(c: &Candidates, set: &[usize], n: usize) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(n, n);
    for &i in set {
        m += c.rows[i].transpose() * &c.rows[i];
    }
    m
}

fn assert_gains(kept: &[(f64, usize)], expected: &[f64], what: &str) {
    for &(g, j) in kept {
        let e = expected[j];
        assert!(
            (g - e).abs() <= GAIN_TOL * (1.0 + e.abs()),
            "{what}: candidate {j}: kept {g}, fresh {e}"
        );
    }
}

/// Gains kept through additions and removals (an exchange's swaps) are
/// those computed afresh, and the gains without a chosen pose are those
/// of the information without it.
#[test]
fn kept_gains_follow_additions_and_removals() {
    let (nx, n) = (6, 20);
    let c = candidates(3, 150, nx, n);
    let reg = 1e-9;
    let mut set: Vec<usize> = (0..8).map(|k| 3 * k).collect();
    let mut kept = Screen::fresh(&c, &info(&c, &set, n), reg).expect("positive definite");
    assert_gains(
        &kept.gains(&set),
        &direct(&c, &info(&c, &set, n), reg),
        "fresh",
    );
    for step in 0..12 {
        if step % 3 == 2 {
            let out = set.remove(step % set.len());
            assert!(kept.update(&c, out, -1.0));
        } else {
            let add = 100 + 4 * step;
            assert!(kept.update(&c, add, 1.0));
            set.push(add);
        }
        let m = info(&c, &set, n);
        assert_gains(&kept.gains(&set), &direct(&c, &m, reg), "kept");
        let k = set[1];
        let without = &m - c.rows[k].transpose() * &c.rows[k];
        let g = kept.gains_without(&c, k, &set).expect("stable");
        assert_gains(&g, &direct(&c, &without, reg), "without");
        assert_eq!(g.len(), c.rows.len() - set.len());
    }
    assert_eq!(kept.updates, 12);
}

/// The shortlist from kept gains is the fresh screen's (the planning's
/// own, one triangular solve per candidate).
#[test]
fn kept_shortlist_is_the_fresh_screens() {
    let (nx, n) = (6, 24);
    let c = candidates(9, 300, nx, n);
    let reg = 1e-9;
    let mut set: Vec<usize> = (0..6).collect();
    let mut kept = Screen::fresh(&c, &info(&c, &set, n), reg).expect("positive definite");
    for add in [40, 41, 77, 150] {
        assert!(kept.update(&c, add, 1.0));
        set.push(add);
    }
    let m = info(&c, &set, n);
    let keep = pkmcal::apply::planning::SCREENED;
    assert_eq!(
        shortlist(kept.gains(&set), keep),
        pkmcal::apply::planning::screen(&c, &m, reg, &set)
    );
    let without = &m - c.rows[40].transpose() * &c.rows[40];
    assert_eq!(
        shortlist(kept.gains_without(&c, 40, &set).expect("stable"), keep),
        pkmcal::apply::planning::screen(&c, &without, reg, &set)
    );
    assert_eq!(
        kept.shortlist_without(&c, 40, &set, keep).expect("stable"),
        pkmcal::apply::planning::screen(&c, &without, reg, &set)
    );
}

/// The shortlist without a pose, bounded, is the shortlist of every
/// candidate's gain without it, for every chosen pose and shortlist
/// length, as the state follows additions and removals; and each gain
/// without a pose lies within its bounds.
#[test]
fn bounded_shortlist_without_is_the_full_ones() {
    let (nx, n) = (6, 16);
    let c = candidates(17, 400, nx, n);
    let reg = 1e-9;
    let mut set: Vec<usize> = (0..12).map(|k| 7 * k).collect();
    let mut kept = Screen::fresh(&c, &info(&c, &set, n), reg).expect("positive definite");
    for step in 0..4 {
        for &k in &set {
            for keep in [1, 5, 24, 500] {
                let full = shortlist(kept.gains_without(&c, k, &set).expect("stable"), keep);
                let bounded = kept.shortlist_without(&c, k, &set, keep).expect("stable");
                assert_eq!(bounded, full, "step {step}, without {k}, {keep} kept");
            }
        }
        let out = set.remove(step);
        assert!(kept.update(&c, out, -1.0));
        for add in [200 + step, 300 + step] {
            assert!(kept.update(&c, add, 1.0));
            set.push(add);
        }
    }
    // The kernel's largest eigenvalue bounds how far a gain can grow.
    let k = set[0];
    let kernel = kept.kernel(k, -1.0).expect("stable");
    let f = DMatrix::from_fn(nx, nx, |s, t| kernel[s][t])
        .symmetric_eigenvalues()
        .max();
    let (lower, without) = (
        kept.gains(&set),
        kept.gains_without(&c, k, &set).expect("stable"),
    );
    for ((l, j), (w, _)) in lower.iter().zip(&without) {
        let mut gf = kept.g[*j];
        for row in gf.iter_mut().take(nx) {
            for v in row.iter_mut().take(nx) {
                *v *= f;
            }
        }
        let upper = log_det_plus_identity(&gf, nx);
        assert!(
            *l <= w + 1e-12 && *w <= upper + 1e-12,
            "{l} ≤ {w} ≤ {upper}"
        );
    }
}

/// Candidates of another shape, or more rows than a block holds, are
/// left to the fresh screen.
#[test]
fn shapes_it_cannot_keep_are_refused() {
    let n = 5;
    let m = DMatrix::identity(n, n);
    assert!(Screen::fresh(&candidates(1, 10, MAX_ROWS + 1, n), &m, 1e-9).is_none());
    let mut c = candidates(1, 10, 3, n);
    c.rows[4] = DMatrix::zeros(2, n);
    assert!(Screen::fresh(&c, &m, 1e-9).is_none());
    assert!(Screen::fresh(&candidates(1, 10, 3, n), &(-m), 1e-9).is_none());
}
