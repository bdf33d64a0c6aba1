//! The command line's words: the option of each user choice the library and
//! the file side name ([`pkmcal::Field`]), warnings' hints in options, and
//! every typed error worded for a terminal. The rules are the library's;
//! only the words are here.

use pkmcal::{Field, RequestError};
use pkmcal_io::Error as IoError;
use pkmcal_io::error::OutputProblem;
use pkmcal_io::gcode::GcodeHint;

/// A usage error of the command line itself (a bad option value or
/// combination the library never sees): exit code 2.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// `Err(Usage(..))`.
pub fn usage<T>(message: impl Into<String>) -> anyhow::Result<T> {
    Err(Usage(message.into()).into())
}

/// The option that sets a choice.
pub fn flag(f: Field) -> &'static str {
    use Field::*;
    match f {
        Mechanism => "--mechanism",
        Data => "--data",
        Model => "--model",
        Free => "--free",
        Fix => "--fix",
        Tolerances => "--tolerance",
        NoTolerances => "--no-tolerances",
        Start => "--start",
        Params => "--params",
        Load => "--load",
        Preload => "--preload",
        Loss => "--loss",
        LossScale => "--loss-scale",
        OutlierThreshold => "--outlier-threshold",
        Validation => "--validate",
        Holdout => "--holdout",
        Kfold => "--kfold",
        Seed => "--seed",
        Frame => "--frame",
        Axes => "--axes",
        Setup => "--setup",
        Distances => "--distances",
        StatedNoise => "--stated-noise",
        StatedAngleNoise => "--stated-angle-noise",
        StatedDistanceNoise => "--stated-distance-noise",
        StatedReadings => "--stated-readings",
        StatedRelative => "--stated-relative",
        Noise => "--noise",
        AngleNoise => "--angle-noise",
        Count => "--count",
        Candidates => "--candidate-spacing",
        MaxCandidates => "--max-candidates",
        Runs => "--runs",
        LengthError => "--length-error",
        AngleError => "--angle-error",
        ValidationTargets => "--validation-targets",
        Samples => "--samples",
        Targets => "--targets",
        Alpha => "--alpha",
        Units => "--units",
        MaxInputSize => "--max-input-mb",
        Weighting => "--weighting",
        Offset => "--offset",
        MaxSegment => "--max-segment",
        Dialect => "--dialect",
        Grid => "--grid",
        Out => "--out",
        FirmwareLetters => "--m665-b",
        ProbeOffset => "--probe-offset",
        G33Radius => "--g33-radius",
        G33Points => "--g33-points",
        Physical => "--physical",
        HeightMap => "--height-map",
        MeshPoints => "--mesh-points",
        ReportDir => "--report-dir",
        OutDir => "--out-dir",
        Previous => "--previous",
        ProbeNoise => "--probe-noise",
        Heights => "--heights",
        Probes => "--probes",
        MaxSigma => "--max-sigma",
        // The solver's settings have no option on the command line.
        _ => "the solver's settings",
    }
}

/// The option with what it takes, where a message shows how to give it.
fn flag_with_value(f: Field) -> String {
    match f {
        Field::Validation => "--validate FILE".into(),
        Field::Holdout => "--holdout F".into(),
        Field::Tolerances => "--tolerance".into(),
        Field::HeightMap => "--height-map FILE".into(),
        f => flag(f).into(),
    }
}

/// A warning's hint in the command line's terms: the library's hints name
/// no option; where a hint is an option to give, it is named here.
pub fn hint(w: &pkmcal::identify::Warning) -> String {
    use pkmcal::identify::WarningKind as K;
    match &w.kind {
        K::StiffnessRatios { fixed } => format!(
            "give `{fixed}` its measured value (--start P.toml), or calibrate with a known tool load (--load)"
        ),
        K::PlanRankDeficient { .. } => {
            "plan more poses (--count), or identify fewer parameters (--fix); `pkmcal analyze` on the planned poses names the combinations that cannot be identified".into()
        }
        K::FrameGauge { .. } => "to choose which parameters define the base frame, fix them yourself (--fix NAMES), or measure in the base frame (--frame base); the combinations are listed under identifiability".into(),
        K::Outliers {
            robust_loss: true,
            dropping: false,
            ..
        } => "the robust loss already limits their influence; inspect them, or refit without them (--drop-outliers)".into(),
        _ => w.hint.clone(),
    }
}

/// The command line's words in summaries and reports.
pub const WORDING: pkmcal_io::text::Wording = pkmcal_io::text::Wording {
    frame_base: "identified; --frame base if the data are in the base frame",
    all_correlations: "--report's JSON",
    hint,
    input: |f| flag(f).to_string(),
};

