//! From measurements in the user's units to what a controller takes:
//! corrections, correction tables, pre-distorted targets and G-code.

use crate::common::{example, fails, json, ok, read_csv};
use std::path::Path;

/// Agreement of two computations of the same command (rad or mm).
const SAME: f64 = 1e-9;
/// How close a pre-distorted target brings the tool (mm).
const REACHED_MM: f64 = 1e-8;
/// G-code coordinates are written to 0.1 µm and 1e-6 degrees; the tool lands
/// within this of the programmed point (mm).
const GCODE_MM: f64 = 1e-3;

/// Calibrated parameters of the reference mechanism (not the nominal ones).
const CAL: &str = "l11 = 280.4\nB3x = 149.6\ndq1 = 0.001\ndq3 = -0.0012\nD2 = 215.2\n";

/// A CSV with empty fields (NaN) allowed.
fn table(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| {
            l.split(',')
                .map(|v| {
                    if v.is_empty() {
                        f64::NAN
                    } else {
                        v.parse().unwrap()
                    }
                })
                .collect()
        })
        .collect();
    (header, rows)
}

fn col(h: &[String], name: &str) -> usize {
    h.iter()
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("{name} in {h:?}"))
}

#[test]
fn corrections_units_and_force_columns() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    std::fs::write(
        d.join("t.csv"),
        "target_x,target_y\n0,180\n40,120\n-60,230\n",
    )
    .unwrap();
    ok(d, &["compensate", "--targets", "t.csv", "--out", "nom.csv"]);
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--targets",
            "t.csv",
            "--out",
            "cal.csv",
        ],
    );
    let (h, nom) = read_csv(&d.join("nom.csv"));
    let (_, cal) = read_csv(&d.join("cal.csv"));
    for a in ["q1", "q2", "q3"] {
        let (c, dc) = (col(&h, a), col(&h, &format!("delta_{a}")));
        for (n, r) in nom.iter().zip(&cal) {
            // Nominal parameters: no correction; calibrated: the difference
            // from the nominal commands.
            assert!(n[dc].abs() < SAME, "{a}: {}", n[dc]);
            assert!((r[dc] - (r[c] - n[c])).abs() < SAME, "{a}");
            assert!(
                r[dc].abs() > 1e-5,
                "{a}: the calibration changes the command"
            );
        }
    }
    // Degrees and encoder counts, from the command line and from [units].
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--targets",
            "t.csv",
            "--units",
            "angle=deg",
            "--out",
            "deg.csv",
        ],
    );
    let (_, deg) = read_csv(&d.join("deg.csv"));
    let text = std::fs::read_to_string(d.join("deg.csv")).unwrap();
    assert!(text.starts_with("# units: angles in deg"), "{text}");
    std::fs::write(
        d.join("m.toml"),
        "type = \"jeong-kim-2dof\"\n[units]\ncounts_per_rev = 4096\nlength = \"m\"\n",
    )
    .unwrap();
    std::fs::write(
        d.join("tm.csv"),
        "target_x,target_y\n0,0.18\n0.04,0.12\n-0.06,0.23\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "compensate",
            "--mechanism",
            "m.toml",
            "--params",
            "cal.toml",
            "--targets",
            "tm.csv",
            "--out",
            "counts.csv",
        ],
    );
    let (_, counts) = read_csv(&d.join("counts.csv"));
    for ((r, g), k) in cal.iter().zip(&deg).zip(&counts) {
        for c in 2..8 {
            assert!((g[c] - r[c].to_degrees()).abs() < 1e-9, "deg column {c}");
            let want = r[c] * 4096.0 / std::f64::consts::TAU;
            assert!(
                (k[c] - want).abs() < 1e-7,
                "counts column {c}: {} vs {want}",
                k[c]
            );
        }
        assert!((k[0] * 1e3 - r[0]).abs() < 1e-9 && (k[1] * 1e3 - r[1]).abs() < 1e-9);
        // Torques stay in N·m.
        assert_eq!(&g[8..], &r[8..]);
    }
    // A Gough–Stewart platform's prismatic legs carry forces.
    let gs = example("gough-stewart-6");
    std::fs::write(
        d.join("g.csv"),
        "target_x,target_y,target_z,target_rx,target_ry,target_rz\n0,0,700,0,0,0\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "compensate",
            "--mechanism",
            &gs,
            "--targets",
            "g.csv",
            "--out",
            "gc.csv",
        ],
    );
    let (h, _) = read_csv(&d.join("gc.csv"));
    assert!(
        h.contains(&"force_L1".to_string()) && h.contains(&"delta_L6".to_string()),
        "{h:?}"
    );
    assert!(!h.iter().any(|c| c.starts_with("torque_")), "{h:?}");
    ok(
        d,
        &[
            "predict",
            "--mechanism",
            &gs,
            "--commands",
            "gc.csv",
            "--out",
            "gp.csv",
        ],
    );
    let (h, _) = read_csv(&d.join("gp.csv"));
    assert!(
        h.contains(&"force_L1".to_string()) && h.contains(&"deflection_L1".to_string()),
        "{h:?}"
    );
    fails(
        d,
        &[
            "compensate",
            "--targets",
            "t.csv",
            "--units",
            "angle=grad",
            "--out",
            "x.csv",
        ],
        2,
        "angle unit `grad`: use rad or deg",
    );
}

