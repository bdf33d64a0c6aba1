//! The file side's errors: typed, each carrying the file, line, row or pose
//! it is about as data, so that a front end words it in its own terms (the
//! command line names its options, Python its keywords) and reads a pose's
//! number from a field, not from a message. No message here names a
//! front end's option.

use pkmcal::{Field, RequestError};
use std::path::{Path, PathBuf};

/// What a file read whole is, for its size limit ([`crate::Files::read`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputKind {
    /// A description or setting: a mechanism, parameter, setup or units
    /// file, a calibration report, a firmware configuration.
    Description,
    /// Data read whole: a measurement CSV, a G-code program.
    Data,
}

impl InputKind {
    /// What such a file is, in words.
    pub fn noun(self) -> &'static str {
        match self {
            InputKind::Description => "description or setting",
            InputKind::Data => "data file",
        }
    }
}

/// What would let the rewrite read a line it refuses, for the front end
/// to word as its own option.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GcodeHint {
    /// The dialect (its name) that reads the line as written, if that
    /// firmware runs the program.
    Dialect(&'static str),
    /// Naming the firmware (a dialect other than strict).
    NameDialect,
    /// Giving the coordinate shift as the rewrite's offset.
    Offset,
    /// A longer segment (or none).
    MaxSegment,
}

/// What was being done to a file when it failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verb {
    /// Opening it.
    Open,
    /// Reading it.
    Read,
    /// Writing it.
    Write,
    /// Creating a directory.
    Create,
}

impl Verb {
    fn word(self) -> &'static str {
        match self {
            Verb::Open => "open",
            Verb::Read => "read",
            Verb::Write => "write",
            Verb::Create => "create",
        }
    }
}

/// Why a planned output cannot be written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OutputProblem {
    /// The path names a directory.
    NamesDirectory,
    /// The path is a symbolic link.
    Symlink,
    /// The path exists and is no regular file (a directory, a pipe, a
    /// device).
    NotRegular,
    /// An output directory's path exists and is no directory.
    NotADirectory,
    /// The output is also an input of the run.
    AlsoInput(PathBuf),
    /// Two outputs are the same file.
    SameAs(PathBuf),
    /// The file's directory does not exist (and the run does not create
    /// it).
    MissingDirectory(PathBuf),
    /// Another user's file in a sticky directory.
    OtherUsers,
    /// No file name.
    NoFileName,
}

