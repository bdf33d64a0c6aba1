//! Benchmarks of the core engine: the exact equilibrium of one pose and the
//! prediction of 10,000 poses (one core).

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use pkmcal::kinds::reference::demo_truth;
use pkmcal::*;
use std::hint::black_box;

fn poses(n: usize) -> (JeongKim2Dof, Vec<Vec<f64>>, Vec<Vec<f64>>) {
    let mech = JeongKim2Dof::new();
    let pool = sample_workspace(&mech, 2.0);
    let step = (pool.len() / n).max(1);
    let picked: Vec<&WorkspacePoint> = pool.iter().step_by(step).cycle().take(n).collect();
    let commands = picked.iter().map(|p| p.q[..3].to_vec()).collect();
    let qs = picked.iter().map(|p| p.q.clone()).collect();
    (mech, commands, qs)
}

fn bench(c: &mut Criterion) {
    let truth = demo_truth();
    let (mech, commands, qs) = poses(64);
    let prepared: Vec<Pose> = commands
        .iter()
        .zip(&qs)
        .map(|(c, q)| prepare_pose(&mech, c, Some(q)).unwrap())
        .collect();
    let starts: Vec<Vec<f64>> = prepared
        .iter()
        .map(|p| {
            predict_pose(&mech, p, &truth, Model::Linear, &[])
                .unwrap()
                .q
        })
        .collect();
    let mut g = c.benchmark_group("engine");
    let mut i = 0;
    g.bench_function("equilibrium_one_pose", |b| {
        b.iter(|| {
            i = (i + 1) % prepared.len();
            let p = &prepared[i];
            black_box(
                equilibrium(
                    &mech,
                    &truth,
                    &p.commands,
                    &[],
                    &starts[i],
                    Some(p.hessians(&mech)),
                )
                .unwrap(),
            )
        })
    });
    for model in Model::ALL {
        let mut i = 0;
        g.bench_function(format!("predict_prepared_pose_{}", model.name()), |b| {
            b.iter(|| {
                i = (i + 1) % prepared.len();
                black_box(predict_pose(&mech, &prepared[i], &truth, model, &[]).unwrap())
            })
        });
    }
    g.bench_function("prepare_pose", |b| {
        b.iter_batched(
            || (),
            |_| {
                i = (i + 1) % commands.len();
                black_box(prepare_pose(&mech, &commands[i], None).unwrap())
            },
            BatchSize::SmallInput,
        )
    });
    g.finish();

    let (mech, commands, _) = poses(10_000);
    let mut g = c.benchmark_group("predict_10000");
    g.sample_size(10);
    g.bench_function("exact_one_core", |b| {
        b.iter(|| {
            let mut start: Option<Vec<f64>> = None;
            for c in &commands {
                let pose = prepare_pose(&mech, c, start.as_deref()).unwrap();
                black_box(predict_pose(&mech, &pose, &truth, Model::Exact, &[]).unwrap());
                start = Some(pose.nominal_q);
            }
        })
    });
    g.finish();
}

fn calibration(c: &mut Criterion) {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let targets: Vec<Vec<f64>> = spread_targets(&mech, 35)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let data = simulate(
        &mech,
        &pkmcal::MeasurementModel::tool(mech.spec()),
        &demo_truth(),
        &targets,
        0.002,
        2004,
    )
    .unwrap();
    let nominal = Params::nominal(spec);
    let mut g = c.benchmark_group("calibration_35_poses_16_params");
    for model in Model::ALL {
        let opts = CalibrationOptions::new(spec, model);
        g.bench_function(model.name(), |b| {
            b.iter(|| {
                black_box(
                    calibrate(
                        &mech,
                        &pkmcal::MeasurementModel::tool(mech.spec()),
                        &data,
                        &nominal,
                        &opts,
                    )
                    .unwrap(),
                )
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench, calibration);
criterion_main!(benches);
