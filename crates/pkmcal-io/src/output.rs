//! The outputs of a run: checked before any work (never an input, never each
//! other, never a device, a pipe or a link), written to temporaries next to
//! their destination, and renamed into place together only when the whole run
//! has succeeded. On failure, a panic, Ctrl-C or SIGTERM the temporaries are
//! removed and every earlier file is left as it was.
//!
//! Written here rather than taken from a crate: `tempfile` persists one file
//! at a time, and a run must commit several (parameters, report, figures) or
//! none.

use crate::error::{Error, OutputProblem, Result, Verb};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// A temporary and the file it becomes.
#[doc(hidden)] // public for the integration tests only
pub struct Staged {
    #[doc(hidden)] // public for the integration tests only
    pub tmp: PathBuf,
    #[doc(hidden)] // public for the integration tests only
    pub dest: PathBuf,
    /// The thread writing a whole output ([`stage`]) and flushing it to
    /// disk, joined at [`commit`].
    #[doc(hidden)] // public for the integration tests only
    pub writing: Option<std::thread::JoinHandle<std::io::Result<()>>>,
}

/// Wait for a temporary's writer, if any; its result.
fn written(writing: Option<std::thread::JoinHandle<std::io::Result<()>>>) -> std::io::Result<()> {
    match writing.map(std::thread::JoinHandle::join) {
        None | Some(Ok(Ok(()))) => Ok(()),
        Some(Ok(Err(e))) => Err(e),
        Some(Err(_)) => Err(std::io::Error::other("the writing thread panicked")),
    }
}

struct State {
    staged: Vec<Staged>,
    /// Directories this run created (removed again on failure if empty).
    created: Vec<PathBuf>,
    /// Whole outputs for standard output (`-`), written on commit.
    stdout: Vec<u8>,
    /// Whether [`commit`] has started renaming (it holds the state while it
    /// does: an interruption waits for the outputs to be in place).
    committed: bool,
}

/// The files this run has read (or declared it will read), each with the
/// keys it is known by; no output may be one of them. Kept only where a
/// process is one run ([`track_inputs`]: the CLI), not in the Python
/// package, where writing a file read earlier is the user's choice.
struct Inputs {
    tracking: bool,
    files: Vec<(PathBuf, Vec<Key>)>,
}

/// One run's files: the inputs it has read and the outputs it has staged.
/// A value, not a global: the CLI makes one per process (and hands it to
/// its Ctrl-C handler), the Python package one per call that writes. Every
/// reader of the file side takes it, so every file read counts as an input
/// ([`Files::input`]); every writer stages through it, so a run's outputs
/// appear all together or not at all ([`Files::commit`]). Dropped before a
/// commit, it removes what it staged.
pub struct Files {
    state: Mutex<State>,
    inputs: Mutex<Inputs>,
    /// A size limit for every file read whole (`--max-input-mb`), replacing
    /// the defaults of [`InputKind`].
    max_input_mb: Option<u64>,
}

impl Default for Files {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for Files {
    fn drop(&mut self) {
        self.discard();
    }
}

impl Files {
    /// No input tracked (a file read may be written again: the Python
    /// package's case), the default size limits.
    pub fn new() -> Self {
        Files {
            state: Mutex::new(State {
                staged: vec![],
                created: vec![],
                stdout: vec![],
                committed: false,
            }),
            inputs: Mutex::new(Inputs {
                tracking: false,
                files: vec![],
            }),
            max_input_mb: None,
        }
    }

    /// One run of a command: every file read through [`Files::input`] (or
    /// declared to [`Files::check`]) counts as an input, which no output
    /// may replace.
    pub fn tracking_inputs(self) -> Self {
        self.inputs().tracking = true;
        self
    }

