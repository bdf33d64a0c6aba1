//! Tests of `pkmcal::engine::atlas`.

use pkmcal::Mechanism;
use pkmcal::engine::atlas::*;
use rand::{RngExt, SeedableRng};

/// Lattice coordinates agree with their computed position to this (in
/// units of the box's extent).
const LATTICE_EPS: f64 = 1e-12;

/// Every lattice axis, for random boxes and spacings, is centred in its
/// box and reaches within half a step of both ends (the lattice used to
/// start at the minimum and stop up to a whole step short of the
/// maximum); a thin box gets its one coordinate.
#[test]
fn lattice_axes_are_centred_and_reach_both_ends() {
    let mut spec = pkmcal::kinds::reference::JeongKim2Dof::default()
        .spec()
        .clone();
    let mut rng = rand::rngs::StdRng::seed_from_u64(35);
    for _ in 0..2000 {
        let lo: f64 = rng.random_range(-500.0..500.0);
        let width: f64 = if rng.random_bool(0.1) {
            0.0
        } else {
            rng.random_range(1e-3..400.0)
        };
        let lo2: f64 = rng.random_range(-500.0..500.0);
        spec.workspace_box = vec![[lo, lo + width], [lo2, lo2 + 50.0]];
        let spacing: f64 = rng.random_range(0.5..300.0);
        let axes = axes_at(&spec, spacing);
        let a = &axes[0];
        let step = spacing / spec.axis_scale(0);
        let tol = LATTICE_EPS * (1.0 + width + lo.abs());
        let (first, last) = (a[0], *a.last().unwrap());
        assert!(
            first >= lo - tol && last <= lo + width + tol,
            "{a:?} in [{lo}, {}]",
            lo + width
        );
        assert!(
            first - lo <= 0.5 * step + tol,
            "{first} from {lo}, step {step}"
        );
        assert!(
            lo + width - last <= 0.5 * step + tol,
            "{last} to {}",
            lo + width
        );
        assert!(
            ((first - lo) - (lo + width - last)).abs() <= tol,
            "not centred: {a:?}"
        );
    }
}

/// Thinning keeps `keep` distinct items in order, centred: the first as
/// far from the start as the last from the end (within one item).
#[test]
fn thinning_is_even_and_centred() {
    for n in 1..200 {
        for keep in 1..n + 3 {
            let t = thin_evenly(n, keep);
            assert_eq!(t.len(), keep.min(n));
            assert!(t.windows(2).all(|w| w[0] < w[1]) && t.iter().all(|&i| i < n));
            let (head, tail) = (t[0], n - 1 - t[t.len() - 1]);
            assert!(head.abs_diff(tail) <= 1, "{n} {keep}: {t:?}");
        }
    }
}

/// [`Atlas::nearest`] returns what a scan of the entries one by one
/// returns (each distance summed actuator by actuator, the first of
/// equal ones kept): on the reference mechanism's atlas, at random
/// commands, at every entry's own commands, halfway between two entries
/// (a tie) and with fewer commands than actuators.
#[test]
fn the_nearest_entry_is_the_one_a_plain_scan_finds() {
    let mech = pkmcal::kinds::reference::JeongKim2Dof::default();
    let atlas = Atlas::build(&mech, 200);
    assert!(atlas.len() > 50, "{} entries", atlas.len());
    let scan = |commands: &[f64]| {
        let d = |a: &[f64]| {
            a.iter()
                .zip(commands)
                .zip(&atlas.scale)
                .map(|((x, c), s)| ((x - c) * s).powi(2))
                .sum::<f64>()
        };
        atlas
            .entries
            .iter()
            .map(|e| (d(&e.0), e))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, e)| e.1.clone())
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(9);
    let mut queries: Vec<Vec<f64>> = (0..200)
        .map(|_| {
            atlas.entries[rng.random_range(0..atlas.len())]
                .0
                .iter()
                .map(|v| v + rng.random_range(-0.2..0.2))
                .collect()
        })
        .collect();
    queries.extend(atlas.entries.iter().map(|e| e.0.clone()));
    let (a, b) = (&atlas.entries[0].0, &atlas.entries[1].0);
    queries.push(a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)).collect());
    queries.push(a[..1].to_vec());
    queries.push(vec![]);
    for q in &queries {
        assert_eq!(atlas.nearest(q), scan(q), "{q:?}");
    }
}
