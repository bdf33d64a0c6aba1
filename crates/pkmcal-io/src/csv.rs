//! Data files: CSV tables read whole or streamed, their columns found by
//! header name (regardless of case, with a "did you mean" for a near miss),
//! whichever delimiter, decimal mark and line ends they use, every row with
//! its line; and numbers written back as they read.

use crate::error::{Error, Result, Verb};
use crate::refuse;
use std::path::{Path, PathBuf};

/// A CSV file read whole, with its header.
pub struct Csv {
    pub path: PathBuf,
    pub headers: Vec<String>,
    /// (line number, fields) per data row.
    pub rows: Vec<(u64, Vec<String>)>,
    /// Whether a comment line declares the data to be in the base frame
    /// (`# frame: base`, as `simulate` and `trilaterate` write).
    pub base_frame: bool,
    /// The field delimiter found ([`detect_delimiter`]).
    pub delimiter: u8,
    /// The units its own `# units:` line declares
    /// ([`crate::fileunits::UNITS_COMMENT`]), if it has one.
    pub units: Option<pkmcal::FileUnits>,
}

/// The comment line that declares a data file's measurements to be in the
/// mechanism's base frame.
pub const BASE_FRAME_COMMENT: &str = "# frame: base";

/// The units a data file's own `# units:` line declares (the first such
/// comment line); an error naming the file and line if it is not one pkmcal
/// writes.
fn declared_units(path: &Path, text: &str) -> Result<Option<pkmcal::FileUnits>> {
    for (k, line) in text.lines().enumerate() {
        if let Some(u) = crate::fileunits::units_line(line) {
            return u.map(Some).map_err(|e| {
                Error::at(
                    path,
                    Some(k as u64 + 1),
                    format!("the units line `{}`: {e}", line.trim()),
                )
            });
        }
    }
    Ok(None)
}

impl Csv {
    pub fn read(run: &crate::Run<'_>, path: &Path) -> Result<Self> {
        let bytes = run.files.read(path, crate::output::InputKind::Data)?;
        // Line ends as `\n`, whichever the file uses (`\r` alone included);
        // a byte order mark is no part of the first line.
        let mut bytes = match bytes.strip_prefix(UTF8_BOM) {
            Some(rest) => rest.to_vec(),
            None => bytes,
        };
        let n = crate::output::LineEnds::default().unify(&mut bytes);
        bytes.truncate(n);
        let base_frame = String::from_utf8_lossy(&bytes)
            .lines()
            .any(|l| l.trim() == BASE_FRAME_COMMENT);
        let units = declared_units(path, &String::from_utf8_lossy(&bytes))?;
        let mut text = Vec::with_capacity(bytes.len());
        std::io::Read::read_to_end(&mut Uncomment::new(bytes.as_slice()), &mut text)
            .map_err(|e| Error::io(path, Verb::Read, e))?;
        let found = detect_delimiter(&text);
        let mut delimiter = found;
        if delimiter == b';' {
            // A semicolon-separated export may use decimal commas: with `;`
            // between fields a comma can only be one.
            for b in text.iter_mut().filter(|b| **b == b',') {
                *b = b'.';
            }
        } else if delimiter == b' ' {
            let mut out = Vec::with_capacity(text.len());
            std::io::Read::read_to_end(&mut Whitespace::new(text.as_slice()), &mut out)
                .map_err(|e| Error::io(path, Verb::Read, e))?;
            text = out;
            delimiter = b',';
        }
        let mut lines = LineCounter::new(text.as_slice());
        let mut rdr = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .flexible(true)
            .delimiter(delimiter)
            .from_reader(text.as_slice());
        let headers: Vec<String> = rdr
            .headers()
            .map_err(|e| Error::at(path, None, format!("cannot read the header line: {e}")))?
            .iter()
            .map(str::to_string)
            .collect();
        if headers.iter().all(String::is_empty) {
            refuse!(
                path,
                None,
                "the file is empty; it needs a header line naming the columns"
            );
        }
        let mut rows = Vec::new();
        for rec in rdr.records() {
            let rec = rec.map_err(|e| Error::at(path, None, format!("malformed CSV: {e}")))?;
            let line = rec.position().map_or(0, |p| lines.line_at(p.byte()));
            if rec.iter().all(str::is_empty) {
                continue;
            }
            // Every file read whole is identification data: bounded as one
            // identification is, before it is held.
            if rows.len() == pkmcal::identify::MAX_POSES {
                refuse!(
                    path,
                    Some(line),
                    "{}",
                    pkmcal::identify::too_many_poses(rows.len() + 1)
                );
            }
            beyond_header(path, line, &headers, found, &rec)?;
            rows.push((line, rec.iter().map(str::to_string).collect()));
        }
        Ok(Self {
            path: path.to_path_buf(),
            headers,
            rows,
            base_frame,
            delimiter: found,
            units,
        })
    }

