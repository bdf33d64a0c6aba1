//! One module per command: its arguments (clap), the files it declares, and
//! its run.

pub mod analyze;
pub mod budget;
pub mod calibrate;
pub mod compensate;
pub mod demo;
pub mod drift;
pub mod gcode;
pub mod klipper;
pub mod marlin;
pub mod montecarlo;
pub mod parameters;
pub mod physical;
pub mod physical_outputs;
pub mod plan;
pub mod predict;
pub mod reprap;
pub mod simulate;
pub mod trilaterate;

/// A refused request; a fault of the mechanism file's `[tolerances]`
/// table is located in that file.
pub fn in_mechanism(
    e: pkmcal::RequestError,
    d: &pkmcal_io::description::Description,
) -> pkmcal_io::Error {
    match e {
        e @ pkmcal::RequestError::ToleranceTable(_) => pkmcal_io::Error::Request {
            file: d.path.clone(),
            cause: e,
        },
        e => e.into(),
    }
}

/// A note for the parameters a request names by their old names.
pub fn note_renamed(run: &pkmcal_io::Run<'_>, spec: &pkmcal::Spec, request: &pkmcal::Request) {
    let renamed = request.renamed(spec);
    if !renamed.is_empty() {
        run.note(pkmcal_io::Note::Renamed {
            place: "the options given".into(),
            renamed,
        });
    }
}

/// A printer's written values with their σ, as a table headed `what`.
pub fn print_written(
    printer: &dyn pkmcal_io::firmware::Firmware,
    calibrated: &pkmcal_io::firmware::PrinterCalibration,
    what: &str,
) -> anyhow::Result<pkmcal_io::firmware::Written> {
    let written = pkmcal_io::firmware::written(printer, calibrated)?;
    print_values(what, &written.values);
    Ok(written)
}

/// A firmware's values before and after, with their σ, as a table.
pub fn print_values(what: &str, values: &[pkmcal_io::firmware::FirmwareValue]) {
    say!(
        "\n  {:<28} {:>14} {:>14} {:>14}",
        what,
        "before",
        "after",
        "σ"
    );
    for v in values {
        let sigma = match v.sigma_shown() {
            pkmcal_io::firmware::Sigma::Known(s) => format!("{s:.4} {}", v.unit),
            pkmcal_io::firmware::Sigma::Unknown => "unknown".into(),
            pkmcal_io::firmware::Sigma::Fixed => "fixed".into(),
        };
        say!(
            "  {:<28} {:>14.6} {:>14.6} {:>14}",
            v.name,
            v.before,
            v.after,
            sigma
        );
    }
}

/// The checks of a printer's written values and of its fit
/// ([`pkmcal_io::firmware::checks`]), worded.
pub fn print_checks(
    printer: &dyn pkmcal_io::firmware::Firmware,
    calibrated: &pkmcal_io::firmware::PrinterCalibration,
    written: &pkmcal_io::firmware::Written,
    max_sigma: f64,
) -> anyhow::Result<()> {
    for w in pkmcal_io::firmware::checks(printer, calibrated, written, max_sigma)? {
        let (message, hint) = crate::words::firmware_warning(&w);
        say!("warning: {message}\n  hint: {hint}");
    }
    Ok(())
}