#[test]
fn data_in_other_units_calibrate_alike_and_wrong_units_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("truth.toml"), CAL).unwrap();
    ok(
        d,
        &[
            "simulate",
            "--grid",
            "30",
            "--truth",
            "truth.toml",
            "--noise",
            "0.002",
            "--out",
            "mm.csv",
        ],
    );
    ok(
        d,
        &[
            "simulate",
            "--grid",
            "30",
            "--truth",
            "truth.toml",
            "--noise",
            "0.002",
            "--units",
            "angle=deg,length=m",
            "--out",
            "m.csv",
        ],
    );
    let text = std::fs::read_to_string(d.join("m.csv")).unwrap();
    assert!(
        text.contains("# units: angles in deg, lengths in m"),
        "{text}"
    );
    ok(d, &["calibrate", "--data", "mm.csv", "--out", "a.toml"]);
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "m.csv",
            "--units",
            "length=m,angle=deg",
            "--out",
            "b.toml",
        ],
    );
    let values = |f: &str| -> Vec<f64> {
        std::fs::read_to_string(d.join(f))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#') && l.contains('='))
            .map(|l| {
                l.split('=')
                    .nth(1)
                    .unwrap()
                    .split('#')
                    .next()
                    .unwrap()
                    .trim()
                    .parse()
                    .unwrap()
            })
            .collect()
    };
    for (a, b) in values("a.toml").iter().zip(values("b.toml")) {
        assert!((a - b).abs() <= 1e-7 * a.abs().max(1.0), "{a} vs {b}");
    }
    // Its own units line is read: no option needed.
    ok(d, &["calibrate", "--data", "m.csv", "--out", "c.toml"]);
    for (a, b) in values("a.toml").iter().zip(values("c.toml")) {
        assert!((a - b).abs() <= 1e-7 * a.abs().max(1.0), "{a} vs {b}");
    }
    std::fs::remove_file(d.join("c.toml")).unwrap();
    // The same numbers without the line (an instrument's export), read as
    // mm and rad: the unit is named with the fix.
    let bare: String = text
        .lines()
        .filter(|l| !l.starts_with("# units:"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d.join("m.csv"), bare).unwrap();
    fails(
        d,
        &["calibrate", "--data", "m.csv", "--out", "c.toml"],
        1,
        "give --units angle=deg",
    );
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "m.csv",
            "--units",
            "angle=deg",
            "--out",
            "c.toml",
        ],
        1,
        "they look like m, not mm; give --units length=m",
    );
    fails(
        d,
        &["predict", "--commands", "m.csv", "--out", "p.csv"],
        1,
        "hint: the commands assemble the mechanism if read in another unit: give --units angle=deg",
    );
    assert!(!d.join("c.toml").exists() && !d.join("p.csv").exists());
    // Predictions written back in the file's units.
    ok(
        d,
        &[
            "predict",
            "--commands",
            "m.csv",
            "--units",
            "angle=deg,length=m",
            "--params",
            "truth.toml",
            "--model",
            "exact",
            "--out",
            "p.csv",
        ],
    );
    let (h, p) = read_csv(&d.join("p.csv"));
    let (hm, m) = read_csv(&d.join("m.csv"));
    for (r, s) in p.iter().zip(&m) {
        for a in ["x", "y"] {
            // Noise of 2 µm on the simulated readings, in metres.
            assert!((r[col(&h, a)] - s[col(&hm, a)]).abs() < 1e-5, "{a}");
        }
    }
}