    /// Whether the file has a column `name`, regardless of case (as
    /// [`Csv::column`] finds it).
    pub fn has(&self, name: &str) -> bool {
        self.headers.iter().any(|h| h.eq_ignore_ascii_case(name))
    }

    /// Index of a column by name; an error naming the file and the columns
    /// found if it is missing or appears twice.
    pub fn column(&self, name: &str) -> Result<usize> {
        column_index(&self.path, &self.headers, name, self.delimiter)
    }

    /// Numeric values of the given columns, row by row.
    pub fn numbers(&self, cols: &[(usize, &str)]) -> Result<Vec<Vec<f64>>> {
        self.rows
            .iter()
            .map(|(line, rec)| {
                cols.iter()
                    .map(|&(c, name)| {
                        field_number(&self.path, *line, name, rec.get(c).map(String::as_str))
                    })
                    .collect()
            })
            .collect()
    }

    /// Numeric values of named columns.
    pub fn named(&self, names: &[String]) -> Result<Vec<Vec<f64>>> {
        let cols: Vec<(usize, &str)> = names
            .iter()
            .map(|n| Ok((self.column(n)?, n.as_str())))
            .collect::<Result<_>>()?;
        self.numbers(&cols)
    }

    pub fn require_rows(&self) -> Result<()> {
        if self.rows.is_empty() {
            refuse!(self.path, None, "no data rows below the header");
        }
        Ok(())
    }

    pub fn line(&self, row: usize) -> u64 {
        self.rows[row].0
    }
}

/// The number in a CSV field (`None`: the row is short), or an error naming
/// the file, line and column.
fn field_number(path: &Path, line: u64, name: &str, field: Option<&str>) -> Result<f64> {
    let Some(field) = field else {
        refuse!(
            path,
            Some(line),
            "the row is short: no value for column `{name}`"
        );
    };
    let Ok(v) = field.parse::<f64>() else {
        refuse!(
            path,
            Some(line),
            "column `{name}`: `{field}` is not a number"
        );
    };
    if !v.is_finite() {
        refuse!(
            path,
            Some(line),
            "column `{name}`: `{field}` is not a finite number"
        );
    }
    Ok(v)
}

/// A row's fields beyond the header's columns are no column's: a decimal
/// comma between commas, or a column left unnamed: refused, at its line.
/// Empty ones (a trailing separator) are nothing.
fn beyond_header(
    path: &Path,
    line: u64,
    headers: &[String],
    delimiter: u8,
    rec: &csv::StringRecord,
) -> Result<()> {
    if rec.iter().skip(headers.len()).all(str::is_empty) {
        return Ok(());
    }
    let fields = rec
        .iter()
        .enumerate()
        .filter(|(_, f)| !f.is_empty())
        .last()
        .map_or(0, |(k, _)| k + 1);
    refuse!(
        path,
        Some(line),
        "{fields} fields, but the header names {} columns ({}, {}); name every column in the header{}",
        headers.len(),
        listed(headers),
        delimiter_name(delimiter),
        if delimiter == b',' {
            ", and write decimals with a point (or separate fields by `;` where they use a comma)"
        } else {
            ""
        }
    )
}

/// A CSV file read as a stream, once (a pipe works), in batches of rows:
/// memory stays flat in the number of rows; every row keeps its line.
pub struct CsvStream {
    pub path: PathBuf,
    pub headers: Vec<String>,
    /// The units its own `# units:` line declares, if it has one (among the
    /// comment lines above its header).
    pub units: Option<pkmcal::FileUnits>,
    rdr: csv::Reader<Tee<Box<dyn std::io::Read>>>,
    lines: LineCounter<Copied>,
    rows: usize,
    delimiter: u8,
}

