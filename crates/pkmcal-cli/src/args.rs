//! Options several commands share, checked into typed values where clap
//! reads them (a bad value exits 2, naming the option), and the files each
//! command declares before any work.

use clap::builder::{PossibleValuesParser, TypedValueParser};
use std::path::PathBuf;

/// The files a command reads and writes, checked before any work
/// (`Files::check`: no output is an input or another output).
#[derive(Default)]
pub struct Paths {
    pub inputs: Vec<PathBuf>,
    pub outputs: Vec<PathBuf>,
    /// Output directories the command creates.
    pub dirs: Vec<PathBuf>,
}

impl Paths {
    /// Inputs (absent ones skipped) and outputs.
    pub fn new(
        inputs: impl IntoIterator<Item = Option<PathBuf>>,
        outputs: impl IntoIterator<Item = PathBuf>,
    ) -> Self {
        Paths {
            inputs: inputs.into_iter().flatten().collect(),
            outputs: outputs.into_iter().collect(),
            dirs: vec![],
        }
    }

    /// The same, with output directories the command creates.
    pub fn with_dirs(mut self, dirs: Vec<PathBuf>) -> Self {
        self.dirs = dirs;
        self
    }
}

/// The mechanism option of every command that works on a mechanism.
#[derive(clap::Args)]
pub struct MechanismArg {
    /// Mechanism file (TOML); the built-in reference mechanism if omitted.
    #[arg(long, value_name = "M.toml")]
    pub mechanism: Option<PathBuf>,
}

/// Which parameters to identify.
#[derive(clap::Args, Default)]
pub struct FreeArgs {
    /// Parameters to identify, comma separated (`all`, `default` allowed); default: the mechanism's default set (the paper's 16 for the reference).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Parameters to keep fixed, comma separated (removed from the free set).
    #[arg(long, value_name = "NAMES")]
    pub fix: Option<String>,
}

impl FreeArgs {
    /// The names onto the request.
    pub fn apply(&self, r: &mut pkmcal::Request) {
        r.free = self.free.as_deref().map(pkmcal::Request::names);
        r.fix = self
            .fix
            .as_deref()
            .map(pkmcal::Request::names)
            .unwrap_or_default();
    }
}

/// Tolerances given on the command line.
#[derive(clap::Args, Default)]
pub struct ToleranceArg {
    /// Tolerances NAME=SIGMA as priors (one standard deviation in the
    /// parameter's unit, or a percentage of its nominal value: k1=20%),
    /// comma-separated or repeated; they replace the mechanism file's
    /// [tolerances] for the same names. A parameter with a tolerance is
    /// identified (unless --fix names it), held by it where the data are
    /// weak.
    #[arg(long, value_name = "NAME=SIGMA")]
    pub tolerance: Vec<String>,
}

impl ToleranceArg {
    /// The `--tolerance` items (`NAME=SIGMA`, comma-separated or
    /// repeated), in the order given; a name given twice is the library's
    /// to refuse.
    pub fn tolerances(&self) -> anyhow::Result<Vec<(String, pkmcal::apply::budget::Tolerance)>> {
        use pkmcal::apply::budget::Tolerance;
        let mut out = vec![];
        for item in self
            .tolerance
            .iter()
            .flat_map(|s| s.split(','))
            .map(str::trim)
        {
            if item.is_empty() {
                continue;
            }
            let Some((name, value)) = item.split_once('=') else {
                return crate::words::usage(format!(
                    "--tolerance {item}: give NAME=SIGMA (e.g. l11=0.05 or k1=20%)"
                ));
            };
            match Tolerance::parse(value) {
                Ok(t) => out.push((name.trim().to_string(), t)),
                Err(e) => return crate::words::usage(format!("--tolerance {item}: {e}")),
            }
        }
        Ok(out)
    }
}