/// Everything the file side can refuse or fail at.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file that cannot be opened, read or written.
    #[error("cannot {} {}{}: {cause}", verb.word(), if what.is_empty() { String::new() } else { format!("{what} ") }, path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done.
        verb: Verb,
        /// What kind of file it is (`"mechanism file"`), or empty.
        what: &'static str,
        /// The system's error.
        cause: std::io::Error,
    },
    /// A file read whole that is larger than its kind's size limit.
    #[error("cannot read {}: it is larger than {limit_mb} MiB, more than a {} should be; if it really is this large, raise the size limit", path.display(), kind.noun())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// The limit (MiB).
        limit_mb: u64,
        /// What kind of file it is.
        kind: InputKind,
    },
    /// A planned output that cannot be written.
    #[error("{}", output_words(path, problem))]
    Output {
        /// The output.
        path: PathBuf,
        /// Why.
        problem: OutputProblem,
    },
    /// What is wrong at a place in a file: its path, and the line where it
    /// is known.
    #[error("{}: {message}", place(path, *line))]
    At {
        /// The file.
        path: PathBuf,
        /// The line (from 1).
        line: Option<u64>,
        /// What is wrong and what to do.
        message: String,
    },
    /// What is wrong in a text whose file the context names
    /// ([`Error::In`]).
    #[error("{0}")]
    Content(String),
    /// A library error at a pose, or a distance between two poses, of a
    /// data file.
    #[error("{}: {} {pose}: {cause}", place(path, *line), if *distance { "distance" } else { "pose" })]
    Pose {
        /// The data file.
        path: PathBuf,
        /// Its line.
        line: Option<u64>,
        /// The pose's (or distance's) number in the file (from 1).
        pose: usize,
        /// Whether it is a distance between poses.
        distance: bool,
        /// What went wrong there.
        cause: Box<pkmcal::Error>,
    },
    /// A data file that reads only some of the tool's axes, without saying
    /// so (the front end's option that says which were measured fixes it).
    #[error("{}: missing column{} `{}`; if the instrument measured only {}, say which axes it measured", path.display(), if missing.len() > 1 { "s" } else { "" }, missing.join("`, `"), present.join(", "))]
    MissingAxes {
        /// The data file.
        path: PathBuf,
        /// The tool axes missing.
        missing: Vec<String>,
        /// Those present.
        present: Vec<String>,
    },
    /// Ball-bar readings without the sockets' positions.
    #[error("{} holds ball-bar distances (d1…); give the socket positions in a setup file (or a [ballbar] table in the mechanism file)", path.display())]
    NeedsSetup {
        /// The data file.
        path: PathBuf,
    },
    /// A data file whose command columns name actuators the mechanism does
    /// not have (data for another mechanism).
    #[error("{}: column(s) {} name actuators that `{mechanism}` does not have (its actuators are {}); is this file for another mechanism?", path.display(), columns.join(", "), actuators.join(", "))]
    ForeignCommands {
        /// The data file.
        path: PathBuf,
        /// The foreign columns.
        columns: Vec<String>,
        /// The mechanism's name.
        mechanism: String,
        /// Its actuators.
        actuators: Vec<String>,
    },
    /// Numbers that look like another unit than the one they are read in.
    #[error("{}: {message}; give the data-file units {key} = {value}", path.display())]
    Units {
        /// The data file.
        path: PathBuf,
        /// What was seen.
        message: String,
        /// The units key (`length`, `angle`).
        key: &'static str,
        /// The unit that fits (`m`, `deg`).
        value: &'static str,
    },
    /// A file that is not a calibration record.
    #[error(
        "{source_name}: no `covariance` entry; give a calibration record (what a calibration writes as its report)"
    )]
    NotARecord {
        /// The file (or what the record was read from).
        source_name: String,
    },
    /// A G-code line the rewrite cannot follow as its firmware reads it.
    #[error("{}:{line}: {message}{}", path.display(), gcode_hint(*hint))]
    Gcode {
        /// The program.
        path: PathBuf,
        /// The line.
        line: u64,
        /// What is wrong and what to do.
        message: String,
        /// What else would let the line be read.
        hint: Option<GcodeHint>,
    },
    /// A user's choice refused, about a file where `file` is given.
    #[error("{}{cause}", file.as_ref().map(|f| format!("{}: ", f.display())).unwrap_or_default())]
    Request {
        /// The file the choice was about, if any.
        file: Option<PathBuf>,
        /// The refusal.
        cause: RequestError,
    },
    /// The library refused something.
    #[error(transparent)]
    Library(Box<pkmcal::Error>),
    /// An error in a context (which file, which part of it).
    #[error("{context}: {cause}")]
    In {
        /// Where.
        context: String,
        /// What.
        cause: Box<Error>,
    },
}

impl From<pkmcal::Error> for Error {
    fn from(e: pkmcal::Error) -> Self {
        Error::Library(Box::new(e))
    }
}

impl From<RequestError> for Error {
    fn from(cause: RequestError) -> Self {
        Error::Request { file: None, cause }
    }
}

/// The file side's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// `path:line`, or `path` alone.
fn place(path: &Path, line: Option<u64>) -> String {
    match line {
        Some(l) => format!("{}:{l}", path.display()),
        None => path.display().to_string(),
    }
}

fn gcode_hint(h: Option<GcodeHint>) -> String {
    use GcodeHint as H;
    match h {
        None => String::new(),
        Some(H::Dialect(d)) => {
            format!(" (or read it in the {d} dialect if that firmware runs the program)")
        }
        Some(H::NameDialect) => ", or name the firmware's dialect".into(),
        Some(H::Offset) => " or give the shift as the offset".into(),
        Some(H::MaxSegment) => "; use longer segments".into(),
    }
}

fn output_words(path: &Path, problem: &OutputProblem) -> String {
    let p = path.display();
    match problem {
        OutputProblem::NamesDirectory => {
            format!("{p} names a directory; give the path of a file")
        }
        OutputProblem::Symlink => {
            format!("{p} is a symbolic link; give the path of the file itself")
        }
        OutputProblem::NotRegular => format!(
            "{p} exists and is not a regular file (a directory, a pipe or a device); give a file path"
        ),
        OutputProblem::NotADirectory => {
            format!("{p} exists and is not a directory; give a directory path")
        }
        OutputProblem::AlsoInput(i) => format!(
            "{p} is also an input ({}); write the output to another file",
            i.display()
        ),
        OutputProblem::SameAs(o) => format!(
            "{} and {p} are the same file; give each output its own path",
            o.display()
        ),
        OutputProblem::MissingDirectory(d) => format!(
            "cannot write {p}: the directory {} does not exist; create it first (an output file's folder must exist, as for `cp`; only output directories are created with their parents)",
            d.display()
        ),
        OutputProblem::OtherUsers => format!(
            "cannot write {p}: it belongs to another user in a directory that keeps each user's files (sticky); no output was written"
        ),
        OutputProblem::NoFileName => format!("{p} is not a file name"),
    }
}