impl CsvStream {
    pub fn open(run: &crate::Run<'_>, path: &Path) -> Result<Self> {
        use std::io::BufRead;
        let file = run.files.open(path)?;
        let read = |e| Error::io(path, Verb::Read, e);
        // A byte order mark is no part of the first line.
        let mut file = std::io::BufReader::with_capacity(1 << 16, file);
        if file.fill_buf().map_err(read)?.starts_with(UTF8_BOM) {
            file.consume(UTF8_BOM.len());
        }
        // A units line among the comment lines above the header.
        let head = file.fill_buf().map_err(read)?;
        let head = String::from_utf8_lossy(head);
        let above: String = head
            .lines()
            .take_while(|l| l.trim().is_empty() || l.trim_start().starts_with('#'))
            .map(|l| format!("{l}\n"))
            .collect();
        let units = declared_units(path, &above)?;
        // The delimiter from the first buffer (it holds the header line).
        let mut buffered = std::io::BufReader::with_capacity(1 << 16, Uncomment::new(file));
        let delimiter = detect_delimiter(buffered.fill_buf().map_err(read)?);
        let source: Box<dyn std::io::Read> = match delimiter {
            b';' => Box::new(DecimalCommas(buffered)),
            b' ' => Box::new(Whitespace::new(buffered)),
            _ => Box::new(buffered),
        };
        let found = delimiter;
        let delimiter = if delimiter == b' ' { b',' } else { delimiter };
        let (tee, lines) = tee(source);
        let mut rdr = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .flexible(true)
            .delimiter(delimiter)
            .from_reader(tee);
        let headers: Vec<String> = rdr
            .headers()
            .map_err(|e| Error::at(path, None, format!("cannot read the header line: {e}")))?
            .iter()
            .map(String::from)
            .collect();
        if headers.iter().all(String::is_empty) {
            refuse!(
                path,
                None,
                "the file is empty; it needs a header line naming the columns"
            );
        }
        Ok(Self {
            path: path.to_path_buf(),
            headers,
            units,
            rdr,
            lines,
            rows: 0,
            delimiter: found,
        })
    }

    /// Column indices of `names`, each an error naming the file if missing.
    pub fn columns(&self, names: &[String]) -> Result<Vec<usize>> {
        names
            .iter()
            .map(|n| column_index(&self.path, &self.headers, n, self.delimiter))
            .collect()
    }

    /// Up to `max` rows (line, values of `cols`), blank lines skipped; an
    /// empty batch at the end; an error naming file, line and column for a
    /// short row or a value that is not a finite number.
    pub fn batch(
        &mut self,
        cols: &[usize],
        names: &[String],
        max: usize,
    ) -> Result<Vec<(u64, Vec<f64>)>> {
        let mut out = Vec::with_capacity(max);
        let mut rec = csv::StringRecord::new();
        while out.len() < max {
            let more = self
                .rdr
                .read_record(&mut rec)
                .map_err(|e| Error::at(&self.path, None, format!("malformed CSV: {e}")))?;
            if !more {
                break;
            }
            let line = rec.position().map_or(0, |p| self.lines.line_at(p.byte()));
            if rec.iter().all(str::is_empty) {
                continue;
            }
            beyond_header(&self.path, line, &self.headers, self.delimiter, &rec)?;
            let values = cols
                .iter()
                .zip(names)
                .map(|(&k, n)| field_number(&self.path, line, n, rec.get(k)))
                .collect::<Result<Vec<f64>>>()?;
            out.push((line, values));
        }
        self.rows += out.len();
        if out.is_empty() && self.rows == 0 {
            refuse!(self.path, None, "no data rows below the header");
        }
        Ok(out)
    }
}

/// Whitespace-separated columns (instrument exports, `numpy.savetxt`) read
/// as comma-separated: a run of blanks between fields is one separator,
/// blanks at the start and end of a line are dropped, and a comma can only be
/// a decimal comma. Line breaks are kept, so line numbers stay right.
pub struct Whitespace<R> {
    inner: R,
    raw: Vec<u8>,
    /// Rewritten bytes not yet handed out (a reader may ask for one byte at
    /// a time, as `read_to_end` does when it probes).
    out: Vec<u8>,
    /// The next byte of `out` to hand out.
    at: usize,
    pending: bool,
    line_start: bool,
}

