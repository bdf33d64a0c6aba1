//! Prediction of one prepared pose (exact model: the equilibrium of the
//! actuators' fight, then the tool position) on a redundant Gough–Stewart
//! platform (examples/gough-stewart-8) and a redundant planar linkage from a
//! description (examples/4-rrr), under parameters 0.05 mm (or rad) off
//! nominal, 50 poses spread over the workspace.

use criterion::{Criterion, criterion_group, criterion_main};
use pkmcal::*;
use std::hint::black_box;

mod common;
use common::example_table as table;

/// Poses prepared at 50 spread targets, and parameters off nominal.
fn setup<M: Mechanism>(m: &M) -> (Vec<Pose>, Params) {
    let spec = m.spec();
    let poses = spread_targets(m, 50)
        .unwrap()
        .iter()
        .map(|p| {
            let c: Vec<f64> = spec.actuated.iter().map(|&j| p.q[j]).collect();
            prepare_pose(m, &c, Some(&p.q)).unwrap()
        })
        .collect();
    let mut truth = Params::nominal(spec);
    for (i, v) in truth.values.iter_mut().enumerate().take(spec.n_geometric()) {
        *v += 0.05 * (1.7 * i as f64).sin();
    }
    (poses, truth)
}

fn run<M: Mechanism>(c: &mut Criterion, label: &str, m: &M) {
    let (poses, truth) = setup(m);
    let mut i = 0;
    c.bench_function(label, |b| {
        b.iter(|| {
            i = (i + 1) % poses.len();
            black_box(predict_pose(m, &poses[i], &truth, Model::Exact, &[]).unwrap())
        })
    });
}

fn bench(c: &mut Criterion) {
    let gs = GoughStewart::new(&table("gough-stewart-8").try_into().unwrap()).unwrap();
    run(c, "predict_pose_exact/gough-stewart-8", &gs);
    let rrr = PlanarLinkage::new(&table("4-rrr").try_into().unwrap()).unwrap();
    run(c, "predict_pose_exact/4-rrr", &rrr);
}

criterion_group!(benches, bench);
criterion_main!(benches);
