//! G-code programs: rewrite the `G0`/`G1` moves through a Cartesian
//! pre-distortion (the caller's, [`pkmcal::predistort`] for a calibration),
//! so that a controller that runs its own (nominal) kinematics makes the
//! calibrated machine reach the programmed points.
//!
//! Tool axes map to words: `x y z` → `X Y Z`, `rx ry rz` → `A B C`, a planar
//! tool's `phi` → `C`; lengths in mm (`G21`, or inches after `G20`), angles
//! in degrees (the G-code convention). Supported: `G90`/`G91` (absolute or
//! relative), `G20`/`G21`, `M82`/`M83` and `G92 E` (extrusion, split with
//! the segments), `;` comments, line numbers and checksums (checked, and
//! written anew). `G28` (homing) forgets the position until the next move
//! gives every axis again. Every line that is not a move of a tool axis is
//! written back byte for byte, its line end included.
//!
//! Each line is read as the firmware named by [`Dialect`] reads it (its own
//! parser: Klipper's `gcode.py`, RepRapFirmware's `StringParser`, Marlin's
//! `FASTER_GCODE_PARSER`): a word given twice, numbers (`X1e1`, `X0X10`),
//! several commands on a line, `(…)`, lower case, lines without a command
//! word; RepRapFirmware's machine mode (`M451`/`M452`/`M453`) followed. What
//! that firmware would read differently from what the rewrite assumes is
//! refused with its line, never guessed: arcs (`G2`/`G3`), `G92` on a tool
//! axis, `G53` with a move, a wrong checksum, two commands on one line.

use crate::error::{Error, Result};
use pkmcal::{Field, RequestError};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// The firmware whose reading of G-code the rewrite follows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Dialect {
    /// Only what Klipper, RepRapFirmware and Marlin (as shipped) all read
    /// the same way; the rest refused.
    #[default]
    Strict,
    /// Klipper: `;` comments; a line with a `(` on a move is refused by
    /// Klipper itself; lower case read; the last of a word given twice read;
    /// a line must start with its command.
    Klipper,
    /// RepRapFirmware: the first of a word given twice read; lower case
    /// read; in CNC or laser mode (`M453`, `M452` in the program) `(…)`
    /// comments are skipped wherever they stand (the words on both sides are
    /// read) and a line without a command continues the last `G0`/`G1`.
    RepRap,
    /// Marlin as shipped: `(` is not a comment (only with `PAREN_COMMENTS`),
    /// lower case is not read (only with `GCODE_CASE_INSENSITIVE`), a line
    /// must start with its command (unless `GCODE_MOTION_MODES`), a line
    /// number must be followed by a space, the last of a word given twice is
    /// read.
    Marlin,
}

impl Dialect {
    /// Every dialect.
    pub const ALL: [Dialect; 4] = [
        Dialect::Strict,
        Dialect::Klipper,
        Dialect::RepRap,
        Dialect::Marlin,
    ];
    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Dialect::Strict => "strict",
            Dialect::Klipper => "klipper",
            Dialect::RepRap => "reprap",
            Dialect::Marlin => "marlin",
        }
    }
    /// The dialect of a name.
    pub fn from_name(s: &str) -> Option<Dialect> {
        Dialect::ALL.into_iter().find(|d| d.name() == s)
    }
}

pub use crate::error::GcodeHint;

/// How a program is rewritten.
#[derive(Debug, Clone, Default)]
pub struct Rewrite {
    /// The firmware whose reading of the words is followed.
    pub dialect: Dialect,
    /// Programmed minus tool coordinates, one value per tool axis (mm, and
    /// degrees for angles); empty for none.
    pub offset: Vec<f64>,
    /// Moves longer than this (mm) are cut into pieces, each pre-distorted.
    pub max_segment: Option<f64>,
}

impl Rewrite {
    /// The settings checked against a tool of `axes`.
    fn check(&self, axes: &[String]) -> std::result::Result<(), RequestError> {
        let nx = axes.len();
        if !self.offset.is_empty() && self.offset.len() != nx {
            return Err(RequestError::invalid(
                Field::Offset,
                format!(
                    "needs {nx} values (mm, and degrees for angles: {}), got {}",
                    axes.join(", "),
                    self.offset.len()
                ),
            ));
        }
        if let Some(v) = self
            .offset
            .iter()
            .find(|v| !(v.is_finite() && v.abs() <= MAX_OFFSET))
        {
            return Err(RequestError::invalid(
                Field::Offset,
                format!(
                    "{v:?} is beyond ±{MAX_OFFSET:e} (mm or degrees); no machine moves that far"
                ),
            ));
        }
        if let Some(m) = self.max_segment
            && !(m.is_finite() && (MIN_SEGMENT..=MAX_SEGMENT).contains(&m))
        {
            return Err(RequestError::invalid(
                Field::MaxSegment,
                format!("{m:?} must be a length between {MIN_SEGMENT:e} and {MAX_SEGMENT:e} mm"),
            ));
        }
        Ok(())
    }
}

/// The largest offset a rewrite takes (mm or degrees).
pub const MAX_OFFSET: f64 = 1e6;
/// The shortest segment a rewrite cuts moves into (mm): 0.1 µm.
pub const MIN_SEGMENT: f64 = 1e-4;
/// The longest segment length that means anything (mm).
pub const MAX_SEGMENT: f64 = 1e6;

/// A rewritten program and what was done.
#[derive(Debug, Clone)]
pub struct Rewritten {
    /// The program.
    pub bytes: Vec<u8>,
    /// Moves rewritten.
    pub moves: usize,
    /// Pre-distorted moves written (pieces of the moves).
    pub segments: usize,
    /// The largest shift of a target (mm).
    pub worst: f64,
    /// Lines of moves sent as written (some axis's position not known).
    pub as_written: Vec<usize>,
}

/// The G-code word of a tool axis.
fn word_of(axis: &str) -> Option<char> {
    match axis {
        "x" => Some('X'),
        "y" => Some('Y'),
        "z" => Some('Z'),
        "rx" => Some('A'),
        "ry" => Some('B'),
        "rz" | "phi" => Some('C'),
        _ => None,
    }
}

