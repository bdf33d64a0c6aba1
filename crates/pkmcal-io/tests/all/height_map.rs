//! Height maps in the firmware's own format (`--physical --height-map`,
//! issue 54): each format written and read back by the firmware's own
//! parsing rules (Klipper's configparser and `ProfileManager`,
//! RepRapFirmware's `HeightMap::LoadFromFile`, Marlin's `M421`), the
//! values to their written precision; every real Klipper mesh profile
//! (`../shared/data/real-configs`, when present) read; and the map's sign
//! checked on a fitted printer: commanding Z plus a node's value puts the
//! fitted nozzle on the bed there.

use pkmcal::Request;
use pkmcal_io::firmware::Firmware;
use pkmcal_io::firmware::height_map::{
    self, HeightMap, KLIPPER_PROFILE, MeshFormat, MeshLayout, ReadMap,
};
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting, read_config};
use pkmcal_io::firmware::physical;
use std::path::{Path, PathBuf};

/// Coordinates read back agree to this (mm).
const SAME_MM: f64 = 1e-9;

/// A map on `layout` with made-up values (a bowl and a tilt, mm).
fn made_up(layout: &MeshLayout) -> HeightMap {
    let xs = layout.nodes(0);
    let ys = layout.nodes(1);
    let z: Vec<Vec<Option<f64>>> = ys
        .iter()
        .map(|y| {
            xs.iter()
                .map(|x| {
                    let (dx, dy) = (x - layout.origin[0], y - layout.origin[1]);
                    layout.probed(dx, dy).then_some(
                        1e-6 * (dx * dx + dy * dy) - 3e-4 * dx + 1.234_567e-4 * dy - 0.0123,
                    )
                })
                .collect()
        })
        .collect();
    HeightMap {
        sd: z.clone(),
        xs,
        ys,
        z,
    }
}

/// The read map's nodes are the written one's, and its values agree to
/// `digits` decimals: every node's filled value (`filled`) or the probed
/// ones with the rest unset.
fn agrees(read: &ReadMap, map: &HeightMap, digits: i32, filled: bool) {
    let tol = 0.5 * 10f64.powi(-digits) + 1e-12;
    assert_eq!(read.xs.len(), map.xs.len());
    assert_eq!(read.ys.len(), map.ys.len());
    for (a, b) in read
        .xs
        .iter()
        .zip(&map.xs)
        .chain(read.ys.iter().zip(&map.ys))
    {
        assert!((a - b).abs() < SAME_MM, "{a} {b}");
    }
    let full = map.filled();
    for (j, (row, full_row)) in map.z.iter().zip(&full).enumerate() {
        for (i, (written, filled_value)) in row.iter().zip(full_row).enumerate() {
            let want = if filled {
                Some(*filled_value)
            } else {
                *written
            };
            match (read.z[j][i], want) {
                (Some(a), Some(b)) => assert!((a - b).abs() <= tol, "({i}, {j}): {a} {b}"),
                (None, None) => {}
                (a, b) => panic!("({i}, {j}): read {a:?}, written {b:?}"),
            }
        }
    }
}

#[test]
fn klipper_profile_is_read_back_as_klipper_reads_it() {
    for (radius, count) in [(140.0, 5), (90.37, 7), (118.0, 9)] {
        let mut layout = MeshLayout::round(MeshFormat::Klipper, radius, count).unwrap();
        layout.origin = [1.5, -2.0];
        let map = made_up(&layout);
        let text = height_map::write(&map, &layout, "a comment\nof two lines");
        assert!(text.starts_with("# a comment\n# of two lines\n[bed_mesh pkmcal]\nversion = 1\n"));
        let read = height_map::read_klipper(&text, KLIPPER_PROFILE).unwrap();
        agrees(&read, &map, 6, true);
        // Klipper's row of a round bed: its outermost probed value repeated.
        let row = &read.z[0];
        assert!(row.iter().all(|v| v == &row[count / 2]), "{row:?}");
        assert_eq!(
            text.contains("algo = bicubic"),
            count > 6,
            "lagrange oscillates above 6 nodes"
        );
        // Another profile's name is not this one.
        assert!(height_map::read_klipper(&text, "default").is_err());
    }
}

