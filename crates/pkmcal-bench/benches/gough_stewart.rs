//! Calibration of Gough–Stewart platforms (examples/gough-stewart-6 and -8):
//! all geometric parameters and leg offsets free, 100 poses, exact model.

use criterion::{Criterion, criterion_group, criterion_main};
use pkmcal::*;
use rand::{RngExt, SeedableRng};
use std::hint::black_box;

mod common;

fn platform(name: &str) -> GoughStewart {
    GoughStewart::new(&common::example_table(name).try_into().unwrap()).unwrap()
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("gough_stewart_calibration");
    group.sample_size(10);
    for name in ["gough-stewart-6", "gough-stewart-8"] {
        let m = platform(name);
        let spec = m.spec();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut truth = Params::nominal(spec);
        let free: Vec<usize> = spec
            .default_free
            .iter()
            .map(|n| spec.param_index(n).unwrap())
            .collect();
        for &i in &free {
            truth.values[i] += rng.random_range(-0.3..0.3);
        }
        let targets: Vec<Vec<f64>> = spread_targets(&m, 100)
            .unwrap()
            .into_iter()
            .map(|p| p.target)
            .collect();
        let data = simulate(
            &m,
            &pkmcal::MeasurementModel::tool(m.spec()),
            &truth,
            &targets,
            0.001,
            1,
        )
        .unwrap();
        let mut opts = CalibrationOptions::new(spec, Model::Exact);
        opts.free = free;
        group.bench_function(
            format!("{}_legs_{}_params_100_poses", m.legs(), opts.free.len()),
            |b| {
                b.iter(|| {
                    calibrate(
                        &m,
                        &pkmcal::MeasurementModel::tool(m.spec()),
                        black_box(&data),
                        &Params::nominal(spec),
                        &opts,
                    )
                    .unwrap()
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