/// One line of the rewritten program, in order.
enum Item {
    /// A line kept as it is (index of its first byte, and its end, line end
    /// included, in the program).
    Raw(usize, usize),
    /// A move sent as written (some axis's position not known yet): the
    /// line, and the positions it sends (axis, G-code units).
    AsWritten(usize, usize, Vec<(usize, f64)>),
    /// `G28`: the position sent is unknown again.
    Reset,
    /// A pre-distorted piece of a move (index into the pieces).
    Piece(usize),
}

/// A piece of a move: its target and how to write it.
struct Piece {
    line_no: usize,
    piece: usize,
    pieces: usize,
    /// Tool coordinates (mm, rad).
    target: Vec<f64>,
    absolute: bool,
    scale: f64,
    /// The line number word (`N10`), on a move not split.
    number: Option<String>,
    checksum: bool,
    g: String,
    e_text: Option<String>,
    others: Vec<String>,
    comment: Vec<u8>,
    /// The line end of the source line (`\n`, `\r\n`, or none at the end of
    /// the file; pieces before the last end in `\n` then).
    eol: &'static str,
}

/// Most pieces one move is split into (`--max-segment`).
const MAX_PIECES: usize = 100_000;
/// Most pieces a whole program is split into (each is kept until the
/// program is written: about 200 bytes a piece).
const MAX_TOTAL_PIECES: usize = 2_000_000;

/// Digits written for lengths (mm: 0.1 µm) and angles (degrees).
const LENGTH_DECIMALS: usize = 4;
const ANGLE_DECIMALS: usize = 6;

/// A line the rewrite follows: a move, or a change of mode.
#[derive(Debug, PartialEq)]
#[doc(hidden)] // public for the integration tests only
pub struct Code {
    /// `N10`, as written (upper case).
    #[doc(hidden)] // public for the integration tests only
    pub number: Option<String>,
    /// A checksum (`*71`) was given: one is written anew.
    #[doc(hidden)] // public for the integration tests only
    pub checksum: bool,
    /// The command's letter and number (`('G', 1)`); `None` for a line that
    /// continues the last `G0`/`G1` (RepRapFirmware).
    #[doc(hidden)] // public for the integration tests only
    pub command: Option<(char, u32)>,
    /// The words after the command: letter (upper case) and number text.
    #[doc(hidden)] // public for the integration tests only
    pub words: Vec<(char, String)>,
    /// The comments, `(…)` ones first, then the `;` one: written after the
    /// words.
    #[doc(hidden)] // public for the integration tests only
    pub comment: Vec<u8>,
}

/// How a line is read.
#[derive(Debug, PartialEq)]
#[doc(hidden)] // public for the integration tests only
pub enum Parsed {
    /// Written back as it is: blank, a comment, a command that neither moves
    /// nor changes a mode the rewrite follows (`M104`, `T0`, Klipper's
    /// `EXCLUDE_OBJECT_START NAME=…`, `M117 text`).
    Raw,
    Code(Code),
}

/// The commands the rewrite follows: moves and the modes they depend on,
/// and RepRapFirmware's machine modes (`M451` 3D printer, `M452` laser,
/// `M453` CNC), which decide how it reads `(` and a line without a command.
fn followed(letter: char, n: u32) -> bool {
    matches!(
        (letter, n),
        ('G', 0 | 1 | 2 | 3 | 20 | 21 | 28 | 90 | 91 | 92) | ('M', 82 | 83 | 451 | 452 | 453)
    )
}

/// The M commands whose text runs to the end of the line (a file name, a
/// message: RepRapFirmware's `GetUnprecedentedString`, Marlin's and
/// Klipper's `M117`), where a `G` or `M` starts no command.
const TEXT_COMMANDS: [u32; 10] = [20, 23, 28, 30, 32, 36, 37, 38, 117, 118];

/// The letters whose values the rewrite reads: the tool axes' words and
/// the extruder's.
const VALUE_LETTERS: [char; 7] = ['X', 'Y', 'Z', 'A', 'B', 'C', 'E'];

/// A command word's number: digits only (`G01` is `G1`; `G29.1`, `M486 T`
/// are other commands).
fn code_number(s: &[u8]) -> Option<(u32, usize)> {
    let n = s.iter().take_while(|b| b.is_ascii_digit()).count();
    if n == 0 || n > 6 || s.get(n) == Some(&b'.') {
        return None;
    }
    let v: u32 = std::str::from_utf8(&s[..n]).ok()?.parse().ok()?;
    Some((v, n))
}

fn trim_start(s: &[u8]) -> &[u8] {
    let k = s.iter().take_while(|b| b.is_ascii_whitespace()).count();
    &s[k..]
}

/// A line refused: what is wrong, and what would let it be read.
#[derive(Debug, PartialEq)]
#[doc(hidden)] // public for the integration tests only
pub struct Refused(pub String, pub Option<GcodeHint>);

impl From<String> for Refused {
    fn from(m: String) -> Self {
        Refused(m, None)
    }
}

/// RepRapFirmware's machine mode, as the program sets it (`M451`, `M452`,
/// `M453`); unknown until it does (the configuration sets it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    /// Not set by the program.
    #[default]
    Unknown,
    /// `M451`: a 3D printer (`(` is a character, a line needs a command).
    Printer,
    /// `M452`/`M453`: a laser or a CNC machine (`(…)` comments, a line
    /// without a command continues the last `G0`/`G1`).
    Cnc,
}

/// The words of a followed line as one firmware reads them: each value
/// letter once, with the value the firmware takes (or why it takes none),
/// and every other word as written.
#[derive(Debug, Clone, PartialEq, Default)]
struct Read {
    values: Vec<(char, std::result::Result<f64, String>)>,
    others: Vec<String>,
}

impl Read {
    fn set(&mut self, letter: char, v: std::result::Result<f64, String>, first: bool) {
        match self.values.iter_mut().find(|(l, _)| *l == letter) {
            Some(slot) if !first => slot.1 = v,
            Some(_) => {}
            None => self.values.push((letter, v)),
        }
    }
}