#[test]
fn correction_grid_matches_compensation_and_reports_its_interpolation_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    let err = |step: f64, out: &str| -> f64 {
        let grid = format!("x=-60:60:{step},y=160:260:{step}");
        ok(
            d,
            &[
                "compensate",
                "--params",
                "cal.toml",
                "--table",
                &grid,
                "--out",
                out,
            ],
        );
        let v = json(&d.join(out));
        v["interpolation_error"]["position_max"].as_f64().unwrap()
    };
    let (coarse, fine) = (err(10.0, "g10.json"), err(5.0, "g5.json"));
    // Multilinear interpolation of a smooth correction: second order.
    assert!(fine < coarse / 3.0, "{coarse} -> {fine}");
    assert!(coarse < 0.02, "{coarse} mm");
    let v = json(&d.join("g10.json"));
    assert_eq!(v["axes"][0]["name"], "x");
    assert_eq!(v["axes"][0]["count"], 13);
    assert_eq!(v["axes"][1]["count"], 11);
    assert_eq!(v["corrections"].as_array().unwrap().len(), 13 * 11);
    // The CSV form: nodes, row-major with y fastest, corrections equal to
    // compensating the node's target.
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--table",
            "x=-60:60:10,y=160:260:10",
            "--out",
            "g.csv",
        ],
    );
    let text = std::fs::read_to_string(d.join("g.csv")).unwrap();
    assert!(
        text.contains("# correction grid: x = -60:60:10 (13 nodes), y = 160:260:10 (11 nodes)"),
        "{text}"
    );
    assert!(
        text.contains("# interpolation error at 120 cell centres"),
        "{text}"
    );
    let (h, rows) = table(&d.join("g.csv"));
    assert_eq!(rows.len(), 13 * 11);
    assert_eq!((rows[1][0], rows[1][1]), (-60.0, 170.0));
    let picks = [0usize, 17, 60, 142];
    let mut t = String::from("target_x,target_y\n");
    for &i in &picks {
        t.push_str(&format!("{},{}\n", rows[i][0], rows[i][1]));
    }
    std::fs::write(d.join("t.csv"), t).unwrap();
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--targets",
            "t.csv",
            "--out",
            "c.csv",
        ],
    );
    let (hc, c) = read_csv(&d.join("c.csv"));
    for (k, &i) in picks.iter().enumerate() {
        for a in ["delta_q1", "delta_q2", "delta_q3", "q1"] {
            assert!(
                (rows[i][col(&h, a)] - c[k][col(&hc, a)]).abs() < SAME,
                "node {i} {a}"
            );
        }
    }
    fails(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--table",
            "x=0:10",
            "--out",
            "x.csv",
        ],
        2,
        "give one value or START:STOP:STEP",
    );
    fails(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--table",
            "w=0:10:1",
            "--out",
            "x.csv",
        ],
        2,
        "`w` is not a tool axis (x, y)",
    );
    fails(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--table",
            "x=2000:3000:100,y=2000:3000:100",
            "--out",
            "x.csv",
        ],
        1,
        "no node of the grid",
    );
}