impl<R: std::io::Read> Whitespace<R> {
    pub fn new(inner: R) -> Self {
        Self {
            inner,
            raw: vec![0; 1 << 15],
            out: Vec::with_capacity(1 << 16),
            at: 0,
            pending: false,
            line_start: true,
        }
    }
}

impl<R: std::io::Read> std::io::Read for Whitespace<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if buf.is_empty() {
            return Ok(0);
        }
        while self.at == self.out.len() {
            self.out.clear();
            self.at = 0;
            let n = self.inner.read(&mut self.raw)?;
            if n == 0 {
                return Ok(0);
            }
            for &b in &self.raw[..n] {
                match b {
                    b'\n' | b'\r' => {
                        self.out.push(b);
                        self.pending = false;
                        self.line_start = true;
                    }
                    b' ' | b'\t' => self.pending = !self.line_start,
                    _ => {
                        if self.pending {
                            self.out.push(b',');
                        }
                        self.out.push(if b == b',' { b'.' } else { b });
                        self.pending = false;
                        self.line_start = false;
                    }
                }
            }
        }
        let k = (self.out.len() - self.at).min(buf.len());
        buf[..k].copy_from_slice(&self.out[self.at..self.at + k]);
        self.at += k;
        Ok(k)
    }
}

/// The UTF-8 byte order mark some editors and spreadsheets write first.
pub const UTF8_BOM: &[u8] = b"\xEF\xBB\xBF";

/// Decimal commas read as points (for semicolon-separated files, where a
/// comma can only be one).
struct DecimalCommas<R>(R);

impl<R: std::io::Read> std::io::Read for DecimalCommas<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.0.read(buf)?;
        for b in buf[..n].iter_mut().filter(|b| **b == b',') {
            *b = b'.';
        }
        Ok(n)
    }
}

/// A reader that blanks comment lines, indented ones too (`  # note`),
/// keeping their line breaks so that line numbers stay right.
pub struct Uncomment<R> {
    inner: R,
    state: CommentState,
}

#[derive(Clone, Copy, PartialEq)]
enum CommentState {
    /// Only blanks so far on this line.
    Start,
    /// In a comment: dropped up to the line break.
    Comment,
    /// In data.
    Data,
}

impl<R: std::io::Read> Uncomment<R> {
    pub fn new(inner: R) -> Self {
        Self {
            inner,
            state: CommentState::Start,
        }
    }
}

impl<R: std::io::Read> std::io::Read for Uncomment<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let n = self.inner.read(buf)?;
            if n == 0 {
                return Ok(0);
            }
            let mut k = 0;
            for i in 0..n {
                let b = buf[i];
                let keep = match (self.state, b) {
                    (_, b'\n') => {
                        self.state = CommentState::Start;
                        true
                    }
                    (CommentState::Comment, _) => false,
                    (CommentState::Start, b' ' | b'\t' | b'\r') => true,
                    (CommentState::Start, b'#') => {
                        self.state = CommentState::Comment;
                        false
                    }
                    (CommentState::Start, _) => {
                        self.state = CommentState::Data;
                        true
                    }
                    (CommentState::Data, _) => true,
                };
                if keep {
                    buf[k] = b;
                    k += 1;
                }
            }
            if k > 0 {
                return Ok(k);
            }
        }
    }
}

/// A reader that hands a copy of every byte it passes on to a
/// [`LineCounter`] ([`tee`]), so that a stream (a pipe) is read once.
pub struct Tee<R> {
    inner: R,
    copy: std::rc::Rc<std::cell::RefCell<std::collections::VecDeque<u8>>>,
}

impl<R: std::io::Read> std::io::Read for Tee<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.copy.borrow_mut().extend(&buf[..n]);
        Ok(n)
    }
}

/// The bytes a [`Tee`] has passed on and the line counter not yet read.
pub struct Copied(std::rc::Rc<std::cell::RefCell<std::collections::VecDeque<u8>>>);