/// Python's `float()` of a stripped text with no letters in it (what
/// Klipper's `float(params[…])` takes): `[+-]` digits with a point.
fn python_float(t: &str) -> Option<f64> {
    let b = t.as_bytes();
    let body = b
        .strip_prefix(b"+")
        .or_else(|| b.strip_prefix(b"-"))
        .unwrap_or(b);
    let digits = body.iter().filter(|c| c.is_ascii_digit()).count();
    let points = body.iter().filter(|c| **c == b'.').count();
    if digits == 0 || points > 1 || digits + points != body.len() {
        return None;
    }
    t.parse().ok()
}

/// Klipper's reading (`gcode.py`): the line upper-cased and split at runs
/// of letters and `_` (or a `*`), each key given its text up to the next
/// key, the last of a key kept; values by Python's `float()`. So `X1e1` is
/// X1 and E1, and `X0x10` is X10.
fn read_klipper(body: &str) -> Read {
    let b = body.as_bytes();
    let key = |c: u8| c.is_ascii_alphabetic() || c == b'_';
    let mut read = Read::default();
    let mut i = 0;
    // Text before the first key belongs to the command.
    while i < b.len() && !(key(b[i]) || b[i] == b'*') {
        i += 1;
    }
    while i < b.len() {
        let start = i;
        if b[i] == b'*' {
            i += 1;
        } else {
            while i < b.len() && key(b[i]) {
                i += 1;
            }
        }
        let name = body[start..i].to_ascii_uppercase();
        let vstart = i;
        while i < b.len() && !(key(b[i]) || b[i] == b'*') {
            i += 1;
        }
        let value = body[vstart..i].trim();
        let letter = name.chars().next().filter(|_| name.len() == 1);
        match letter.filter(|l| VALUE_LETTERS.contains(l)) {
            Some(l) => read.set(
                l,
                python_float(value).ok_or_else(|| {
                    format!("Klipper cannot read `{name}{value}` as a number and refuses the move")
                }),
                false,
            ),
            None => read.others.push(body[start..i].trim().to_string()),
        }
    }
    read
}

/// The number `SafeStrtod` reads at the start of `s` (RepRapFirmware):
/// spaces, a sign, digits, a point, digits, an exponent (taken even without
/// digits: an exponent of 0); its value and length, or `None` without a
/// digit. The one reading of RepRapFirmware's numbers: G-code moves and
/// `config.g`'s parameters ([`crate::firmware::reprap`]).
pub(crate) fn safe_strtod(s: &str) -> Option<(f64, usize)> {
    let b = s.as_bytes();
    let mut i = 0;
    while matches!(b.get(i), Some(b' ' | b'\t')) {
        i += 1;
    }
    let start = i;
    if matches!(b.get(i), Some(b'-' | b'+')) {
        i += 1;
    }
    let mut digits = 0;
    while b.get(i).is_some_and(u8::is_ascii_digit) {
        i += 1;
        digits += 1;
    }
    if b.get(i) == Some(&b'.') {
        i += 1;
        while b.get(i).is_some_and(u8::is_ascii_digit) {
            i += 1;
            digits += 1;
        }
    }
    if digits == 0 {
        return None;
    }
    let mantissa = &s[start..i];
    let mut exp = String::new();
    if matches!(b.get(i), Some(b'e' | b'E')) {
        i += 1;
        if let Some(&c @ (b'-' | b'+')) = b.get(i) {
            exp.push(c as char);
            i += 1;
        }
        while let Some(&c) = b.get(i).filter(|c| c.is_ascii_digit()) {
            exp.push(c as char);
            i += 1;
        }
    }
    let exp = if exp.trim_start_matches(['+', '-']).is_empty() {
        "0".to_string()
    } else {
        exp
    };
    let v: f64 = format!("{mantissa}e{exp}").parse().ok()?;
    Some((v, i))
}

/// RepRapFirmware's reading (its `StringParser`): a parameter starts at
/// each letter (either case; an `E` right after a digit is an exponent), the
/// first of a letter is the one read (`Seen`), its value by `SafeStrtod`.
/// So `X1e1` is X10, and `X0x10` is X0.
fn read_reprap(body: &str) -> std::result::Result<Read, String> {
    if let Some(c) = body.chars().find(|c| matches!(c, '{' | '"' | '\'')) {
        return Err(format!(
            "`{c}` on a move: RepRapFirmware reads an expression or a string there, which the rewrite does not evaluate; write the numbers"
        ));
    }
    let b = body.as_bytes();
    let starts: Vec<usize> = (0..b.len())
        .filter(|&k| {
            b[k].is_ascii_alphabetic()
                && !(matches!(b[k], b'e' | b'E') && k > 0 && b[k - 1].is_ascii_digit())
        })
        .collect();
    let mut read = Read::default();
    for (n, &k) in starts.iter().enumerate() {
        let end = starts.get(n + 1).copied().unwrap_or(b.len());
        let letter = (b[k] as char).to_ascii_uppercase();
        let word = body[k..end].trim();
        if !VALUE_LETTERS.contains(&letter) {
            read.others.push(word.to_string());
            continue;
        }
        let text = &body[k + 1..end];
        let v = match safe_strtod(text) {
            None => Err(format!(
                "RepRapFirmware finds no number after `{letter}` in `{word}` and refuses the move"
            )),
            Some((x, len)) if !text[len..].trim().is_empty() => Err(format!(
                "RepRapFirmware reads `{word}` as {letter}{x} and ignores `{}`; write the number as meant",
                text[len..].trim()
            )),
            Some((x, _)) => Ok(x),
        };
        read.set(letter, v, true);
    }
    Ok(read)
}