#[test]
fn predistorted_targets_bring_the_real_machine_to_the_wanted_ones() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    std::fs::write(
        d.join("t.csv"),
        "target_x,target_y\n0,180\n40,120\n-60,230\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--targets",
            "t.csv",
            "--cartesian",
            "--out",
            "pd.csv",
        ],
    );
    let (h, rows) = read_csv(&d.join("pd.csv"));
    // The commands the nominal controller sends for command_x, command_y,
    // driven through the calibrated machine, reach target_x, target_y.
    let mut cmds = String::from("q1,q2,q3\n");
    for r in &rows {
        let q: Vec<String> = ["q1", "q2", "q3"]
            .iter()
            .map(|a| r[col(&h, a)].to_string())
            .collect();
        cmds.push_str(&format!("{}\n", q.join(",")));
        assert!((r[col(&h, "delta_x")] - (r[col(&h, "command_x")] - r[0])).abs() < SAME);
    }
    std::fs::write(d.join("q.csv"), cmds).unwrap();
    ok(
        d,
        &[
            "predict",
            "--params",
            "cal.toml",
            "--commands",
            "q.csv",
            "--out",
            "p.csv",
        ],
    );
    let (hp, p) = read_csv(&d.join("p.csv"));
    for (r, x) in rows.iter().zip(&p) {
        let e = (x[col(&hp, "x")] - r[0]).hypot(x[col(&hp, "y")] - r[1]);
        assert!(e < REACHED_MM, "{e} mm");
    }
    // A non-redundant platform: the controller's commands for the
    // pre-distorted target are the compensated commands.
    let gs = example("gough-stewart-6");
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &gs,
            "--grid",
            "2",
            "--out",
            "gt.csv",
        ],
    );
    let gp = "gp.toml";
    std::fs::write(d.join(gp), "a1x = 492.9\nb3z = -0.4\n").unwrap();
    ok(
        d,
        &[
            "compensate",
            "--mechanism",
            &gs,
            "--params",
            gp,
            "--targets",
            "gt.csv",
            "--out",
            "gc.csv",
        ],
    );
    ok(
        d,
        &[
            "compensate",
            "--mechanism",
            &gs,
            "--params",
            gp,
            "--targets",
            "gt.csv",
            "--cartesian",
            "--out",
            "gd.csv",
        ],
    );
    let (h1, c1) = read_csv(&d.join("gc.csv"));
    let (h2, c2) = read_csv(&d.join("gd.csv"));
    for (a, b) in c1.iter().zip(&c2) {
        for leg in 1..=6 {
            let n = format!("L{leg}");
            assert!((a[col(&h1, &n)] - b[col(&h2, &n)]).abs() < 1e-8, "{n}");
        }
    }
    fails(
        d,
        &[
            "compensate",
            "--targets",
            "t.csv",
            "--cartesian",
            "--preload",
            "1,2,3",
            "--out",
            "x.csv",
        ],
        2,
        "--preload needs actuator commands",
    );
}

/// The X, Y words of a G-code line.
fn xy(line: &str) -> Option<(f64, f64)> {
    let word = |c: char| -> Option<f64> {
        line.split_whitespace()
            .find(|w| w.starts_with(c))
            .map(|w| w[1..].parse().unwrap())
    };
    Some((word('X')?, word('Y')?))
}

