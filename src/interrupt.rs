//! How the process ends when it is interrupted: Ctrl-C (SIGINT), SIGTERM
//! (a batch's workers get it when their parent dies) and SIGHUP end it at
//! once with 128 + the signal, as a shell reports it, after removing the
//! temporary folders that are registered here (a results folder being
//! filled, the capture of SUMO's messages). Nothing half-written is left
//! behind: a results folder only ever appears complete.
//!
//! The signals are blocked in every thread and taken by one watcher thread
//! ([`watch`], called first thing, before any other thread exists), so the
//! removal runs in an ordinary thread, not in a signal handler. A process
//! killed outright (SIGKILL, the kernel's OOM killer) cannot clean up: its
//! folders carry its pid and the next coid removes them (`io::folder`,
//! `bridge`). A panic unwinds, and the owners' destructors remove them.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Temporary paths to remove if the process is interrupted.
static TEMPORARY: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Set by [`watch`]: coid is the process's main program and owns its
/// signals. Inside someone else's Python (the package's API) it is not
/// set, and the interpreter keeps its own handlers (Ctrl-C raises
/// `KeyboardInterrupt` when the call returns).
static OWNS_SIGNALS: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Set when the interpreter that loaded coid was interrupted (Ctrl-C)
/// while a command runs (the Python package's `call`): the command stops
/// at its next SUMO step with an error, and its temporary folders are
/// removed by their owners as on any error.
static STOP: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Asks the running command to stop ([`STOP`]).
pub fn request_stop() {
    STOP.store(true, std::sync::atomic::Ordering::SeqCst);
}

/// Lets commands run again (the next command starts afresh).
pub fn clear_stop() {
    STOP.store(false, std::sync::atomic::Ordering::SeqCst);
}

/// Whether the running command was asked to stop.
pub fn stop_requested() -> bool {
    STOP.load(std::sync::atomic::Ordering::SeqCst)
}

/// Blocks SIGINT, SIGTERM and SIGHUP in this thread (and so in every
/// thread started after it) and starts the thread that takes them: it
/// removes the registered paths, then ends the process with 128 + the
/// signal. Call once, while the process has one thread. Should the
/// thread not start, the signals end the process as before (without the
/// removal).
pub fn watch() {
    OWNS_SIGNALS.store(true, std::sync::atomic::Ordering::SeqCst);
    // SAFETY: plain signal-set manipulation on a local set.
    let set = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            libc::sigaddset(&mut set, signal);
        }
        libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
        set
    };
    let started = std::thread::Builder::new()
        .name("coid-signals".into())
        .spawn(move || {
            loop {
                let mut signal: libc::c_int = 0;
                // SAFETY: waits for one of the blocked signals.
                if unsafe { libc::sigwait(&set, &mut signal) } == 0 {
                    remove_paths(&registered());
                    // SAFETY: ends the process without running other
                    // threads' destructors (they may be mid-write).
                    unsafe { libc::_exit(128 + signal) };
                }
            }
        });
    if started.is_err() {
        // SAFETY: undoes the block above.
        unsafe {
            libc::pthread_sigmask(libc::SIG_UNBLOCK, &set, std::ptr::null_mut());
        }
    }
    install_handlers();
}

/// Handlers that end the process with 128 + the signal, in case a signal
/// reaches a thread that does not block it (the watcher could not start,
/// or foreign code changed a thread's mask): no removal then, but never a
/// Python KeyboardInterrupt inside SUMO. Installed again after Python
/// starts, in case an imported module took the signals. Nothing when
/// coid does not own the process's signals ([`watch`] was not called).
pub fn install_handlers() {
    if !OWNS_SIGNALS.load(std::sync::atomic::Ordering::SeqCst) {
        return;
    }
    extern "C" fn on_signal(signal: libc::c_int) {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(128 + signal) }
    }
    for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: a plain handler that only calls _exit.
        unsafe {
            libc::signal(signal, on_signal as *const () as libc::sighandler_t);
        }
    }
    // A closed pipe on stdout (`coid ... | head`) ends the process
    // quietly, as it does any Unix tool, instead of a panic in println!.
    // SAFETY: restores the default disposition.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// The registered paths, newest last.