    /// The size limit of every file read whole (MiB), replacing the
    /// defaults of [`InputKind`]; `None` keeps them.
    pub fn with_max_input_mb(mut self, mb: Option<u64>) -> Self {
        self.max_input_mb = mb;
        self
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn inputs(&self) -> std::sync::MutexGuard<'_, Inputs> {
        self.inputs.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// For an interruption (Ctrl-C, SIGTERM): remove the temporaries and
    /// the directories created, then call `then` with whether the outputs
    /// were already in place, the state still held, so that nothing can be
    /// staged or committed before `then` (which ends the process) returns.
    pub fn interrupt(&self, then: impl FnOnce(bool)) {
        let mut s = self.state();
        let committed = s.committed;
        discard_in(&mut s);
        then(committed);
    }
}

impl Files {
    /// Register `path` as an input of the run: a file read, however it was
    /// named or reached (an option, a file named inside another, an include).
    /// Every reader of the file side calls this where it opens a file.
    pub fn input(&self, path: &Path) {
        let mut i = self.inputs();
        if !i.tracking || is_stdout(path) {
            return;
        }
        let Ok(k) = keys(path, &[]) else {
            return;
        };
        if !i.files.iter().any(|(_, known)| known == &k) {
            i.files.push((path.to_path_buf(), k));
        }
    }

    fn limit_of(&self, kind: InputKind) -> u64 {
        self.max_input_mb.unwrap_or(match kind {
            InputKind::Description => MAX_DESCRIPTION_MB,
            InputKind::Data => MAX_DATA_MB,
        })
    }

    /// Read a whole input file, registered first ([`input`]), at most its
    /// kind's size limit (a larger file, or an endless one such as `/dev/zero`,
    /// is [`Error::TooLarge`]).
    pub fn read(&self, path: &Path, kind: InputKind) -> Result<Vec<u8>> {
        use std::io::Read;
        self.input(path);
        let mb = self.limit_of(kind);
        let limit = mb.saturating_mul(1 << 20);
        let mut out = vec![];
        std::fs::File::open(path)
            .map_err(|e| Error::io(path, Verb::Open, e))?
            .take(limit.saturating_add(1))
            .read_to_end(&mut out)
            .map_err(|e| Error::io(path, Verb::Read, e))?;
        if out.len() as u64 > limit {
            return Err(Error::TooLarge {
                path: path.to_path_buf(),
                limit_mb: mb,
                kind,
            });
        }
        Ok(out)
    }

    /// Read a whole input text file ([`read`]).
    pub fn read_to_string(&self, path: &Path, kind: InputKind) -> Result<String> {
        String::from_utf8(self.read(path, kind)?).map_err(|_| {
            Error::io(
                path,
                Verb::Read,
                std::io::Error::new(std::io::ErrorKind::InvalidData, "it is not UTF-8 text"),
            )
        })
    }

    /// Open an input file to stream it, registered first ([`input`]); each of
    /// its lines at most [`MAX_LINE_BYTES`] long.
    pub fn open(&self, path: &Path) -> Result<LineLimit<std::fs::File>> {
        self.input(path);
        Ok(LineLimit {
            inner: std::fs::File::open(path).map_err(|e| Error::io(path, Verb::Open, e))?,
            run: 0,
            ends: LineEnds::default(),
        })
    }

    /// The input `dest` would replace, if any.
    fn input_hit(&self, dest: &Path, created: &[PathBuf]) -> Option<PathBuf> {
        let k = keys(dest, created).ok()?;
        self.inputs()
            .files
            .iter()
            .find(|(_, ik)| k.iter().any(|a| ik.contains(a)))
            .map(|(p, _)| p.clone())
    }

    /// Check a run's planned outputs before any work: each must be a new or
    /// regular file in an existing directory, none may be one of the `inputs`
    /// (through any path or link) or another output. Files in `dirs` (output
    /// directories the run creates) may have a missing directory. Errors are
    /// usage errors.
    pub fn check(&self, inputs: &[&Path], outputs: &[&Path], dirs: &[PathBuf]) -> Result<()> {
        let mut input_keys = vec![];
        for i in inputs {
            self.input(i);
            if let Ok(k) = keys(i, &[]) {
                input_keys.push((i, k));
            }
        }
        let mut seen: Vec<(&Path, Vec<Key>)> = vec![];
        for o in outputs.iter().filter(|o| !is_stdout(o)) {
            let text = o.as_os_str().to_string_lossy();
            if text.ends_with('/') || text.ends_with("/.") || text.ends_with("/..") {
                return Err(Error::Output {
                    path: o.to_path_buf(),
                    problem: OutputProblem::NamesDirectory,
                });
            }
            if let Ok(meta) = std::fs::symlink_metadata(o) {
                let t = meta.file_type();
                if t.is_symlink() {
                    return Err(Error::Output {
                        path: o.to_path_buf(),
                        problem: OutputProblem::Symlink,
                    });
                }
                if !t.is_file() {
                    return Err(Error::Output {
                        path: o.to_path_buf(),
                        problem: OutputProblem::NotRegular,
                    });
                }
            }
            let k = keys(o, dirs)?;
            for (i, ik) in &input_keys {
                if k.iter().any(|a| ik.contains(a)) {
                    return Err(Error::Output {
                        path: o.to_path_buf(),
                        problem: OutputProblem::AlsoInput(i.to_path_buf()),
                    });
                }
            }
            for (p, pk) in &seen {
                if k.iter().any(|a| pk.contains(a)) {
                    return Err(Error::Output {
                        path: o.to_path_buf(),
                        problem: OutputProblem::SameAs(p.to_path_buf()),
                    });
                }
            }
            seen.push((o, k));
        }
        Ok(())
    }

