//! Work bounded by construction on large mechanisms and inputs (issue 34,
//! D12): each case runs to a result or a clear error within a memory bound,
//! measured as the child's peak resident memory (never timed).

use crate::common::run_measured;
use std::fmt::Write as _;

/// Peak memory allowed to each run below (kB): far below what the unbounded
/// code took (a 24-leg plan: 249 MB; a million probe points: 6.1 GB).
const PEAK_KB: u64 = 150 * 1024;

/// A Gough–Stewart platform with `n` legs (no target points: the tool is the
/// platform pose).
fn gough_stewart(n: usize) -> String {
    let mut s = format!("type = \"gough-stewart\"\nname = \"{n} legs\"\n\n");
    for i in 0..n {
        let a = std::f64::consts::TAU * i as f64 / n as f64;
        let sign = if i % 2 == 0 { -1.0 } else { 1.0 };
        let b = a + sign * 0.6 * std::f64::consts::PI / n as f64;
        let _ = write!(
            s,
            "[[leg]]\nbase = [{:.3}, {:.3}, 0.0]\nplatform = [{:.3}, {:.3}, 0.0]\nstiffness = 50000.0\n\n",
            500.0 * a.cos(),
            500.0 * a.sin(),
            300.0 * b.cos(),
            300.0 * b.sin()
        );
    }
    s + "[assembly]\npose = [0.0, 0.0, 700.0, 0.0, 0.0, 0.0]\n\n[workspace]\nx = [-80.0, 80.0]\ny = [-80.0, 80.0]\nz = [640.0, 760.0]\nrx = [-0.12, 0.12]\nry = [-0.12, 0.12]\nrz = [-0.15, 0.15]\n"
}

/// A linear delta with `n` towers around the bed.
fn delta(n: usize) -> String {
    let mut s = String::from(
        "type = \"spatial\"\nname = \"many towers\"\nfree = [\"delta_radius\"]\n\n[platform]\nmotion = \"translation\"\n\n",
    );
    for i in 0..n {
        let a = std::f64::consts::TAU * i as f64 / n as f64 + 0.1;
        let _ = write!(
            s,
            "[[leg]]\nname = \"tower_{i}\"\nangle = {a:.6}\n[[leg.joint]]\nname = \"j{i}\"\nkind = \"prismatic\"\nat = [\"delta_radius\", 0.0, 0.0]\naxis = [0.0, 0.0, 1.0]\nactuated = true\nstiffness = 2000.0\n[leg.end]\nkind = \"rod\"\nlength = 250.0\nplatform = [0.0, 0.0, 0.0]\n\n"
        );
    }
    s.push_str("[parameters]\ndelta_radius = 130.0\n\n[assembly]\npose = [0.0, 0.0, 50.0]\n");
    for i in 0..n {
        let _ = writeln!(s, "j{i} = 263.5");
    }
    s + "\n[workspace]\nx = [-70.0, 70.0]\ny = [-70.0, 70.0]\nz = [0.0, 120.0]\n"
}

/// Planning keeps each candidate's rows, not its information matrix
/// (candidates × parameters² numbers): 168 free parameters, 1,000 candidates.
#[test]
fn planning_a_24_leg_platform_stays_small() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("gs24.toml"), gough_stewart(24)).unwrap();
    let (code, err, kb) = run_measured(
        d,
        &[
            "plan",
            "--mechanism",
            "gs24.toml",
            "--count",
            "30",
            "--max-candidates",
            "1000",
            "--out",
            "p.csv",
            "--quiet",
        ],
    );
    assert_eq!(code, Some(0), "{err}");
    assert!(kb < PEAK_KB, "plan took {kb} kB");
    assert_eq!(
        std::fs::read_to_string(d.join("p.csv"))
            .unwrap()
            .lines()
            .count(),
        31
    );
}

