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
//! [`g33`] to compare).

pub mod g33;
pub mod klipper;
pub mod klipper_rotary;
pub mod marlin;
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

/// A printer's firmware configuration, read: what a front end calibrates.
pub trait Firmware {
    /// The firmware's name (`Klipper`, `RepRapFirmware`).
    fn name(&self) -> &'static str;

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
}

/// A printer's calibration request: the firmware's default free set in
/// place of the description's, the user's names, `fix` and the firmware's
/// own settings; checked against what the firmware can hold.
pub fn request<F: Firmware + ?Sized>(
    firmware: &F,
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
pub fn problem<F: Firmware + ?Sized>(firmware: &F, request: Request) -> Result<PrinterProblem> {
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

/// Calibrate `firmware`'s printer from its readings as `request` asks
/// (the firmware's default free set where it names none), from the
/// firmware's values; an error at a reading names it in the firmware's
/// terms.
pub fn calibrate<F: Firmware + ?Sized>(
    firmware: &F,
    request: Request,
) -> Result<PrinterCalibration> {
    let PrinterProblem {
        mech,
        readings,
        opts,
        free_names,
    } = problem(firmware, request)?;
    let nominal = Params::nominal(mech.spec());
    let free = opts.calibration.free.clone();
    let study = pkmcal::identify::study(
        &mech,
        &readings.measurement,
        &readings.poses,
        readings.distances.clone(),
        &nominal,
        &opts,
        &|| {},
    )
    .map_err(|e| match &e.error {
        pkmcal::Error::Pose { .. } => firmware.located(e.error),
        _ => Error::from(e.error),
    })?;
    Ok(PrinterCalibration {
        mech,
        readings,
        free_names,
        free,
        study,
    })
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
            measurement.observe(&pr.x, bed, &mut y);
            Ok(y[0] - m.measured[0])
        })
        .collect()
}