/// Marlin's reading as shipped (`FASTER_GCODE_PARSER`): a parameter at
/// each upper-case letter, its value the characters `0-9 . + -` after it
/// (spaces skipped), read by `strtof`; the last of a letter kept. So `X1E1`
/// is X1 and E1, and `X0X10` is X10.
fn read_marlin(body: &str) -> Read {
    let b = body.as_bytes();
    let mut read = Read::default();
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        i += 1;
        if !c.is_ascii_uppercase() {
            continue;
        }
        let start = i - 1;
        while b.get(i) == Some(&b' ') {
            i += 1;
        }
        let vstart = i;
        while b
            .get(i)
            .is_some_and(|c| c.is_ascii_digit() || matches!(c, b'.' | b'+' | b'-'))
        {
            i += 1;
        }
        let text = &body[vstart..i];
        let word = body[start..i].trim();
        let letter = c as char;
        if !VALUE_LETTERS.contains(&letter) {
            read.others.push(word.to_string());
            continue;
        }
        // `valid_float`: a sign, a point, then a digit.
        let t = text.trim_start_matches(['+', '-']);
        let valid = t.starts_with(|c: char| c.is_ascii_digit())
            || (t.starts_with('.') && t[1..].starts_with(|c: char| c.is_ascii_digit()));
        let valid = valid && text.len() - t.len() <= 1;
        let v = if !valid {
            Err(format!(
                "Marlin finds no number after `{letter}` in `{word}` and does not move that axis"
            ))
        } else if matches!(t, "0") && b.get(i) == Some(&b'X') {
            Err(format!(
                "`{word}X…`: some Marlin builds read `0X…` as a hexadecimal number; write each word with its own number"
            ))
        } else {
            match python_float(text) {
                Some(x) => Ok(x),
                None => {
                    let x = text
                        .char_indices()
                        .rev()
                        .find_map(|(k, _)| python_float(&text[..k]))
                        .unwrap_or(0.0);
                    Err(format!(
                        "Marlin reads `{word}` as {letter}{x} and ignores the rest; write the number as meant"
                    ))
                }
            }
        };
        read.set(letter, v, false);
    }
    read
}

/// Where the G and M commands after the first on a line start, as
/// RepRapFirmware splits it: a `G` or `M` outside quotes and braces and not
/// after `'` (`body`: the line after its first command's letter). The one
/// rule the G-code reader and config.g's reader split lines by.
pub(crate) fn later_command_starts(body: &[u8]) -> Vec<usize> {
    let (mut quoted, mut escaped, mut braces) = (false, false, 0usize);
    let mut out = vec![];
    for (k, &c) in body.iter().enumerate() {
        if c == b'\'' {
            escaped = !quoted;
            continue;
        }
        if c == b'"' {
            quoted = !quoted;
        } else if !quoted {
            if c == b'{' {
                braces += 1;
            } else if braces > 0 {
                if c == b'}' {
                    braces -= 1;
                }
            } else if !escaped && matches!(c.to_ascii_uppercase(), b'G' | b'M') {
                out.push(k);
            }
        }
        escaped = false;
    }
    out
}

/// The G and M commands after the first on a line as RepRapFirmware splits
/// it ([`later_command_starts`]), with their numbers.
fn later_commands(body: &[u8]) -> Vec<(char, Option<u32>)> {
    later_command_starts(body)
        .into_iter()
        .map(|k| {
            (
                (body[k] as char).to_ascii_uppercase(),
                code_number(&body[k + 1..]).map(|(n, _)| n),
            )
        })
        .collect()
}

