//! Files: paths from `str` or `os.PathLike`, inputs read as the command-line
//! tool reads them (size limits, typed errors), outputs staged and renamed
//! into place only when complete.

use crate::errors::{io_err, wrong_type};
use pyo3::prelude::*;

/// A path from a `str` or an `os.PathLike`.
pub fn path_arg(path: &Bound<'_, PyAny>) -> PyResult<String> {
    let p = if path.hasattr("__fspath__")? {
        path.call_method0("__fspath__")?
    } else {
        path.clone()
    };
    p.extract()
        .map_err(|_| wrong_type("path", "a path (str or os.PathLike)", path))
}

/// Outputs are staged and renamed into place only when complete
/// (`pkmcal_io::Files`): each call that writes is a run of its own, with its
/// own files, so calls from several threads never share a staging area.
pub fn written(write: impl FnOnce(&pkmcal_io::Run) -> pkmcal_io::Result<()>) -> PyResult<()> {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    // A failure drops `files`, which removes what it staged.
    write(&run).and_then(|()| files.commit()).map_err(io_err)
}

/// Refuse a call's planned outputs before any work, as the command line
/// refuses them (`pkmcal_io::Files::check`): each a new or regular file in
/// an existing directory (or in one of `dirs`, the directories the call
/// creates), none one of its `inputs` (through any path or link) nor
/// another output.
pub fn check_outputs(
    inputs: &[&std::path::Path],
    outputs: &[&std::path::Path],
    dirs: &[std::path::PathBuf],
) -> PyResult<()> {
    pkmcal_io::Files::new()
        .check(inputs, outputs, dirs)
        .map_err(io_err)
}

/// A run that only reads (no unit override, no progress display).
pub fn reading<T>(read: impl FnOnce(&pkmcal_io::Run) -> T) -> T {
    read(&pkmcal_io::Run::quiet(&pkmcal_io::Files::new()))
}

/// A run that reads calibration records. A record holds every pose (about
/// 600 bytes each on a planar linkage): it is read within a data file's
/// size limit, not a setting's, so that what `Calibration.save` wrote reads
/// back.
pub fn reading_records<T>(read: impl FnOnce(&pkmcal_io::Run) -> T) -> T {
    let files = pkmcal_io::Files::new().with_max_input_mb(Some(pkmcal_io::output::MAX_DATA_MB));
    read(&pkmcal_io::Run::quiet(&files))
}