fn registered() -> Vec<PathBuf> {
    TEMPORARY.lock().map(|v| v.clone()).unwrap_or_default()
}

/// Removes `paths` (files and folders, newest first, best effort).
fn remove_paths(paths: &[PathBuf]) {
    for p in paths.iter().rev() {
        if p.is_dir() {
            // Other threads may still add a file meanwhile: try again.
            for _ in 0..5 {
                if std::fs::remove_dir_all(p).is_ok() || !p.exists() {
                    break;
                }
            }
        } else {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// A path removed if the process is interrupted, for as long as this
/// value lives (its owner removes it otherwise).
#[derive(Debug)]
pub struct Registered(PathBuf);

/// Makes a temporary path with `make` and registers it in one step. The
/// watcher reads the registry under the same lock, so a signal taken
/// between the path's creation and its registration waits for the
/// registration and then removes it: no window in which a made path
/// escapes removal.
pub fn make_registered<T: AsRef<Path>, E>(
    make: impl FnOnce() -> Result<T, E>,
) -> Result<(T, Registered), E> {
    let mut paths = TEMPORARY
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let made = make()?;
    let path = made.as_ref().to_owned();
    paths.push(path.clone());
    Ok((made, Registered(path)))
}

impl Drop for Registered {
    fn drop(&mut self) {
        if let Ok(mut v) = TEMPORARY.lock()
            && let Some(k) = v.iter().rposition(|p| p == &self.0)
        {
            v.remove(k);
        }
    }
}

/// Whether process `pid` exists (signal 0 probes without sending): the
/// temporary folders of a process that is gone may be removed.
pub fn process_runs(pid: i32) -> bool {
    if pid <= 0 {
        return false;
    }
    // SAFETY: kill with signal 0 only checks for the process.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression (CI of 2026-11-26, `r31_12_no_temporary_files_are_left_behind`):
    /// Ctrl-C right after a staging folder was made, before it was
    /// registered, left it behind. The watcher's read of the registry now
    /// waits for a path being made and finds it.
    #[test]
    fn r33_ctrl_c_while_a_staging_folder_is_made_finds_it_registered() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("staging");
        let (inside, wait) = std::sync::mpsc::channel();
        let maker = {
            let path = path.clone();
            std::thread::spawn(move || {
                make_registered(|| {
                    inside.send(()).unwrap();
                    std::thread::sleep(std::time::Duration::from_millis(100));
                    std::fs::create_dir(&path).map(|()| path.clone())
                })
                .unwrap()
            })
        };
        wait.recv().unwrap();
        // What the watcher reads when a signal comes now.
        assert!(registered().contains(&path));
        drop(maker.join().unwrap());
        assert!(!registered().contains(&path));
    }

    #[test]
    fn registered_paths_are_listed_until_dropped_and_removed_on_demand() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a");
        std::fs::create_dir_all(a.join("inner")).unwrap();
        let b = dir.path().join("b.log");
        std::fs::write(&b, "x").unwrap();
        let kept = dir.path().join("kept");
        std::fs::create_dir_all(&kept).unwrap();
        let register = |p: &PathBuf| make_registered(|| Ok::<_, ()>(p.clone())).unwrap().1;
        let (ra, rb) = (register(&a), register(&b));
        drop(register(&kept));
        let now = registered();
        assert!(now.contains(&a) && now.contains(&b) && !now.contains(&kept));
        remove_paths(&[a.clone(), b.clone()]);
        assert!(!a.exists() && !b.exists());
        assert!(kept.exists());
        drop((ra, rb));
        assert!(!registered().contains(&a));
        // Made and registered in one step; a failed make is an error.
        let made = dir.path().join("made");
        let (path, r) = make_registered(|| {
            std::fs::create_dir(&made)?;
            Ok::<_, std::io::Error>(made.clone())
        })
        .unwrap();
        assert_eq!(path, made);
        assert!(registered().contains(&made));
        drop(r);
        assert!(!registered().contains(&made));
        assert!(make_registered(|| Err::<PathBuf, _>("no")).is_err());
        assert!(process_runs(std::process::id() as i32));
        assert!(!process_runs(2_147_483_000));
    }
}