    /// Create `dir` (and its parents) for outputs; removed again if the run
    /// fails and it is still empty.
    pub fn create_dir(&self, dir: &Path) -> Result<()> {
        let mut missing = vec![];
        let mut d = Some(dir);
        while let Some(p) = d.filter(|p| !p.as_os_str().is_empty() && !p.exists()) {
            missing.push(p.to_path_buf());
            d = p.parent();
        }
        // Created and registered under the state (an interruption removes it).
        let mut s = self.state();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, Verb::Create, e))?;
        s.created.extend(missing);
        Ok(())
    }

    /// A fresh temporary for `dest`, created (never opened if it exists, so no
    /// file, an input included, is ever truncated or reused): `.NAME.tmp-PID-N`
    /// next to `dest`, `N` counting up from a per-run start.
    fn temporary(&self, dest: &Path) -> Result<(std::fs::File, PathBuf)> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let (dir, prefix) = temporary_prefix(dest).ok_or_else(|| Error::Output {
            path: dest.to_path_buf(),
            problem: OutputProblem::NoFileName,
        })?;
        let start = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos() as u64);
        for attempt in 0.. {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let tmp = dir.join(format!(
                "{prefix}{}-{}",
                std::process::id(),
                start.wrapping_add(n)
            ));
            if self.input_hit(&tmp, &[]).is_some() {
                continue;
            }
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&tmp)
            {
                Ok(f) => return Ok((f, tmp)),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempt < 1000 => {
                    continue;
                }
                Err(e) => {
                    return Err(Error::io(dest, Verb::Write, e));
                }
            }
        }
        unreachable!("the loop returns")
    }

    /// Remove temporaries of `dest` left by runs that were killed (SIGKILL
    /// cannot be caught): `.NAME.tmp-PID` or `.NAME.tmp-PID-N` whose process no
    /// longer exists, and that are no input of this run.
    fn sweep_stale(&self, dest: &Path) {
        let Some((dir, prefix)) = temporary_prefix(dest) else {
            return;
        };
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return;
        };
        for e in entries.flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            let Some(rest) = n.strip_prefix(&prefix) else {
                continue;
            };
            let (pid, nonce) = rest.split_once('-').unwrap_or((rest, "0"));
            let (Ok(pid), Ok(_)) = (pid.parse::<u32>(), nonce.parse::<u64>()) else {
                continue;
            };
            let alive = pid == std::process::id() || Path::new(&format!("/proc/{pid}")).exists();
            let regular = e.file_type().is_ok_and(|t| t.is_file());
            if !alive
                && regular
                && Path::new("/proc/self").exists()
                && self.input_hit(&e.path(), &[]).is_none()
            {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    /// Stage `bytes` for `dest`: the temporary is created now, written and
    /// flushed to disk (`fsync`) on a thread of its own while the run goes on
    /// (the flush takes about 0.5 ms, a twentieth of a small calibration), and
    /// renamed at [`commit`], which waits for it and reports a failed write.
    pub fn stage(&self, dest: &Path, bytes: &[u8]) -> Result<()> {
        if is_stdout(dest) {
            self.state().stdout.extend_from_slice(bytes);
            return Ok(());
        }
        let (f, tmp) = self.stage_file(dest)?;
        let bytes: std::sync::Arc<[u8]> = bytes.into();
        let write =
            |mut f: std::fs::File, bytes: &[u8]| f.write_all(bytes).and_then(|()| f.sync_all());
        let mine = bytes.clone();
        match std::thread::Builder::new()
            .name("write".into())
            .spawn(move || write(f, &mine))
        {
            Ok(handle) => {
                if let Some(s) = self.state().staged.iter_mut().find(|x| x.dest == dest) {
                    s.writing = Some(handle);
                }
                Ok(())
            }
            // No thread to be had (the closure and its file are gone): written
            // here, through the temporary's path.
            Err(_) => std::fs::OpenOptions::new()
                .write(true)
                .truncate(true)
                .open(&tmp)
                .and_then(|f| write(f, &bytes))
                .map_err(|e| Error::io(dest, Verb::Write, e)),
        }
    }

    /// A temporary file for `dest`, registered for [`commit`] (for outputs
    /// written as they are computed).
    pub fn stage_file(&self, dest: &Path) -> Result<(std::fs::File, PathBuf)> {
        // A second output for the same destination replaces the first: its
        // writer (same temporary) finishes first.
        let earlier = self
            .state()
            .staged
            .iter_mut()
            .find(|x| x.dest == dest)
            .and_then(|x| x.writing.take());
        if let Some(h) = earlier {
            let _ = h.join();
        }
        // Created and registered under the state (an interruption removes it).
        let mut s = self.state();
        if let Some(i) = self.input_hit(dest, &s.created) {
            return Err(also_an_input(dest, &i));
        }
        self.sweep_stale(dest);
        let (f, tmp) = self.temporary(dest)?;
        if let Some(old) = s.staged.iter().find(|x| x.dest == dest) {
            let _ = std::fs::remove_file(&old.tmp);
        }
        s.staged.retain(|x| x.dest != dest);
        s.staged.push(Staged {
            tmp: tmp.clone(),
            dest: dest.to_path_buf(),
            writing: None,
        });
        Ok((f, tmp))
    }

    /// A buffered writer for an output written as it is computed: standard
    /// output for `-`, else a staged temporary ([`stage_file`]). Flush it at the
    /// end.
    /// Its errors name `dest` (a full disk says which output could not be
    /// written).
    pub fn writer(&self, dest: &Path) -> Result<Box<dyn Write>> {
        if is_stdout(dest) {
            return Ok(Box::new(Named {
                inner: std::io::BufWriter::new(std::io::stdout()),
                dest: dest.to_path_buf(),
            }));
        }
        let (f, _) = self.stage_file(dest)?;
        Ok(Box::new(Named {
            inner: std::io::BufWriter::new(f),
            dest: dest.to_path_buf(),
        }))
    }

    /// Rename every staged temporary into place, all or nothing: every
    /// destination is checked first (no input of the run, whatever read it; a
    /// replaceable file), each file a destination replaces is kept aside (a hard
    /// link, else a copy) until every rename has succeeded, and a failed rename
    /// puts the old files back. If even that fails, the error says which files
    /// are new and where the old ones are.
    pub fn commit(&self) -> Result<()> {
        /// What a failed commit that changed nothing says (the run's
        /// summary may already have announced its outputs).
        const NOTHING_WRITTEN: &str = "no output was written (the outputs announced above are not there; every earlier file is as it was)";
        // The writers finish first, their temporaries still registered (so that
        // Ctrl-C meanwhile removes them).
        let writers: Vec<_> = self
            .state()
            .staged
            .iter_mut()
            .filter_map(|s| s.writing.take().map(|w| (s.dest.clone(), w)))
            .collect();
        for (dest, w) in writers {
            if let Err(e) = written(Some(w)) {
                self.discard();
                return Err(Error::io(&dest, Verb::Write, e).context(NOTHING_WRITTEN));
            }
        }
        // The renames hold the state: Ctrl-C or SIGTERM meanwhile waits until
        // every output is in place or every old file is back (then reports it),
        // instead of exiting halfway.
        let mut guard = self.state();
        if let Err(e) = self.replaceable(&guard) {
            discard_in(&mut guard);
            return Err(e.context(NOTHING_WRITTEN));
        }
        // Each replaced file kept aside first.
        let mut kept: Vec<Option<PathBuf>> = vec![];
        for s in &guard.staged {
            match self.keep_aside(&s.dest) {
                Ok(k) => kept.push(k),
                Err(e) => {
                    for k in kept.iter().flatten() {
                        let _ = std::fs::remove_file(k);
                    }
                    discard_in(&mut guard);
                    return Err(e.context(NOTHING_WRITTEN));
                }
            }
        }
        guard.committed = true;
        let staged = std::mem::take(&mut guard.staged);
        for (k, s) in staged.iter().enumerate() {
            if let Err(e) = std::fs::rename(&s.tmp, &s.dest) {
                for rest in &staged[k..] {
                    let _ = std::fs::remove_file(&rest.tmp);
                }
                let undone = roll_back(&staged[..k], &kept[..k]);
                for k in kept[k..].iter().flatten() {
                    let _ = std::fs::remove_file(k);
                }
                guard.committed = false;
                discard_in(&mut guard);
                let e = Error::io(&s.dest, Verb::Write, e);
                return Err(match undone {
                    Ok(()) => e.context(
                        "no output was written (the files replaced so far are back; the outputs announced above are not there)",
                    ),
                    Err(left) => e.context(left),
                });
            }
        }
        for k in kept.iter().flatten() {
            let _ = std::fs::remove_file(k);
        }
        guard.created.clear();
        drop(guard);
        let out = std::mem::take(&mut self.state().stdout);
        if !out.is_empty() {
            let mut o = std::io::stdout().lock();
            o.write_all(&out)
                .and_then(|()| o.flush())
                .map_err(|e| Error::io(Path::new("-"), Verb::Write, e))?;
        }
        Ok(())
    }

    /// Every staged destination can be replaced: it is no input of the run (an
    /// input read after the output was planned included), no two are the same
    /// file, each is a regular file or absent, and its directory lets this user
    /// replace it (a sticky directory keeps other users' files).
    fn replaceable(&self, s: &State) -> Result<()> {
        let mut seen: Vec<(&Path, Vec<Key>)> = vec![];
        for x in &s.staged {
            if let Some(i) = self.input_hit(&x.dest, &s.created) {
                return Err(also_an_input(&x.dest, &i));
            }
            let k = keys(&x.dest, &s.created)?;
            if let Some((p, _)) = seen.iter().find(|(_, pk)| k.iter().any(|a| pk.contains(a))) {
                return Err(Error::Output {
                    path: x.dest.clone(),
                    problem: OutputProblem::SameAs(p.to_path_buf()),
                });
            }
            seen.push((&x.dest, k));
            if let Ok(meta) = std::fs::symlink_metadata(&x.dest) {
                if !meta.file_type().is_file() {
                    return Err(Error::Output {
                        path: x.dest.clone(),
                        problem: OutputProblem::NotRegular,
                    });
                }
                if !may_replace(&x.dest, &meta) {
                    return Err(Error::Output {
                        path: x.dest.clone(),
                        problem: OutputProblem::OtherUsers,
                    });
                }
            }
        }
        Ok(())
    }

    /// Keep the file `dest` would replace: a hard link beside it (else a copy)
    /// named `.NAME.tmp-PID-N`; `None` when there is no such file.
    #[doc(hidden)] // public for the integration tests only
    pub fn keep_aside(&self, dest: &Path) -> Result<Option<PathBuf>> {
        if std::fs::symlink_metadata(dest).is_err() {
            return Ok(None);
        }
        let (f, aside) = self.temporary(dest)?;
        drop(f);
        let _ = std::fs::remove_file(&aside);
        if std::fs::hard_link(dest, &aside).is_ok() {
            return Ok(Some(aside));
        }
        match std::fs::copy(dest, &aside) {
            Ok(_) => Ok(Some(aside)),
            Err(e) => {
                let _ = std::fs::remove_file(&aside);
                Err(Error::io(dest, Verb::Write, e).context(format!(
                    "cannot keep the old {} aside while the outputs are written; no output was written",
                    dest.display()
                )))
            }
        }
    }

    /// Remove every staged temporary and the directories this run created.
    pub fn discard(&self) {
        discard_in(&mut self.state());
    }
}

