//! `--physical --height-map` on `klipper`, `reprap` and `marlin` (issue
//! 54): the map is written in the firmware's own format and reads back by
//! its rules, it is said in the summary, it is written with the other
//! outputs or not at all, and misuse is refused by name; the extra
//! measurement suggested is named in the firmware's commands.

use crate::common::{fails, ok};
use pkmcal_io::firmware::height_map::{self, KLIPPER_PROFILE};
use std::path::{Path, PathBuf};

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples")
}

fn arg(p: PathBuf) -> String {
    p.to_str().unwrap().to_string()
}

#[test]
fn each_firmware_writes_a_map_it_can_read() {
    let dir = tempfile::tempdir().unwrap();
    let e = examples();
    let klipper = arg(e.join("klipper-delta/printer.cfg"));
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            &klipper,
            "--physical",
            "--height-map",
            "mesh.cfg",
            "--mesh-points",
            "7",
        ],
    );
    assert!(
        out.contains("height map of what the written values leave on the bed (Klipper [bed_mesh pkmcal] profile, 7 x 7 nodes"),
        "{out}"
    );
    assert!(
        out.contains("the extra measurements that would shrink the cube's uncertainty most")
            && out.contains("1. the 12 distances of Klipper's calibration object")
            && out.contains("DELTA_ANALYZE CENTER_DISTS=")
            && out.contains(" then PROBE (the probe at "),
        "{out}"
    );
    let text = std::fs::read_to_string(dir.path().join("mesh.cfg")).unwrap();
    let map = height_map::read_klipper(&text, KLIPPER_PROFILE).unwrap();
    assert_eq!((map.xs.len(), map.ys.len()), (7, 7));
    assert!(text.contains("BED_MESH_PROFILE LOAD=pkmcal") && text.contains("algo = bicubic"));

    let (config, probes) = (
        arg(e.join("reprap-delta/config.g")),
        arg(e.join("reprap-delta/probes.csv")),
    );
    let out = ok(
        dir.path(),
        &[
            "reprap",
            "--config",
            &config,
            "--probes",
            &probes,
            "--physical",
            "--height-map",
            "heightmap.csv",
        ],
    );
    assert!(
        out.contains("RepRapFirmware heightmap.csv, 5 x 5 nodes"),
        "{out}"
    );
    let text = std::fs::read_to_string(dir.path().join("heightmap.csv")).unwrap();
    let map = height_map::read_reprap(&text).unwrap();
    assert_eq!(map.z.len(), 5);
    assert!(map.z[2][2].is_some() && map.z[0][0].is_none());

    let (m503, g30) = (
        arg(e.join("marlin-delta/M503.txt")),
        arg(e.join("marlin-delta/G30.log")),
    );
    let out = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            &m503,
            "--probes",
            &g30,
            "--physical",
            "--height-map",
            "mesh.gcode",
            "--mesh-points",
            "3",
        ],
    );
    assert!(out.contains("one more probe point: G30 X"), "{out}");
    let text = std::fs::read_to_string(dir.path().join("mesh.gcode")).unwrap();
    assert!(text.contains("GRID_MAX_POINTS_X and _Y 3"), "{text}");
    let xs = [-90.0, 0.0, 90.0];
    let map = height_map::read_marlin(&text, &xs, &xs).unwrap();
    assert!(map.z.iter().flatten().all(Option::is_some));
}

#[test]
fn the_map_is_written_with_the_values_or_not_at_all() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = arg(examples().join("klipper-delta/printer.cfg"));
    // An --out that cannot be written (a directory): nothing is.
    std::fs::create_dir(dir.path().join("taken")).unwrap();
    let out = crate::common::run(
        dir.path(),
        &[
            "klipper",
            "--config",
            &cfg,
            "--physical",
            "--out",
            "taken",
            "--height-map",
            "mesh.cfg",
        ],
    );
    assert!(!out.status.success());
    assert!(!dir.path().join("mesh.cfg").exists());
    // Never over an input.
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            &cfg,
            "--physical",
            "--height-map",
            &cfg,
        ],
        2,
        "printer.cfg",
    );
}

