//! Firmware configurations as data: a printer's configuration read as its
//! firmware reads it (includes, saved results), the printer as a pkmcal
//! mechanism, the readings it holds (or was given), the firmware's own
//! parameter set, and its values written back from calibrated parameters,
//! every other byte kept.
//!
//! [`Firmware`] is the one interface the front ends calibrate a printer
//! through; each firmware is one module: [`klipper`] (Klipper's linear
//! delta), [`klipper_rotary`] (Klipper's rotary delta), [`reprap`]
//! (RepRapFirmware's), [`marlin`] (Marlin's, with its own calibration
//! [`g33`] to compare). [`physical`] is the printer as built, for the
//! linear deltas (`--physical`).

pub mod choices;
pub mod g33;
pub mod height_map;
pub mod klipper;
pub mod klipper_rotary;
pub mod marlin;
pub mod physical;
pub mod physical_drift;
pub mod physical_heights;
pub mod physical_plan;
pub mod physical_report;
pub mod reprap;

use crate::description::Mech;
use crate::error::{Error, Result};
use pkmcal::{Calibration, Measurement, MeasurementModel, Mechanism, Params, Request, Spec};

/// One value a firmware keeps, before and after a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct FirmwareValue {
    /// Where the firmware keeps it, in its own terms (`[printer]
    /// delta_radius`, `M665 R`).
    pub name: String,
    /// Its value before.
    pub before: f64,
    /// Its value from the calibrated parameters.
    pub after: f64,
    /// Its unit (`mm`, `°`, `%`).
    pub unit: &'static str,
    /// The standard uncertainty of `after` in `unit`, propagated from the
    /// calibration's covariance ([`written`]); `None` until then, `Some(0)`
    /// for a value no free parameter moves.
    pub sigma: Option<f64>,
}

impl FirmwareValue {
    /// Its σ as shown beside it ([`Sigma::of`]); a value with no σ yet
    /// (`None`) is one no free parameter moves: fixed.
    pub fn sigma_shown(&self) -> Sigma {
        self.sigma.map_or(Sigma::Fixed, Sigma::of)
    }
}

/// A written value's σ as it is shown: the one rule of every table and
/// result that gives it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sigma {
    /// The value's standard uncertainty (above 0), in its unit.
    Known(f64),
    /// Not known (the covariance is not: NaN).
    Unknown,
    /// No free parameter moves the value (σ 0 or less): the fit holds it.
    Fixed,
}

impl Sigma {
    /// A propagated σ as shown: above 0 the value's, NaN unknown, anything
    /// else fixed.
    pub fn of(sigma: f64) -> Self {
        if sigma > 0.0 {
            Sigma::Known(sigma)
        } else if sigma.is_nan() {
            Sigma::Unknown
        } else {
            Sigma::Fixed
        }
    }
}

/// The largest size and the RMS of errors (mm), as the summaries give
/// them (0 for none).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    /// The largest absolute error.
    pub max: f64,
    /// The root mean square about 0.
    pub rms: f64,
}

impl Spread {
    /// The spread of `errors`.
    pub fn of(errors: &[f64]) -> Self {
        Spread {
            max: errors.iter().fold(0.0, |m, x| m.max(x.abs())),
            rms: (errors.iter().map(|x| x * x).sum::<f64>() / errors.len().max(1) as f64).sqrt(),
        }
    }
}

/// What a printer gives a calibration: the readings (probe heights as
/// poses, distances measured on a calibration object as pairs of poses),
/// what they read, and each reading's name in the firmware's terms.
pub struct Readings {
    /// The instrument's model (a probe: heights over a bed plane).
    pub measurement: MeasurementModel,
    /// The poses.
    pub poses: Vec<Measurement>,
    /// The distances between pairs of poses.
    pub distances: Vec<Measurement>,
}

/// Which firmware a printer runs: what decides its commands' spelling and
/// where an extra reading goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flavour {
    /// Klipper (its linear and rotary deltas).
    Klipper,
    /// RepRapFirmware.
    RepRapFirmware,
    /// Marlin.
    Marlin,
}

impl Flavour {
    /// The firmware's name.
    pub fn name(self) -> &'static str {
        match self {
            Flavour::Klipper => "Klipper",
            Flavour::RepRapFirmware => "RepRapFirmware",
            Flavour::Marlin => "Marlin",
        }
    }

    /// Whether it reads the distances of a printed calibration object
    /// (Klipper's `DELTA_ANALYZE`).
    pub fn reads_object_distances(self) -> bool {
        self == Flavour::Klipper
    }
}

