//! `--physical --report-dir` (issue 54): the owner's HTML report is
//! written beside the values, its figures present, its numbers those of
//! the summary; all or nothing; refused without --physical.

use crate::common::{fails, ok};
use pkmcal_io::firmware::physical_report::FILES;
use std::path::{Path, PathBuf};

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples")
}

/// How often `tag` opens and closes in `html`.
fn balance(html: &str, tag: &str) -> (usize, usize) {
    (
        html.matches(&format!("<{tag}>")).count() + html.matches(&format!("<{tag} ")).count(),
        html.matches(&format!("</{tag}>")).count(),
    )
}

/// The report in `dir` is whole: every file, one page that closes what it
/// opens, every figure inlined; returns the page.
fn whole(dir: &Path) -> String {
    for f in FILES {
        let p = dir.join(f);
        assert!(
            std::fs::metadata(&p).is_ok_and(|m| m.len() > 0),
            "{} missing",
            p.display()
        );
    }
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(html.trim_end().ends_with("</html>"));
    for tag in ["table", "tr", "ul", "li", "figure", "svg", "h2", "p"] {
        let (open, close) = balance(&html, tag);
        assert_eq!(open, close, "<{tag}> opened {open} times, closed {close}");
    }
    for id in ["nozzle-z", "nozzle-xy", "nozzle-sigma"] {
        assert!(
            html.contains(&format!("<figure id=\"{id}\"><h3>")),
            "figure {id} missing"
        );
    }
    for section in [
        "<h2>Verdict</h2>",
        "<h2>Values to write</h2>",
        "<h2>The nozzle's error over the build volume</h2>",
        "<h2>Predicted 20 mm cube</h2>",
    ] {
        assert!(html.contains(section), "{section} missing");
    }
    html
}

#[test]
fn klipper_report_shows_the_summarys_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg.to_str().unwrap(),
            "--physical",
            "--out",
            "new.cfg",
            "--height-map",
            "mesh.cfg",
            "--report-dir",
            "report",
        ],
    );
    assert!(out.contains("report -> report"), "{out}");
    let html = whole(&dir.path().join("report"));
    // Each written value, as the summary prints it.
    let mut values = 0;
    for line in out.lines().filter(|l| l.trim_start().starts_with("[")) {
        // `[section] name  before  after  σ unit` (or `fixed`).
        let numbers: Vec<&str> = line
            .split_whitespace()
            .filter(|t| t.parse::<f64>().is_ok())
            .collect();
        let after = numbers[1];
        assert!(
            html.contains(&format!("<b>{after}</b>")),
            "{after} of `{line}` not in the report"
        );
        let sigma = numbers.get(2).copied().unwrap_or("fixed");
        assert!(
            html.contains(&format!("<td>{sigma}</td>")),
            "σ {sigma} of `{line}` not in the report"
        );
        values += 1;
    }
    assert_eq!(values, 10, "{out}");
    // The build-volume errors and the cubes, as printed.
    let numbers = |line: &str| -> Vec<String> {
        line.split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '+' || c == '-'))
            .filter(|w| w.contains('.') && w.len() > 2)
            .map(String::from)
            .collect()
    };
    let errors = out
        .lines()
        .find(|l| l.trim_start().starts_with("the values for the nozzle "))
        .unwrap();
    for n in numbers(errors) {
        assert!(
            html.contains(&format!("<td>{n}</td>")),
            "{n} not in the report"
        );
    }
    let cubes: Vec<&str> = out.lines().filter(|l| l.contains("top flatness")).collect();
    assert_eq!(cubes.len(), 2);
    for c in cubes {
        let n = numbers(c.split("):").nth(1).unwrap());
        assert_eq!(n.len(), 6, "{c}");
        for pair in n.chunks(2) {
            assert!(
                html.contains(&format!("{} ± {}", pair[0], pair[1])),
                "{} ± {} not in the report",
                pair[0],
                pair[1]
            );
        }
    }
    // The height map, written, and its nodes on the page.
    assert!(html.contains("<h2>Height map</h2>") && html.contains("mesh.cfg"));
    // The next measurements, in Klipper's commands.
    assert!(html.contains("<h2>Next measurements</h2>") && html.contains("DELTA_ANALYZE"));
}