#[test]
fn gcode_moves_are_rewritten_through_the_predistortion() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    // In CNC mode (M453), where RepRapFirmware continues the last G0/G1 on
    // a line without a command and skips ( ) comments.
    let program = "M453 ; a square\nG21\nG90\nM83\nG0 X-20 Y180 F6000 ; start\nG1 X20 E1.5 F1200\nY220 E1.5\nG91\nG1 X-40 E1.5\nG90\nG1 Y180 (back)\nM2\n";
    std::fs::write(d.join("part.gcode"), program).unwrap();
    ok(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "part.gcode",
            "--dialect",
            "reprap",
            "--out",
            "cal.gcode",
        ],
    );
    let out = std::fs::read_to_string(d.join("cal.gcode")).unwrap();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), program.lines().count(), "{out}");
    assert_eq!(lines[0], "M453 ; a square");
    assert_eq!(lines[3], "M83");
    assert!(
        lines[4].starts_with("G0 X") && lines[4].ends_with("F6000 ; start"),
        "{}",
        lines[4]
    );
    assert!(
        lines[5].contains("E1.50000") && lines[5].contains("F1200"),
        "{}",
        lines[5]
    );
    assert!(lines[10].ends_with("(back)"));
    // Absolute moves: the programmed points, sent through the nominal
    // controller and the calibrated machine, are reached.
    let wanted = [(-20.0, 180.0), (20.0, 180.0), (20.0, 220.0)];
    let sent: Vec<(f64, f64)> = [4, 5, 6].iter().map(|&i| xy(lines[i]).unwrap()).collect();
    let mut t = String::from("target_x,target_y\n");
    for (x, y) in &sent {
        t.push_str(&format!("{x},{y}\n"));
    }
    std::fs::write(d.join("sent.csv"), t).unwrap();
    // The nominal controller's commands for the sent targets drive the
    // calibrated machine to the programmed points.
    let (h, p) = crate::common::reached_from_sent(d, None, "cal.toml", "sent.csv");
    for (r, (x, y)) in p.iter().zip(wanted) {
        let e = (r[col(&h, "x")] - x).hypot(r[col(&h, "y")] - y);
        assert!(e < GCODE_MM, "{e} mm");
    }
    // The relative move keeps relative coordinates: it ends where an
    // absolute move to (-20, 220) would.
    let (dx, dy) = xy(lines[8]).unwrap();
    std::fs::write(d.join("abs.gcode"), "G90\nG1 X20 Y220\nG1 X-20 Y220\n").unwrap();
    ok(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "abs.gcode",
            "--out",
            "abs.out",
        ],
    );
    let abs = std::fs::read_to_string(d.join("abs.out")).unwrap();
    let a: Vec<(f64, f64)> = abs.lines().filter_map(xy).collect();
    assert!(
        (a[0].0 + dx - a[1].0).abs() < 2e-4 && (a[0].1 + dy - a[1].1).abs() < 2e-4,
        "{abs} vs {dx} {dy}"
    );
    // Long moves split into segments, extrusion shared among them.
    ok(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "part.gcode",
            "--dialect",
            "reprap",
            "--max-segment",
            "5",
            "--out",
            "seg.gcode",
        ],
    );
    let seg = std::fs::read_to_string(d.join("seg.gcode")).unwrap();
    assert_eq!(
        seg.lines().filter(|l| l.contains("E0.18750")).count(),
        3 * 8,
        "{seg}"
    );
    // Refusals name the line.
    for (text, needle) in [
        (
            "G1 X0 Y180\nG2 X10 Y190 I5 J5\n",
            "bad.gcode:2: arcs (G2/G3) are not rewritten",
        ),
        ("G1 X0 Y180\nG92 X0\n", "bad.gcode:2: G92 on a tool axis"),
        (
            "G91\nG1 X5\n",
            "bad.gcode:2: relative move before the position of x is known",
        ),
        ("G1 X0 Y900\n", "bad.gcode:1: target"),
        (
            "G1 X0 Y1-2\n",
            "bad.gcode:1: `G1 X0 Y1-2`: Klipper cannot read `Y1-2` as a number",
        ),
        (
            "G1 X0 Y180\nG1 X1000000\n",
            "bad.gcode:2: segments of 5 mm would split",
        ),
    ] {
        std::fs::write(d.join("bad.gcode"), text).unwrap();
        fails(
            d,
            &[
                "gcode",
                "--params",
                "cal.toml",
                "--program",
                "bad.gcode",
                "--max-segment",
                "5",
                "--out",
                "bad.out",
            ],
            1,
            needle,
        );
        assert!(!d.join("bad.out").exists());
    }
}

