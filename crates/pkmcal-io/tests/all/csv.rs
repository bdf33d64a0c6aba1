//! Tests of `pkmcal_io::csv`, and fuzzing of the readers: random and
//! mutated CSV, parameter, mechanism and setup files must give an `Err` or
//! an `Ok`, never a panic. Run more with
//! `PKMCAL_FUZZ_CASES=100000 cargo test --release -p pkmcal-io --test all csv::fuzz_`.

use crate::fuzz_readers::cases;
use pkmcal::JeongKim2Dof;
use pkmcal_io::csv::*;
use pkmcal_io::description::{SetupFile, mechanism_from_str};
use pkmcal_io::error::Result;
use pkmcal_io::params::params_from_str;
use proptest::prelude::*;

/// Numbers are written in positional notation unless that is long;
/// every one reads back to itself.
#[test]
fn numbers_are_written_short_and_read_back() {
    assert_eq!(number(-7.0), "-7");
    assert_eq!(number(203.00000000000006), "203.00000000000006");
    assert_eq!(number(1e300), "1e300");
    assert_eq!(number(-2.5e-45), "-2.5e-45");
    assert_eq!(number(-4.489464355827977e-14), "-4.489464355827977e-14");
    assert_eq!(number(0.00012), "0.00012");
    for v in [
        0.0,
        -0.0,
        1e-5,
        1.2345678901234567e-7,
        1e16,
        1.7976931348623157e308,
        5e-324,
    ] {
        let s = number(v);
        assert!(s.len() <= MAX_POSITIONAL_DIGITS, "{s}");
        assert_eq!(s.parse::<f64>().unwrap().to_bits(), v.to_bits(), "{s}");
    }
}

/// Blank-separated text reads the same whatever size of buffer the
/// reader is asked to fill (`read_to_end` probes with small ones).
#[test]
fn whitespace_reads_alike_in_any_buffer() {
    let text = b"  a  b\tc\n1 2,5   3\r\n\n  4 5 6  \n";
    let mut whole = vec![];
    std::io::Read::read_to_end(&mut Whitespace::new(&text[..]), &mut whole).unwrap();
    assert_eq!(whole, b"a,b,c\n1,2.5,3\r\n\n4,5,6\n");
    for size in 1..8 {
        let mut r = Whitespace::new(&text[..]);
        let mut out = vec![];
        let mut buf = vec![0; size];
        loop {
            let n = std::io::Read::read(&mut r, &mut buf).unwrap();
            if n == 0 {
                break;
            }
            out.extend_from_slice(&buf[..n]);
        }
        assert_eq!(out, whole, "buffer of {size}");
    }
}

const VALID_CSV: &str = "target_x,target_y,q1,q2,q3,x,y\n-7,203,1.356,3.236,-2.652,-7.1,203.5\n";
const VALID_MECH: &str = "type = \"jeong-kim-2dof\"\n[nominal]\nl11 = 280.0\nk1 = 8360.0\n[workspace]\nx = [-140.0, 250.0]\n";

/// Apply byte edits (position, new byte, delete?) to a text.
fn mutate(base: &str, edits: &[(usize, u8, bool)]) -> String {
    String::from_utf8_lossy(&crate::fuzz_readers::mutate(base.as_bytes(), edits)).into_owned()
}

fn read_csv_text(text: &str) -> Result<Vec<Vec<f64>>> {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = dir.path().join("f.csv");
    std::fs::write(&p, text).expect("write");
    let csv = Csv::read(&pkmcal_io::Run::quiet(&pkmcal_io::Files::new()), &p)?;
    csv.require_rows()?;
    csv.named(&["q1".into(), "q2".into(), "x".into()])
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), rng_seed: proptest::test_runner::RngSeed::Fixed(11), ..ProptestConfig::default() })]

    #[test]
    fn fuzz_csv_reader(edits in proptest::collection::vec((0usize..200, any::<u8>(), any::<bool>()), 0..12), noise in ".{0,80}") {
        let _ = read_csv_text(&mutate(VALID_CSV, &edits));
        let _ = read_csv_text(&noise);
    }

    #[test]
    fn fuzz_parameter_reader(edits in proptest::collection::vec((0usize..100, any::<u8>(), any::<bool>()), 0..10), noise in ".{0,60}") {
        let spec = JeongKim2Dof::default_spec();
        let _ = params_from_str(&mutate("l11 = 280.3\ndq3 = 0.002\nk2 = 7000\n", &edits), &spec);
        let _ = params_from_str(&noise, &spec);
    }

    #[test]
    fn fuzz_mechanism_reader(edits in proptest::collection::vec((0usize..200, any::<u8>(), any::<bool>()), 0..10)) {
        let _ = mechanism_from_str(&mutate(VALID_MECH, &edits));
    }

    #[test]
    fn fuzz_setup_reader(edits in proptest::collection::vec((0usize..80, any::<u8>(), any::<bool>()), 0..10)) {
        let text = mutate("bar_offset = 0.0\nsockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n", &edits);
        if let Ok(f) = toml::from_str::<SetupFile>(&text) {
            let setup = pkmcal::Setup { sockets: f.sockets, bar_offset: f.bar_offset };
            if setup.validate(2).is_ok() {
                let _ = pkmcal::trilaterate(&setup, &[300.0, 310.0, 280.0], 0.002, None);
            }
        }
    }
}
