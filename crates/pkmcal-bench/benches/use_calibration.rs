//! Compensation throughput (1 and 2 cores), planning 35 of ~2,000 candidates,
//! Monte Carlo calibrations per second.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pkmcal::kinds::reference::demo_truth;
use pkmcal::*;
use rayon::prelude::*;
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let truth = demo_truth();
    let targets = random_targets(&mech, 2000, 1).unwrap();
    let many: Vec<Vec<f64>> = targets.iter().cycle().take(100_000).cloned().collect();
    let none = CompensationOptions::default();
    let loaded = CompensationOptions {
        force: vec![10.0, -30.0],
        preload: vec![],
    };
    let mut g = c.benchmark_group("compensate_100k_targets");
    g.sample_size(10)
        .throughput(Throughput::Elements(many.len() as u64));
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        for (label, opts) in [("no_load", &none), ("load", &loaded)] {
            g.bench_function(format!("{label}_{threads}_cores"), |b| {
                b.iter(|| {
                    pool.install(|| {
                        many.par_iter()
                            .map(|t| {
                                compensate(&mech, &truth, t, Model::Exact, opts)
                                    .unwrap()
                                    .commands[0]
                            })
                            .sum::<f64>()
                    })
                })
            });
        }
    }
    g.finish();

    let free = CalibrationOptions::new(spec, Model::Exact).free;
    let mut g = c.benchmark_group("plan");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("35_of_2003_candidates_O5_2_cores", |b| {
        b.iter(|| {
            let cands = candidate_jacobians(
                &mech,
                sample_workspace(&mech, 6.0),
                &Params::nominal(spec),
                Model::Exact,
                &free,
            )
            .unwrap();
            black_box(plan_poses(&cands, 35, PlanCriterion::O5).unwrap())
        })
    });
    g.finish();

    let poses: Vec<Vec<f64>> = spread_targets(&mech, 35)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let validation = random_targets(&mech, 50, 2).unwrap();
    let mut g = c.benchmark_group("montecarlo_100_runs");
    g.sample_size(10).throughput(Throughput::Elements(100));
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let opts = MonteCarloOptions {
            runs: 100,
            noise: 0.002.into(),
            seed: 1,
            length_error: 0.3,
            angle_error: 1e-3,
            calibration: CalibrationOptions::new(spec, Model::Exact),
        };
        g.bench_function(format!("exact_{threads}_cores"), |b| {
            b.iter(|| {
                pool.install(|| {
                    black_box(monte_carlo(&mech, &poses, &validation, &opts, &|| {}).unwrap())
                })
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