impl std::fmt::Display for Flavour {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A printer's firmware configuration, read: what a front end calibrates.
pub trait Firmware {
    /// Which firmware it is.
    fn flavour(&self) -> Flavour;

    /// The firmware's name (`Klipper`, `RepRapFirmware`, `Marlin`).
    fn name(&self) -> &'static str {
        self.flavour().name()
    }

    /// The printer as a pkmcal mechanism description (TOML).
    fn description(&self) -> String;

    /// The printer as a mechanism ([`Firmware::description`], read).
    fn mechanism(&self) -> Result<Mech> {
        crate::description::mechanism_from_str(&self.description()).map_err(|e| {
            e.context(format!(
                "the {} geometry does not describe a delta that assembles",
                self.name()
            ))
        })
    }

    /// The readings of the printer's probe (and calibration object) for
    /// `spec`.
    fn readings(&self, spec: &Spec) -> Result<Readings>;

    /// The readings as the physical model ([`physical`]) takes them: where
    /// the carriages were when the probe triggered, the probe's offset from
    /// the nozzle included ([`Firmware::readings`] by default, where the
    /// firmware saves the carriages' positions or moves by the offset).
    fn physical_readings(&self, spec: &Spec) -> Result<Readings> {
        self.readings(spec)
    }

    /// The firmware's own free set, given what the readings hold.
    fn default_free(&self, spec: &Spec, readings: &Readings) -> Vec<String>;

    /// The parameters the firmware can keep (`None`: every parameter of the
    /// description); a fit that frees another is refused by name.
    fn holds(&self) -> Option<Vec<String>> {
        None
    }

    /// What the firmware sets in a study of its readings (exactly
    /// determined fits, a weighting of its readings).
    fn configure(&self, _request: &mut Request, _readings: &Readings) {}

    /// A refusal of a free set the firmware cannot hold.
    fn check_free(&self, _names: &[String]) -> std::result::Result<(), pkmcal::RequestError> {
        Ok(())
    }

    /// The firmware's values for the description's parameters `params` and
    /// the instrument's `instrument` (the bed's), beside its own.
    fn values(
        &self,
        spec: &Spec,
        params: &Params,
        instrument: &[f64],
    ) -> Result<Vec<FirmwareValue>>;

    /// The configuration with the values of `params` and `instrument`
    /// written back, every other byte as it was.
    fn updated(&self, spec: &Spec, params: &Params, instrument: &[f64]) -> Result<String>;

    /// An error at a reading, located in the firmware's terms (`height3`
    /// of the configuration; line 7 of the probe file).
    fn located(&self, e: pkmcal::Error) -> Error;

    /// The printer as a linear delta for the physical model
    /// ([`physical`]); `None` when it is not one (a rotary delta).
    fn linear_delta(&self) -> Result<Option<physical::LinearDelta>> {
        Ok(None)
    }

    /// The levelling mesh a height map of this printer is written on
    /// ([`height_map`]), `count` nodes across where given, over a circle of
    /// `radius` (mm) unless the configuration sets its own mesh; `None`
    /// where the firmware has no format for one.
    fn mesh_layout(
        &self,
        _radius: f64,
        _count: Option<usize>,
    ) -> Result<Option<height_map::MeshLayout>> {
        Ok(None)
    }

    /// Whether the readings' σ the firmware gave the fit are a weighting
    /// only (Klipper's fixed ratio of heights to distances), so that the
    /// uncertainties take their scale from the residuals.
    fn relative_sigma(&self, _readings: &Readings) -> bool {
        false
    }

    /// What, besides keeping one of them fixed, would separate two written
    /// values the readings cannot tell apart.
    fn separation(&self) -> Separation {
        Separation::FurtherOut
    }

    /// Where a bed tilt the probe heights show, and the fit left out, has
    /// a place.
    fn tilt_place(&self) -> TiltPlace {
        TiltPlace::Levelling
    }
}

/// What separates two written values that move together.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Separation {
    /// Distances measured on a calibration object (Klipper's
    /// DELTA_ANALYZE): they see lengths that heights cannot.
    Distances,
    /// Probe points further out towards the bed's edge: the heights' bowl
    /// grows with the radius probed.
    FurtherOut,
}