/// A rectangular `[bed_mesh]` (Klipper's `mesh_min`, `mesh_max`,
/// `probe_count`) is written as Klipper saves the profile it probes there:
/// its nodes `min + i · spacing`, the spacing floored to 0.01 mm (so the
/// last node may fall short of `mesh_max`), `x_count` and `y_count` apart,
/// and read back by Klipper's rules.
#[test]
fn klipper_rectangular_profile_is_read_back_as_klipper_reads_it() {
    let floor = |d: f64| (d * 100.0).floor() / 100.0;
    for (min, max, counts) in [
        ([-80.0, -70.0], [80.0, 70.0], [5, 3]),
        ([-100.5, -60.0], [99.0, 61.3], [7, 9]),
        ([10.0, 20.0], [200.0, 180.0], [4, 6]),
    ] {
        let layout =
            MeshLayout::rectangular(MeshFormat::Klipper, min, max, counts, 1000.0).unwrap();
        let map = made_up(&layout);
        let text = height_map::write(&map, &layout, "a comment");
        let read = height_map::read_klipper(&text, KLIPPER_PROFILE).unwrap();
        agrees(&read, &map, 6, true);
        assert_eq!([read.xs.len(), read.ys.len()], counts);
        assert!(text.contains(&format!(
            "x_count = {}\ny_count = {}\n",
            counts[0], counts[1]
        )));
        for k in 0..2 {
            let nodes = if k == 0 { &read.xs } else { &read.ys };
            let s = floor((max[k] - min[k]) / (counts[k] - 1) as f64);
            assert!((nodes[0] - min[k]).abs() < SAME_MM);
            let last = min[k] + s * (counts[k] - 1) as f64;
            assert!(
                (nodes[counts[k] - 1] - last).abs() < SAME_MM,
                "{nodes:?} {last}"
            );
            assert!(last <= max[k] + SAME_MM);
        }
        assert_eq!(
            text.contains("algo = bicubic"),
            counts[0].max(counts[1]) > 6,
            "lagrange oscillates above 6 nodes"
        );
    }
    // Klipper's own refusals.
    for (min, max, counts) in [
        ([0.0, 0.0], [0.0, 10.0], [3, 3]),
        ([0.0, 0.0], [10.0, 10.0], [2, 3]),
        ([0.0, 0.0], [3.0, 30.0], [5, 3]),
    ] {
        assert!(
            MeshLayout::rectangular(MeshFormat::Klipper, min, max, counts, 100.0).is_err(),
            "{min:?} {max:?} {counts:?}"
        );
    }
}