/// A refused choice in the command line's words.
pub fn request(e: &RequestError) -> String {
    match e {
        RequestError::Invalid {
            field,
            problem,
            suggest,
        } => format!(
            "{}: {problem}{}",
            flag(*field),
            suggest
                .as_ref()
                .map(|s| format!(" ({} {})", flag(s.field), s.value))
                .unwrap_or_default()
        ),
        RequestError::Exclusive { a, b } => format!(
            "give either {} or {}, not both",
            flag_with_value(*a),
            flag_with_value(*b)
        ),
        RequestError::Needs { field, needs } => {
            format!("{} needs {}", flag(*field), flag(*needs))
        }
        RequestError::ToleranceTable(problem) => {
            format!("in the [tolerances] table of the mechanism: {problem}")
        }
        RequestError::Belongs { field, needs, why } => {
            format!("{} {why}: add {}", flag(*field), flag_with_value(*needs))
        }
        RequestError::Excluded { field, with, why } => {
            format!("{} {why}; leave it out with {}", flag(*field), flag(*with))
        }
    }
}

/// A file-side error in the command line's words.
pub fn io(e: &IoError) -> String {
    match e {
        IoError::TooLarge { .. } => format!("{e} with --max-input-mb"),
        IoError::Output {
            path,
            problem: OutputProblem::MissingDirectory(dir),
        } => format!(
            "cannot write {}: the directory {} does not exist; create it first (an output file's folder must exist, as for `cp`; only the output directories, --out-dir and --report-dir, are created with their parents)",
            path.display(),
            dir.display()
        ),
        IoError::MissingAxes {
            path,
            missing,
            present,
        } => format!(
            "{}: missing column{} `{}`; if the instrument measured only {}, say so with --axes {}",
            path.display(),
            if missing.len() > 1 { "s" } else { "" },
            missing.join("`, `"),
            present.join(", "),
            present.join(",")
        ),
        IoError::NeedsSetup { path } => format!(
            "{} holds ball-bar distances (d1…); give the socket positions with --setup S.toml (or a [ballbar] table in the mechanism file)",
            path.display()
        ),
        IoError::ForeignCommands { .. } => format!("{e} Give the matching --mechanism"),
        IoError::Units {
            path,
            message,
            key,
            value,
        } => format!(
            "{}: {message}; give {}",
            path.display(),
            units_option(key, value)
        ),
        IoError::NotARecord { source_name } => format!(
            "{source_name}: no `covariance` entry; pass the report written by `pkmcal calibrate --report` or Python's Calibration.save"
        ),
        IoError::Gcode {
            path,
            line,
            message,
            hint,
        } => format!(
            "{}:{line}: {message}{}",
            path.display(),
            match hint {
                None => String::new(),
                Some(GcodeHint::Dialect(d)) =>
                    format!(" (or use --dialect {d} if that firmware runs it)"),
                Some(GcodeHint::NameDialect) => ", or name the firmware with --dialect".into(),
                Some(GcodeHint::Offset) => " or give the shift with --offset".into(),
                Some(GcodeHint::MaxSegment) => "; use a larger --max-segment (or none)".into(),
            }
        ),
        IoError::Request { file, cause } => match (cause, file) {
            (RequestError::ToleranceTable(problem), Some(f)) => {
                format!("in the [tolerances] table of {}: {problem}", f.display())
            }
            (c, Some(f)) => format!("{}: {}", f.display(), request(c)),
            (c, None) => request(c),
        },
        IoError::In { context, cause } => format!("{context}: {}", io(cause)),
        IoError::Library(l) if matches!(l.as_ref(), pkmcal::Error::Request(_)) => {
            match l.as_ref() {
                pkmcal::Error::Request(r) => request(r),
                l => l.to_string(),
            }
        }
        e => e.to_string(),
    }
}

/// `--units key=value (or [units] …)`.
pub fn units_option(key: &str, value: &str) -> String {
    format!("--units {key}={value} (or [units] {key} = \"{value}\" in the mechanism file)")
}

