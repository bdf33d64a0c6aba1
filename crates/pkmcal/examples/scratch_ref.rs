use pkmcal::reference::demo_truth;
use pkmcal::*;
use std::time::Instant;
fn main() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let targets: Vec<Vec<f64>> = spread_targets(&mech, 35)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let mm = pkmcal::MeasurementModel::tool(spec);
    let data = simulate(&mech, &mm, &demo_truth(), &targets, 0.002, 2004).unwrap();
    let nominal = Params::nominal(spec);
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let n: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse().unwrap())
        .unwrap_or(2000);
    let mut times = vec![];
    for _ in 0..n {
        let t0 = Instant::now();
        std::hint::black_box(calibrate(&mech, &mm, &data, &nominal, &opts).unwrap());
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    println!("ref calibrate: median {:.3} ms", times[n / 2]);
}