/// A configuration's rectangular `[bed_mesh]` sets the layout; on a delta
/// its nodes beyond the build volume's radius (which the nozzle cannot
/// reach) take their row's outermost value, and the profile reads back
/// whole.
#[test]
fn klippers_rectangular_bed_mesh_sets_the_layout() {
    let p = klipper_with(
        "[bed_mesh]\nmesh_min: -120, -120\nmesh_max: 120, 120\nprobe_count: 5, 7\nmesh_pps: 2\n\n",
    );
    let l = p.mesh_layout(120.0, None).unwrap().unwrap();
    let r = l.rect.clone().unwrap();
    assert_eq!(
        (r.min, r.max, r.counts),
        ([-120.0, -120.0], [120.0, 120.0], [5, 7])
    );
    assert_eq!(l.spacings(), [60.0, 40.0]);
    assert_eq!(l.klipper.algo, "bicubic");
    assert_eq!(
        p.mesh_layout(120.0, Some(5)).unwrap().unwrap().counts(),
        [5, 5]
    );
    // An even count each way is a rectangular mesh's own.
    assert_eq!(
        p.mesh_layout(120.0, Some(6)).unwrap().unwrap().counts(),
        [6, 6]
    );
    let defaults = klipper_with("[bed_mesh]\nmesh_min: -50, -50\nmesh_max: 50, 50\n\n");
    assert_eq!(
        defaults.mesh_layout(120.0, None).unwrap().unwrap().counts(),
        [3, 3]
    );
    for bad in [
        "mesh_min: -50\nmesh_max: 50, 50",
        "mesh_min: -50, -50\nmesh_max: 50, 50\nprobe_count: 2",
    ] {
        let p = klipper_with(&format!("[bed_mesh]\n{bad}\n\n"));
        assert!(p.mesh_layout(120.0, None).is_err(), "{bad}");
    }
    let ld = p.linear_delta().unwrap().unwrap();
    let fw = p.mechanism().unwrap();
    let fit = physical::calibrate(&p, &ld, Request::new(pkmcal::Model::Exact)).unwrap();
    let cal = &fit.study.calibration;
    let proj = physical::project(&ld, &fw, &fit.mech, &cal.params, &cal.measurement).unwrap();
    let layout = p.mesh_layout(ld.print_radius(), None).unwrap().unwrap();
    let map = height_map::residual_map(&fit, &fw, &proj.params, None, &layout).unwrap();
    // The corners (170 mm out) are beyond the print radius (140 mm); the
    // middle row is within it.
    assert!(map.z[0][0].is_none() && map.z[3].iter().all(Option::is_some));
    let read =
        height_map::read_klipper(&height_map::write(&map, &layout, ""), KLIPPER_PROFILE).unwrap();
    agrees(&read, &map, 6, true);
}

#[test]
fn reprap_heightmap_is_read_back_as_rrf_loads_it() {
    for (radius, count) in [(150.0, 7), (85.0, 5), (100.0, 21)] {
        let layout = MeshLayout::round(MeshFormat::RepRap, radius, count).unwrap();
        let map = made_up(&layout);
        let text = height_map::write(&map, &layout, "ignored");
        let mut lines = text.lines();
        assert!(
            lines
                .next()
                .unwrap()
                .starts_with("RepRapFirmware height map file v2, min error ")
        );
        assert_eq!(
            lines.next().unwrap(),
            "axis0,axis1,min0,max0,min1,max1,radius,spacing0,spacing1,num0,num1"
        );
        // RepRapFirmware's fixed field of 7 characters, and `0` unprobed.
        for row in lines.skip(1) {
            assert!(row.split(',').all(|c| c.len() == 7), "{row}");
        }
        let read = height_map::read_reprap(&text).unwrap();
        agrees(&read, &map, 3, false);
        assert!(read.z[0][0].is_none() && read.z[count / 2][count / 2].is_some());
    }
    // The reader's rules: the header's prefix only; the older label lines;
    // a bare 0 unprobed, `0.000` a value.
    let old = "RepRapFirmware height map file v2 generated at 2024-01-01 10:00, min error 0\n\
               xmin,xmax,ymin,ymax,radius,xspacing,yspacing,xnum,ynum\n\
               -10.00,10.00,-10.00,10.00,15.00,10.00,10.00,3,2\n  0,0.000,  1.5\n-2e-1,0,\t0\n";
    let read = height_map::read_reprap(old).unwrap();
    assert_eq!(
        read.z,
        vec![
            vec![None, Some(0.0), Some(1.5)],
            vec![Some(-0.2), None, None]
        ]
    );
    for bad in [
        old.replace("file v2", "file v1"),
        old.replace("xnum,ynum", "xcount,ycount"),
        old.replace("  1.5", "  x"),
        old.replace("10.00,10.00,3,2", "10.00,10.00,3"),
        // A value's comma must follow it: RepRapFirmware stops at the tab.
        old.replace("0,\t0", "0\t,0"),
    ] {
        assert!(height_map::read_reprap(&bad).is_err(), "{bad}");
    }
}