pub use crate::error::InputKind;

/// The largest description read whole, by default (MiB): a mechanism file
/// or a printer's configuration is kilobytes.
pub const MAX_DESCRIPTION_MB: u64 = 16;
/// The largest data file read whole, by default (MiB): 10⁶ measured poses
/// are about 100 MB. (Commands and targets are streamed: no limit but a
/// line's, [`MAX_LINE_BYTES`].)
pub const MAX_DATA_MB: u64 = 256;
/// The longest line of a streamed file.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// A writer whose errors name its destination: "cannot write out.csv: No
/// space left on device".
struct Named<W> {
    inner: W,
    dest: PathBuf,
}

impl<W: Write> Named<W> {
    fn named(&self, e: std::io::Error) -> std::io::Error {
        if is_stdout(&self.dest) {
            let message = format!("cannot write to standard output: {e}");
            return std::io::Error::new(e.kind(), message);
        }
        std::io::Error::new(e.kind(), Error::io(&self.dest, Verb::Write, e))
    }
}

impl<W: Write> Write for Named<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.inner.write(buf).map_err(|e| self.named(e))
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.inner.write_all(buf).map_err(|e| self.named(e))
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush().map_err(|e| self.named(e))
    }
}

/// A reader that fails on a line longer than [`MAX_LINE_BYTES`], so that a
/// stream without line ends (`/dev/zero`) cannot grow a record without
/// bound.
pub struct LineLimit<R> {
    inner: R,
    /// Bytes since the last line end.
    run: usize,
    /// Line ends as `\n`.
    ends: LineEnds,
}

