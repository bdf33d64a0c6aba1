//! The least-squares solver on the NIST StRD nonlinear regression problems
//! (certified values): from the second start every problem to ≥ 6 significant
//! digits of the parameters and of the residual sum of squares; from the first
//! start at least 25 of 27; certified standard deviations to 3 digits.

#[path = "../nist/mod.rs"]
mod nist;

use pkmcal::lm::{Options, covariance, minimize};

/// Correct significant digits required of parameters and RSS.
const DIGITS: f64 = 6.0;
/// Correct significant digits required of the standard deviations.
const SD_DIGITS: f64 = 3.0;
/// Problems that must pass from the first (harder) start.
const FIRST_START_PASSES: usize = 25;
/// Rank tolerance of the covariance.
const RANK_TOL: f64 = 1e-14;

struct Outcome {
    params: f64,
    rss: f64,
    sd: f64,
    reason: String,
}

fn solve(p: &nist::Nist, start: usize) -> Outcome {
    let rep = minimize(p, &p.starts[start], &Options::default());
    let params = rep
        .x
        .iter()
        .zip(&p.certified)
        .map(|(a, b)| nist::lre(*a, *b))
        .fold(f64::INFINITY, f64::min);
    let rss = nist::lre(rep.sum_of_squares, p.rss);
    let (cov, _) = covariance(&rep.jacobian, RANK_TOL);
    let dof = (p.data.len() - p.certified.len()) as f64;
    let s2 = rep.sum_of_squares / dof;
    let sd = (0..p.certified.len())
        .map(|k| nist::lre((cov[(k, k)] * s2).sqrt(), p.std_dev[k]))
        .fold(f64::INFINITY, f64::min);
    Outcome {
        params,
        rss,
        sd,
        reason: rep.termination.reason(),
    }
}

#[test]
fn nist_strd_certified_values() {
    let mut report = String::new();
    let mut first_passes = 0;
    let mut failures = vec![];
    for name in nist::NAMES {
        let p = nist::load(name);
        for start in [1, 0] {
            let o = solve(&p, start);
            let pass = o.params >= DIGITS && o.rss >= DIGITS;
            report.push_str(&format!(
                "{name:<9} start {} params {:5.1} rss {:5.1} sd {:5.1} {}\n",
                start + 1,
                o.params,
                o.rss,
                o.sd,
                o.reason
            ));
            if start == 1 {
                if !pass {
                    failures.push(format!("{name} from start 2: {o:?}", o = (o.params, o.rss)));
                }
                if o.sd < SD_DIGITS {
                    failures.push(format!("{name} standard deviations: {:.1} digits", o.sd));
                }
            } else if pass {
                first_passes += 1;
            }
        }
    }
    println!("{report}");
    assert!(failures.is_empty(), "{failures:#?}\n{report}");
    assert!(
        first_passes >= FIRST_START_PASSES,
        "only {first_passes} of 27 from the first start\n{report}"
    );
}

/// A fit whose cancel flag is set stops with `Cancelled` (not converged);
/// the flag left clear changes nothing; and the covariance from the report
/// (the solver's last QR) is the one of a new QR of its Jacobian.
#[test]
fn cancelling_stops_the_fit_and_a_clear_flag_changes_nothing() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let p = nist::load("Misra1a");
    let plain = minimize(&p, &p.starts[1], &Options::default());
    let flag = Arc::new(AtomicBool::new(false));
    let opts = Options {
        cancel: Some(flag.clone()),
        ..Options::default()
    };
    let clear = minimize(&p, &p.starts[1], &opts);
    assert_eq!(plain.x, clear.x);
    assert_eq!(plain.evaluations, clear.evaluations);
    assert_eq!(
        plain.covariance(RANK_TOL),
        covariance(&plain.jacobian, RANK_TOL)
    );
    flag.store(true, Ordering::Relaxed);
    let stopped = minimize(&p, &p.starts[1], &opts);
    assert_eq!(stopped.termination, pkmcal::lm::Termination::Cancelled);
    assert!(!stopped.termination.converged());
    assert_eq!(stopped.x, p.starts[1]);
}

/// Agreement of a bounded fit's sum of squares with that of the same fit
/// with the bounded parameter fixed at its bound (relative): both reach the
/// same minimum (the parameters of problems with symmetric terms, Lanczos'
/// exponentials, may come in another order).
const BOUNDED_AGREE: f64 = 1e-9;

/// A bound that cuts off the certified optimum: the fit converges (not on
/// its evaluation budget) with the parameter on the bound, at the optimum of
/// the others with that parameter fixed there (the same sum of squares), on
/// every NIST problem whose
/// optimum is then held by the bound. Bounds that leave the optimum inside
/// change nothing.
#[test]
fn a_bound_holds_a_parameter_and_the_fit_converges() {
    let mut held = 0;
    for name in nist::NAMES {
        let p = nist::load(name);
        let free = minimize(&p, &p.starts[1], &Options::default());
        if !free.termination.converged() {
            continue;
        }
        let n = p.certified.len();
        // The first parameter bounded at 1 % of its value inward of the
        // optimum, from the side of the start.
        let best = free.x[0];
        let bound = best - 0.01 * best.abs() * (best - p.starts[1][0]).signum();
        let mut lower = vec![f64::NEG_INFINITY; n];
        let mut upper = vec![f64::INFINITY; n];
        if bound < best {
            upper[0] = bound;
        } else {
            lower[0] = bound;
        }
        let mut start = p.starts[1].clone();
        start[0] = bound;
        let bounded = minimize(
            &p,
            &start,
            &Options {
                lower: Some(lower),
                upper: Some(upper),
                ..Options::default()
            },
        );
        let mut mask = vec![true; n];
        mask[0] = false;
        let fixed = minimize(
            &p,
            &start,
            &Options {
                free: Some(mask),
                ..Options::default()
            },
        );
        if !fixed.termination.converged() {
            continue;
        }
        held += 1;
        assert!(
            bounded.termination.converged(),
            "{name}: the bounded fit stopped: {}",
            bounded.termination.reason()
        );
        let inside = if bound < best {
            bounded.x[0] <= bound
        } else {
            bounded.x[0] >= bound
        };
        assert!(
            inside && (bounded.x[0] - bound).abs() <= BOUNDED_AGREE * bound.abs(),
            "{name}: {} against the bound {bound}",
            bounded.x[0]
        );
        let gap = (bounded.sum_of_squares - fixed.sum_of_squares).abs()
            / fixed.sum_of_squares.max(1e-300);
        assert!(gap < BOUNDED_AGREE, "{name}: sums of squares {gap:e} apart");
        // A box around the optimum changes nothing.
        let loose = minimize(
            &p,
            &p.starts[1],
            &Options {
                lower: Some(free.x.iter().map(|v| v - 10.0 * v.abs() - 1.0).collect()),
                upper: Some(free.x.iter().map(|v| v + 10.0 * v.abs() + 1.0).collect()),
                ..Options::default()
            },
        );
        assert!(loose.termination.converged(), "{name}");
    }
    assert!(held >= 20, "only {held} problems held by a bound");
}
