//! Leave-one-out evidence for weighting a delta's extended calibration
//! (Klipper's probe heights against the distances measured on its
//! calibration object): for every real printer's extended calibration, each
//! reading is left out in turn, the rest fitted as `pkmcal klipper` fits
//! them (estimated weighting, then Klipper's fixed ratio), and the left-out
//! reading predicted. Prints the RMS prediction error of the held-out
//! heights and distances per printer and weighting (BENCHMARKS.md, issue 39).
//!
//!     cargo run --release -p pkmcal-io --example klipper_loo -- <real-configs/klipper/cases>

use anyhow::{Context, Result};
use pkmcal::{Mechanism, Model, Params};
use pkmcal_io::klipper::{
    KlipperProblem, Weighting, delta_from_config, klipper_problem, parse_config,
};

/// The prediction error of reading `m` under a fit's parameters.
fn held_out_error(
    p: &KlipperProblem,
    params: &Params,
    mvals: &[f64],
    m: &pkmcal::Measurement,
) -> Result<f64> {
    let predict = |c: &[f64]| pkmcal::predict(&p.mech, params, c, Model::Exact, &[]).map(|r| r.x);
    let x = predict(&m.commands)?;
    Ok(match &m.partner {
        Some(other) => p.measurement.distance(&x, &predict(other)?) - m.measured[0],
        None => {
            let mut y = vec![0.0; p.measurement.axes().len()];
            p.measurement.observe(&x, mvals, &mut y);
            y[0] - m.measured[0]
        }
    })
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn main() -> Result<()> {
    let root = std::env::args()
        .nth(1)
        .context("give the folder of real Klipper cases")?;
    let mut cases: Vec<_> = std::fs::read_dir(&root)?
        .map(|e| e.map(|e| e.path()))
        .collect::<std::io::Result<_>>()?;
    cases.sort();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    println!(
        "| printer | heights | distances | estimated: heights | distances | Klipper's: heights | distances |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut totals = [[0.0f64; 2]; 2];
    let mut better = [0usize; 2];
    let mut count = 0;
    for case in cases {
        let path = case.join("printer.cfg");
        let Ok(text) = std::fs::read_to_string(&path) else {
            continue;
        };
        let ini = parse_config(&run, &text, &path)?;
        let delta = delta_from_config(&ini)?;
        if delta.distances.is_empty() {
            continue;
        }
        let nh = delta.probes.len();
        let mut row = vec![];
        for weighting in [Weighting::Estimated, Weighting::Klipper] {
            let p = klipper_problem(&delta, weighting, None, None)?;
            let nominal = Params::nominal(p.mech.spec());
            let (mut eh, mut ed) = (vec![], vec![]);
            for i in 0..p.data.len() {
                let mut rest = p.data.clone();
                let out = rest.remove(i);
                let split = if i < nh { nh - 1 } else { nh };
                let (poses, distances) = rest.split_at(split);
                let study = pkmcal::identify::study(
                    &p.mech,
                    &p.measurement,
                    poses,
                    distances.to_vec(),
                    &nominal,
                    &pkmcal::identify::StudyOptions {
                        calibration: p.opts.clone(),
                        validation: pkmcal::identify::ValidationPlan::None,
                        kfold: None,
                        seed: 0,
                    },
                    &|| {},
                )
                .map_err(|e| anyhow::anyhow!("{}: {}", case.display(), e.error))?;
                let cal = &study.calibration;
                let e = held_out_error(&p, &cal.params, &cal.measurement, &out)?;
                if i < nh { eh.push(e) } else { ed.push(e) }
            }
            row.push((rms(&eh), rms(&ed)));
        }
        let name = case.file_name().unwrap().to_string_lossy().into_owned();
        println!(
            "| {name} | {nh} | {} | {:.1} µm | {:.1} µm | {:.1} µm | {:.1} µm |",
            delta.distances.len(),
            row[0].0 * 1e3,
            row[0].1 * 1e3,
            row[1].0 * 1e3,
            row[1].1 * 1e3
        );
        for (w, (h, d)) in row.iter().enumerate() {
            totals[w][0] += h * h;
            totals[w][1] += d * d;
        }
        // The weighting whose held-out readings (heights and distances
        // together, each by its own RMS) are predicted better.
        let score = |(h, d): (f64, f64)| h * h + d * d;
        better[usize::from(score(row[1]) < score(row[0]))] += 1;
        count += 1;
    }
    let q = |v: f64| (v / count.max(1) as f64).sqrt() * 1e3;
    println!(
        "| all {count} (RMS over printers) | | | {:.1} µm | {:.1} µm | {:.1} µm | {:.1} µm |",
        q(totals[0][0]),
        q(totals[0][1]),
        q(totals[1][0]),
        q(totals[1][1])
    );
    println!(
        "\nheld-out readings predicted better: estimated weighting on {} printers, Klipper's on {}",
        better[0], better[1]
    );
    Ok(())
}