/// `\r\n` and a lone `\r` (old Mac files) as `\n`, over one buffer or a
/// stream of them: lines are then counted right and comment lines found,
/// whichever line ends a file uses.
#[derive(Debug, Default)]
pub struct LineEnds {
    /// Whether the last byte seen was a `\r`.
    cr: bool,
}

impl LineEnds {
    /// Rewrite `buf` in place, its line ends as `\n`; its new length.
    pub fn unify(&mut self, buf: &mut [u8]) -> usize {
        let mut w = 0;
        for r in 0..buf.len() {
            let b = buf[r];
            if b == b'\n' && self.cr {
                // The `\n` of a `\r\n`: the `\r` already ended the line.
                self.cr = false;
                continue;
            }
            self.cr = b == b'\r';
            buf[w] = if self.cr { b'\n' } else { b };
            w += 1;
        }
        w
    }
}

impl<R: std::io::Read> std::io::Read for LineLimit<R> {
    /// Line ends read as `\n`, whichever the file uses (`\n`, `\r\n`, or
    /// `\r` alone, as old Mac files have), so that lines are counted right.
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let n = self.inner.read(buf)?;
            if n == 0 {
                return Ok(0);
            }
            let w = self.ends.unify(&mut buf[..n]);
            if w > 0 {
                self.check(&buf[..w])?;
                return Ok(w);
            }
        }
    }
}