#[test]
fn marlin_lines_are_read_back_as_marlin_takes_them() {
    let layout = MeshLayout::round(MeshFormat::Marlin, 90.0, 7).unwrap();
    let map = made_up(&layout);
    let text = height_map::write(&map, &layout, "G29 first");
    assert!(text.starts_with("; G29 first\nM421 I0 J0 Z"));
    assert_eq!(text.lines().filter(|l| l.starts_with("M421")).count(), 49);
    let read = height_map::read_marlin(&text, &map.xs, &map.ys).unwrap();
    agrees(&read, &map, 4, true);
    assert!(height_map::read_marlin("M421 I7 J0 Z0.1", &map.xs, &map.ys).is_err());
    assert!(height_map::read_marlin("M421 I1 Z0.1", &map.xs, &map.ys).is_err());
}

#[test]
fn mesh_counts_and_spacings_are_bounded() {
    for n in [0, 1, 2, 23, 1001] {
        assert!(height_map::mesh_points(n).is_err(), "{n}");
        assert!(height_map::round_mesh_points(n).is_err(), "{n}");
    }
    // Even counts: a rectangular mesh's, not a round one's.
    assert_eq!(height_map::mesh_points(4), Ok(4));
    assert!(height_map::round_mesh_points(4).is_err());
    assert_eq!(height_map::mesh_points(21), Ok(21));
    assert_eq!(height_map::round_mesh_points(21), Ok(21));
    assert!(MeshLayout::round(MeshFormat::Klipper, 5.0, 21).is_err());
    assert!(MeshLayout::round(MeshFormat::Klipper, f64::NAN, 5).is_err());
    // Klipper's spacing: the diameter's share floored to 0.01 mm, the
    // radius to 0.1 mm.
    let l = MeshLayout::round(MeshFormat::Klipper, 90.37, 7).unwrap();
    assert_eq!((l.radius, l.spacing()), (90.3, 30.1));
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples")
}

fn klipper_with(prefix: &str) -> KlipperPrinter {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("printer.cfg");
    let text = std::fs::read_to_string(examples().join("klipper-delta/printer.cfg")).unwrap();
    std::fs::write(&path, format!("{prefix}{text}")).unwrap();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let (text, ini) = read_config(&run, &path).unwrap();
    KlipperPrinter::from_parsed(&path, text, ini, Weighting::Klipper).unwrap()
}

#[test]
fn klippers_own_bed_mesh_sets_the_layout() {
    let p = klipper_with(
        "[bed_mesh]\nmesh_radius: 95.37\nmesh_origin: 2, -3\nround_probe_count: 7\nmesh_pps: 3\nalgorithm: lagrange\n\n",
    );
    let l = p.mesh_layout(140.0, None).unwrap().unwrap();
    assert_eq!((l.radius, l.count, l.origin), (95.3, 7, [2.0, -3.0]));
    assert_eq!(
        (l.klipper.pps, l.klipper.algo.as_str()),
        ([3, 3], "bicubic")
    );
    assert_eq!(p.mesh_layout(140.0, Some(5)).unwrap().unwrap().count, 5);
    // A printer's own mesh finer than pkmcal writes (23 across, as a real
    // configuration has): the profile has the most nodes pkmcal writes.
    let fine = klipper_with("[bed_mesh]\nmesh_radius: 90\nround_probe_count: 23\n\n");
    let l = fine.mesh_layout(140.0, None).unwrap().unwrap();
    assert_eq!(l.count, pkmcal_io::firmware::height_map::MAX_MESH_POINTS);
    let plain = klipper_with("");
    let l = plain.mesh_layout(140.0, None).unwrap().unwrap();
    assert_eq!(
        (l.radius, l.count, l.klipper.algo.as_str()),
        (140.0, 5, "lagrange")
    );
    for bad in [
        "mesh_pps: -1",
        "algorithm: spline",
        "bicubic_tension: 3",
        "round_probe_count: 4",
    ] {
        let p = klipper_with(&format!("[bed_mesh]\nmesh_radius: 90\n{bad}\n\n"));
        assert!(p.mesh_layout(140.0, None).is_err(), "{bad}");
    }
}