/// The physical model of a linear delta (`--physical`, issue 54).
#[derive(clap::Args, Default)]
pub struct PhysicalArgs {
    /// Fit the printer as built (each tower's radius, angle and lean, each
    /// parallelogram's two rods and ball joints, the effector's tilt, the
    /// probe's offset, the bed's plane) within its parts' tolerances, then
    /// write the firmware values that put the nozzle best over the whole
    /// build volume (XY and Z), not those that fit the probe best; linear
    /// deltas only.
    #[arg(long)]
    pub physical: bool,
    /// With --physical: tolerances NAME=SIGMA replacing the physical
    /// model's defaults (rod_a1=0.05, radius_a=0.3, a.tilt1=0.002,
    /// bed.rx=0.001; `pkmcal parameters` on its description lists the
    /// names), comma-separated or repeated.
    #[command(flatten)]
    pub given: ToleranceArg,
    /// With --physical: heights measured by hand, read besides the
    /// firmware's probe results: a CSV with columns x, y, z (the position
    /// the firmware displays when the tool touches), tool (nozzle or
    /// probe), surface (the height over the bed of what it touched: 0 for
    /// the bed, a gauge block's height) and optionally sigma (mm; by
    /// default 0.02 for the nozzle, a paper test's, the probe's own for the
    /// probe). The nozzle touching where the probe triggers shows the
    /// effector's tilt that the probe's offset turns into Z error.
    #[arg(long, value_name = "HEIGHTS.csv")]
    pub heights: Option<std::path::PathBuf>,
    /// With --physical: write the Z error the written values leave over the
    /// bed (the fitted nozzle's, at each node of a round mesh, or of
    /// Klipper's rectangular [bed_mesh] where it has one) as the
    /// firmware's own height map here: for Klipper a `[bed_mesh pkmcal]`
    /// profile to [include] (BED_MESH_PROFILE LOAD=pkmcal), for
    /// RepRapFirmware a heightmap.csv (G29 S1 P"FILE"), for Marlin the
    /// M421 lines of its bilinear grid.
    #[arg(long, value_name = "FILE")]
    pub height_map: Option<std::path::PathBuf>,
    /// With --height-map: nodes across the mesh, each way (3 to 21; odd on a
    /// round mesh, which has a centre node); by default Klipper's [bed_mesh] round_probe_count
    /// or probe_count, else 5. Marlin's must be its GRID_MAX_POINTS_X.
    #[arg(long, value_name = "N", value_parser = values::mesh_points)]
    pub mesh_points: Option<usize>,
    /// With --physical: a directory (created if missing) of the report for
    /// the printer's owner: report.html with the verdict in words, the
    /// values to write with their σ, the nozzle's error maps over the bed
    /// (Z and XY, with their σ), the predicted cubes, the next
    /// measurements and the height map's nodes; its figures as SVG and PNG.
    #[arg(long, value_name = "DIR")]
    pub report_dir: Option<std::path::PathBuf>,
    /// With --physical: the probe's σ (mm, above 0 and at most 1; its
    /// repeatability, e.g. the standard deviation Klipper's PROBE_ACCURACY
    /// reports), which weighs the probe heights against the parts'
    /// tolerances; by default a typical probe's 0.01 mm is assumed.
    #[arg(long, value_name = "MM", allow_negative_numbers = true, value_parser = values::probe_noise)]
    pub probe_noise: Option<f64>,
}

impl PhysicalArgs {
    /// The files --physical writes besides --out.
    pub fn outputs(&self) -> anyhow::Result<Vec<std::path::PathBuf>> {
        let mut out: Vec<_> = self.height_map.iter().cloned().collect();
        if let Some(d) = &self.report_dir {
            out.extend(pkmcal_io::output::in_dir(
                d,
                pkmcal_io::firmware::physical_report::FILES,
            )?);
        }
        Ok(out)
    }

    /// The directories --physical creates.
    pub fn dirs(&self) -> Vec<std::path::PathBuf> {
        self.report_dir.iter().cloned().collect()
    }

    /// A firmware command's files: its `inputs`, `--out` and what
    /// --physical writes.
    pub fn paths(
        &self,
        inputs: impl IntoIterator<Item = Option<PathBuf>>,
        out: Option<&PathBuf>,
    ) -> anyhow::Result<Paths> {
        Ok(Paths::new(
            inputs.into_iter().chain(self.inputs()),
            out.into_iter().cloned().chain(self.outputs()?),
        )
        .with_dirs(self.dirs()))
    }

    /// The files --physical reads besides the firmware's.
    pub fn inputs(&self) -> Vec<Option<PathBuf>> {
        vec![self.heights.clone()]
    }

    /// The choices of a firmware command, as far as its rules go
    /// ([`pkmcal_io::firmware::choices`]); the command adds its own.
    pub fn choices(&self) -> pkmcal_io::firmware::choices::Choices {
        pkmcal_io::firmware::choices::Choices {
            physical: self.physical,
            tolerances: !self.given.tolerance.is_empty(),
            height_map: self.height_map.is_some(),
            mesh_points: self.mesh_points,
            report_dir: self.report_dir.is_some(),
            probe_noise: self.probe_noise,
            heights: self.heights.is_some(),
            ..Default::default()
        }
    }