impl std::io::Read for Copied {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let mut q = self.0.borrow_mut();
        let n = q.len().min(buf.len());
        for (b, v) in buf.iter_mut().zip(q.drain(..n)) {
            *b = v;
        }
        Ok(n)
    }
}

/// A reader for the CSV parser and a line counter over the same bytes,
/// reading the source once.
pub fn tee<R: std::io::Read>(r: R) -> (Tee<R>, LineCounter<Copied>) {
    let copy = std::rc::Rc::new(std::cell::RefCell::new(std::collections::VecDeque::new()));
    (
        Tee {
            inner: r,
            copy: copy.clone(),
        },
        LineCounter::new(Copied(copy)),
    )
}

/// Line numbers from byte offsets, reading forward through a second copy of
/// the stream. (The csv crate's own line count is off for CRLF files.)
pub struct LineCounter<R: std::io::Read> {
    reader: std::io::BufReader<R>,
    offset: u64,
    line: u64,
    at_line_start: bool,
}

impl<R: std::io::Read> LineCounter<R> {
    pub fn new(r: R) -> Self {
        Self {
            reader: std::io::BufReader::new(r),
            offset: 0,
            line: 1,
            at_line_start: true,
        }
    }

    /// The 1-based line of the record the csv crate says starts at `byte`
    /// (offsets must not decrease). The crate reports the end of the previous
    /// record (for CRLF files its `\n`) and counts skipped comment lines into
    /// the record, so line terminators, blank lines and `#` comment lines
    /// after `byte` are passed over before the record's own line is known.
    pub fn line_at(&mut self, byte: u64) -> u64 {
        use std::io::BufRead;
        while self.offset < byte {
            let Ok(buf) = self.reader.fill_buf() else {
                break;
            };
            if buf.is_empty() {
                break;
            }
            let take = ((byte - self.offset) as usize).min(buf.len());
            let newlines = buf[..take].iter().filter(|b| **b == b'\n').count() as u64;
            self.at_line_start = if take > 0 {
                buf[take - 1] == b'\n'
            } else {
                self.at_line_start
            };
            self.line += newlines;
            self.offset += take as u64;
            self.reader.consume(take);
        }
        let mut in_comment = false;
        while let Ok(buf) = self.reader.fill_buf() {
            let Some(&c) = buf.first() else { break };
            match c {
                b'\n' => {
                    self.line += 1;
                    in_comment = false;
                    self.at_line_start = true;
                }
                b'#' if self.at_line_start => in_comment = true,
                _ if in_comment => {}
                b'\r' | b' ' | b'\t' => {}
                _ => break,
            }
            if c != b'\n' && c != b'\r' && c != b' ' && c != b'\t' {
                self.at_line_start = false;
            }
            self.offset += 1;
            self.reader.consume(1);
        }
        self.line
    }
}

/// Most column names a message lists (a file may have a million).
const MAX_LISTED: usize = 30;

/// `headers` for a message: the first [`MAX_LISTED`], then how many more.
fn listed(headers: &[String]) -> String {
    let shown: Vec<&str> = headers
        .iter()
        .take(MAX_LISTED)
        .map(String::as_str)
        .collect();
    if headers.len() > MAX_LISTED {
        format!(
            "{}, … ({} more)",
            shown.join(", "),
            headers.len() - MAX_LISTED
        )
    } else {
        shown.join(", ")
    }
}

