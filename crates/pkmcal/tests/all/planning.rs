//! Tests of `pkmcal::apply::planning`.

use nalgebra::DMatrix;
use pkmcal::apply::planning::*;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

const CRITERIA: [PlanCriterion; 3] = [PlanCriterion::O1, PlanCriterion::O3, PlanCriterion::O5];

/// Random candidates (`nx` rows of `n` columns each, columns of very
/// different scales), half of them near copies of others: close scores
/// are the hard case for pruning.
fn candidates(seed: u64, count: usize, nx: usize, n: usize) -> Candidates {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut rows: Vec<DMatrix<f64>> = vec![];
    for k in 0..count {
        let noise = DMatrix::from_fn(nx, n, |_, j| {
            let g: f64 = StandardNormal.sample(&mut rng);
            g * 10f64.powi(j as i32 % 3 - 1)
        });
        rows.push(if k % 2 == 1 {
            &rows[k - 1] + noise * 1e-4
        } else {
            noise
        });
    }
    Candidates {
        points: vec![],
        rows,
    }
}

fn information(c: &Candidates, set: &[usize], n: usize) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(n, n);
    for &i in set {
        m += c.rows[i].transpose() * &c.rows[i];
    }
    m
}

/// Exchanges that start from a given set (the plain grid, in `plan`)
/// end at least as high on the criterion as that set, and at the greedy
/// start's level when started from its answer.
#[test]
fn exchanges_from_a_start_never_end_below_it() {
    let (nx, n, count) = (3, 10, 8);
    let c = candidates(21, 120, nx, n);
    let none = DMatrix::zeros(n, n);
    let reg = 1e-9;
    for criterion in CRITERIA {
        for start in [
            (0..count).collect::<Vec<_>>(),
            (0..count).map(|k| 119 - 3 * k).collect(),
        ] {
            let from = score(&information(&c, &start, n), reg, criterion);
            let chosen =
                choose(&c, count, criterion, &|_, _| {}, None, &none, Some(&start)).unwrap();
            assert_eq!(chosen.len(), count);
            let to = score(&information(&c, &chosen, n), reg, criterion);
            assert!(to >= from, "{criterion:?}: {to} below the start's {from}");
        }
        let greedy = choose(&c, count, criterion, &|_, _| {}, None, &none, None).unwrap();
        let again = choose(&c, count, criterion, &|_, _| {}, None, &none, Some(&greedy)).unwrap();
        assert_eq!(greedy, again, "{criterion:?}");
    }
}

/// Every candidate's exact score is at most its bound, from the
/// tangent at `M` and from the tangent at `M` plus another candidate,
/// while the set is rank deficient and once it is not.
#[test]
fn tangents_bound_every_score_from_above() {
    let (nx, n) = (2, 8);
    let c = candidates(11, 60, nx, n);
    let reg = 1e-9;
    for set_size in [1, 3, 5, 12] {
        let set: Vec<usize> = (0..set_size).map(|k| 2 * k + 1).collect();
        let m = information(&c, &set, n);
        for criterion in CRITERIA {
            let t = tangent(&m, reg, criterion).expect("positive definite");
            let b = 40;
            let mut t2 = tangent(&(&m + c.rows[b].transpose() * &c.rows[b]), reg, criterion)
                .expect("positive definite");
            t2.base -= tangent_value(&t2, &c.rows[b]) - t2.base;
            for (i, a) in c.rows.iter().enumerate() {
                let exact = score(&(&m + a.transpose() * a), reg, criterion);
                for (which, t) in [("M", &t), ("M + A_bᵀA_b", &t2)] {
                    let bound = score_bound(t, a);
                    assert!(
                        exact <= bound + t.margin * exact.abs(),
                        "{criterion:?}, {set_size} poses, candidate {i}, tangent at {which}: score {exact} above its bound {bound}"
                    );
                }
            }
        }
    }
}

/// Pruning by the bounds chooses what scoring every candidate chooses,
/// and scores at most half the candidates once the set has full rank.
#[test]
fn pruned_choice_equals_scoring_every_candidate() {
    let (nx, n) = (3, 10);
    let c = candidates(5, 400, nx, n);
    let info: Vec<DMatrix<f64>> = c.rows.iter().map(|a| a.transpose() * a).collect();
    let reg = 1e-9;
    for criterion in CRITERIA {
        let mut chosen: Vec<usize> = vec![];
        let mut m = DMatrix::zeros(n, n);
        let mut scored_full_rank = (0, 0);
        while chosen.len() < 12 {
            let pool: Vec<usize> = (0..c.rows.len()).filter(|i| !chosen.contains(i)).collect();
            let every = pool
                .iter()
                .map(|&i| (score(&(&m + &info[i]), reg, criterion), i))
                .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
            let (best, scored) = best_of(&c, &m, reg, criterion, pool.clone(), None);
            assert_eq!(best, every, "{criterion:?}, step {}", chosen.len());
            // A floor at or below the best leaves the choice as it is; one
            // above it finds nothing above it.
            let top = every.expect("a candidate").0;
            for (floor, below) in [
                (top, true),
                (top - 1e-3 * top.abs(), true),
                (top + 1e-3 * top.abs(), false),
            ] {
                let (got, _) = best_of(&c, &m, reg, criterion, pool.clone(), Some(floor));
                if below {
                    assert_eq!(got, every, "{criterion:?}, floor {floor}");
                } else {
                    assert!(
                        got.is_none_or(|g| g.0 < floor),
                        "{criterion:?}, floor {floor}"
                    );
                }
            }
            if chosen.len() * nx >= n {
                scored_full_rank.0 += scored;
                scored_full_rank.1 += pool.len();
            }
            let i = best.expect("a candidate").1;
            m += &info[i];
            chosen.push(i);
        }
        assert!(
            scored_full_rank.0 * 2 < scored_full_rank.1,
            "{criterion:?}: scored {} of {} candidates exactly",
            scored_full_rank.0,
            scored_full_rank.1
        );
    }
}