/// Where a bed tilt has a place in a firmware.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TiltPlace {
    /// In the firmware's own values (RepRapFirmware's `M666 A B`), written
    /// when the parameters named are freed.
    Values {
        /// The values.
        values: &'static str,
        /// The parameters that write them.
        free: Vec<String>,
    },
    /// In a bed mesh (Klipper's `bed_mesh`), not in the delta's values.
    BedMesh,
    /// In bed levelling (Marlin's G29), not in the delta's values.
    Levelling,
}

/// What a firmware calibration's summary warns of, beside the fit's own
/// warnings: a user words each ([`checks`]).
#[derive(Debug, Clone, PartialEq)]
pub enum FirmwareWarning {
    /// Two written values, or the two free parameters that write them,
    /// correlated beyond [`MAX_CORRELATION`]: the readings cannot tell them
    /// apart.
    Correlated {
        /// The values, in the firmware's terms: a pair, or every value
        /// linked to another by such a correlation.
        values: Vec<String>,
        /// The free parameters correlated, when it is theirs (each writes
        /// mostly its value: `arm_a` the arm length, `da` the endstop);
        /// `None` when the written values themselves are.
        parameters: Option<[String; 2]>,
        /// The correlation of a pair; of a group, the largest in size.
        r: f64,
        /// The smallest correlation in size linking a group (a pair's |r|).
        weakest: f64,
        /// Probe heights read.
        heights: usize,
        /// Distances read.
        distances: usize,
        /// What would separate them, besides keeping `fix` fixed.
        separation: Separation,
        /// The free parameter whose fixing separates them (the one of the
        /// two the firmware's own fit does not free, else the less certain).
        fix: String,
    },
    /// Written values whose σ exceed the limit asked.
    Uncertain {
        /// Each value, in the firmware's terms, with its σ and unit.
        values: Vec<(String, f64, &'static str)>,
        /// The limit (in each value's unit).
        limit: f64,
        /// Under `--physical`: the nozzle's σ with all the values written,
        /// XY then Z (mm, root mean square over the build volume in the
        /// bed's frame; [`physical::nozzle_sigma`]). Below the limit, the
        /// values move together: each alone is uncertain, the nozzle they
        /// place is not.
        nozzle: Option<[f64; 2]>,
    },
    /// The probe heights show a bed tilt that the fit has no parameter
    /// for: the fitted values took it.
    TiltAbsorbed {
        /// The firmware's name.
        firmware: &'static str,
        /// The bed's slopes the data show, x then y (mm per mm: the
        /// height `x·sx + y·sy`).
        slopes: [f64; 2],
        /// The score test's p-value ([`pkmcal::identify::omitted_test`]).
        p: f64,
        /// The share of the heights' misfit the tilt explains.
        share: f64,
        /// The written values that took it, most first, with how much
        /// each took (the value written less the one a fit with the tilt
        /// would write) and its unit.
        absorbed: Vec<(String, f64, &'static str)>,
        /// Where a tilt has a place in this firmware.
        place: TiltPlace,
    },
}

impl FirmwareWarning {
    /// What the warning found, in words that name no option (each front
    /// end adds its hint, naming its own options or keywords).
    pub fn message(&self) -> String {
        match self {
            FirmwareWarning::Correlated {
                values,
                parameters,
                r,
                weakest,
                heights,
                distances,
                ..
            } => {
                let read = if *distances == 0 {
                    format!("{heights} probe heights")
                } else {
                    format!("{heights} probe heights and {distances} distances")
                };
                let listed = match values.as_slice() {
                    [rest @ .., last] if !rest.is_empty() => {
                        format!("{} and {last}", rest.join(", "))
                    }
                    v => v.join(""),
                };
                let what = match parameters {
                    Some([pa, pb]) => format!("`{pa}` and `{pb}` (written as {listed})"),
                    None => listed,
                };
                let by = if values.len() == 2 {
                    format!("r = {r:.3}")
                } else {
                    format!("|r| {weakest:.3} to {:.3}", r.abs())
                };
                format!("{what} move together ({by}): {read} cannot tell them apart")
            }
            FirmwareWarning::Uncertain {
                values,
                limit,
                nozzle,
            } => {
                let listed = values
                    .iter()
                    .map(|(n, s, u)| format!("{n} σ {s:.4} {u}"))
                    .collect::<Vec<_>>()
                    .join(", ");
                let nozzle = match nozzle {
                    Some([xy, z]) => format!(
                        "; {}the nozzle they place has σ {xy:.4} mm in XY and {z:.4} mm in Z (RMS over the build volume, in the bed's frame)",
                        match uncertain_cause(*limit, Some([*xy, *z])) {
                            UncertainCause::Together => "but they move together: ",
                            _ => "",
                        }
                    ),
                    None => String::new(),
                };
                format!("written with a σ beyond {limit} (in each one's unit): {listed}{nozzle}")
            }
            FirmwareWarning::TiltAbsorbed {
                firmware,
                slopes,
                p,
                share,
                absorbed,
                place,
            } => {
                let took: Vec<String> = absorbed
                    .iter()
                    .map(|(n, d, u)| format!("{n} by {d:+.4} {u}"))
                    .collect();
                let whose = match place {
                    TiltPlace::Values { .. } => format!("{firmware}'s fit as asked"),
                    _ => (*firmware).to_string(),
                };
                format!(
                    "the probe heights show a bed tilt of {:+.3} % in x and {:+.3} % in y (mm per 100 mm; score test p = {p:.1e}, {:.0} % of the heights' misfit) that {whose} has no value for; the fitted values absorbed it: {}",
                    100.0 * slopes[0],
                    100.0 * slopes[1],
                    100.0 * share,
                    took.join(", ")
                )
            }
        }
    }
}

/// Written values correlated beyond this are warned of (issue 49: arm
/// lengths from heights alone correlate with their endstops at 0.996–0.998).
pub const MAX_CORRELATION: f64 = 0.99;

/// The default limit of a written value's σ (mm, °, %) before a warning
/// (issue 49): a quarter of a 0.2 mm layer.
pub const DEFAULT_MAX_SIGMA: f64 = 0.05;

/// The largest limit of σ a user may ask (in the values' units): beyond
/// it no value of a printer would ever be warned of.
pub const MAX_SIGMA_LIMIT: f64 = 1000.0;

/// Absorbed values listed at most in a [`FirmwareWarning::TiltAbsorbed`].
pub const ABSORBED_LISTED: usize = 3;

/// The finite-difference step of [`written`], in each parameter's σ.
const SIGMA_STEP: f64 = 1e-3;

/// A printer's calibration request: the firmware's default free set in
/// place of the description's, the user's names, `fix` and the firmware's
/// own settings; checked against what the firmware can hold.
pub fn request(
    firmware: &dyn Firmware,
    spec: &Spec,
    readings: &Readings,
    mut request: Request,
) -> std::result::Result<(Request, Vec<usize>, Vec<String>), pkmcal::RequestError> {
    request.default_free = Some(firmware.default_free(spec, readings));
    firmware.configure(&mut request, readings);
    let (priors, free) = request.priors_and_free(spec, &readings.measurement, &[])?;
    let _ = priors;
    let names = request.free_names(spec, &readings.measurement, &free);
    firmware.check_free(&names)?;
    if let Some(holds) = firmware.holds()
        && let Some(n) = names.iter().find(|n| !holds.contains(n))
    {
        return Err(pkmcal::RequestError::invalid(
            pkmcal::Field::Free,
            format!(
                "`{n}` has no place in {}'s configuration, so the firmware could not run what the fit finds; the parameters it holds are {}",
                firmware.name(),
                holds.join(", ")
            ),
        ));
    }
    Ok((request, free, names))
}

/// A calibration of a printer's readings: the study every front end runs.
pub struct PrinterCalibration {
    /// The printer's mechanism.
    pub mech: Mech,
    /// Its readings.
    pub readings: Readings,
    /// The free parameters' names, in the order given.
    pub free_names: Vec<String>,
    /// Their indices in the identification vector, in that order (what was
    /// asked; the fit may have fixed some it could not identify).
    pub free: Vec<usize>,
    /// The study.
    pub study: pkmcal::identify::Study,
}

impl PrinterCalibration {
    /// The calibration.
    pub fn calibration(&self) -> &Calibration {
        &self.study.calibration
    }
}

/// What a printer's calibration fits: its mechanism, its readings, the
/// study's options and the free parameters' names in the order given.
pub struct PrinterProblem {
    /// The printer's mechanism.
    pub mech: Mech,
    /// Its readings.
    pub readings: Readings,
    /// The study's options (the free set in the order of the names).
    pub opts: pkmcal::identify::StudyOptions,
    /// The free parameters' names.
    pub free_names: Vec<String>,
}

/// The problem a calibration of `firmware`'s printer fits, as `request`
/// asks (the firmware's default free set where it names none).
pub fn problem(firmware: &dyn Firmware, request: Request) -> Result<PrinterProblem> {
    let mech = firmware.mechanism()?;
    let spec = mech.spec();
    let readings = firmware.readings(spec)?;
    let (request, _free, free_names) = self::request(firmware, spec, &readings, request)?;
    let nominal = Params::nominal(spec);
    let mut opts = request.study_options(&mech, &readings.measurement, &[], &nominal)?;
    // In the order the names were given (the firmware's own order by
    // default), as the identifiability analysis takes the columns.
    opts.calibration.free = free_names
        .iter()
        .map(|n| readings.measurement.index_of(spec, n))
        .collect::<pkmcal::Result<Vec<usize>>>()?;
    Ok(PrinterProblem {
        mech,
        readings,
        opts,
        free_names,
    })
}

/// The study of `readings` on `mech` from its nominal values (the
/// firmware's or the physical model's); an error at a reading names it in
/// the firmware's terms.
pub(crate) fn study(
    firmware: &dyn Firmware,
    mech: &Mech,
    readings: &Readings,
    opts: &pkmcal::identify::StudyOptions,
) -> Result<pkmcal::identify::Study> {
    study_located(mech, readings, opts, &|e| firmware.located(e))
}

/// [`study`], an error at a reading named by `located`.
pub(crate) fn study_located(
    mech: &Mech,
    readings: &Readings,
    opts: &pkmcal::identify::StudyOptions,
    located: &dyn Fn(pkmcal::Error) -> Error,
) -> Result<pkmcal::identify::Study> {
    pkmcal::identify::study(
        mech,
        &readings.measurement,
        &readings.poses,
        readings.distances.clone(),
        &Params::nominal(mech.spec()),
        opts,
        &|| {},
    )
    .map_err(|e| match &e.error {
        pkmcal::Error::Pose { .. } => located(e.error),
        _ => Error::from(e.error),
    })
}

/// Calibrate `firmware`'s printer from its readings as `request` asks
/// (the firmware's default free set where it names none), from the
/// firmware's values; an error at a reading names it in the firmware's
/// terms.
pub fn calibrate(firmware: &dyn Firmware, request: Request) -> Result<PrinterCalibration> {
    let PrinterProblem {
        mech,
        readings,
        opts,
        free_names,
    } = problem(firmware, request)?;
    let free = opts.calibration.free.clone();
    let study = study(firmware, &mech, &readings, &opts)?;
    Ok(PrinterCalibration {
        mech,
        readings,
        free_names,
        free,
        study,
    })
}

/// The values a calibration writes, each with its σ, and how they
/// move together.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// The values ([`Firmware::values`]) with their σ.
    pub values: Vec<FirmwareValue>,
    /// Their correlation matrix (rows and columns in `values` order; 0
    /// beside a value with σ 0).
    pub correlation: Vec<Vec<f64>>,
    /// Each value's derivative by each free parameter (rows: values;
    /// columns: [`pkmcal::Calibration::free`] order).
    pub jacobian: Vec<Vec<f64>>,
}

/// The values a printer's calibration writes into `firmware`'s
/// configuration with their σ:
/// the calibration's covariance of the free parameters propagated through
/// [`Firmware::values`] (a pure function of the parameters and the bed),
/// its Jacobian by central differences. The step is a thousandth of each
/// parameter's σ: small against the values' curvature over the
/// uncertainty, whatever the parameter's unit (mm, °, N/mm), and far above
/// rounding since the values are not rounded.
pub fn written(firmware: &dyn Firmware, calibrated: &PrinterCalibration) -> Result<Written> {
    let spec = calibrated.mech.spec();
    let cal = calibrated.calibration();
    let np = spec.n_params();
    let mut values = firmware.values(spec, &cal.params, &cal.measurement)?;
    let n = values.len();
    let nf = cal.free.len();
    let mut jac = vec![vec![0.0; nf]; n];
    for (k, &j) in cal.free.iter().enumerate() {
        let sd = cal
            .covariance
            .get((k, k))
            .map_or(0.0, |v| v.max(0.0).sqrt());
        if !(sd.is_finite() && sd > 0.0) {
            continue;
        }
        let h = SIGMA_STEP * sd;
        let at = |d: f64| -> Result<Vec<f64>> {
            let (mut p, mut m) = (cal.params.clone(), cal.measurement.clone());
            if j < np {
                p.values[j] += d;
            } else {
                m[j - np] += d;
            }
            Ok(firmware
                .values(spec, &p, &m)?
                .iter()
                .map(|v| v.after)
                .collect())
        };
        let (up, down) = (at(h)?, at(-h)?);
        for i in 0..n.min(up.len()).min(down.len()) {
            jac[i][k] = (up[i] - down[i]) / (2.0 * h);
        }
    }
    // A weighting's σ set ratios, not the scale: the readings' variance of
    // unit weight gives it.
    let scale = if firmware.relative_sigma(&calibrated.readings) {
        cal.unit_weight_sigma.powi(2)
    } else {
        1.0
    };
    let c = &cal.covariance * scale;
    let cov: Vec<Vec<f64>> = (0..n)
        .map(|a| {
            (0..n)
                .map(|b| {
                    let mut s = 0.0;
                    for k in 0..nf {
                        for l in 0..nf {
                            s += jac[a][k] * c.get((k, l)).copied().unwrap_or(0.0) * jac[b][l];
                        }
                    }
                    s
                })
                .collect()
        })
        .collect();
    let sd: Vec<f64> = (0..n).map(|i| cov[i][i].max(0.0).sqrt()).collect();
    let correlation = (0..n)
        .map(|a| {
            (0..n)
                .map(|b| {
                    if sd[a] > 0.0 && sd[b] > 0.0 {
                        (cov[a][b] / (sd[a] * sd[b])).clamp(-1.0, 1.0)
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect();
    for (v, s) in values.iter_mut().zip(&sd) {
        v.sigma = Some(*s);
    }
    Ok(Written {
        values,
        correlation,
        jacobian: jac,
    })
}

/// The bed's tilt parameters, which every firmware's probe model has.
const TILT: [&str; 2] = ["bed.rx", "bed.ry"];

/// The checks of a printer's calibration and the values it writes:
/// written values correlated beyond [`MAX_CORRELATION`], σ beyond
/// `max_sigma` (in each value's unit), and a bed tilt the data show that
/// the fit left out (its score test at [`pkmcal::identify::OMITTED_ALPHA`]).
pub fn checks(
    firmware: &dyn Firmware,
    calibrated: &PrinterCalibration,
    written: &Written,
    max_sigma: f64,
) -> Result<Vec<FirmwareWarning>> {
    let spec = calibrated.mech.spec();
    let readings = &calibrated.readings;
    let cal = calibrated.calibration();
    let values = &written.values;
    let sigma = |i: usize| values[i].sigma.unwrap_or(0.0);
    let mut out = vec![];
    // The free parameter a value moves most over its uncertainty.
    let all = readings.measurement.all_names(spec);
    let dominant = |i: usize| -> Option<(usize, f64)> {
        written.jacobian[i]
            .iter()
            .enumerate()
            .map(|(k, g)| {
                let sd = cal
                    .covariance
                    .get((k, k))
                    .map_or(0.0, |v| v.max(0.0).sqrt());
                (k, (g * sd).abs())
            })
            .filter(|(_, w)| *w > 0.0)
            .max_by(|a, b| a.1.total_cmp(&b.1))
    };
    let own = firmware.default_free(spec, readings);
    // The written values' pairs, then the free parameters' (named by the
    // value each writes: the one whose sensitivities it has the largest
    // share of, `arm_a` the arm length rather than the endstop it moves
    // too).
    let mut pairs: Vec<(usize, usize, f64, Option<[usize; 2]>)> = vec![];
    for a in 0..values.len() {
        for b in a + 1..values.len() {
            let r = written.correlation[a][b];
            if r.abs() > MAX_CORRELATION && sigma(a) > 0.0 && sigma(b) > 0.0 {
                pairs.push((a, b, r, None));
            }
        }
    }
    let sd = |k: usize| {
        cal.covariance
            .get((k, k))
            .map_or(0.0, |v| v.max(0.0).sqrt())
    };
    let writes = |k: usize| -> Option<usize> {
        (0..values.len())
            .map(|i| {
                let part = |l: usize| (written.jacobian[i][l] * sd(l)).powi(2);
                let all: f64 = (0..cal.free.len()).map(part).sum();
                (i, if all > 0.0 { part(k) / all } else { 0.0 })
            })
            .filter(|(_, w)| *w > 0.0)
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i)
    };
    for ka in 0..cal.free.len() {
        for kb in ka + 1..cal.free.len() {
            let (va, vb) = (sd(ka), sd(kb));
            let r = cal.covariance.get((ka, kb)).copied().unwrap_or(0.0) / (va * vb);
            if r.is_nan() || r.abs() <= MAX_CORRELATION {
                continue;
            }
            let (Some(a), Some(b)) = (writes(ka), writes(kb)) else {
                continue;
            };
            if a != b && !pairs.iter().any(|p| (p.0, p.1) == (a.min(b), a.max(b))) {
                pairs.push((a, b, r, Some([ka, kb])));
            }
        }
    }
    pairs.sort_by(|x, y| y.2.abs().total_cmp(&x.2.abs()));
    // The written values' pairs joined into groups (a shoulder height and
    // three endstops that all move together are one warning).
    let mut group: Vec<usize> = (0..values.len()).collect();
    fn root(group: &mut [usize], mut i: usize) -> usize {
        while group[i] != i {
            group[i] = group[group[i]];
            i = group[i];
        }
        i
    }
    for &(a, b, _, params) in &pairs {
        if params.is_none() {
            let (ra, rb) = (root(&mut group, a), root(&mut group, b));
            group[ra.max(rb)] = ra.min(rb);
        }
    }
    let mut said: Vec<usize> = vec![];
    for &(a, b, r, params) in &pairs {
        let (members, links): (Vec<usize>, Vec<f64>) = match params {
            Some(_) => (vec![a, b], vec![r.abs()]),
            None => {
                let g = root(&mut group, a);
                if said.contains(&g) {
                    continue;
                }
                said.push(g);
                let members: Vec<usize> = (0..values.len())
                    .filter(|&i| root(&mut group, i) == g)
                    .collect();
                let links = pairs
                    .iter()
                    .filter(|p| p.3.is_none() && members.contains(&p.0))
                    .map(|p| p.2.abs())
                    .collect();
                (members, links)
            }
        };
        // The parameter to keep fixed: one the firmware's own fit does not
        // free, else the one behind the least certain value.
        let behind: Vec<(usize, usize)> = match params {
            Some([ka, kb]) => vec![(a, ka), (b, kb)],
            None => members
                .iter()
                .filter_map(|&i| dominant(i).map(|(k, _)| (i, k)))
                .collect(),
        };
        let Some(fix) = behind
            .iter()
            .max_by(|x, y| {
                let outside = |k: usize| !own.contains(&all[cal.free[k]]);
                (outside(x.1), sigma(x.0))
                    .partial_cmp(&(outside(y.1), sigma(y.0)))
                    .unwrap_or(std::cmp::Ordering::Equal)
            })
            .map(|(_, k)| all[cal.free[*k]].clone())
        else {
            continue;
        };
        out.push(FirmwareWarning::Correlated {
            values: members.iter().map(|&i| values[i].name.clone()).collect(),
            parameters: params
                .map(|[ka, kb]| [all[cal.free[ka]].clone(), all[cal.free[kb]].clone()]),
            r,
            weakest: links.iter().copied().fold(f64::INFINITY, f64::min),
            heights: readings.poses.len(),
            distances: readings.distances.len(),
            separation: firmware.separation(),
            fix,
        });
    }
    out.extend(uncertain(values, max_sigma, None));
    if let Some(w) = tilt_absorbed(firmware, calibrated, written)? {
        out.push(w);
    }
    Ok(out)
}

/// Why written values are uncertain ([`FirmwareWarning::Uncertain`]):
/// what a front end's hint answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UncertainCause {
    /// Each value alone is uncertain, the nozzle they place together is
    /// known within the limit: they move together.
    Together,
    /// The nozzle itself is uncertain beyond the limit: the readings do
    /// not show it.
    Nozzle,
    /// The nozzle's σ is not known (the firmware's own fit, without the
    /// physical model): fewer free values or more readings.
    Readings,
}

/// The cause of a σ-beyond-limit warning with limit `limit` and the
/// nozzle's σ `nozzle` (XY, Z; mm) where known.
pub fn uncertain_cause(limit: f64, nozzle: Option<[f64; 2]>) -> UncertainCause {
    match nozzle {
        Some([xy, z]) if xy.max(z) <= limit => UncertainCause::Together,
        Some(_) => UncertainCause::Nozzle,
        None => UncertainCause::Readings,
    }
}

/// The written values whose σ exceeds `max_sigma` (`--max-sigma`), as
/// one warning, with the nozzle's σ they leave where it is known
/// ([`FirmwareWarning::Uncertain`]); `None` when every σ is within it.
pub fn uncertain(
    values: &[FirmwareValue],
    max_sigma: f64,
    nozzle: Option<[f64; 2]>,
) -> Option<FirmwareWarning> {
    let beyond: Vec<(String, f64, &'static str)> = values
        .iter()
        .filter_map(|v| {
            v.sigma
                .filter(|s| *s > max_sigma)
                .map(|s| (v.name.clone(), s, v.unit))
        })
        .collect();
    (!beyond.is_empty()).then_some(FirmwareWarning::Uncertain {
        values: beyond,
        limit: max_sigma,
        nozzle,
    })
}

/// The bed tilt the fit left out, when its score test says the probe
/// heights show it.
fn tilt_absorbed(
    firmware: &dyn Firmware,
    calibrated: &PrinterCalibration,
    written: &Written,
) -> Result<Option<FirmwareWarning>> {
    let spec = calibrated.mech.spec();
    let readings = &calibrated.readings;
    let cal = calibrated.calibration();
    let measurement = &readings.measurement;
    let Ok(tilt) = TILT
        .iter()
        .map(|n| measurement.index_of(spec, n))
        .collect::<pkmcal::Result<Vec<usize>>>()
    else {
        return Ok(None);
    };
    if tilt.iter().any(|j| cal.free.contains(j)) {
        return Ok(None);
    }
    let data: Vec<Measurement> = readings
        .poses
        .iter()
        .chain(&readings.distances)
        .filter(|m| m.origin.is_none_or(|o| !cal.dropped.contains(&o)))
        .cloned()
        .collect();
    let problem = pkmcal::identify::IdentificationProblem::new(
        &calibrated.mech,
        measurement,
        &data,
        cal.model,
        &[],
    )?;
    let Some(t) = pkmcal::identify::omitted_test(&problem, cal, &tilt)? else {
        return Ok(None);
    };
    if t.p.is_nan() || t.p >= pkmcal::identify::OMITTED_ALPHA || t.indices.len() != tilt.len() {
        return Ok(None);
    }
    let (rx, ry) = (t.values[0], t.values[1]);
    // The plane `h = bed.z − x·tan(bed.ry) + y·tan(bed.rx)`.
    let slopes = [-ry.tan(), rx.tan()];
    let mut absorbed: Vec<(String, f64, &'static str)> = written
        .values
        .iter()
        .zip(&written.jacobian)
        .map(|(v, g)| {
            let moved: f64 = g.iter().zip(&t.free_shift).map(|(g, d)| g * d).sum();
            (v.name.clone(), -moved, v.unit)
        })
        .filter(|(_, d, _)| d.is_finite() && *d != 0.0)
        .collect();
    absorbed.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    absorbed.truncate(ABSORBED_LISTED);
    Ok(Some(FirmwareWarning::TiltAbsorbed {
        firmware: firmware.name(),
        slopes,
        p: t.p,
        share: t.share,
        absorbed,
        place: firmware.tilt_place(),
    }))
}

/// Height errors (mm) of every probe reading for the printer's parameters
/// `p` and the bed plane's `bed`: the predicted reading minus the probed
/// one.
pub fn probe_errors(
    mech: &Mech,
    measurement: &MeasurementModel,
    p: &Params,
    bed: &[f64],
    data: &[Measurement],
) -> Result<Vec<f64>> {
    use rayon::prelude::*;
    data.par_iter()
        .map(|m| {
            let pr = pkmcal::predict(mech, p, &m.commands, pkmcal::Model::Exact, &[])?;
            let mut y = [0.0];
            measurement.observe_point(&pr.x, bed, m.point.as_deref(), &mut y);
            Ok(y[0] - m.measured[0])
        })
        .collect()
}

/// The file a firmware command writes (`--out`): the firmware's lines
/// `updated` ([`Firmware::updated`]) with, for the firmwares whose
/// settings are G-code lines, a comment saying where they came from
/// (`source`, `probes` probe points; `physical`: the physical model's
/// values for the nozzle, its projection written, not the firmware's own
/// fit) and, for Marlin, how to keep them.
pub fn out_file(
    firmware: &dyn Firmware,
    updated: &str,
    source: &str,
    probes: usize,
    physical: bool,
) -> String {
    let version = env!("CARGO_PKG_VERSION");
    let how = if physical {
        format!(
            "for the nozzle over the build volume by pkmcal {version}, the physical model, from {source} ({probes} probe points)"
        )
    } else {
        format!("identified by pkmcal {version} from {source} ({probes} probe points)")
    };
    match firmware.flavour() {
        Flavour::RepRapFirmware => format!("; Delta parameters {how}\n{updated}"),
        Flavour::Marlin => format!(
            "; Marlin delta settings {how}\n{updated}; send M500 once to keep them in EEPROM (not in a start script)\n"
        ),
        Flavour::Klipper => updated.to_string(),
    }
}
