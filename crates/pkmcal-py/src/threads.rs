//! Where the work runs: each call on a thread pool of its own while it
//! runs (taken from the idle pools, made when none is idle), with the GIL
//! released, so that calls from several Python threads compute side by
//! side; a long call watched for Ctrl-C.

use crate::errors::raise;
use pyo3::prelude::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The threads wanted per pool ([`set_threads`]; 0 for one per core).
static THREADS: AtomicUsize = AtomicUsize::new(0);

/// The most threads a pool may have: beyond any machine's cores, and a
/// bound on what a typo can start.
pub const MAX_THREADS: usize = 1024;

/// Idle pools kept for the next calls (more are let go when their calls
/// end).
const IDLE_POOLS: usize = 4;

/// This process's idle pools: its process id, their size and the pools. A
/// process forked from one that had pools inherits their handles but not
/// their threads, so work sent to them would wait forever: a process makes
/// its own, and a forked child leaves its parent's alone.
struct Idle {
    pid: u32,
    threads: usize,
    pools: Vec<Arc<rayon::ThreadPool>>,
}

static IDLE: std::sync::Mutex<Option<Idle>> = std::sync::Mutex::new(None);

/// A pool lent to one call, back with the idle ones when the call ends.
pub struct Lease {
    pool: Arc<rayon::ThreadPool>,
    threads: usize,
}

impl Lease {
    /// The pool.
    pub fn pool(&self) -> &rayon::ThreadPool {
        &self.pool
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        let mut g = IDLE.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(idle) = g.as_mut()
            && idle.pid == std::process::id()
            && idle.threads == self.threads
            && idle.pools.len() < IDLE_POOLS
        {
            idle.pools.push(self.pool.clone());
        }
    }
}

/// A pool for one call. Called with the GIL held, so that no fork (which
/// holds the GIL) can copy the lock while it is held.
pub fn lease() -> PyResult<Lease> {
    let threads = THREADS.load(Ordering::Relaxed);
    let pid = std::process::id();
    {
        let mut g = IDLE.lock().unwrap_or_else(|e| e.into_inner());
        match g.as_mut() {
            Some(idle) if idle.pid == pid && idle.threads == threads => {
                if let Some(pool) = idle.pools.pop() {
                    return Ok(Lease { pool, threads });
                }
            }
            _ => {
                if let Some(old) = g.replace(Idle {
                    pid,
                    threads,
                    pools: vec![],
                }) && old.pid != pid
                {
                    // The parent's pools, copied by a fork: their threads
                    // are not here, so dropping them would wait forever.
                    std::mem::forget(old);
                }
            }
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| raise(format!("cannot start pkmcal's threads: {e}"), None))?;
    Ok(Lease {
        pool: Arc::new(pool),
        threads,
    })
}

/// The number of threads each call computes with (read by the wrapper).
pub fn set_threads(n: usize) {
    THREADS.store(n, Ordering::Relaxed);
}

/// How often a long call looks for Ctrl-C while the work runs.
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(20);

/// Run `f` (given a cancel flag the library polls between its steps) on a
/// pool of its own, on a thread of its own, while this thread, the
/// caller's, looks for Python's signals every [`SIGNAL_POLL`]: a Ctrl-C
/// sets the flag, waits for the work to stop at its next step (a row, a
/// pose, an evaluation, a run, a candidate) and raises Python's
/// KeyboardInterrupt. The GIL is released meanwhile. A panic in the work is
/// an exception, never a crash.
pub fn interruptible<T: Send>(
    py: Python<'_>,
    f: impl FnOnce(Arc<AtomicBool>) -> T + Send,
) -> PyResult<T> {
    let cancel = Arc::new(AtomicBool::new(false));
    let flag = cancel.clone();
    let lease = lease()?;
    let pool = lease.pool();
    let out = std::thread::scope(|scope| {
        let work = scope.spawn(move || pool.install(|| f(flag)));
        loop {
            let done = py.detach(|| {
                let start = std::time::Instant::now();
                while !work.is_finished() && start.elapsed() < SIGNAL_POLL {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                }
                work.is_finished()
            });
            if done {
                break;
            }
            if let Err(e) = py.check_signals() {
                cancel.store(true, Ordering::Relaxed);
                let _ = py.detach(|| work.join());
                return Err(e);
            }
        }
        py.detach(|| work.join()).map_err(|_| internal())
    });
    drop(lease);
    out
}

/// Rows a call handles at once without watching for Ctrl-C: well under a
/// second of work on any mechanism.
pub const QUICK_ROWS: usize = 1000;

/// `f` as [`interruptible`] runs it when `long`; else at once (a short
/// call needs no watching, nor a thread of its own to watch from).
pub fn run<T: Send>(
    py: Python<'_>,
    long: bool,
    f: impl FnOnce(Arc<AtomicBool>) -> T + Send,
) -> PyResult<T> {
    if long {
        interruptible(py, f)
    } else {
        let flag = Arc::new(AtomicBool::new(false));
        quick(py, || f(flag))
    }
}

/// Run `f` (a short computation) on a pool of its own with the GIL
/// released; a panic in it is an exception.
pub fn quick<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    let lease = lease()?;
    let pool = lease.pool();
    py.detach(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| pool.install(f))))
        .map_err(|_| internal())
}

fn internal() -> PyErr {
    raise(
        "pkmcal's computation failed unexpectedly (an internal error); please report it".into(),
        None,
    )
}
