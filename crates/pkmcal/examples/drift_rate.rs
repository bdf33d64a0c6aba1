//! The drift test on real calibrations: pairs of calibrations of the
//! reference mechanism from independent measurements (35 planned poses,
//! 2 µm noise, seeded), of an unchanged machine and of one whose `l11`
//! changed by 3σ of the difference; the false-alarm rate of the
//! Holm–Bonferroni parameter test and of the joint test, and their power.
//!
//!     cargo run --release -p pkmcal --features studies --example drift_rate -- [REPEATS]

use pkmcal::identify::{Compared, DEFAULT_ALPHA, drift};
use pkmcal::{CalibrationOptions, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise, Params};

fn compared(cal: &pkmcal::Calibration) -> Compared {
    Compared::from_calibration(cal)
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .map_or(1000, |a| a.parse().expect("a number of repeats"));
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let tool = MeasurementModel::tool(spec);
    let targets: Vec<Vec<f64>> = pkmcal::apply::workspace::spread_targets(&mech, 35)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let mut truth = Params::nominal(spec);
    let l11 = spec.param_index("l11").unwrap();
    truth.values[l11] += 0.3;
    let calibrate = |p: &Params, seed: u64| {
        let data =
            pkmcal::simulate(&mech, &tool, p, &targets, Noise::lengths(0.002), seed).unwrap();
        pkmcal::calibrate(
            &mech,
            &tool,
            &data,
            &Params::nominal(spec),
            &CalibrationOptions::new(spec, Model::Exact),
        )
        .unwrap()
    };
    // The difference's σ of l11, from one pair.
    let (a, b) = (calibrate(&truth, 1), calibrate(&truth, 2));
    let sd = |c: &pkmcal::Calibration| c.parameters[l11].std_dev;
    let step = 3.0 * (sd(&a).powi(2) + sd(&b).powi(2)).sqrt();
    let mut moved = truth.clone();
    moved.values[l11] += step;
    let start = std::time::Instant::now();
    let (mut fa_any, mut fa_joint, mut hit, mut hit_joint) = (0, 0, 0, 0);
    for r in 0..repeats as u64 {
        let base = calibrate(&truth, 10 + 3 * r);
        let same = calibrate(&truth, 11 + 3 * r);
        let changed = calibrate(&moved, 12 + 3 * r);
        let d = drift(&compared(&base), &compared(&same), DEFAULT_ALPHA).unwrap();
        fa_any += usize::from(d.parameters.iter().any(|p| p.drifted));
        fa_joint += usize::from(d.joint_drift);
        let d = drift(&compared(&base), &compared(&changed), DEFAULT_ALPHA).unwrap();
        hit += usize::from(d.parameters.iter().any(|p| p.drifted && p.name == "l11"));
        hit_joint += usize::from(d.joint_drift);
    }
    let rate = |k: usize| k as f64 / repeats as f64;
    let sd_rate = (DEFAULT_ALPHA * (1.0 - DEFAULT_ALPHA) / repeats as f64).sqrt();
    println!(
        "{repeats} repeats ({:.1} s), alpha {DEFAULT_ALPHA} (binomial sd {sd_rate:.4}):",
        start.elapsed().as_secs_f64()
    );
    println!(
        "  unchanged machine: false alarms {:.4} (any parameter, Holm–Bonferroni), {:.4} (joint F)",
        rate(fa_any),
        rate(fa_joint)
    );
    println!(
        "  l11 moved by 3σ of the difference ({step:.5} mm): found {:.4} (l11 called drifted), {:.4} (joint F)",
        rate(hit),
        rate(hit_joint)
    );
}
