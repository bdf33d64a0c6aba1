//! The outputs of a run: checked before any work (never an input, never each
//! other, never a device, a pipe or a link), written to temporaries next to
//! their destination, and renamed into place together only when the whole run
//! has succeeded. On failure, a panic, Ctrl-C or SIGTERM the temporaries are
//! removed and every earlier file is left as it was.
//!
//! Written here rather than taken from a crate: `tempfile` persists one file
//! at a time, and a run must commit several (parameters, report, figures) or
//! none.

use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// A usage error: a bad option value or combination, exit code 2.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for Usage {}

/// `Err(Usage(..))`.
pub fn usage<T>(message: impl Into<String>) -> Result<T> {
    Err(Usage(message.into()).into())
}

/// A temporary and the file it becomes.
struct Staged {
    tmp: PathBuf,
    dest: PathBuf,
    /// The thread writing a whole output ([`stage`]) and flushing it to
    /// disk, joined at [`commit`].
    writing: Option<std::thread::JoinHandle<std::io::Result<()>>>,
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

static STATE: Mutex<State> = Mutex::new(State {
    staged: vec![],
    created: vec![],
    stdout: vec![],
    committed: false,
});

fn state() -> std::sync::MutexGuard<'static, State> {
    STATE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Remove the temporaries on Ctrl-C, SIGTERM and panics.
pub fn install_cleanup() {
    let _ = ctrlc::set_handler(|| {
        // The state stays held until the exit: the run cannot stage or
        // commit anything after the temporaries are removed.
        let mut s = state();
        let committed = s.committed;
        discard_in(&mut s);
        // (Not `eprintln!`: with standard error closed it would panic, and
        // the panic hook wait for the state held here.)
        let _ = writeln!(
            std::io::stderr(),
            "{}",
            if committed {
                "interrupted after the outputs were written (they are complete)"
            } else {
                "interrupted: no output was written"
            }
        );
        std::process::exit(130);
    });
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        discard();
        // `println!` panics when standard output is closed (`| head`) or
        // full: a one-line error and exit 1, not a panic report.
        let message = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if let Some(cause) = message.strip_prefix("failed printing to stdout: ") {
            eprintln!("error: cannot write to standard output: {cause}");
            std::process::exit(1);
        }
        default(info);
    }));
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
    let name = path
        .file_name()
        .with_context(|| format!("{} is not a file name", path.display()))?;
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
        Err(_) => usage(format!(
            "cannot write {}: the directory {} does not exist",
            path.display(),
            dir.display()
        )),
    }
}

fn keys(path: &Path, created: &[PathBuf]) -> Result<Vec<Key>> {
    let mut k = vec![Key::Path(canonical(path, created)?)];
    if let Ok(meta) = std::fs::metadata(path) {
        k.push(identity(&meta));
    }
    Ok(k)
}

/// Check a run's planned outputs before any work: each must be a new or
/// regular file in an existing directory, none may be one of the `inputs`
/// (through any path or link) or another output. Files in `dirs` (output
/// directories the run creates) may have a missing directory. Errors are
/// usage errors.
pub fn check(inputs: &[&Path], outputs: &[&Path], dirs: &[PathBuf]) -> Result<()> {
    let mut input_keys = vec![];
    for i in inputs {
        if let Ok(k) = keys(i, &[]) {
            input_keys.push((i, k));
        }
    }
    let mut seen: Vec<(&Path, Vec<Key>)> = vec![];
    for o in outputs.iter().filter(|o| !is_stdout(o)) {
        if let Ok(meta) = std::fs::symlink_metadata(o) {
            let t = meta.file_type();
            if t.is_symlink() {
                return usage(format!(
                    "{} is a symbolic link; give the path of the file itself",
                    o.display()
                ));
            }
            if !t.is_file() {
                return usage(format!(
                    "{} exists and is not a regular file (a directory, a pipe or a device); give a file path",
                    o.display()
                ));
            }
        }
        let k = keys(o, dirs)?;
        for (i, ik) in &input_keys {
            if k.iter().any(|a| ik.contains(a)) {
                return usage(format!(
                    "{} is also an input ({}); write the output to another file",
                    o.display(),
                    i.display()
                ));
            }
        }
        for (p, pk) in &seen {
            if k.iter().any(|a| pk.contains(a)) {
                return usage(format!(
                    "{} and {} are the same file; give each output its own path",
                    p.display(),
                    o.display()
                ));
            }
        }
        seen.push((o, k));
    }
    Ok(())
}

/// The files a directory output holds (`names` inside `dir`), for
/// [`check`]; the directory itself must be a directory if it exists.
pub fn in_dir(dir: &Path, names: &[&str]) -> Result<Vec<PathBuf>> {
    if let Ok(meta) = std::fs::symlink_metadata(dir)
        && !meta.is_dir()
    {
        return usage(format!(
            "{} exists and is not a directory; give a directory path",
            dir.display()
        ));
    }
    Ok(names.iter().map(|n| dir.join(n)).collect())
}

/// Create `dir` (and its parents) for outputs; removed again if the run
/// fails and it is still empty.
pub fn create_dir(dir: &Path) -> Result<()> {
    let mut missing = vec![];
    let mut d = Some(dir);
    while let Some(p) = d.filter(|p| !p.as_os_str().is_empty() && !p.exists()) {
        missing.push(p.to_path_buf());
        d = p.parent();
    }
    // Created and registered under the state (an interruption removes it).
    let mut s = state();
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    s.created.extend(missing);
    Ok(())
}

