//! Parameters renamed for one name per meaning (the Gough–Stewart kind's
//! stiffness `k1…` is `kL1…`) are still read by their old names wherever a
//! user gives them — an option, a parameter file, a saved calibration — with
//! a note saying what they are read as; nothing is refused for it.

use crate::common::{ok, run};

fn mech() -> String {
    concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../examples/gough-stewart-6/mechanism.toml"
    )
    .to_string()
}

#[test]
fn old_names_are_read_with_a_note() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let m = mech();
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &m,
            "--grid",
            "40",
            "--noise",
            "0.002",
            "--seed",
            "3",
            "--out",
            "d.csv",
            "--quiet",
        ],
    );
    // An option: the old name in --fix and in --tolerance.
    let o = run(
        d,
        &[
            "calibrate",
            "--mechanism",
            &m,
            "--data",
            "d.csv",
            "--fix",
            "k1",
            "--tolerance",
            "k2=20%",
            "--out",
            "p.toml",
            "--report",
            "new.json",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("`k1` → `kL1`") && err.contains("`k2` → `kL2`"),
        "{err}"
    );
    let summary = String::from_utf8_lossy(&o.stdout);
    assert!(summary.contains("kL2"), "{summary}");

    // A parameter file of old names predicts as the same file of new ones.
    let new = std::fs::read_to_string(d.join("p.toml")).unwrap();
    let old: String = new
        .lines()
        .map(|l| {
            let mut l = l.to_string();
            for k in 1..=6 {
                l = l.replace(&format!("kL{k} ="), &format!("k{k} ="));
            }
            l + "\n"
        })
        .collect();
    assert_ne!(old, new);
    std::fs::write(d.join("old.toml"), &old).unwrap();
    let args = |p: &'static str, out: &'static str| {
        vec![
            "predict".to_string(),
            "--mechanism".into(),
            m.clone(),
            "--params".into(),
            p.into(),
            "--commands".into(),
            "d.csv".into(),
            "--out".into(),
            out.into(),
        ]
    };
    let a: Vec<String> = args("p.toml", "a.csv");
    let b: Vec<String> = args("old.toml", "b.csv");
    let oa = run(d, &a.iter().map(String::as_str).collect::<Vec<_>>());
    let ob = run(d, &b.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(oa.status.success() && ob.status.success());
    let note = String::from_utf8_lossy(&ob.stderr);
    assert!(
        note.contains("parameter file old.toml") && note.contains("`k1` → `kL1`"),
        "{note}"
    );
    assert!(!String::from_utf8_lossy(&oa.stderr).contains("→"));
    assert_eq!(
        std::fs::read(d.join("a.csv")).unwrap(),
        std::fs::read(d.join("b.csv")).unwrap()
    );

    // A saved calibration of old names is compared on today's: nothing left
    // out for the renaming.
    let report = std::fs::read_to_string(d.join("new.json")).unwrap();
    let mut old_report = report.clone();
    for k in 1..=6 {
        old_report = old_report.replace(&format!("\"kL{k}\""), &format!("\"k{k}\""));
    }
    assert_ne!(old_report, report);
    std::fs::write(d.join("old.json"), old_report).unwrap();
    let o = run(
        d,
        &[
            "drift",
            "--mechanism",
            &m,
            "--old",
            "old.json",
            "--new",
            "new.json",
            "--grid",
            "0",
        ],
    );
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("`k1` → `kL1`"), "{err}");
    assert!(out.contains("0 of"), "{out}");
    // The same comparison as of the record under today's names: the
    // renaming leaves nothing out and changes nothing.
    std::fs::copy(d.join("new.json"), d.join("same.json")).unwrap();
    let same = run(
        d,
        &[
            "drift",
            "--mechanism",
            &m,
            "--old",
            "same.json",
            "--new",
            "new.json",
            "--grid",
            "0",
        ],
    );
    assert!(same.status.success());
    assert_eq!(
        out.replace("old.json", "same.json"),
        String::from_utf8_lossy(&same.stdout)
    );
}
