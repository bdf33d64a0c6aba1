//! Leave-one-out evidence for weighting a delta's extended calibration
//! (Klipper's probe heights against the distances measured on its
//! calibration object): for every real printer's extended calibration, each
//! reading is left out in turn, the rest fitted as `pkmcal klipper` fits
//! them (estimated weighting, the estimate shrunk towards Klipper's ratio
//! with several numbers of pseudo-readings, then Klipper's fixed ratio), and
//! the left-out reading predicted. Prints the RMS prediction error of the
//! held-out heights and distances per printer (estimated against Klipper's),
//! and per weighting their RMS over the printers, on how many printers it
//! predicts better or worse than Klipper's ratio, and its median score
//! against Klipper's (BENCHMARKS.md, issues 39 and 37).
//!
//!     cargo run --release -p pkmcal-io --features studies --example klipper_loo -- <real-configs/klipper/cases>

use anyhow::{Context, Result};
use pkmcal::{Mechanism, Model, Params};
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting, delta_from_config, parse_config};
use pkmcal_io::firmware::{PrinterProblem, problem};

/// The prediction error of reading `m` under a fit's parameters.
fn held_out_error(
    p: &PrinterProblem,
    params: &Params,
    mvals: &[f64],
    m: &pkmcal::Measurement,
) -> Result<f64> {
    let predict = |c: &[f64]| pkmcal::predict(&p.mech, params, c, Model::Exact, &[]).map(|r| r.x);
    let x = predict(&m.commands)?;
    let measurement = &p.readings.measurement;
    Ok(match &m.partner {
        Some(other) => measurement.distance(&x, &predict(other)?) - m.measured[0],
        None => {
            let mut y = vec![0.0; measurement.axes().len()];
            measurement.observe(&x, mvals, &mut y);
            y[0] - m.measured[0]
        }
    })
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The weightings compared, with their labels: the estimated one, the
/// estimate shrunk towards Klipper's ratio with ν₀ pseudo-readings, and
/// Klipper's fixed ratio.
fn weightings() -> Vec<(String, Weighting)> {
    let mut w = vec![("estimated".to_string(), Weighting::Estimated)];
    for nu in [1.0, 2.0, 3.0, 5.0, 10.0, 20.0, 50.0] {
        w.push((format!("shrunk:{nu}"), Weighting::Shrunk(nu)));
    }
    w.push(("klipper".to_string(), Weighting::Klipper));
    w
}

/// Held-out RMS errors (heights, distances) of every reading of `delta`
/// left out in turn under `weighting`.
fn leave_one_out(printer: &KlipperPrinter) -> Result<(f64, f64)> {
    let nh = printer.delta.probes.len();
    let p = problem(printer, pkmcal::Request::new(Model::Exact))?;
    let nominal = Params::nominal(p.mech.spec());
    let data: Vec<pkmcal::Measurement> = p
        .readings
        .poses
        .iter()
        .chain(&p.readings.distances)
        .cloned()
        .collect();
    let (mut eh, mut ed) = (vec![], vec![]);
    for i in 0..data.len() {
        let mut rest = data.clone();
        let out = rest.remove(i);
        let split = if i < nh { nh - 1 } else { nh };
        let (poses, distances) = rest.split_at(split);
        let study = pkmcal::identify::study(
            &p.mech,
            &p.readings.measurement,
            poses,
            distances.to_vec(),
            &nominal,
            &p.opts,
            &|| {},
        )
        .map_err(|e| anyhow::anyhow!("{}", e.error))?;
        let cal = &study.calibration;
        let e = held_out_error(&p, &cal.params, &cal.measurement, &out)?;
        if i < nh { eh.push(e) } else { ed.push(e) }
    }
    Ok((rms(&eh), rms(&ed)))
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
    let ws = weightings();
    let klipper = ws.len() - 1;
    println!(
        "| printer | heights | distances | estimated: heights | distances | Klipper's: heights | distances |"
    );
    println!("|---|---|---|---|---|---|---|");
    // Per printer, per weighting: (heights RMS, distances RMS).
    let mut all: Vec<Vec<(f64, f64)>> = vec![];
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
        let row = ws
            .iter()
            .map(|(_, w)| {
                leave_one_out(&KlipperPrinter {
                    path: path.clone(),
                    text: text.clone(),
                    ini: parse_config(&run, &text, &path)?,
                    delta: delta.clone(),
                    weighting: *w,
                })
            })
            .collect::<Result<Vec<_>>>()
            .with_context(|| case.display().to_string())?;
        let name = case.file_name().unwrap().to_string_lossy().into_owned();
        println!(
            "| {name} | {} | {} | {:.1} µm | {:.1} µm | {:.1} µm | {:.1} µm |",
            delta.probes.len(),
            delta.distances.len(),
            row[0].0 * 1e3,
            row[0].1 * 1e3,
            row[klipper].0 * 1e3,
            row[klipper].1 * 1e3
        );
        all.push(row);
    }
    let count = all.len();
    // A weighting's score on a printer: its held-out heights and distances
    // together, each by its own RMS.
    let score = |(h, d): (f64, f64)| h * h + d * d;
    println!(
        "\n| weighting | heights (RMS over printers) | distances | printers predicted better than by Klipper's ratio | worse | median score / Klipper's |"
    );
    println!("|---|---|---|---|---|---|");
    for (w, (label, _)) in ws.iter().enumerate() {
        let q = |f: &dyn Fn(&(f64, f64)) -> f64| {
            (all.iter().map(|r| f(&r[w]).powi(2)).sum::<f64>() / count.max(1) as f64).sqrt() * 1e3
        };
        let better = all
            .iter()
            .filter(|r| score(r[w]) < score(r[klipper]))
            .count();
        let worse = all
            .iter()
            .filter(|r| score(r[w]) > score(r[klipper]))
            .count();
        let mut ratio: Vec<f64> = all
            .iter()
            .map(|r| score(r[w]) / score(r[klipper]))
            .collect();
        ratio.sort_by(f64::total_cmp);
        let median = if ratio.is_empty() {
            f64::NAN
        } else if ratio.len() % 2 == 1 {
            ratio[ratio.len() / 2]
        } else {
            0.5 * (ratio[ratio.len() / 2 - 1] + ratio[ratio.len() / 2])
        };
        println!(
            "| {label} | {:.1} µm | {:.1} µm | {better} | {worse} | {median:.4} |",
            q(&|r| r.0),
            q(&|r| r.1),
        );
    }
    println!("\n{count} printers with distances");
    Ok(())
}