impl<R> LineLimit<R> {
    fn check(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        for &b in bytes {
            if b == b'\n' {
                self.run = 0;
            } else {
                self.run += 1;
                if self.run > MAX_LINE_BYTES {
                    return Err(std::io::Error::other(format!(
                        "a line is longer than {} MiB; this is not a table of numbers",
                        MAX_LINE_BYTES >> 20
                    )));
                }
            }
        }
        Ok(())
    }
}

fn also_an_input(dest: &Path, input: &Path) -> Error {
    Error::Output {
        path: dest.to_path_buf(),
        problem: OutputProblem::AlsoInput(input.to_path_buf()),
    }
}

/// What a path names, for comparisons: its file identity when it exists,
/// else its canonical directory joined with its name.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Key {
    File(u64, u64),
    Path(PathBuf),
}

fn identity(meta: &std::fs::Metadata) -> Key {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        Key::File(meta.dev(), meta.ino())
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        Key::Path(PathBuf::new())
    }
}

/// The canonical form of a path whose file may not exist yet; its directory
/// must exist unless it lies in one of `created` (directories the run makes).
fn canonical(path: &Path, created: &[PathBuf]) -> Result<PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Ok(p);
    }
    let name = path.file_name().ok_or_else(|| Error::Output {
        path: path.to_path_buf(),
        problem: OutputProblem::NoFileName,
    })?;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    match dir.canonicalize() {
        Ok(d) => Ok(d.join(name)),
        Err(_) if created.iter().any(|c| dir.starts_with(c)) => {
            // The nearest existing ancestor, then the rest as given.
            let mut base = dir;
            let mut rest = vec![name];
            while let Some(p) = base.parent().filter(|_| base.canonicalize().is_err()) {
                rest.push(base.file_name().unwrap_or_default());
                base = if p.as_os_str().is_empty() {
                    Path::new(".")
                } else {
                    p
                };
            }
            let mut out = base.canonicalize().unwrap_or_else(|_| base.to_path_buf());
            for r in rest.iter().rev() {
                out.push(r);
            }
            Ok(out)
        }
        Err(_) => Err(Error::Output {
            path: path.to_path_buf(),
            problem: OutputProblem::MissingDirectory(dir.to_path_buf()),
        }),
    }
}

