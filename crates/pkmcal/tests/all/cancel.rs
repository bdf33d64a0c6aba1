//! The long loops a front end stops (Ctrl-C in Python): each returns
//! `Error::Cancelled` once its flag is set, and gives the same results as
//! before when it is not; the row loops that write into the caller's
//! buffers agree bit for bit with those that keep every prediction.

use crate::common::{planar, spread};
use pkmcal::apply::budget::{
    BudgetOptions, budget, budget_cancellable, budget_targets_cancellable,
};
use pkmcal::identify::{AnalysisOptions, Compared, analyze, analyze_cancellable};
use pkmcal::{
    CompensationOptions, Error, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise, Params,
    RowBuffers, RowSettings, compensate, compensate_rows, predict_rows, predict_rows_into,
    simulate, simulate_cancellable,
};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

fn set() -> AtomicBool {
    AtomicBool::new(true)
}

fn cancelled<T: std::fmt::Debug>(r: pkmcal::Result<T>) {
    assert!(matches!(r, Err(Error::Cancelled)), "{r:?}");
}

/// Commands of `targets`, and one row that does not assemble and one with
/// a NaN in the middle.
fn rows_with_failures<M: Mechanism>(m: &M, targets: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let mut rows: Vec<Vec<f64>> = targets
        .iter()
        .map(|t| pkmcal::nominal_commands(m, t).unwrap())
        .collect();
    let width = rows[0].len();
    rows.insert(3, vec![5.0; width]);
    rows.insert(7, vec![f64::NAN; width]);
    rows
}