/// The README's walk-through, step by step.
#[test]
fn readme_walkthrough_from_a_tracker_export_to_controller_corrections() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("truth.toml"),
        "l11 = 280.4\nB3x = 149.6\nB3y = 420.5\nD2 = 215.2\ndq1 = 0.004\ndq3 = -0.003\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "simulate",
            "--grid",
            "35",
            "--truth",
            "truth.toml",
            "--noise",
            "0.002",
            "--instrument-frame",
            "1200,-400,0.03",
            "--units",
            "angle=deg,length=m",
            "--out",
            "sim.csv",
        ],
    );
    // sed -e '/^#/d; s/,/;/g; s/\./,/g' (an export has no comment lines)
    let text: String = std::fs::read_to_string(d.join("sim.csv"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.replace(',', ";").replace('.', ","))
        .map(|l| l + "\n")
        .collect();
    std::fs::write(d.join("tracker.csv"), text).unwrap();
    fails(
        d,
        &["calibrate", "--data", "tracker.csv", "--out", "cal.toml"],
        1,
        "but they do in another unit; give --units angle=deg",
    );
    let out = ok(
        d,
        &[
            "calibrate",
            "--data",
            "tracker.csv",
            "--units",
            "angle=deg,length=m",
            "--out",
            "cal.toml",
            "--report",
            "r.json",
            "--report-dir",
            "report",
        ],
    );
    assert!(
        out.contains("instrument frame in the base frame (identified"),
        "{out}"
    );
    let r = json(&d.join("r.json"));
    let after = r["accuracy"]["after"]["distance_max"].as_f64().unwrap();
    let before = r["accuracy"]["before"]["distance_max"].as_f64().unwrap();
    assert!(after < 0.01 && before > 0.5, "{before} -> {after} mm");
    let frame = r["frame"].as_array().unwrap();
    assert!(
        (frame[0].as_f64().unwrap() - 1200.0).abs() < 0.1,
        "{frame:?}"
    );
    std::fs::write(
        d.join("path.csv"),
        "target_x,target_y\n0,200\n50,250\n-80,300\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--targets",
            "path.csv",
            "--units",
            "angle=deg",
            "--out",
            "commands.csv",
        ],
    );
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--table",
            "x=-60:60:5,y=160:260:5",
            "--units",
            "angle=deg",
            "--out",
            "table.json",
        ],
    );
    let t = json(&d.join("table.json"));
    assert_eq!(t["actuators"][0]["unit"], "deg");
    assert!(t["interpolation_error"]["position_max"].as_f64().unwrap() < 0.005);
    ok(
        d,
        &[
            "compensate",
            "--params",
            "cal.toml",
            "--targets",
            "path.csv",
            "--cartesian",
            "--out",
            "targets.csv",
        ],
    );
    std::fs::write(
        d.join("part.gcode"),
        "G21\nG90\nG0 X-40 Y200 F6000\nG1 X40 F1200\nG1 Y260\nG1 X-40\nG1 Y200\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "part.gcode",
            "--max-segment",
            "10",
            "--out",
            "part-cal.gcode",
        ],
    );
    let g = std::fs::read_to_string(d.join("part-cal.gcode")).unwrap();
    assert_eq!(g.lines().filter(|l| l.starts_with("G1")).count(), 28, "{g}");
}

/// A program is split into a bounded number of pieces in all (issue 34,
/// D10); what firmwares read differently is tested in tests/all/gcode.rs.
#[test]
fn gcode_pieces_are_bounded_in_all() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    // 401 moves of 20 mm at 1 µm: 8 million pieces, refused by the bound.
    let mut long = String::from("G21\nG90\nG1 X0 Y180\n");
    for k in 0..400 {
        long.push_str(if k % 2 == 0 {
            "G1 X10 Y197\n"
        } else {
            "G1 X0 Y180\n"
        });
    }
    std::fs::write(d.join("long.gcode"), long).unwrap();
    fails(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "long.gcode",
            "--max-segment",
            "0.001",
            "--out",
            "o2.gcode",
        ],
        1,
        "pieces in all",
    );
}