fn keys(path: &Path, created: &[PathBuf]) -> Result<Vec<Key>> {
    let mut k = vec![Key::Path(canonical(path, created)?)];
    if let Ok(meta) = std::fs::metadata(path) {
        k.push(identity(&meta));
    }
    Ok(k)
}

/// The files a directory output holds (`names` inside `dir`), for
/// [`check`]; the directory itself must be a directory if it exists.
pub fn in_dir(dir: &Path, names: &[&str]) -> Result<Vec<PathBuf>> {
    if let Ok(meta) = std::fs::symlink_metadata(dir)
        && !meta.is_dir()
    {
        return Err(Error::Output {
            path: dir.to_path_buf(),
            problem: OutputProblem::NotADirectory,
        });
    }
    Ok(names.iter().map(|n| dir.join(n)).collect())
}

/// The longest part of a destination's name a temporary's name keeps (a
/// legal 255-byte name plus the suffix would exceed the file system's limit).
const TEMPORARY_NAME_KEEP: usize = 160;

/// The directory of `dest`'s temporaries and their name's start,
/// `.NAME.tmp-` (`NAME` cut to [`TEMPORARY_NAME_KEEP`] bytes); `None` when
/// `dest` has no file name.
fn temporary_prefix(dest: &Path) -> Option<(PathBuf, String)> {
    let name = dest.file_name()?.to_string_lossy();
    let dir = dest
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut cut = name.len().min(TEMPORARY_NAME_KEEP);
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    Some((dir.to_path_buf(), format!(".{}.tmp-", &name[..cut])))
}

/// The path that means standard output.
pub fn is_stdout(dest: &Path) -> bool {
    dest == Path::new("-")
}

/// Whether this user may rename over the existing file `dest`: in a sticky
/// directory only the file's or the directory's owner (or root) may.
#[cfg(unix)]
fn may_replace(dest: &Path, meta: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    let dir = dest
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let Ok(d) = std::fs::metadata(dir) else {
        return true;
    };
    // The effective user is the owner of a file this process creates: the
    // process's own temporaries show it without an unsafe call.
    let me = current_uid();
    const STICKY: u32 = 0o1000;
    d.mode() & STICKY == 0 || me == Some(0) || me == Some(meta.uid()) || me == Some(d.uid())
}

#[cfg(not(unix))]
fn may_replace(_: &Path, _: &std::fs::Metadata) -> bool {
    true
}

/// The effective user id, read from `/proc/self` (owned by it); `None`
/// where that cannot be read (then no destination is refused for it).
#[cfg(unix)]
fn current_uid() -> Option<u32> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata("/proc/self").ok().map(|m| m.uid())
}

/// Undo the renames of `done`: each old file back from where it was kept,
/// each new one removed where there was none. On failure, a message that
/// names the new files left and where the old ones are.
#[doc(hidden)] // public for the integration tests only
pub fn roll_back(done: &[Staged], kept: &[Option<PathBuf>]) -> std::result::Result<(), String> {
    let mut left = vec![];
    for (s, k) in done.iter().zip(kept).rev() {
        let back = match k {
            Some(k) => std::fs::rename(k, &s.dest),
            None => std::fs::remove_file(&s.dest),
        };
        if back.is_err() {
            left.push(match k {
                Some(k) => format!(
                    "{} is new; the old file is {}",
                    s.dest.display(),
                    k.display()
                ),
                None => format!("{} is new (there was none before)", s.dest.display()),
            });
        }
    }
    if left.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "some outputs could not be put back: {}",
            left.join("; ")
        ))
    }
}

/// [`discard`] with the state held.
fn discard_in(s: &mut State) {
    s.stdout.clear();
    for x in s.staged.drain(..) {
        let _ = written(x.writing);
        let _ = std::fs::remove_file(&x.tmp);
    }
    // Deepest first: a directory is empty only once those inside it are gone.
    let mut created = std::mem::take(&mut s.created);
    created.sort_by_key(|d| std::cmp::Reverse(d.components().count()));
    for d in created {
        let _ = std::fs::remove_dir(&d);
    }
}