    /// The tolerances and the probe's stated noise onto the request
    /// (refused without --physical).
    pub fn apply(&self, r: &mut pkmcal::Request) -> anyhow::Result<()> {
        self.choices().check()?;
        r.tolerances = self.given.tolerances()?;
        r.stated_noise = self.probe_noise;
        Ok(())
    }
}

/// What is known of the parameters before the data: their tolerances, as
/// priors of the fit.
#[derive(clap::Args, Default)]
pub struct PriorArgs {
    #[command(flatten)]
    pub given: ToleranceArg,
    /// Ignore the mechanism file's [tolerances]: no priors.
    #[arg(long)]
    pub no_tolerances: bool,
}

impl PriorArgs {
    /// The tolerances onto the request.
    pub fn apply(&self, r: &mut pkmcal::Request) -> anyhow::Result<()> {
        r.tolerances = self.given.tolerances()?;
        r.no_tolerances = self.no_tolerances;
        Ok(())
    }
}

/// The instrument's stated noise that weighs readings against the
/// tolerances (`analyze`, `plan`, `budget`).
#[derive(clap::Args)]
pub struct WeighingNoiseArgs {
    /// With tolerances: the instrument's stated noise on each length
    /// reading without a given σ (mm; default 0.002), which weighs what the
    /// readings tell against what the tolerances already tell.
    #[arg(value_parser = values::length_noise, long, value_name = "MM", alias = "noise")]
    pub stated_noise: Option<f64>,
    /// With tolerances: the stated noise on each angle reading, rad
    /// (default: the length noise over a 200 mm lever arm).
    #[arg(value_parser = values::angle_noise, long, value_name = "RAD", alias = "angle-noise")]
    pub stated_angle_noise: Option<f64>,
}

impl WeighingNoiseArgs {
    /// The stated noise onto the request.
    pub fn apply(&self, r: &mut pkmcal::Request) {
        r.stated_noise = self.stated_noise;
        r.stated_angle_noise = self.stated_angle_noise;
    }
}

/// What the instrument read and where it stood, for the commands that read
/// measurements (`calibrate`, `analyze`).
#[derive(clap::Args)]
pub struct InstrumentArgs {
    /// Ball-bar setup (sockets, bar offset) for data with distances d1, d2,
    /// … (default: the mechanism file's [ballbar] table).
    #[arg(long, value_name = "S.toml")]
    pub setup: Option<PathBuf>,
    /// Where the measuring instrument stands: `free` (a tracker or camera
    /// where it was put: its frame is identified with the rest), `base` (the
    /// data are in the base frame, e.g. trilaterated from ball-bar sockets at
    /// known places), `auto`: base when the data file says `# frame: base`
    /// (simulate and trilaterate write it), otherwise free. Ball-bar
    /// readings and probe heights carry no frame.
    #[arg(long, default_value = "auto", value_parser = PossibleValuesParser::new(pkmcal::FrameChoice::NAMES).try_map(|s| s.parse::<pkmcal::FrameChoice>()))]
    pub frame: pkmcal::FrameChoice,
    /// Only these tool axes were measured (comma-separated, e.g. `z` for a
    /// height probe); the data file then needs only their columns.
    #[arg(long, value_name = "AXES")]
    pub axes: Option<String>,
    /// Distances measured between pairs of poses (calipers on a printed
    /// object, a gauge), used with the data: CSV with the commands of both
    /// poses (`<actuator>_1`, `<actuator>_2` for every actuated joint) and
    /// `distance` in mm (optional `sigma_distance`; otherwise their noise is
    /// estimated apart from the data's).
    #[arg(long, value_name = "PAIRS.csv")]
    pub distances: Option<PathBuf>,
}

impl InstrumentArgs {
    /// The measured axes given.
    pub fn axes(&self) -> Option<Vec<String>> {
        self.axes.as_deref().map(pkmcal::Request::names)
    }
}

/// Comma-separated finite numbers.
#[derive(Debug, Clone)]
pub struct Numbers(pub Vec<f64>);

/// A tool load: one value per tool coordinate (N, N·m).
#[derive(Debug, Clone)]
pub struct Wrench(pub Vec<f64>);

