use pkmcal::*;
use std::time::Instant;
fn main() {
    let name = std::env::args().nth(1).unwrap_or("4-rrr".into());
    let text = std::fs::read_to_string(format!("../../examples/{name}/mechanism.toml")).unwrap();
    let mut t: toml::Table = toml::from_str(&text).unwrap();
    t.remove("type");
    t.remove("target");
    let d: PlanarDescription = t.try_into().unwrap();
    let mech = PlanarLinkage::new(&d).unwrap();
    let pool = sample_workspace(&mech, 20.0);
    let spec = mech.spec();
    let step = (pool.len() / 50).max(1);
    let picked: Vec<&WorkspacePoint> = pool.iter().step_by(step).take(50).collect();
    let na = spec.actuated.len();
    let poses: Vec<Pose> = picked
        .iter()
        .map(|p| {
            let c: Vec<f64> = spec.actuated.iter().map(|&j| p.q[j]).collect();
            prepare_pose(&mech, &c, Some(&p.q)).unwrap()
        })
        .collect();
    let mut truth = Params::nominal(spec);
    for (i, v) in truth.values.iter_mut().enumerate().take(spec.n_geometric()) {
        *v += 0.05 * ((i as f64) * 1.7).sin();
    }
    let _ = na;
    let mut its = 0;
    let mut times = vec![];
    for _ in 0..20 {
        let t0 = Instant::now();
        its = 0;
        for p in &poses {
            let r = predict_pose(&mech, p, &truth, Model::Exact, &[]).unwrap();
            its += r.iterations;
        }
        times.push(t0.elapsed().as_secs_f64() * 1e6 / poses.len() as f64);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{name}: {} poses, mean iterations {:.2}, median {:.2} µs per predict_pose",
        poses.len(),
        its as f64 / poses.len() as f64,
        times[10]
    );
    let mut times = vec![];
    let lam = vec![0.3; spec.n_constraints];
    let mu = vec![0.1; spec.tool_axes.len()];
    for _ in 0..20 {
        let t0 = Instant::now();
        for p in &poses {
            std::hint::black_box(mech.weighted_hessian(&p.nominal_q, truth.geometric(), &lam, &mu));
        }
        times.push(t0.elapsed().as_secs_f64() * 1e6 / poses.len() as f64);
    }
    times.sort_by(f64::total_cmp);
    println!("weighted_hessian {:.2} µs", times[10]);
    let mut times = vec![];
    let n = spec.joints.len();
    let mut j = pkmcal::autodiff::Jacobians::empty();
    for _ in 0..20 {
        let t0 = Instant::now();
        for p in &poses {
            mech.first_derivatives_into(&p.nominal_q, truth.geometric(), 0..n, &mut j);
        }
        times.push(t0.elapsed().as_secs_f64() * 1e6 / poses.len() as f64);
    }
    times.sort_by(f64::total_cmp);
    println!("first derivatives (joints) {:.2} µs", times[10]);
    let targets: Vec<Vec<f64>> = spread_targets(&mech, 50)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let mm = pkmcal::MeasurementModel::tool(spec);
    let data = simulate(&mech, &mm, &truth, &targets, 0.002, 2004).unwrap();
    let nominal = Params::nominal(spec);
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let mut times = vec![];
    for _ in 0..11 {
        let t0 = Instant::now();
        std::hint::black_box(calibrate(&mech, &mm, &data, &nominal, &opts).unwrap());
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    println!("calibrate 50 poses: median {:.2} ms", times[5]);
}

#[allow(dead_code)]
fn unused() {}