/// Read one line (without its line end) as `dialect` reads it, in the
/// RepRapFirmware machine `mode` the program has set.
#[doc(hidden)] // public for the integration tests only
pub fn parse(line: &[u8], dialect: Dialect, mode: Mode) -> std::result::Result<Parsed, Refused> {
    use Dialect::*;
    let (code, semi) = match line.iter().position(|&b| b == b';') {
        Some(i) => (&line[..i], &line[i..]),
        None => (line, &line[line.len()..]),
    };
    // `(…)` comments (RepRapFirmware in CNC or laser mode): cut out (each
    // leaves a space), kept for the end.
    let cnc = dialect == RepRap && mode == Mode::Cnc;
    let mut parens: Vec<u8> = vec![];
    let mut bare: Vec<u8> = Vec::with_capacity(code.len());
    let mut i = 0;
    while i < code.len() {
        if code[i] == b'(' {
            let end = code[i..]
                .iter()
                .position(|&b| b == b')')
                .map_or(code.len(), |k| i + k + 1);
            if !parens.is_empty() {
                parens.push(b' ');
            }
            parens.extend_from_slice(&code[i..end]);
            bare.push(b' ');
            i = end;
        } else {
            bare.push(code[i]);
            i += 1;
        }
    }
    // A `(` where the firmware does not read a comment: refused on a line
    // that would be followed if it were one (`(go) G1 X5` too, on which
    // the firmwares would not move).
    let shown = || String::from_utf8_lossy(line).trim().to_string();
    if code.contains(&b'(') && !cnc && !matches!(parse(line, RepRap, Mode::Cnc), Ok(Parsed::Raw)) {
        return Err(Refused(
            format!(
                "a (comment) on `{}`: {}; use a `;` comment at the end of the line",
                shown(),
                match dialect {
                    Klipper => "Klipper refuses the line".to_string(),
                    Marlin =>
                        "Marlin reads its letters as words unless built with PAREN_COMMENTS".into(),
                    RepRap => "RepRapFirmware skips it only in CNC or laser mode (M453, M452), and reads its letters as words in 3D printer mode (or put M453 or M452 at the start of the program if the machine runs in that mode)".into(),
                    Strict =>
                        "Klipper refuses such a line, Marlin reads its letters as words unless built with PAREN_COMMENTS, RepRapFirmware skips it only in CNC mode".into(),
                },
            ),
            (dialect == Strict).then_some(GcodeHint::NameDialect),
        ));
    }
    let s = trim_start(if cnc { &bare } else { code });
    // A line number.
    let mut number: Option<(u8, String)> = None;
    let mut glued = false;
    let mut s = s;
    if matches!(s.first(), Some(b'N' | b'n'))
        && s.get(1).is_some_and(|b| b.is_ascii_digit() || *b == b'-')
    {
        let n = 1 + s[1..]
            .iter()
            .enumerate()
            .take_while(|(k, b)| b.is_ascii_digit() || (*k == 0 && **b == b'-'))
            .count();
        number = Some((s[0], String::from_utf8_lossy(&s[..n]).to_uppercase()));
        let rest = &s[n..];
        // Marlin skips a line number up to the next space.
        glued = !rest.is_empty() && !rest[0].is_ascii_whitespace();
        s = trim_start(rest);
    }
    // The command word.
    let Some(&first) = s.first() else {
        return Ok(Parsed::Raw);
    };
    let letter = (first as char).to_ascii_uppercase();
    if !first.is_ascii_alphabetic() {
        return Ok(Parsed::Raw);
    }
    let code_at = code_number(trim_start(&s[1..]));
    // `G53`: the command after it on the line moves in machine coordinates
    // (RepRapFirmware; Marlin with CNC_COORDINATE_SYSTEMS), or not at all
    // (Klipper, and Marlin as shipped: an unknown command).
    if letter == 'G'
        && code_at.is_some_and(|(n, _)| n == 53)
        && later_commands(&s[1..]).iter().any(|(_, n)| n.is_some())
    {
        return Err(format!(
            "`{}`: G53 with a move on its line moves in machine coordinates in RepRapFirmware (and Marlin built with CNC_COORDINATE_SYSTEMS), whose offset from the program's the rewrite does not know, and not at all in Klipper (an unknown command); write the move without G53, in the program's coordinates",
            shown()
        )
        .into());
    }
    let command = match code_at {
        Some((n, _)) if matches!(letter, 'G' | 'M') => {
            if !followed(letter, n) {
                // RepRapFirmware runs every command of a line: a move after
                // another command moves.
                if dialect != Klipper
                    && dialect != Marlin
                    && !(letter == 'M' && TEXT_COMMANDS.contains(&n))
                    && let Some((l, n)) = later_commands(&s[1..])
                        .into_iter()
                        .find(|(l, n)| n.is_some_and(|n| followed(*l, n)))
                {
                    return Err(format!(
                        "`{}`: RepRapFirmware runs the {l}{} on this line after the first command (Klipper and Marlin do not); put each command on its own line",
                        shown(),
                        n.unwrap_or(0)
                    )
                    .into());
                }
                return Ok(Parsed::Raw);
            }
            Some((letter, n))
        }
        Some(_) | None
            if matches!(letter, 'X' | 'Y' | 'Z' | 'A' | 'B' | 'C' | 'E' | 'F')
                && trim_start(&s[1..])
                    .first()
                    .is_some_and(|b| b.is_ascii_digit() || matches!(b, b'-' | b'+' | b'.')) =>
        {
            // A line without a command: a modal move.
            None
        }
        _ => return Ok(Parsed::Raw),
    };
    // From here the line is one the rewrite follows: every rule of the
    // dialect applies.
    if command.is_none() {
        match (dialect, mode) {
            (RepRap, Mode::Cnc) => {}
            // A 3D printer's RepRapFirmware: a "bad command", no move.
            (RepRap, Mode::Printer) => return Ok(Parsed::Raw),
            (RepRap, Mode::Unknown) => {
                return Err(format!(
                    "`{}` has no command word: RepRapFirmware continues the last G0/G1 on it only in CNC or laser mode (M453, M452), and moves on nothing in 3D printer mode (M451); start the line with G1, or put M453 or M452 at the start of the program if the machine runs in that mode",
                    shown()
                )
                .into());
            }
            _ => {
                return Err(Refused(
                    format!(
                        "`{}` has no command word: {}; start the line with G1",
                        shown(),
                        match dialect {
                            Klipper => "Klipper reads it as an unknown command and does not move",
                            Marlin => "Marlin moves on it only when built with GCODE_MOTION_MODES",
                            _ =>
                                "Klipper does not move on it, Marlin only with GCODE_MOTION_MODES, RepRapFirmware continues the last G0/G1 in CNC mode",
                        }
                    ),
                    Some(GcodeHint::Dialect(RepRap.name())),
                ));
            }
        }
    }
    if glued && matches!(dialect, Strict | Marlin) {
        return Err(format!(
            "`{}`: a line number not followed by a space, which Marlin reads as a line without a command; write `N10 G1 …`",
            shown()
        )
        .into());
    }
    let lower = s.iter().any(|b| b.is_ascii_lowercase())
        || number.as_ref().is_some_and(|(c, _)| *c == b'n');
    if lower && matches!(dialect, Strict | Marlin) {
        return Err(Refused(
            format!(
                "`{}` is in lower case, which Marlin reads only when built with GCODE_CASE_INSENSITIVE; write it in upper case",
                shown(),
            ),
            (dialect == Strict).then_some(GcodeHint::NameDialect),
        ));
    }
    // A checksum at the end: the firmwares that check one skip a line whose
    // checksum does not match, so it is checked here and never written anew
    // over a wrong one.
    let mut checksum = false;
    let mut body = s;
    if let Some(k) = s.iter().position(|&b| b == b'*') {
        let tail = std::str::from_utf8(&s[k + 1..]).unwrap_or("").trim_end();
        if tail.is_empty() || !tail.bytes().all(|b| b.is_ascii_digit()) {
            return Err(format!(
                "unexpected `*` in `{}`: a checksum is `*` and digits at the end of the line",
                shown()
            )
            .into());
        }
        let head = &line[..line.len() - semi.len()];
        let head = &head[..head.iter().rposition(|&b| b == b'*').unwrap_or(0)];
        let sum = head.iter().fold(0u8, |a, b| a ^ b);
        if tail.parse::<u32>().ok() != Some(u32::from(sum)) {
            return Err(format!(
                "the checksum *{tail} does not match the line (its characters give *{sum}): the line was changed after the checksum was written, and the firmwares that check it skip the line; restore the line, or remove its checksum (the program's sender adds its own)"
            )
            .into());
        }
        checksum = true;
        body = &s[..k];
    }
    let body = std::str::from_utf8(body)
        .map_err(|_| Refused::from(format!("`{}` is not ASCII", shown())))?;
    if let Some(c) = body.chars().find(|c| !c.is_ascii()) {
        return Err(format!("`{c}` in `{}`: not ASCII", shown()).into());
    }
    // The words after the command word.
    let rest = match command {
        Some(_) => {
            let t = &body[1..];
            let lead = t.len() - t.trim_start().len();
            let digits = t[lead..].bytes().take_while(u8::is_ascii_digit).count();
            &t[lead + digits..]
        }
        None => body,
    };
    if let Some((l, n)) = later_commands(rest.as_bytes()).first()
        && (dialect != Klipper || n.is_some())
    {
        return Err(format!(
            "a second command `{l}{}` on `{}`: the firmwares read it differently (RepRapFirmware runs both, Klipper and Marlin read its letters as words); put each command on its own line",
            n.map(|n| n.to_string()).unwrap_or_default(),
            shown()
        )
        .into());
    }
    // The words as the firmware reads them; values only where the command
    // takes them (a move, G92).
    let takes_values = matches!(command, None | Some(('G', 0..=3 | 92)));
    let read = |d: Dialect| -> std::result::Result<Read, String> {
        let r = match d {
            Klipper => read_klipper(rest),
            RepRap => read_reprap(rest)?,
            _ => read_marlin(rest),
        };
        if takes_values && let Some((_, Err(e))) = r.values.iter().find(|(_, v)| v.is_err()) {
            return Err(e.clone());
        }
        Ok(r)
    };
    let read = match dialect {
        Strict => {
            let readings = [Klipper, RepRap, Marlin].map(read);
            if let Some(e) = readings.iter().find_map(|r| r.as_ref().err()) {
                return Err(Refused(
                    format!("`{}`: {e}", shown()),
                    Some(GcodeHint::NameDialect),
                ));
            }
            let readings = readings.map(|r| r.expect("checked"));
            if takes_values {
                for l in VALUE_LETTERS {
                    let of = |r: &Read| {
                        r.values
                            .iter()
                            .find(|(x, _)| *x == l)
                            .map(|(_, v)| v.clone().unwrap_or(f64::NAN))
                    };
                    let [k, r, m] = [&readings[0], &readings[1], &readings[2]].map(of);
                    if k != r || k != m {
                        let say = |v: Option<f64>| match v {
                            Some(v) => format!("{l}{v}"),
                            None => format!("no {l}"),
                        };
                        return Err(Refused(
                            format!(
                                "`{}`: the firmwares read it differently (Klipper {}, RepRapFirmware {}, Marlin {}); write each word once, as a plain number",
                                shown(),
                                say(k),
                                say(r),
                                say(m)
                            ),
                            Some(GcodeHint::NameDialect),
                        ));
                    }
                }
            }
            readings.into_iter().next().expect("three readings")
        }
        d => read(d).map_err(|e| Refused::from(format!("`{}`: {e}", shown())))?,
    };
    let mut words: Vec<(char, String)> = read
        .values
        .into_iter()
        .filter_map(|(l, v)| Some((l, format!("{:?}", v.ok()?))))
        .collect();
    words.extend(read.others.into_iter().filter(|w| !w.is_empty()).map(|w| {
        let mut c = w.chars();
        let l = c.next().unwrap_or(' ').to_ascii_uppercase();
        (l, c.as_str().trim().to_string())
    }));
    let mut comment = if cnc { parens } else { vec![] };
    if !semi.is_empty() {
        if !comment.is_empty() {
            comment.push(b' ');
        }
        comment.extend_from_slice(semi);
    }
    Ok(Parsed::Code(Code {
        number: number.map(|(_, n)| n),
        checksum,
        command,
        words,
        comment,
    }))
}