/// The tool load, on every command that predicts, fits or inverts the model
/// (`--load`; `--force` is its old spelling).
#[derive(clap::Args)]
pub struct LoadArg {
    /// External load on the tool (a payload's weight, the measuring force),
    /// one value per tool coordinate, a wrench: a force in N along each
    /// length coordinate, a moment in N·m about each angle coordinate's axis
    /// (phi: the plane's normal; rx, ry, rz: the base x, y, z axes), e.g.
    /// `0,-9.81`.
    #[arg(long, alias = "force", value_name = "F1,F2,…", allow_hyphen_values = true, value_parser = values::load)]
    pub load: Option<Wrench>,
}

impl LoadArg {
    /// The values, empty without a load.
    pub fn values(&self) -> Vec<f64> {
        self.load.clone().map(|w| w.0).unwrap_or_default()
    }
}

/// The forward models a command may use, by name.
pub const MODELS: [&str; 3] = ["exact", "linear", "rigid"];
/// The models that can be inverted (compensation).
pub const INVERTIBLE_MODELS: [&str; 2] = ["exact", "rigid"];

/// A model among `names`, read into [`pkmcal::Model`].
pub fn model(names: &'static [&'static str]) -> impl TypedValueParser<Value = pkmcal::Model> {
    PossibleValuesParser::new(names).try_map(|s| s.parse::<pkmcal::Model>())
}

/// Option values checked by the parser (a bad value exits 2, naming the
/// option).
pub mod values {
    pub use pkmcal::identify::request::{MAX_ANGLE_RAD, MAX_LENGTH_MM};