#[test]
fn reprap_and_marlin_reports_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let ex = examples();
    let rrf = [
        ex.join("reprap-delta/config.g"),
        ex.join("reprap-delta/probes.csv"),
    ];
    ok(
        dir.path(),
        &[
            "reprap",
            "--config",
            rrf[0].to_str().unwrap(),
            "--probes",
            rrf[1].to_str().unwrap(),
            "--physical",
            "--report-dir",
            "rrf",
        ],
    );
    let html = whole(&dir.path().join("rrf"));
    assert!(html.contains("M665 L") && html.contains("G30 P&lt;next&gt;"));
    let marlin = [
        ex.join("marlin-delta/M503.txt"),
        ex.join("marlin-delta/G30.log"),
    ];
    ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            marlin[0].to_str().unwrap(),
            "--probes",
            marlin[1].to_str().unwrap(),
            "--physical",
            "--report-dir",
            "deep/marlin",
        ],
    );
    let html = whole(&dir.path().join("deep/marlin"));
    assert!(html.contains("M665 L"));
}

#[test]
fn report_is_all_or_nothing_and_needs_physical() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let cfg = cfg.to_str().unwrap();
    fails(
        dir.path(),
        &["klipper", "--config", cfg, "--report-dir", "r"],
        2,
        "add --physical",
    );
    assert!(!dir.path().join("r").exists());
    // The report's directory is a file: nothing written.
    std::fs::write(dir.path().join("taken"), "mine").unwrap();
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg,
            "--physical",
            "--out",
            "new.cfg",
            "--height-map",
            "mesh.cfg",
            "--report-dir",
            "taken",
        ],
        2,
        "taken",
    );
    assert_eq!(
        std::fs::read_to_string(dir.path().join("taken")).unwrap(),
        "mine"
    );
    // The page would overwrite the configuration read: nothing written,
    // the input kept.
    let d = dir.path().join("cfgdir");
    std::fs::create_dir(&d).unwrap();
    std::fs::copy(cfg, d.join("report.html")).unwrap();
    let before = std::fs::read(d.join("report.html")).unwrap();
    let o = crate::common::run(
        dir.path(),
        &[
            "klipper",
            "--config",
            "cfgdir/report.html",
            "--physical",
            "--out",
            "new.cfg",
            "--height-map",
            "mesh.cfg",
            "--report-dir",
            "cfgdir",
        ],
    );
    assert!(!o.status.success());
    assert_eq!(std::fs::read(d.join("report.html")).unwrap(), before);
    assert!(!d.join("nozzle-z.svg").exists());
    for f in ["new.cfg", "mesh.cfg"] {
        assert!(!dir.path().join(f).exists(), "{f} written");
    }
}

#[test]
fn klipper_report_says_the_drift_against_previous() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let cfg = cfg.to_str().unwrap();
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg,
            "--physical",
            "--previous",
            cfg,
            "--report-dir",
            "r",
        ],
    );
    let html = whole(&dir.path().join("r"));
    // The same readings twice: no change, in the verdict and its section,
    // with the summary's χ².
    assert!(
        out.contains("no change beyond the two calibrations' uncertainty"),
        "{out}"
    );
    let since = out.lines().find(|l| l.contains("joint test")).unwrap();
    let chi2 = since
        .split("χ² ")
        .nth(1)
        .unwrap()
        .split(',')
        .next()
        .unwrap();
    assert!(html.contains("<h2>Since ") && html.contains(&format!("χ² {chi2}")));
    assert!(html.contains("<b>no change beyond the two calibrations' uncertainty</b>"));
}

/// The page says what the fit was given: the tolerances it held the parts
/// by (a user's in place of the defaults, as the summary says them) and
/// the touches measured by hand; the next measurements name the command
/// line's own options.
#[test]
fn the_report_says_the_tolerances_and_touches_the_fit_read() {
    let dir = tempfile::tempdir().unwrap();
    let ex = examples();
    let cfg = ex.join("klipper-delta/printer.cfg");
    let heights = ex.join("klipper-delta/heights.csv");
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg.to_str().unwrap(),
            "--physical",
            "--tolerance",
            "rod_a1=0.01,bed.rx=0.004",
            "--heights",
            heights.to_str().unwrap(),
            "--report-dir",
            "report",
        ],
    );
    let tolerances = "rods 0.01–0.1 mm, tower radii 0.5 mm, tower lean 1 mrad, ball joints 0.1 mm, bed tilt 2–4 mrad";
    assert!(out.contains(tolerances), "{out}");
    let html = whole(&dir.path().join("report"));
    assert!(html.contains(tolerances), "the page's tolerances");
    assert!(
        html.contains("13 probe heights from")
            && html.contains("; 11 touches measured by hand (7 of the nozzle)"),
        "the page's readings"
    );
    assert!(
        html.contains("give --height-map to write it"),
        "the height map's option"
    );
    assert!(
        html.contains("read back from --heights as `nozzle` rows"),
        "the nozzle touches' input"
    );
}
