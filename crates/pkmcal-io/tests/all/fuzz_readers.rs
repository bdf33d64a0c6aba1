//! Fuzzing of the readers of users' files in process (issue 34): random
//! bytes and byte-mutated real files (real slicers' G-code, real Klipper,
//! RepRapFirmware and Marlin files when `../shared` is beside the
//! repository, the shipped Klipper and Marlin examples, a calibration
//! record) through the G-code line reader in every dialect, the Klipper
//! (linear and rotary), RepRapFirmware and Marlin readers, and the
//! calibration-record reader. Each must answer `Ok` or `Err`: no panic, no
//! hang. 1,000 cases per property in the suite; `PKMCAL_FUZZ_CASES=N` for
//! long runs (BENCHMARKS.md).

use pkmcal_io::gcode::{Dialect, Mode, Parsed, parse};
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

pub(crate) fn cases() -> u32 {
    std::env::var("PKMCAL_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000)
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Apply byte edits (position, new byte, delete?) to a text.
pub(crate) fn mutate(base: &[u8], edits: &[(usize, u8, bool)]) -> Vec<u8> {
    let mut b = base.to_vec();
    for &(pos, byte, delete) in edits {
        if b.is_empty() {
            b.push(byte);
            continue;
        }
        let p = pos % b.len();
        if delete {
            b.remove(p);
        } else {
            b.insert(p, byte);
        }
    }
    b
}

/// Lines of the real G-code programs (every 7th, for variety).
fn gcode_lines() -> &'static [Vec<u8>] {
    static LINES: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    LINES.get_or_init(|| {
        let dir = root().join("crates/pkmcal-cli/tests/data/gcode");
        let mut out = vec![];
        for f in [
            "cura_slicer.gcode",
            "creality_print.gcode",
            "idea_maker.gcode",
            "bambu_lab.gcode",
        ] {
            let text = std::fs::read(dir.join(f)).expect("shipped G-code");
            out.extend(text.split(|&b| b == b'\n').step_by(7).map(<[u8]>::to_vec));
        }
        out
    })
}

/// Every real configuration of `kind` beside the repository, and `extra`.
fn configs(kind: &str, name: &str, extra: &[PathBuf]) -> Vec<Vec<u8>> {
    let mut out: Vec<Vec<u8>> = extra
        .iter()
        .map(|p| std::fs::read(p).expect("shipped"))
        .collect();
    let dir = root()
        .join("../shared/data/real-configs")
        .join(kind)
        .join("cases");
    if let Ok(cases) = std::fs::read_dir(dir) {
        let mut paths: Vec<PathBuf> = cases.flatten().map(|e| e.path().join(name)).collect();
        paths.sort();
        out.extend(paths.iter().filter_map(|p| std::fs::read(p).ok()));
    }
    out
}

fn klipper_configs() -> &'static [Vec<u8>] {
    static C: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    C.get_or_init(|| {
        configs(
            "klipper",
            "printer.cfg",
            &[root().join("examples/klipper-delta/printer.cfg")],
        )
    })
}

fn reprap_configs() -> &'static [Vec<u8>] {
    static C: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    C.get_or_init(|| {
        let mut c = configs("reprap", "config.g", &[]);
        c.push(b"M665 L360 R190 H420 B150 X0 Y0 Z0\nM666 X0 Y0 Z0 A0 B0\n".to_vec());
        c
    })
}

/// Marlin's settings and probe logs: the shipped example's, and every real
/// file beside the repository.
fn marlin_texts() -> &'static [Vec<u8>] {
    static C: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    C.get_or_init(|| {
        let ex = root().join("examples/marlin-delta");
        let mut out: Vec<Vec<u8>> = ["M503.txt", "G30.log"]
            .iter()
            .map(|f| std::fs::read(ex.join(f)).expect("shipped"))
            .collect();
        let dir = root().join("../shared/data/real-configs/marlin/cases");
        if let Ok(cases) = std::fs::read_dir(dir) {
            let mut paths: Vec<PathBuf> = cases
                .flatten()
                .filter_map(|c| std::fs::read_dir(c.path()).ok())
                .flat_map(|d| d.flatten().map(|f| f.path()))
                .filter(|p| !p.ends_with("SOURCE.txt"))
                .collect();
            paths.sort();
            out.extend(paths.iter().filter_map(|p| std::fs::read(p).ok()));
        }
        out
    })
}

fn rotary_configs() -> &'static [Vec<u8>] {
    static C: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    C.get_or_init(|| {
        vec![
            std::fs::read(root().join("examples/klipper-rotary-delta/printer.cfg"))
                .expect("shipped"),
        ]
    })
}