/// The checksum RepRapFirmware and Marlin check: the exclusive or of the
/// line's bytes before the `*`.
#[doc(hidden)] // public for the integration tests only
pub fn checksum(line: &str) -> u8 {
    line.bytes().fold(0, |a, b| a ^ b)
}

/// Rewrite the program `text` (read from `path`, for messages) for a tool
/// of `axes` in `units`: every `G0`/`G1` move of a tool axis sent as the
/// target `predistort` gives for it (tool coordinates: mm, rad), cut into
/// pieces of at most `settings.max_segment`; every other line byte for byte.
pub fn rewrite<F>(
    path: &Path,
    text: &[u8],
    axes: &[String],
    units: &[pkmcal::Unit],
    settings: &Rewrite,
    predistort: F,
) -> Result<Rewritten>
where
    F: Fn(&[f64]) -> pkmcal::Result<pkmcal::Predistortion> + Sync,
{
    settings.check(axes).map_err(|cause| Error::Request {
        file: Some(path.to_path_buf()),
        cause,
    })?;
    let nx = axes.len();
    let mut words: Vec<char> = Vec::with_capacity(nx);
    for a in axes {
        match word_of(a) {
            Some(w) => words.push(w),
            None => crate::refuse!(path, None, "tool axis `{a}` has no G-code word"),
        }
    }
    let angle: Vec<bool> = units.iter().map(|u| *u == pkmcal::Unit::Radian).collect();
    let offset = if settings.offset.is_empty() {
        vec![0.0; nx]
    } else {
        settings.offset.clone()
    };
    let gcode = |line: usize, message: String, hint: Option<GcodeHint>| Error::Gcode {
        path: path.to_path_buf(),
        line: line as u64,
        message,
        hint,
    };
    if text.starts_with(&[0xEF, 0xBB, 0xBF]) {
        return Err(gcode(
            1,
            "the file starts with a byte-order mark, which firmwares read as part of the first command; save it without one".into(),
            None,
        ));
    }
    if let Some(k) = text.windows(2).position(|w| w[0] == b'\r' && w[1] != b'\n') {
        let line = text[..=k].iter().filter(|&&b| b == b'\n').count() + 1;
        return Err(gcode(
            line,
            "a line ends in a carriage return alone (old Mac style), which firmwares read differently; convert the file to \\n or \\r\\n line ends".into(),
            None,
        ));
    }
    // Programmed position in G-code units of each tool axis (None: unknown);
    // rotations not programmed stay at 0.
    let mut pos: Vec<Option<f64>> = (0..nx).map(|k| angle[k].then_some(0.0)).collect();
    // The pre-distorted position last sent (for relative moves).
    let mut sent_pos: Vec<Option<f64>> = pos.clone();
    let (mut absolute, mut inches, mut abs_e) = (true, false, true);
    // RepRapFirmware's machine mode, as the program sets it.
    let mut mode = Mode::Unknown;
    let mut motion: Option<u32> = None;
    let mut e_pos = 0.0;
    // First pass: parse, follow the modes, cut moves into pieces (in order);
    // then every piece is pre-distorted in parallel; then the program is
    // written, relative coordinates from the pieces sent before.
    let mut items: Vec<Item> = vec![];
    let mut pieces_out: Vec<Piece> = vec![];
    let mut moves = 0usize;
    // Moves sent as written: some axis's position was not known yet.
    let mut unknown: Vec<usize> = vec![];
    let mut start = 0usize;
    for (n, whole) in text.split_inclusive(|&b| b == b'\n').enumerate() {
        let line_no = n + 1;
        let (begin, end) = (start, start + whole.len());
        start = end;
        let (raw, eol) = if whole.ends_with(b"\r\n") {
            (&whole[..whole.len() - 2], "\r\n")
        } else if whole.ends_with(b"\n") {
            (&whole[..whole.len() - 1], "\n")
        } else if whole.ends_with(b"\r") {
            (&whole[..whole.len() - 1], "\r")
        } else {
            (whole, "")
        };
        let here = |m: String| gcode(line_no, m, None);
        let l = match parse(raw, settings.dialect, mode)
            .map_err(|Refused(m, hint)| gcode(line_no, m, hint))?
        {
            Parsed::Raw => {
                items.push(Item::Raw(begin, end));
                continue;
            }
            Parsed::Code(l) => l,
        };
        let num = |v: &str, w: char| -> Result<f64> {
            let x: f64 = v
                .parse()
                .map_err(|_| here(format!("`{w}{v}` is not a number")))?;
            if !x.is_finite() {
                return Err(here(format!("`{w}{v}` is not finite")));
            }
            Ok(x)
        };
        let mut is_move = false;
        let mut g92 = false;
        match l.command {
            Some(('G', m @ (0 | 1))) => {
                motion = Some(m);
                is_move = true;
            }
            Some(('G', 2 | 3)) => {
                return Err(here(
                    "arcs (G2/G3) are not rewritten; have the CAM or slicer write them as G1 segments (in PrusaSlicer, OrcaSlicer and Bambu Studio: turn arc fitting off)".into(),
                ));
            }
            Some(('G', 90)) => absolute = true,
            Some(('G', 91)) => absolute = false,
            Some(('G', 20)) => inches = true,
            Some(('G', 21)) => inches = false,
            Some(('G', 92)) => g92 = true,
            Some(('G', 28)) => {
                for k in 0..nx {
                    if !angle[k] {
                        pos[k] = None;
                    }
                }
                items.push(Item::Reset);
            }
            Some(('M', 82)) => abs_e = true,
            Some(('M', 83)) => abs_e = false,
            Some(('M', 451)) => mode = Mode::Printer,
            Some(('M', 452 | 453)) => mode = Mode::Cnc,
            _ => {}
        }
        let has_axis = l.words.iter().any(|(w, _)| words.contains(w));
        if g92 {
            if has_axis {
                return Err(gcode(
                    line_no,
                    "G92 on a tool axis shifts the coordinates; remove it".into(),
                    Some(GcodeHint::Offset),
                ));
            }
            if let Some((_, v)) = l.words.iter().find(|(w, _)| *w == 'E') {
                e_pos = num(v, 'E')?;
            }
            items.push(Item::Raw(begin, end));
            continue;
        }
        if l.command.is_none() {
            // A modal move (RepRapFirmware): the last G0/G1 again.
            if motion.is_none() {
                return Err(here(
                    "a line without a command before any G0/G1; start it with G1".into(),
                ));
            }
            is_move = true;
        }
        if !is_move || !has_axis {
            if let Some((_, v)) = l.words.iter().find(|(w, _)| *w == 'E')
                && is_move
            {
                let e = num(v, 'E')?;
                e_pos = if abs_e { e } else { e_pos + e };
            }
            items.push(Item::Raw(begin, end));
            continue;
        }
        // A move: the new programmed position.
        let scale = if inches { 25.4 } else { 1.0 };
        let from = pos.clone();
        for (k, w) in words.iter().enumerate() {
            if let Some((_, v)) = l.words.iter().find(|(x, _)| x == w) {
                let x = num(v, *w)? * if angle[k] { 1.0 } else { scale };
                pos[k] = Some(if absolute {
                    x
                } else {
                    pos[k].map_or(x, |p| p + x)
                });
                if !absolute && from[k].is_none() {
                    return Err(here(format!(
                        "relative move before the position of {} is known",
                        axes[k]
                    )));
                }
            }
        }
        if pos.iter().any(Option::is_none) {
            // Where the machine is after the start or a homing is the
            // firmware's (and its start macros') to know: the move is sent
            // as written, and told.
            let sent: Vec<(usize, f64)> = (0..nx)
                .filter(|&k| l.words.iter().any(|(x, _)| *x == words[k]))
                .filter_map(|k| Some((k, pos[k]? / scale)))
                .collect();
            if let Some((_, v)) = l.words.iter().find(|(w, _)| *w == 'E') {
                let e = num(v, 'E')?;
                e_pos = if abs_e { e } else { e_pos + e };
            }
            unknown.push(line_no);
            items.push(Item::AsWritten(begin, end, sent));
            continue;
        }
        let to: Vec<f64> = pos.iter().map(|p| p.unwrap_or(0.0)).collect();
        let e_word = l
            .words
            .iter()
            .find(|(w, _)| *w == 'E')
            .map(|(_, v)| v.as_str());
        let e_new = match e_word {
            Some(v) => {
                let e = num(v, 'E')?;
                Some(if abs_e { e } else { e_pos + e })
            }
            None => None,
        };
        // Segments: straight in programmed coordinates.
        let pieces = match (settings.max_segment, from.iter().all(Option::is_some)) {
            (Some(max), true) => {
                let d: f64 = (0..nx)
                    .filter(|&k| !angle[k])
                    .map(|k| (to[k] - from[k].unwrap_or(0.0)).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let n = (d / max).ceil();
                if n > MAX_PIECES as f64 {
                    return Err(gcode(
                        line_no,
                        format!(
                            "segments of {max} mm would split this {d:.3} mm move into more than {MAX_PIECES} pieces"
                        ),
                        Some(GcodeHint::MaxSegment),
                    ));
                }
                (n as usize).max(1)
            }
            _ => 1,
        };
        if pieces > 1 && l.number.is_some() {
            return Err(gcode(
                line_no,
                "a numbered line would be split into several moves, whose line numbers would no longer follow each other; remove the line numbers (the host that sends the file adds them)".into(),
                Some(GcodeHint::MaxSegment),
            ));
        }
        if pieces_out.len() + pieces > MAX_TOTAL_PIECES {
            return Err(gcode(
                line_no,
                format!(
                    "the program would be split into more than {MAX_TOTAL_PIECES} pieces in all"
                ),
                Some(GcodeHint::MaxSegment),
            ));
        }
        let g = format!("G{}", motion.unwrap_or(1));
        // Words kept as they are (feed rate, other codes).
        let others: Vec<String> = l
            .words
            .iter()
            .filter(|(w, _)| !(words.contains(w) || *w == 'E'))
            .map(|(w, v)| format!("{w}{v}"))
            .collect();
        for p in 1..=pieces {
            let f = p as f64 / pieces as f64;
            let point: Vec<f64> = (0..nx)
                .map(|k| match from[k] {
                    Some(a) if pieces > 1 => a + (to[k] - a) * f,
                    _ => to[k],
                })
                .collect();
            // Programmed (G-code units) to tool coordinates (mm, rad).
            let target: Vec<f64> = (0..nx)
                .map(|k| {
                    if angle[k] {
                        (point[k] + offset[k]).to_radians()
                    } else {
                        point[k] + offset[k]
                    }
                })
                .collect();
            let e_text = e_new.map(|en| {
                let e_here = e_pos + (en - e_pos) * f;
                let e_prev = e_pos + (en - e_pos) * (p - 1) as f64 / pieces as f64;
                let v = if abs_e { e_here } else { e_here - e_prev };
                format!(" E{v:.5}")
            });
            let last = p == pieces;
            items.push(Item::Piece(pieces_out.len()));
            pieces_out.push(Piece {
                line_no,
                piece: p,
                pieces,
                target,
                absolute,
                scale,
                number: l.number.clone(),
                checksum: l.checksum,
                g: g.clone(),
                e_text,
                others: others.clone(),
                comment: if last { l.comment.clone() } else { vec![] },
                eol: if last || !eol.is_empty() { eol } else { "\n" },
            });
        }
        if let Some(en) = e_new {
            e_pos = en;
        }
        moves += 1;
    }
    let results: Vec<pkmcal::Result<pkmcal::Predistortion>> = pieces_out
        .par_iter()
        .map(|pc| predistort(&pc.target))
        .collect();
    let mut out: Vec<u8> = Vec::with_capacity(text.len() * 2);
    let (mut segments, mut worst) = (0usize, 0.0f64);
    for item in &items {
        let k_piece = match item {
            Item::Raw(a, b) => {
                out.extend_from_slice(&text[*a..*b]);
                continue;
            }
            Item::AsWritten(a, b, sent) => {
                out.extend_from_slice(&text[*a..*b]);
                for &(k, v) in sent {
                    sent_pos[k] = Some(v);
                }
                continue;
            }
            Item::Reset => {
                for k in 0..nx {
                    if !angle[k] {
                        sent_pos[k] = None;
                    }
                }
                continue;
            }
            Item::Piece(i) => *i,
        };
        let pc = &pieces_out[k_piece];
        let pd = match &results[k_piece] {
            Ok(pd) => pd,
            Err(e) => {
                let (line_no, p, pieces) = (pc.line_no, pc.piece, pc.pieces);
                return Err(if p < pieces {
                    gcode(
                        line_no,
                        format!(
                            "the straight move passes outside the reachable workspace (piece {p} of {pieces}): {e}; add an intermediate point or move around"
                        ),
                        None,
                    )
                } else {
                    gcode(line_no, e.to_string(), None)
                });
            }
        };
        let target = &pc.target;
        worst = worst.max(
            (0..nx)
                .filter(|&k| !angle[k])
                .map(|k| (pd.command_target[k] - target[k]).abs())
                .fold(0.0, f64::max),
        );
        let send: Vec<f64> = (0..nx)
            .map(|k| {
                if angle[k] {
                    pd.command_target[k].to_degrees() - offset[k]
                } else {
                    (pd.command_target[k] - offset[k]) / pc.scale
                }
            })
            .collect();
        let mut line = String::new();
        if let Some(nw) = &pc.number {
            line.push_str(nw);
            line.push(' ');
        }
        line.push_str(&pc.g);
        for k in 0..nx {
            // Every axis: the correction moves them all.
            let v = if pc.absolute {
                send[k]
            } else {
                send[k] - sent_pos[k].unwrap_or(send[k])
            };
            let decimals = if angle[k] {
                ANGLE_DECIMALS
            } else {
                LENGTH_DECIMALS
            };
            // A value that rounds to zero is written `0.0000`, never
            // `-0.0000` (which a second rewrite would write otherwise).
            let mut text = format!("{v:.decimals$}");
            if text.starts_with('-') && text[1..].bytes().all(|b| b == b'0' || b == b'.') {
                text.remove(0);
            }
            let _ = write!(line, " {}{text}", words[k]);
            sent_pos[k] = Some(send[k]);
        }
        if let Some(e) = &pc.e_text {
            line.push_str(e);
        }
        for o in &pc.others {
            line.push(' ');
            line.push_str(o);
        }
        if pc.checksum {
            let cs = checksum(&line);
            let _ = write!(line, "*{cs}");
        }
        out.extend_from_slice(line.as_bytes());
        if !pc.comment.is_empty() {
            out.push(b' ');
            out.extend_from_slice(&pc.comment);
        }
        out.extend_from_slice(pc.eol.as_bytes());
        segments += 1;
    }
    Ok(Rewritten {
        bytes: out,
        moves,
        segments,
        worst,
        as_written: unknown,
    })
}