/// The conditioning of a lattice point solves for the joints only, not for
/// the 100 towers' parameters too: `simulate --grid` on a 100-tower delta.
#[test]
fn a_hundred_tower_delta_simulates_a_grid() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("d100.toml"), delta(100)).unwrap();
    let (code, err, kb) = run_measured(
        d,
        &[
            "simulate",
            "--mechanism",
            "d100.toml",
            "--grid",
            "5",
            "--out",
            "s.csv",
            "--quiet",
        ],
    );
    assert_eq!(code, Some(0), "{err}");
    assert!(kb < PEAK_KB, "simulate took {kb} kB");
    let s = std::fs::read_to_string(d.join("s.csv")).unwrap();
    assert_eq!(s.lines().filter(|l| !l.starts_with('#')).count(), 6, "{s}");
}

/// A million probe points (or measured rows) are refused while reading, at
/// the first row past what one identification takes, naming file and line.
#[test]
fn a_million_probe_points_are_refused_within_memory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.g"),
        "M665 R105.6 L215.0 H250 B85\nM666 X0 Y0 Z0\n",
    )
    .unwrap();
    let mut probes = String::with_capacity(24 << 20);
    probes.push_str("x,y,z\n");
    for i in 0..1_000_000u32 {
        let a = f64::from(i) * 2.399963;
        let r = 80.0 * (f64::from(i % 1000) / 1000.0).sqrt();
        let _ = writeln!(
            probes,
            "{:.3},{:.3},{:.4}",
            r * a.cos(),
            r * a.sin(),
            0.01 * a.sin()
        );
    }
    std::fs::write(d.join("probes.csv"), &probes).unwrap();
    let (code, err, kb) = run_measured(
        d,
        &[
            "reprap",
            "--config",
            "config.g",
            "--probes",
            "probes.csv",
            "--quiet",
        ],
    );
    assert_eq!(code, Some(1), "{err}");
    let limit = pkmcal::identify::MAX_POSES;
    assert!(
        err.contains(&format!("probes.csv:{}: ", limit + 2))
            && err.contains("more than one identification takes"),
        "{err}"
    );
    assert!(kb < PEAK_KB, "reprap took {kb} kB");
}

/// Issue 50, 7: work bounded by a limit a user can read. A 1,000-tower
/// delta (simulate ran for over 60 s) and a 1,000-leg platform are refused
/// where the description is read, naming the file and the limit; a
/// correction table of 1.5 million nodes on the 3-PRS (118 s, 814 MB) is a
/// usage error naming `--table`, before any work.
#[test]
fn a_thousand_legs_and_a_million_node_table_are_refused_early() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("d1000.toml"), delta(1000)).unwrap();
    std::fs::write(d.join("gs1000.toml"), gough_stewart(1000)).unwrap();
    for m in ["d1000.toml", "gs1000.toml"] {
        let (code, err, kb) = run_measured(
            d,
            &[
                "simulate",
                "--mechanism",
                m,
                "--grid",
                "20",
                "--out",
                "s.csv",
            ],
        );
        assert_eq!(code, Some(1), "{err}");
        assert!(
            err.contains(&format!(
                "{m}: invalid mechanism: 1000 legs, more than the 128"
            )),
            "{err}"
        );
        assert!(kb < PEAK_KB, "{kb} kB");
    }
    std::fs::write(d.join("p.toml"), "").unwrap();
    let prs = crate::common::example("3-prs");
    let (code, err, _) = run_measured(
        d,
        &[
            "compensate",
            "--mechanism",
            &prs,
            "--params",
            "p.toml",
            "--table",
            "z=350:450:0.5,rx=-0.15:0.15:0.0035,ry=-0.15:0.15:0.0035",
            "--out",
            "t.json",
        ],
    );
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--table: `z=350:450:0.5,rx=-0.15:0.15:0.0035,ry=-0.15:0.15:0.0035` makes 1486596 nodes, more than the 200000"),
        "{err}"
    );
    assert!(!d.join("t.json").exists());
}