fn record() -> &'static [u8] {
    static R: OnceLock<Vec<u8>> = OnceLock::new();
    R.get_or_init(|| {
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/record.json"))
            .expect("shipped record")
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), rng_seed: proptest::test_runner::RngSeed::Fixed(34), ..ProptestConfig::default() })]

    #[test]
    fn fuzz_gcode_lines(pick in any::<usize>(), edits in proptest::collection::vec((0usize..200, any::<u8>(), any::<bool>()), 0..8), noise in proptest::collection::vec(any::<u8>(), 0..80)) {
        let lines = gcode_lines();
        let line = mutate(&lines[pick % lines.len()], &edits);
        for d in pkmcal_io::gcode::Dialect::ALL {
            for l in [&line, &noise] {
                fuzz_parse(l, d);
            }
        }
    }

    #[test]
    fn fuzz_klipper_configs(pick in any::<usize>(), edits in proptest::collection::vec((0usize..20_000, any::<u8>(), any::<bool>()), 0..8)) {
        let all = klipper_configs();
        let text = String::from_utf8_lossy(&mutate(&all[pick % all.len()], &edits)).into_owned();
        let dir = tempfile::tempdir().expect("temp dir");
        let file = dir.path().join("printer.cfg");
        let files = pkmcal_io::Files::new();
        let run = pkmcal_io::Run::quiet(&files);
        if let Ok(ini) = pkmcal_io::firmware::klipper::parse_config(&run, &text, &file)
            && let Ok(delta) = pkmcal_io::firmware::klipper::delta_from_config(&ini)
        {
            let _ = pkmcal_io::firmware::klipper::updated_config(&text, &delta, &ini);
        }
    }

    #[test]
    fn fuzz_reprap_configs(pick in any::<usize>(), edits in proptest::collection::vec((0usize..20_000, any::<u8>(), any::<bool>()), 0..8)) {
        let all = reprap_configs();
        let text = String::from_utf8_lossy(&mutate(&all[pick % all.len()], &edits)).into_owned();
        let _ = pkmcal_io::firmware::reprap::delta_from_gcode(&text, "config.g");
    }

    #[test]
    fn fuzz_marlin_settings_and_probes(pick in any::<usize>(), other in any::<usize>(), edits in proptest::collection::vec((0usize..20_000, any::<u8>(), any::<bool>()), 0..8)) {
        use pkmcal_io::firmware::marlin;
        let all = marlin_texts();
        let text = String::from_utf8_lossy(&mutate(&all[pick % all.len()], &edits)).into_owned();
        let log_text = String::from_utf8_lossy(&all[other % all.len()]).into_owned();
        let path = Path::new("m503.txt");
        let _ = marlin::parse_settings(&text, path, None);
        let _ = marlin::probes_from_text(&text, path, Some(80.0));
        if let Ok(settings) = marlin::settings_from_text(&text, path, Some(marlin::LetterB::RodTrim))
            && let Ok(log) = marlin::probes_from_text(&log_text, path, None)
            && let Ok(p) = marlin::MarlinPrinter::new(path, settings, path, log, Some([0.0, 0.0]), None)
        {
            for q in &p.log.points {
                let _ = p.commands(q);
            }
            let _ = p.delta().gcode();
        }
    }

    #[test]
    fn fuzz_klipper_rotary_configs(pick in any::<usize>(), edits in proptest::collection::vec((0usize..20_000, any::<u8>(), any::<bool>()), 0..8)) {
        let all = rotary_configs();
        let text = String::from_utf8_lossy(&mutate(&all[pick % all.len()], &edits)).into_owned();
        let dir = tempfile::tempdir().expect("temp dir");
        let file = dir.path().join("printer.cfg");
        let files = pkmcal_io::Files::new();
        let run = pkmcal_io::Run::quiet(&files);
        if let Ok(ini) = pkmcal_io::firmware::klipper::parse_config(&run, &text, &file)
            && let Ok(p) = pkmcal_io::firmware::klipper_rotary::RotaryPrinter::from_parsed(&file, text, ini, pkmcal_io::firmware::klipper::Weighting::Klipper)
        {
            let _ = p.delta.mechanism_toml();
        }
    }

    #[test]
    fn fuzz_calibration_records(edits in proptest::collection::vec((0usize..20_000, any::<u8>(), any::<bool>()), 0..6)) {
        let dir = tempfile::tempdir().expect("temp dir");
        let p = dir.path().join("record.json");
        std::fs::write(&p, mutate(record(), &edits)).expect("write");
        let files = pkmcal_io::Files::new();
        let run = pkmcal_io::Run::quiet(&files);
        if let Ok(r) = pkmcal_io::record::read_calibration_record(&run, &p) {
            let spec = pkmcal::kinds::reference::JeongKim2Dof::default_spec();
            if r.check(&spec).is_ok() {
                let _ = r.params(&spec);
            }
        }
    }
}

/// [`parse`] for the fuzzing of the readers: a line read in a dialect must
/// give an answer, and a followed line only upper-case word letters.
fn fuzz_parse(line: &[u8], dialect: Dialect) {
    for mode in [Mode::Unknown, Mode::Printer, Mode::Cnc] {
        fuzz_parse_in(line, dialect, mode);
    }
}

fn fuzz_parse_in(line: &[u8], dialect: Dialect, mode: Mode) {
    if let Ok(Parsed::Code(c)) = parse(line, dialect, mode) {
        assert!(
            c.words.iter().all(|(w, _)| w.is_ascii_uppercase()),
            "{line:?}"
        );
    }
}