    fn number(s: &str) -> Result<f64, String> {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("`{s}` is not a finite number"))
    }
    pub fn positive(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (v > 0.0)
            .then_some(v)
            .ok_or_else(|| format!("{v:?} must be positive"))
    }
    /// A number of readings (or anything counted that may be 0 or
    /// fractional).
    pub fn non_negative(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (v >= 0.0)
            .then_some(v)
            .ok_or_else(|| format!("{v:?} must be at least 0"))
    }
    /// A standard deviation of a length reading, mm: the library's bounds.
    pub fn sigma_mm(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (pkmcal::identify::MIN_SIGMA..=MAX_LENGTH_MM)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| {
                format!(
                    "{v:?} mm must be between {:e} and {MAX_LENGTH_MM:e} mm",
                    pkmcal::identify::MIN_SIGMA
                )
            })
    }
    pub fn fraction(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (v > 0.0 && v < 1.0)
            .then_some(v)
            .ok_or_else(|| format!("{v:?} must be between 0 and 1 (exclusive)"))
    }
    pub fn length_noise(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (0.0..=MAX_LENGTH_MM)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| format!("{v:?} mm must be between 0 and {MAX_LENGTH_MM} mm"))
    }
    pub fn angle_noise(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (0.0..=MAX_ANGLE_RAD)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| format!("{v:?} rad must be between 0 and {MAX_ANGLE_RAD} rad"))
    }
    /// A whole number (0 included); one too large for any count says so.
    fn whole(s: &str) -> Result<usize, String> {
        let t = s.trim();
        t.parse().map_err(|_| {
            if !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit()) {
                format!("`{t}` is beyond any count pkmcal takes")
            } else {
                format!("`{s}` is not a whole number")
            }
        })
    }
    pub fn count(s: &str) -> Result<usize, String> {
        let v = whole(s)?;
        (v >= 1)
            .then_some(v)
            .ok_or_else(|| "must be at least 1".to_string())
    }
    /// A number of targets spread over the workspace: at least 1, at most
    /// [`pkmcal::MAX_TARGETS`].
    pub fn targets(s: &str) -> Result<usize, String> {
        let v = count(s)?;
        targets_or_none(&v.to_string())
    }
    /// [`targets`], or 0 for none.
    pub fn targets_or_none(s: &str) -> Result<usize, String> {
        let v = whole(s)?;
        (v <= pkmcal::MAX_TARGETS).then_some(v).ok_or_else(|| {
            format!(
                "{v} targets are more than the {} one request spreads over the workspace",
                pkmcal::MAX_TARGETS
            )
        })
    }
    /// Machines a budget draws: 0 (none) to
    /// [`pkmcal::apply::budget::MAX_SAMPLES`].
    pub fn samples(s: &str) -> Result<usize, String> {
        let v = whole(s)?;
        let max = pkmcal::apply::budget::MAX_SAMPLES;
        (v <= max).then_some(v).ok_or_else(|| {
            format!("{v} samples are more than a budget draws ({max}); a few thousand settle the RMS to a percent")
        })
    }
    pub fn runs(s: &str) -> Result<usize, String> {
        let v = count(s)?;
        (v <= pkmcal::apply::montecarlo::MAX_RUNS)
            .then_some(v)
            .ok_or_else(|| {
                format!(
                    "at most {} runs (each is kept in memory); run several studies with other seeds for more",
                    pkmcal::apply::montecarlo::MAX_RUNS
                )
            })
    }
    pub fn folds(s: &str) -> Result<usize, String> {
        let v = count(s)?;
        (v >= 2)
            .then_some(v)
            .ok_or_else(|| "k-fold cross-validation needs at least 2 folds".to_string())
    }
    pub fn weighting(s: &str) -> Result<pkmcal_io::firmware::klipper::Weighting, String> {
        s.parse()
    }
    pub fn letter_b(s: &str) -> Result<pkmcal_io::firmware::marlin::LetterB, String> {
        s.parse()
    }
    /// The σ beyond which a written firmware value is warned of (in its
    /// own unit: mm, °, %).
    pub fn max_sigma(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        pkmcal_io::firmware::choices::max_sigma(v).map_err(|e| match e {
            pkmcal::RequestError::Invalid { problem, .. } => problem,
            e => e.to_string(),
        })
    }
    /// A probe's stated σ (mm), bounded by the library's rule.
    pub fn probe_noise(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        pkmcal_io::firmware::choices::probe_noise(v).map_err(|e| match e {
            pkmcal::RequestError::Invalid { problem, .. } => problem,
            e => e.to_string(),
        })
    }
    /// Nodes across a height map's mesh, each way (3 to 21; odd on a round
    /// one, which the printer's mesh decides).
    pub fn mesh_points(s: &str) -> Result<usize, String> {
        let n = s
            .trim()
            .parse::<usize>()
            .map_err(|_| format!("`{s}` is not a count of nodes"))?;
        pkmcal_io::firmware::height_map::mesh_points(n)
    }
    /// A probe's x, y offset from the nozzle (mm): two numbers, each at
    /// most 1 m in size.
    pub fn probe_offset(s: &str) -> Result<[f64; 2], String> {
        let v: Vec<&str> = s.split(',').collect();
        if v.len() != 2 {
            return Err(format!("`{s}`: give two numbers X,Y (mm), e.g. 0,0"));
        }
        let (x, y) = (number(v[0])?, number(v[1])?);
        if x.abs() > 1e3 || y.abs() > 1e3 {
            return Err(format!("`{s}`: a probe offset is at most 1000 mm in size"));
        }
        Ok([x, y])
    }
    /// A spacing (mm): positive, at most [`MAX_LENGTH_MM`].
    pub fn spacing(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (v > 0.0 && v <= MAX_LENGTH_MM)
            .then_some(v)
            .ok_or_else(|| format!("{v:?} mm must be positive and at most {MAX_LENGTH_MM} mm"))
    }
    /// Comma-separated finite numbers.
    pub fn numbers(s: &str) -> Result<super::Numbers, String> {
        s.split(',')
            .map(|t| number(t).map_err(|_| format!("`{}` is not a finite number", t.trim())))
            .collect::<Result<Vec<f64>, String>>()
            .map(super::Numbers)
    }
    /// A G-code segment length (mm): the file side's bounds.
    pub fn segment(s: &str) -> Result<f64, String> {
        use pkmcal_io::gcode::{MAX_SEGMENT, MIN_SEGMENT};
        let v = number(s)?;
        (MIN_SEGMENT..=MAX_SEGMENT)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| {
                format!("{v:?} must be a length between {MIN_SEGMENT:e} and {MAX_SEGMENT:e} mm")
            })
    }
    /// A tool load (wrench): comma-separated finite numbers, each within
    /// [`pkmcal::units::MAX_LOAD`] (N, N·m); its length is checked against
    /// the mechanism's tool axes where the mechanism is known.
    pub fn load(s: &str) -> Result<super::Wrench, String> {
        let v = s
            .split(',')
            .map(|t| number(t).map_err(|_| format!("`{}` is not a finite number", t.trim())))
            .collect::<Result<Vec<f64>, String>>()?;
        if let Some(x) = v.iter().find(|x| x.abs() > pkmcal::units::MAX_LOAD) {
            return Err(format!(
                "{x:?} is beyond ±{:e} (N, N·m); no machine bears that",
                pkmcal::units::MAX_LOAD
            ));
        }
        Ok(super::Wrench(v))
    }
}