/// The map's sign: on the Klipper example fitted (`--physical`), with the
/// values for the nozzle written, a nozzle sent to a node at Z equal to
/// the node's value (read back from the written profile, as Klipper adds
/// it) lands on the fitted bed there, where without it it misses by the
/// value.
#[test]
fn a_nodes_value_added_to_z_puts_the_nozzle_on_the_bed() {
    /// What the value leaves: the map's rounding (mm) and a share of the
    /// value, the error's change with Z (measured 1.3e-4 of it).
    const ROUNDING_MM: f64 = 1e-6;
    const LEFT_SHARE: f64 = 1e-3;
    let printer = klipper_with("");
    let ld = printer.linear_delta().unwrap().unwrap();
    let fw = printer.mechanism().unwrap();
    let fit = physical::calibrate(&printer, &ld, Request::new(pkmcal::Model::Exact)).unwrap();
    let cal = &fit.study.calibration;
    let proj = physical::project(&ld, &fw, &fit.mech, &cal.params, &cal.measurement).unwrap();
    let layout = printer
        .mesh_layout(ld.print_radius(), None)
        .unwrap()
        .unwrap();
    let map = height_map::residual_map(&fit, &fw, &proj.params, None, &layout).unwrap();
    let read =
        height_map::read_klipper(&height_map::write(&map, &layout, ""), KLIPPER_PROFILE).unwrap();
    let mut largest = 0.0_f64;
    for (j, row) in map.z.iter().enumerate() {
        for (i, v) in row.iter().enumerate() {
            let Some(v) = v else { continue };
            let z = read.z[j][i].unwrap();
            let e = |z: f64| {
                physical::nozzle_errors(
                    &fw,
                    &proj.params,
                    None,
                    &fit.mech,
                    &cal.params,
                    &cal.measurement,
                    ld.nozzle(),
                    &[[map.xs[i], map.ys[j], z]],
                )
                .unwrap()[0]
            };
            // Sent to the bed, the nozzle's Z over it is minus the value;
            // sent to the value, it is on the bed.
            assert!((e(0.0)[2] + v).abs() < 1e-12);
            let on = e(z)[2] + z;
            assert!(
                on.abs() < ROUNDING_MM + LEFT_SHARE * v.abs(),
                "({i}, {j}): {v} leaves {on}"
            );
            largest = largest.max(v.abs());
        }
    }
    assert!(largest > 1e-3, "the example's map is {largest} mm at most");
    assert!(map.largest_sd().unwrap() > 0.0);
}

/// The real users' Klipper folder (`../shared/data/real-configs/klipper`).
fn real() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/real-configs/klipper/cases");
    if root.exists() {
        return Some(root);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing in CI",
        root.display()
    );
    use std::io::Write as _;
    let _ = writeln!(
        std::io::stderr().lock(),
        "SKIPPED: no real configurations at {}",
        root.display()
    );
    None
}

/// Every `[bed_mesh default]` Klipper saved in the real users'
/// SAVE_CONFIG blocks is read by the reader the written profiles are
/// checked with (the block's `#*# ` taken off as Klipper's configfile
/// takes it off).
#[test]
fn every_real_klipper_mesh_profile_is_read() {
    let Some(root) = real() else {
        return;
    };
    let mut read = 0;
    let mut cases: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .flatten()
        .map(|c| c.path().join("printer.cfg"))
        .filter(|p| p.exists())
        .collect();
    cases.sort();
    for case in cases {
        let text = std::fs::read_to_string(&case).unwrap();
        let Some(at) = text.find("#*# <---------------------- SAVE_CONFIG") else {
            continue;
        };
        let block: String = text[at..]
            .lines()
            .skip(3)
            .map(|l| l.get(4..).unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        if !block.contains("[bed_mesh default]") {
            continue;
        }
        let map = height_map::read_klipper(&block, "default")
            .unwrap_or_else(|e| panic!("{}: {e}", case.display()));
        assert!(map.z.len() >= 3 && map.z.iter().flatten().all(Option::is_some));
        assert!(map.xs[0] < map.xs[map.xs.len() - 1]);
        read += 1;
    }
    assert!(read >= 29, "{read} real mesh profiles (29 collected)");
}