/// An error of a run, worded, and whether it is a usage error (exit 2):
/// each layer of context as it reads, then the first typed error of the
/// library or the file side in the command line's words.
pub fn message(e: &anyhow::Error) -> (String, bool) {
    let mut parts = vec![];
    let mut usage = false;
    for layer in e.chain() {
        if let Some(u) = layer.downcast_ref::<Usage>() {
            parts.push(u.0.clone());
            usage = true;
            break;
        }
        if let Some(io_error) = layer.downcast_ref::<IoError>() {
            usage |= io_error.is_usage();
            parts.push(io(io_error));
            break;
        }
        if let Some(r) = layer.downcast_ref::<RequestError>() {
            usage = true;
            parts.push(request(r));
            break;
        }
        if let Some(l) = layer.downcast_ref::<pkmcal::Error>() {
            match l {
                pkmcal::Error::Request(r) => {
                    usage = true;
                    parts.push(request(r));
                }
                l => parts.push(l.to_string()),
            }
            break;
        }
        parts.push(layer.to_string());
    }
    (parts.join(": "), usage)
}

/// A firmware calibration's check, worded: what it found (the library's
/// words) and what to do (in the command line's options).
pub fn firmware_warning(w: &pkmcal_io::firmware::FirmwareWarning) -> (String, String) {
    use pkmcal_io::firmware::{FirmwareWarning as W, Separation, TiltPlace, UncertainCause};
    let hint = match w {
        W::Correlated {
            distances,
            separation,
            fix,
            ..
        } => {
            let separate = match (separation, distances) {
                (Separation::Distances, 0) => {
                    "add DELTA_ANALYZE distances (measured on a calibration object)"
                }
                (Separation::Distances, _) => "add more DELTA_ANALYZE distances",
                (Separation::FurtherOut, _) => "probe points further out towards the bed's edge",
            };
            format!("{separate}, or keep `{fix}` fixed at a measured value (--fix {fix})")
        }
        W::Uncertain { limit, nozzle, .. } => match pkmcal_io::firmware::uncertain_cause(*limit, *nozzle) {
            UncertainCause::Together => "each value's σ is of it alone; a print shows the nozzle's. To pin each value down, measure what the probe cannot see (the next measurements below); --max-sigma sets the limit".into(),
            UncertainCause::Nozzle => "the readings leave the nozzle itself uncertain: take the next measurements below, or state tighter tolerances of the parts you know (--tolerance); --max-sigma sets the limit".into(),
            UncertainCause::Readings => "probe more points over the whole bed, or keep fixed what the readings cannot determine (--fix); --max-sigma sets the limit".into(),
        },
        W::TiltAbsorbed { place, .. } => match place {
            TiltPlace::Values { values, free } => format!(
                "free {} to write the tilt as {values} (--free default,{}), or level the bed",
                free.join(" and "),
                free.join(",")
            ),
            TiltPlace::BedMesh => "level the bed and probe again (a tilt is the bed's, not the delta's: Klipper's bed_mesh can take it when printing)".into(),
            TiltPlace::Levelling => "level the bed and probe again (a tilt is the bed's, not the delta's: Marlin's bed levelling, G29, can take it when printing)".into(),
        },
    };
    (w.message(), hint)
}

/// What the physical fit's residuals say of the readings' noise, worded:
/// whether the σ they were weighed with was stated (`--probe-noise`) or
/// assumed, and what to do about each.
pub fn noise_note(n: &pkmcal_io::firmware::physical::NoiseNote) -> String {
    use pkmcal_io::firmware::physical::ProbeNoise;
    let message = n.message();
    if !n.is_warning() {
        return message;
    }
    let model = if n.suspects.is_empty() {
        "the printer moves in a way the physical model does not describe (backlash, a loose joint, thermal drift between the probes)"
    } else {
        "free the parameters named (--free) and calibrate again"
    };
    let hint = match (n.more, n.heights, n.noise) {
        (false, _, s) => format!(
            "the σ stated is larger than the heights show: check --probe-noise {} against the probe's repeatability (the standard deviation of repeated probes at one point, as PROBE_ACCURACY reports it), or leave --probe-noise out to assume a typical probe's {}",
            s.mm(),
            pkmcal_io::firmware::physical::PROBE_NOISE_MM
        ),
        (true, true, ProbeNoise::Assumed(_)) => format!(
            "the probe's σ was assumed, not stated: measure its repeatability (the standard deviation of repeated probes at one point, as PROBE_ACCURACY reports it) and state it with --probe-noise; if it is as small as assumed, {model}"
        ),
        (true, true, ProbeNoise::Stated(s)) => format!(
            "check --probe-noise {s} against the probe's repeatability measured as the heights were (speed, temperature); if it is right, {model}"
        ),
        (true, false, _) => format!(
            "check the distances measured on the calibration object for a misread value; if they are right, {model}"
        ),
    };
    format!("warning: {message}\n  hint: {hint}")
}
