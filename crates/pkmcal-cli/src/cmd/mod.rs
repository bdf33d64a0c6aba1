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
