//! Raw ball-bar distances, weights and outliers (issue 4).

use crate::common::{fails, ok, read_csv};

fn setup(d: &std::path::Path) {
    std::fs::write(
        d.join("setup.toml"),
        "bar_offset = 0.0\nsockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n",
    )
    .unwrap();
    std::fs::write(
        d.join("truth.toml"),
        "l11 = 280.4\nB3x = 149.6\ndq1 = 0.001\ndq3 = -0.0012\nD2 = 215.2\n",
    )
    .unwrap();
}

fn param(file: &std::path::Path, name: &str) -> f64 {
    let text = std::fs::read_to_string(file).unwrap();
    text.lines()
        .find(|l| l.starts_with(&format!("{name} = ")))
        .unwrap()
        .split_whitespace()
        .nth(2)
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn both_ball_bar_routes_agree_on_noise_free_data() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    ok(
        d,
        &[
            "simulate",
            "--truth",
            "truth.toml",
            "--grid",
            "30",
            "--setup",
            "setup.toml",
            "--out",
            "bb.csv",
        ],
    );
    let (h, rows) = read_csv(&d.join("bb.csv"));
    assert_eq!(
        h,
        ["target_x", "target_y", "q1", "q2", "q3", "d1", "d2", "d3"]
    );
    assert_eq!(rows.len(), 30);
    ok(
        d,
        &[
            "trilaterate",
            "--setup",
            "setup.toml",
            "--data",
            "bb.csv",
            "--out",
            "tri.csv",
        ],
    );
    let (th, _) = read_csv(&d.join("tri.csv"));
    assert_eq!(&th[5..], ["x", "y", "sigma_x", "sigma_y"]);
    ok(
        d,
        &["calibrate", "--data", "tri.csv", "--out", "p-tri.toml"],
    );
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "bb.csv",
            "--setup",
            "setup.toml",
            "--out",
            "p-bb.toml",
        ],
    );
    for name in ["l11", "B3x", "D2", "dq1", "dq3", "Pty"] {
        let (a, b) = (
            param(&d.join("p-tri.toml"), name),
            param(&d.join("p-bb.toml"), name),
        );
        assert!((a - b).abs() < 1e-6, "{name}: {a} vs {b}");
    }
    assert!((param(&d.join("p-bb.toml"), "l11") - 280.4).abs() < 1e-6);
    // The identified parameters drive predict (mechanism names only).
    ok(
        d,
        &[
            "predict",
            "--params",
            "p-bb.toml",
            "--commands",
            "bb.csv",
            "--out",
            "pr.csv",
        ],
    );
    // Sockets and the bar offset can be identified too.
    let out = ok(
        d,
        &[
            "calibrate",
            "--data",
            "bb.csv",
            "--setup",
            "setup.toml",
            "--free",
            "default,s3x,dbar",
            "--out",
            "p2.toml",
        ],
    );
    assert!(out.contains("s3x") && out.contains("dbar"), "{out}");
    // Freeing every socket coordinate exposes the frame rotation, named.
    let out = ok(
        d,
        &[
            "analyze",
            "--data",
            "bb.csv",
            "--setup",
            "setup.toml",
            "--free",
            "default,s1x,s1y,s2x,s2y,s3x,s3y",
        ],
    );
    assert!(out.contains("1 direction cannot be identified"), "{out}");
    // Distances without a setup: a clear message.
    fails(
        d,
        &["calibrate", "--data", "bb.csv", "--out", "p3.toml"],
        1,
        "give the socket positions with --setup",
    );
}

#[test]
fn weights_and_outliers() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    ok(
        d,
        &[
            "simulate",
            "--truth",
            "truth.toml",
            "--grid",
            "35",
            "--noise",
            "0.002",
            "--seed",
            "4",
            "--out",
            "data.csv",
        ],
    );
    // Corrupt poses 7 and 19.
    let text = std::fs::read_to_string(d.join("data.csv")).unwrap();
    let mut lines: Vec<Vec<String>> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    let bump = |v: &str, by: f64| (v.parse::<f64>().unwrap() + by).to_string();
    lines[7][5] = bump(&lines[7][5], 0.06);
    lines[19][6] = bump(&lines[19][6], -0.09);
    let joined: Vec<String> = lines.iter().map(|l| l.join(",")).collect();
    // Still in the base frame, as simulated.
    std::fs::write(
        d.join("bad.csv"),
        format!("# frame: base\n{}", joined.join("\n")),
    )
    .unwrap();
    // Least squares flags the worst pose (the other can be masked: its error
    // leaks into neighbours); the robust fits and iterative dropping find both.
    let out = ok(d, &["calibrate", "--data", "bad.csv", "--out", "p.toml"]);
    assert!(out.contains("outlier: pose 19"), "{out}");
    for (args, report) in [
        (vec!["--loss", "huber"], "h.json"),
        (vec!["--loss", "cauchy"], "c.json"),
        (vec!["--drop-outliers"], "dr.json"),
    ] {
        let mut a = vec![
            "calibrate",
            "--data",
            "bad.csv",
            "--out",
            "x.toml",
            "--report",
            report,
        ];
        a.extend(args.iter());
        ok(d, &a);
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join(report)).unwrap()).unwrap();
        let mut poses: Vec<u64> = r["outliers"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["pose"].as_u64().unwrap())
            .collect();
        poses.sort_unstable();
        assert_eq!(poses, [7, 19], "{args:?}");
        if report == "dr.json" {
            assert_eq!(r["dropped"].as_array().unwrap().len(), 2);
            assert_eq!(r["poses"], 33);
        }
    }
    // Robust losses and dropping recover the truth far better than plain least squares.
    let err = |f: &str| {
        (param(&d.join(f), "l11") - 280.4).abs() + (param(&d.join(f), "B3x") - 149.6).abs()
    };
    for (args, file) in [
        (vec!["--loss", "huber"], "h.toml"),
        (vec!["--loss", "cauchy"], "c.toml"),
        (vec!["--drop-outliers"], "dr.toml"),
    ] {
        let mut a = vec!["calibrate", "--data", "bad.csv", "--out", file];
        a.extend(args.iter());
        ok(d, &a);
        assert!(
            err(file) < 0.5 * err("p.toml"),
            "{args:?}: {} vs least squares {}",
            err(file),
            err("p.toml")
        );
    }
    // Per-axis standard deviations as weights (from trilateration or the user).
    let mut lines2 = lines.clone();
    lines2[0].extend(["sigma_x".to_string(), "sigma_y".to_string()]);
    for (i, l) in lines2.iter_mut().enumerate().skip(1) {
        let s = if i == 7 || i == 19 { "1.0" } else { "0.002" };
        l.extend([s.to_string(), s.to_string()]);
    }
    let joined: Vec<String> = lines2.iter().map(|l| l.join(",")).collect();
    std::fs::write(
        d.join("w.csv"),
        format!("# frame: base\n{}", joined.join("\n")),
    )
    .unwrap();
    ok(d, &["calibrate", "--data", "w.csv", "--out", "w.toml"]);
    assert!(
        err("w.toml") < 0.5 * err("p.toml"),
        "weighted {} vs {}",
        err("w.toml"),
        err("p.toml")
    );
}
