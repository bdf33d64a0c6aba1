//! Helpers shared by the CLI tests.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_pkmcal");
/// Agreement of predict with simulate on noise-free data (mm).
const SAME_MM: f64 = 1e-9;

pub fn run(dir: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .output()
        .expect("pkmcal runs")
}

pub fn ok(dir: &Path, args: &[&str]) -> String {
    let o = run(dir, args);
    assert!(
        o.status.success(),
        "pkmcal {args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn fails(dir: &Path, args: &[&str], code: i32, needle: &str) {
    let o = run(dir, args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(code), "pkmcal {args:?}: {err}");
    assert!(
        err.contains(needle),
        "pkmcal {args:?}: `{needle}` not in: {err}"
    );
}

pub fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

/// The mechanism file of a shipped example.
pub fn example(name: &str) -> String {
    format!(
        "{}/../../examples/{name}/mechanism.toml",
        env!("CARGO_MANIFEST_DIR")
    )
}

/// A JSON file (a report).
pub fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// A folder of real users' configurations (`../shared/data/real-configs/<kind>`,
/// beside the repository), if present: CI must have it; elsewhere its tests
/// say they skipped.
pub fn real_configs(kind: &str) -> Option<std::path::PathBuf> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/real-configs")
        .join(kind);
    if root.exists() {
        return Some(root);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing in CI",
        root.display()
    );
    skipped(&format!("no real configurations at {}", root.display()));
    None
}

/// Say that a test skipped its work, where the person running the tests sees
/// it: straight to standard error, past the test harness's capture of
/// `eprintln!` (which hides it on a passing test).
pub fn skipped(why: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr().lock(), "SKIPPED: {why}");
}

/// Run pkmcal in `dir` with standard output and error to files: its exit
/// code, its standard error, and its peak resident memory (kB, the kernel's
/// own count for that child, `wait4`).
#[allow(dead_code)]
// The child is reaped by `wait4` below, which also gives its peak memory.
#[allow(clippy::zombie_processes)]
pub fn run_measured(dir: &Path, args: &[&str]) -> (Option<i32>, String, u64) {
    use std::os::unix::process::ExitStatusExt as _;
    let err = dir.join(".stderr");
    let child = Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&err).expect("stderr file"))
        .spawn()
        .expect("pkmcal runs");
    let mut status = 0;
    // SAFETY: rusage is plain data that wait4 fills; the child is ours and
    // waited for only here.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = child.id() as libc::pid_t;
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(r, pid, "wait4");
    let code = std::process::ExitStatus::from_raw(status).code();
    let stderr = std::fs::read_to_string(&err).unwrap_or_default();
    (code, stderr, usage.ru_maxrss as u64)
}

/// Where the machine calibrated as `params` lands when a controller running
/// the nominal (rigid) model is sent the targets of `sent` (a CSV of
/// `target_<axis>` columns in `dir`): the controller's commands by
/// `compensate --model rigid`, then `predict` with `params`. The predicted
/// table (header, rows).
#[allow(dead_code)]
pub fn reached_from_sent(
    dir: &Path,
    mechanism: Option<&str>,
    params: &str,
    sent: &str,
) -> (Vec<String>, Vec<Vec<f64>>) {
    let mech: Vec<&str> = mechanism.map_or(vec![], |m| vec!["--mechanism", m]);
    let compensate = [
        &["compensate"][..],
        &mech,
        &["--targets", sent, "--model", "rigid", "--out", "q.csv"],
    ]
    .concat();
    ok(dir, &compensate);
    let predict = [
        &["predict"][..],
        &mech,
        &["--params", params, "--commands", "q.csv", "--out", "p.csv"],
    ]
    .concat();
    ok(dir, &predict);
    read_csv(&dir.join("p.csv"))
}