fn temporary(dest: &Path) -> Result<PathBuf> {
    let name = dest
        .file_name()
        .with_context(|| format!("{} is not a file name", dest.display()))?;
    let dir = dest
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    Ok(dir.join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    )))
}

/// Remove temporaries of `dest` left by runs that were killed (SIGKILL
/// cannot be caught): `.NAME.tmp-PID` whose process no longer exists.
fn sweep_stale(dest: &Path) {
    let (Some(name), dir) = (
        dest.file_name(),
        dest.parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new(".")),
    ) else {
        return;
    };
    let prefix = format!(".{}.tmp-", name.to_string_lossy());
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = n.strip_prefix(&prefix).and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        let alive = pid == std::process::id() || Path::new(&format!("/proc/{pid}")).exists();
        if !alive && Path::new("/proc/self").exists() {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Stage `bytes` for `dest`: the temporary is created now, written and
/// flushed to disk (`fsync`) on a thread of its own while the run goes on
/// (the flush takes about 0.5 ms, a twentieth of a small calibration), and
/// renamed at [`commit`], which waits for it and reports a failed write.
pub fn stage(dest: &Path, bytes: &[u8]) -> Result<()> {
    if is_stdout(dest) {
        state().stdout.extend_from_slice(bytes);
        return Ok(());
    }
    let (f, tmp) = stage_file(dest)?;
    let bytes: std::sync::Arc<[u8]> = bytes.into();
    let write = |mut f: std::fs::File, bytes: &[u8]| f.write_all(bytes).and_then(|()| f.sync_all());
    let mine = bytes.clone();
    match std::thread::Builder::new()
        .name("write".into())
        .spawn(move || write(f, &mine))
    {
        Ok(handle) => {
            if let Some(s) = state().staged.iter_mut().find(|x| x.dest == dest) {
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
            .with_context(|| format!("cannot write {}", dest.display())),
    }
}

/// A temporary file for `dest`, registered for [`commit`] (for outputs
/// written as they are computed).
pub fn stage_file(dest: &Path) -> Result<(std::fs::File, PathBuf)> {
    // A second output for the same destination replaces the first: its
    // writer (same temporary) finishes first.
    let earlier = state()
        .staged
        .iter_mut()
        .find(|x| x.dest == dest)
        .and_then(|x| x.writing.take());
    if let Some(h) = earlier {
        let _ = h.join();
    }
    // Created and registered under the state (an interruption removes it).
    let mut s = state();
    sweep_stale(dest);
    let tmp = temporary(dest)?;
    let f =
        std::fs::File::create(&tmp).with_context(|| format!("cannot write {}", dest.display()))?;
    s.staged.retain(|x| x.dest != dest);
    s.staged.push(Staged {
        tmp: tmp.clone(),
        dest: dest.to_path_buf(),
        writing: None,
    });
    Ok((f, tmp))
}

/// The path that means standard output.
pub fn is_stdout(dest: &Path) -> bool {
    dest == Path::new("-")
}

/// A buffered writer for an output written as it is computed: standard
/// output for `-`, else a staged temporary ([`stage_file`]). Flush it at the
/// end.
pub fn writer(dest: &Path) -> Result<Box<dyn Write>> {
    if is_stdout(dest) {
        return Ok(Box::new(std::io::BufWriter::new(std::io::stdout())));
    }
    let (f, _) = stage_file(dest)?;
    Ok(Box::new(std::io::BufWriter::new(f)))
}

/// Rename every staged temporary into place.
pub fn commit() -> Result<()> {
    // The writers finish first, their temporaries still registered (so that
    // Ctrl-C meanwhile removes them).
    let writers: Vec<_> = state()
        .staged
        .iter_mut()
        .filter_map(|s| s.writing.take().map(|w| (s.dest.clone(), w)))
        .collect();
    for (dest, w) in writers {
        if let Err(e) = written(Some(w)) {
            discard();
            return Err(e).with_context(|| format!("cannot write {}", dest.display()));
        }
    }
    // The renames hold the state: Ctrl-C or SIGTERM meanwhile waits until
    // every output is in place (then reports it), instead of exiting with
    // some renamed and the others' temporaries left behind.
    let mut guard = state();
    guard.committed = true;
    let staged = std::mem::take(&mut guard.staged);
    for (k, s) in staged.iter().enumerate() {
        if let Err(e) = std::fs::rename(&s.tmp, &s.dest) {
            for rest in &staged[k..] {
                let _ = std::fs::remove_file(&rest.tmp);
            }
            return Err(e).with_context(|| format!("cannot write {}", s.dest.display()));
        }
    }
    guard.created.clear();
    drop(guard);
    let out = std::mem::take(&mut state().stdout);
    if !out.is_empty() {
        let mut o = std::io::stdout().lock();
        o.write_all(&out)
            .and_then(|()| o.flush())
            .context("cannot write to standard output")?;
    }
    Ok(())
}

/// Remove every staged temporary and the directories this run created.
pub fn discard() {
    discard_in(&mut state());
}

/// [`discard`] with the state held.
fn discard_in(s: &mut State) {
    s.stdout.clear();
    for x in s.staged.drain(..) {
        let _ = written(x.writing);
        let _ = std::fs::remove_file(&x.tmp);
    }
    for d in s.created.drain(..) {
        let _ = std::fs::remove_dir(&d);
    }
}