#[test]
fn misuse_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = arg(examples().join("klipper-delta/printer.cfg"));
    for (args, says) in [
        (
            vec!["--height-map", "m.cfg"],
            "--height-map maps what the physical model's values leave: add --physical",
        ),
        (
            vec!["--previous", "old.cfg"],
            "--previous compares physical calibrations: add --physical",
        ),
        (
            vec!["--physical", "--mesh-points", "5"],
            "--mesh-points sets the height map's mesh: add --height-map FILE",
        ),
        (
            vec!["--physical", "--height-map", "m.cfg", "--mesh-points", "6"],
            "--mesh-points: 6 nodes across: a round bed's mesh has an odd count from 3 to 21 (this printer's mesh is round)",
        ),
        (
            vec!["--physical", "--height-map", "m.cfg", "--mesh-points", "23"],
            "invalid value '23' for '--mesh-points <N>': 23 nodes across: a mesh has 3 to 21 nodes each way",
        ),
        (
            vec!["--physical", "--height-map", "m.cfg", "--mesh-points", "x"],
            "is not a count of nodes",
        ),
    ] {
        let mut all = vec!["klipper", "--config", &cfg];
        all.extend(args);
        fails(dir.path(), &all, 2, says);
        // Refused before any work: nothing printed.
        let o = crate::common::run(dir.path(), &all);
        assert!(o.stdout.is_empty(), "{all:?} printed before refusing");
    }
    assert!(!dir.path().join("m.cfg").exists());
}

#[test]
fn previous_says_whether_the_printer_changed() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = arg(examples().join("klipper-delta/printer.cfg"));
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            &cfg,
            "--physical",
            "--previous",
            &cfg,
        ],
    );
    assert!(
        out.contains("no change beyond the two calibrations' uncertainty (joint test over the"),
        "{out}"
    );
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            &cfg,
            "--physical",
            "--previous",
            "missing.cfg",
        ],
        1,
        "missing.cfg",
    );
    // A recalibration changes the configured geometry, not the printer: the
    // same saved probe results under another delta_radius, tower angle and
    // endstop are no change (each file's own geometry gave χ² 218 to 3.6e6).
    let text = std::fs::read_to_string(examples().join("klipper-delta/printer.cfg")).unwrap();
    let relabelled = text
        .replace("delta_radius: 174.75", "delta_radius: 174.80")
        .replace(
            "position_endstop: 297.05   #",
            "position_endstop: 297.10   #",
        );
    assert_ne!(relabelled, text);
    let recalibrated = dir.path().join("recalibrated.cfg");
    std::fs::write(&recalibrated, &relabelled).unwrap();
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            &arg(recalibrated.clone()),
            "--physical",
            "--previous",
            &cfg,
        ],
    );
    assert!(
        out.contains("no change beyond the two calibrations' uncertainty"),
        "{out}"
    );
    // Carriage a 1 mm (80 steps) further from its endstop at every probe:
    // the printer changed.
    let moved: String = text
        .lines()
        .map(|l| match l.split_once("_pos = ") {
            Some((head, v)) if l.starts_with("#*# height") => {
                let mut x: Vec<f64> = v.split(',').map(|t| t.trim().parse().unwrap()).collect();
                x[0] += 80.0;
                format!("{head}_pos = {:.3},{:.3},{:.3}\n", x[0], x[1], x[2])
            }
            _ => format!("{l}\n"),
        })
        .collect();
    let moved_path = dir.path().join("moved.cfg");
    std::fs::write(&moved_path, moved).unwrap();
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            &arg(recalibrated),
            "--physical",
            "--previous",
            &arg(moved_path),
        ],
    );
    assert!(out.contains("the printer changed"), "{out}");
}
