//! Tests of `pkmcal_io::output`.

use pkmcal_io::output::*;

/// Directories a run created are removed deepest first, however they
/// were created (the demo makes its directory, then `report` inside).
#[test]
fn discard_removes_nested_directories() {
    let dir = tempfile::tempdir().unwrap();
    let top = dir.path().join("a/b/demo");
    let files = Files::new();
    files.create_dir(&top).unwrap();
    files.create_dir(&top.join("report")).unwrap();
    files.discard();
    assert!(!dir.path().join("a").exists());
}

/// Two runs' files are two values: one run's failure (its files dropped
/// uncommitted) removes its own temporaries and leaves the other's
/// outputs to be committed; a file one run read is no input of another.
#[test]
fn runs_stage_apart() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("in.csv"), "x\n").unwrap();
    let a = Files::new().tracking_inputs();
    let b = Files::new();
    a.read(&d.join("in.csv"), InputKind::Data).unwrap();
    assert!(a.stage(&d.join("in.csv"), b"out").is_err());
    b.stage(&d.join("in.csv"), b"b's output").unwrap();
    a.stage(&d.join("a.toml"), b"a").unwrap();
    drop(a);
    let names: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert!(!names.iter().any(|n| n.contains("a.toml")), "{names:?}");
    b.commit().unwrap();
    assert_eq!(std::fs::read(d.join("in.csv")).unwrap(), b"b's output");
}

/// A failed commit puts back every file it had replaced and removes the
/// new ones it had created.
#[test]
fn roll_back_restores_the_old_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("old.toml"), "old").unwrap();
    let files = Files::new();
    let kept = files.keep_aside(&d.join("old.toml")).unwrap();
    assert!(kept.is_some());
    assert_eq!(files.keep_aside(&d.join("none.toml")).unwrap(), None);
    std::fs::write(d.join("t1"), "new").unwrap();
    std::fs::rename(d.join("t1"), d.join("old.toml")).unwrap();
    std::fs::write(d.join("none.toml"), "new").unwrap();
    let done = [
        Staged {
            tmp: d.join("t1"),
            dest: d.join("old.toml"),
            writing: None,
        },
        Staged {
            tmp: d.join("t2"),
            dest: d.join("none.toml"),
            writing: None,
        },
    ];
    roll_back(&done, &[kept, None]).unwrap();
    assert_eq!(std::fs::read_to_string(d.join("old.toml")).unwrap(), "old");
    assert!(!d.join("none.toml").exists());
    let left: Vec<_> = std::fs::read_dir(d).unwrap().collect();
    assert_eq!(left.len(), 1);
}