/// Index of column `name` in `headers` of file `path`; an error naming the
/// file and the columns found if it is missing or appears more than once.
pub fn column_index(path: &Path, headers: &[String], name: &str, delimiter: u8) -> Result<usize> {
    // `X` for `x`: headers match regardless of case, when unambiguous.
    let hits: Vec<usize> = (0..headers.len())
        .filter(|&i| headers[i].eq_ignore_ascii_case(name))
        .collect();
    if let Some(&other) = hits.iter().find(|&&i| headers[i] != headers[hits[0]]) {
        refuse!(
            path,
            None,
            "columns `{}` and `{}` differ only in case, so `{name}` is ambiguous; rename one",
            headers[hits[0]],
            headers[other]
        );
    }
    match hits.as_slice() {
        [i] => Ok(*i),
        [] => {
            // The nearest headers (ignoring case and punctuation), if near.
            let norm = |t: &str| -> String {
                t.chars()
                    .filter(|c| c.is_alphanumeric())
                    .flat_map(char::to_lowercase)
                    .collect()
            };
            // `q2` is not a typo of `q1`: another index is another column.
            let letters =
                |t: &str| -> String { norm(t).chars().filter(|c| !c.is_ascii_digit()).collect() };
            let dist: Vec<usize> = headers
                .iter()
                .map(|h| {
                    if letters(h) == letters(name) && norm(h) != norm(name) {
                        usize::MAX
                    } else {
                        edit_distance(&norm(h), &norm(name))
                    }
                })
                .collect();
            let best = dist.iter().copied().min().unwrap_or(usize::MAX);
            let near: Vec<&str> = headers
                .iter()
                .zip(&dist)
                .filter(|(_, d)| **d == best && best <= (norm(name).len() / 3).max(1))
                .map(|(h, _)| h.as_str())
                .take(MAX_LISTED / 6)
                .collect();
            refuse!(
                path,
                None,
                "missing column `{}`{} (columns found, {}: {})",
                name,
                if near.is_empty() {
                    String::new()
                } else {
                    format!("; did you mean `{}`?", near.join("`, `"))
                },
                delimiter_name(delimiter),
                listed(headers)
            )
        }
        _ => refuse!(
            path,
            None,
            "column `{}` appears {} times; keep one",
            name,
            hits.len()
        ),
    }
}

/// Levenshtein distance (for "did you mean").
use pkmcal::error::edit_distance;

/// How a file's fields were found to be separated, for messages.
pub fn delimiter_name(d: u8) -> &'static str {
    match d {
        b';' => "separated by semicolons",
        b'\t' => "separated by tabs",
        b' ' => "separated by blanks",
        _ => "separated by commas",
    }
}

/// The field delimiter of a CSV text, from its header line: the most
/// frequent of comma, semicolon and tab (spreadsheet exports use all three);
/// `b' '` (runs of blanks, read through [`Whitespace`]) when the header has
/// none of them but several names separated by blanks; comma otherwise.
pub fn detect_delimiter(text: &[u8]) -> u8 {
    let header = text
        .split(|&b| b == b'\n')
        .find(|l| l.iter().any(|b| !b.is_ascii_whitespace()))
        .unwrap_or(&[]);
    let count = |d: u8| header.iter().filter(|&&b| b == d).count();
    let words = header
        .split(|b| *b == b' ')
        .filter(|w| w.iter().any(|b| !b.is_ascii_whitespace()))
        .count();
    [b',', b';', b'\t']
        .into_iter()
        .max_by_key(|&d| (count(d), d == b','))
        .filter(|&d| count(d) > 0)
        .unwrap_or(if words > 1 { b' ' } else { b',' })
}

/// The longest number written out in positional notation; a longer one
/// (1e300 would take 301 digits) is written with an exponent.
pub const MAX_POSITIONAL_DIGITS: usize = 40;

/// Below this magnitude a number is written with an exponent
/// (`-4.489464355827977e-14`, not `-0.00000000000004489464355827977`).
pub const MIN_POSITIONAL: f64 = 1e-5;

/// A number as data files hold it: its shortest round-trip digits, in
/// positional notation (`-7`, `203.00000000000006`), or with an exponent
/// (`1e300`, `2.5e-45`, `-4.4e-14`) where that would be longer than
/// [`MAX_POSITIONAL_DIGITS`] or the number is below [`MIN_POSITIONAL`]. Both
/// read back to the same number.
pub fn number(v: f64) -> String {
    let s = format!("{v}");
    if s.len() > MAX_POSITIONAL_DIGITS || (v != 0.0 && v.abs() < MIN_POSITIONAL) {
        format!("{v:e}")
    } else {
        s
    }
}

/// CSV text from a header and rows of numbers (shortest round-trip format).
pub fn csv_bytes(header: &[String], rows: &[Vec<f64>]) -> Vec<u8> {
    let mut out = String::with_capacity(rows.len() * header.len() * 20);
    out.push_str(&header.join(","));
    out.push('\n');
    for r in rows {
        for (i, v) in r.iter().enumerate() {
            if i > 0 {
                out.push(',');
            }
            out.push_str(&number(*v));
        }
        out.push('\n');
    }
    out.into_bytes()
}