impl Error {
    /// `message` at `path` (and `line`).
    pub fn at(path: &Path, line: Option<u64>, message: impl Into<String>) -> Self {
        Error::At {
            path: path.to_path_buf(),
            line,
            message: message.into(),
        }
    }

    /// An I/O failure on `path`.
    pub fn io(path: &Path, verb: Verb, cause: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            verb,
            what: "",
            cause,
        }
    }

    /// The same error, saying what kind of file failed to be read
    /// (`"mechanism file"`): "cannot read mechanism file m.toml: …".
    pub fn named(self, kind: &'static str) -> Self {
        match self {
            Error::Io {
                path,
                verb: Verb::Open | Verb::Read,
                cause,
                ..
            } => Error::Io {
                path,
                verb: Verb::Read,
                what: kind,
                cause,
            },
            e => e,
        }
    }

    /// This error in a context (`"in mechanism file m.toml"`).
    pub fn context(self, context: impl Into<String>) -> Self {
        Error::In {
            context: context.into(),
            cause: Box::new(self),
        }
    }

    /// A library error located in the data file `path` when it names one of
    /// its poses ([`pkmcal::Error::Pose`]); in that file's context
    /// otherwise.
    pub fn located(e: pkmcal::Error, path: &Path) -> Self {
        match e {
            pkmcal::Error::Pose {
                pose,
                line,
                distance,
                source,
            } => Error::Pose {
                path: path.to_path_buf(),
                line,
                pose,
                distance,
                cause: source,
            },
            e => Error::from(e).context(format!("calibrating from {}", path.display())),
        }
    }

    /// The innermost error of an [`Error::In`] chain.
    pub fn innermost(&self) -> &Error {
        match self {
            Error::In { cause, .. } => cause.innermost(),
            e => e,
        }
    }

    /// The pose this error is about, if any: its number and whether it is a
    /// distance between poses.
    pub fn pose(&self) -> Option<(usize, bool)> {
        match self.innermost() {
            Error::Pose { pose, distance, .. } => Some((*pose, *distance)),
            Error::Library(e) => match e.as_ref() {
                pkmcal::Error::Pose { pose, distance, .. } => Some((*pose, *distance)),
                _ => None,
            },
            _ => None,
        }
    }

    /// The user's choice this error refuses, if it is one.
    pub fn field(&self) -> Option<Field> {
        match self.innermost() {
            Error::Request { cause, .. } => cause.field(),
            _ => None,
        }
    }

    /// Whether a user's request (a choice, an output path) was refused,
    /// rather than a file's content or the machine: a front end's usage
    /// error.
    pub fn is_usage(&self) -> bool {
        match self.innermost() {
            Error::Request { .. } | Error::Output { .. } => true,
            Error::Library(e) => matches!(e.as_ref(), pkmcal::Error::Request(_)),
            _ => false,
        }
    }

    /// The system's error of an [`Error::Io`], if this is one.
    pub fn io_error(&self) -> Option<&std::io::Error> {
        match self.innermost() {
            Error::Io { cause, .. } => Some(cause),
            _ => None,
        }
    }
}

/// Context for results (`.within("in parameter file p.toml")`).
pub trait Within<T> {
    /// The error in a context.
    fn within(self, context: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: Into<Error>> Within<T> for std::result::Result<T, E> {
    fn within(self, context: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| e.into().context(context()))
    }
}

/// `return Err(Error::Content(..))` with a formatted message.
#[macro_export]
macro_rules! invalid {
    ($($t:tt)*) => {
        return Err($crate::error::Error::Content(format!($($t)*)))
    };
}

/// `return Err(Error::At { .. })`: a formatted message at a file (a path or
/// a path buffer) and an optional line.
#[macro_export]
macro_rules! refuse {
    ($path:expr, $line:expr, $($t:tt)*) => {
        return Err($crate::error::Error::at(
            ::std::convert::AsRef::<::std::path::Path>::as_ref(&$path),
            $line,
            format!($($t)*),
        ))
    };
}