#[test]
fn rows_written_into_buffers_are_those_kept_row_by_row() {
    let m = planar("4-rrr");
    let spec = m.spec();
    let rows = rows_with_failures(&m, &spread(&m, 40));
    let params = Params::nominal(spec);
    let settings = RowSettings {
        params: &params,
        model: Model::Exact,
        force: &[],
        covariance: None,
    };
    let kept = predict_rows(&m, &settings, &rows, &|_| {});
    let (n, nx, nq, na) = (
        rows.len(),
        spec.tool_axes.len(),
        spec.joints.len(),
        spec.n_actuated(),
    );
    let (mut x, mut q, mut t, mut d) = (
        vec![0.0; n * nx],
        vec![0.0; n * nq],
        vec![0.0; n * na],
        vec![0.0; n * na],
    );
    let failed = predict_rows_into(
        &m,
        &settings,
        &rows.concat(),
        RowBuffers {
            x: Some(&mut x),
            q: Some(&mut q),
            torque: Some(&mut t),
            deflection: Some(&mut d),
            covariance: None,
        },
        None,
    );
    let failed: Vec<usize> = failed.iter().map(|(i, _)| *i).collect();
    assert_eq!(failed, [3, 7]);
    for (i, k) in kept.iter().enumerate() {
        match k {
            Ok(p) => {
                let p = &p.prediction;
                assert_eq!(&x[i * nx..(i + 1) * nx], &p.x[..], "row {i}");
                assert_eq!(&q[i * nq..(i + 1) * nq], &p.q[..], "row {i}");
                assert_eq!(&t[i * na..(i + 1) * na], &p.torque[..], "row {i}");
                assert_eq!(&d[i * na..(i + 1) * na], &p.deflection[..], "row {i}");
            }
            Err(_) => {
                assert!(failed.contains(&i), "row {i}");
                assert!(x[i * nx..(i + 1) * nx].iter().all(|v| v.is_nan()));
            }
        }
    }
    // Only x asked for: the same x.
    let mut only = vec![0.0; n * nx];
    predict_rows_into(
        &m,
        &settings,
        &rows.concat(),
        RowBuffers {
            x: Some(&mut only),
            ..Default::default()
        },
        None,
    );
    assert_eq!(
        only.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        x.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    // Cancelled: stopped, and said so.
    let failed = predict_rows_into(
        &m,
        &settings,
        &rows.concat(),
        RowBuffers {
            x: Some(&mut only),
            ..Default::default()
        },
        Some(&set()),
    );
    assert!(matches!(failed.first(), Some((0, Error::Cancelled))));
}

#[test]
fn targets_compensated_together_are_those_compensated_one_by_one() {
    let m = planar("4-rrr");
    let params = Params::nominal(m.spec());
    let opts = CompensationOptions::default();
    let mut targets = spread(&m, 20);
    targets[5] = vec![f64::NAN; targets[5].len()];
    let all = compensate_rows(&m, &params, &targets.concat(), Model::Exact, &opts, None);
    for (t, c) in targets.iter().zip(&all) {
        match compensate(&m, &params, t, Model::Exact, &opts) {
            Ok(one) if t.iter().all(|v| v.is_finite()) => assert_eq!(c.as_ref().unwrap(), &one),
            _ => assert!(c.is_err()),
        }
    }
    assert!(all[5].is_err());
    let stopped = compensate_rows(
        &m,
        &params,
        &targets.concat(),
        Model::Exact,
        &opts,
        Some(&set()),
    );
    assert!(stopped.iter().all(|c| matches!(c, Err(Error::Cancelled))));
}

#[test]
fn every_long_loop_stops_once_cancelled() {
    let m = JeongKim2Dof::new();
    let spec = m.spec();
    let tool = MeasurementModel::tool(spec);
    let truth = Params::nominal(spec);
    let targets = spread(&m, 20);
    // Simulation: the same measurements when not cancelled.
    assert_eq!(
        simulate_cancellable(&m, &tool, &truth, &targets, 0.002, 3, None).unwrap(),
        simulate(&m, &tool, &truth, &targets, 0.002, 3).unwrap()
    );
    cancelled(simulate_cancellable(
        &m,
        &tool,
        &truth,
        &targets,
        0.002,
        3,
        Some(&set()),
    ));
    // The budget: the same when not cancelled.
    let tol = [(0, 0.01), (9, 0.02)];
    let opts = BudgetOptions {
        model: Model::Exact,
        force: vec![],
        samples: 2500,
        seed: 3,
        calibration: None,
    };
    assert_eq!(
        budget_cancellable(&m, &targets, &tol, &opts, None).unwrap(),
        budget(&m, &targets, &tol, &opts).unwrap()
    );
    cancelled(budget_cancellable(&m, &targets, &tol, &opts, Some(&set())));
    cancelled(budget_targets_cancellable(&m, 50, Some(&set())));
    // The analysis: the same when not cancelled.
    let data = simulate(&m, &tool, &truth, &targets, 0.002, 3).unwrap();
    let free: Vec<usize> = (0..spec.n_params())
        .filter(|&i| spec.default_free.iter().any(|n| n == spec.param_names()[i]))
        .collect();
    let mut opts = AnalysisOptions {
        model: Model::Exact,
        free: free.clone(),
        force: vec![],
        priors: vec![],
        noise: Noise::lengths(1.0),
        cancel: None,
    };
    assert_eq!(
        analyze_cancellable(&m, &tool, &data, &truth, &opts).unwrap(),
        analyze(&m, &tool, &data, &truth, Model::Exact, &free, &[]).unwrap()
    );
    opts.cancel = Some(Arc::new(set()));
    cancelled(analyze_cancellable(&m, &tool, &data, &truth, &opts));
    // The change at the tool between two calibrations: the nominal values against one identifying a parameter (two sets of
    // nominal values identify nothing to compare).
    let nominal = Compared::nominal(spec);
    let first = spec.param_names()[free[0]].to_string();
    let identified = Compared {
        names: vec![first],
        covariance: vec![vec![1e-4]],
        ..nominal.clone()
    };
    let drift = |cancel: Option<&AtomicBool>| {
        pkmcal::apply::tooldrift::workspace_drift_cancellable(
            &m,
            &nominal,
            &identified,
            &targets,
            0.05,
            cancel,
        )
    };
    assert!(drift(None).is_ok());
    cancelled(drift(Some(&set())));
}
