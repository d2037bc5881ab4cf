//! Process plumbing for the 1 kHz programs: an orderly-stop flag set by SIGINT/SIGTERM/SIGHUP, a
//! watchdog on the last valid message, the exit codes, and the loop options both `run`
//! commands share ([`LoopArgs`]).
#![allow(unsafe_code)]

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);
static SIGNALLED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_sig: libc::c_int) {
    SIGNALLED.store(true, Ordering::SeqCst);
    STOP.store(true, Ordering::SeqCst);
}

/// Installs SIGINT, SIGTERM and SIGHUP handlers that only set a flag ([`stop_requested`]);
/// the loop checks it and stops in order (safe state, recording closed, summary written).
pub fn install_stop_handlers() -> std::io::Result<()> {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        let prev = unsafe { libc::signal(sig, on_signal as *const () as libc::sighandler_t) };
        if prev == libc::SIG_ERR {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

/// Whether a stop was requested: SIGINT, SIGTERM, SIGHUP or [`request_stop`].
pub fn stop_requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

/// Whether SIGINT, SIGTERM or SIGHUP has arrived (a stop asked for by [`request_stop`] is not a
/// signal).
pub fn signal_received() -> bool {
    SIGNALLED.load(Ordering::SeqCst)
}

/// Requests an orderly stop from inside the process (e.g. at the end of a fixed duration).
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// Stops this process in order when its parent dies: the kernel sends SIGTERM when the parent
/// exits (`PR_SET_PDEATHSIG`), and a watcher thread checks every 50 ms that the parent is
/// still `parent_pid` (it catches a parent that died before the signal was armed, or a
/// reparenting the signal misses). Either requests an orderly stop ([`request_stop`]).
/// For a child started by another program (`h4-master loopback` starts `h4-slave run
/// --parent-pid PID`).
pub fn stop_with_parent(parent_pid: u32) -> std::io::Result<()> {
    // SAFETY: plain prctl on the calling process with an integer argument.
    let rc = unsafe {
        libc::prctl(
            libc::PR_SET_PDEATHSIG,
            libc::SIGTERM as libc::c_ulong,
            0,
            0,
            0,
        )
    };
    if rc != 0 {
        return Err(std::io::Error::last_os_error());
    }
    let parent_alive = move || {
        // SAFETY: getppid has no preconditions and cannot fail.
        let ppid = unsafe { libc::getppid() };
        u32::try_from(ppid).is_ok_and(|p| p == parent_pid)
    };
    if !parent_alive() {
        request_stop();
        return Ok(());
    }
    std::thread::Builder::new()
        .name("parent-watch".into())
        .spawn(move || {
            while parent_alive() {
                std::thread::sleep(std::time::Duration::from_millis(50));
            }
            eprintln!("parent process {parent_pid} is gone: stopping");
            request_stop();
        })
        .map(|_| ())
}

/// Checks before a run that `path` (the value of `flag`, e.g. `--summary`) can be written:
/// not a directory, its directory exists, and the file can be opened for writing. A file that
/// did not exist is created for the check and removed again. The error names the flag, the
/// path and the reason.
pub fn check_writable(flag: &str, path: &std::path::Path) -> Result<(), String> {
    let fail = |why: String| format!("{flag} {}: cannot be written: {why}", path.display());
    if path.is_dir() {
        return Err(fail("it is a directory".into()));
    }
    let existed = path.exists();
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .map_err(|e| fail(e.to_string()))?;
    if !existed {
        let _ = std::fs::remove_file(path);
    }
    Ok(())
}

/// CPU time (user + system, all threads) this process has used so far, s; 0 if unknown.
pub fn cpu_time_s() -> f64 {
    // SAFETY: `rusage` is plain data; getrusage fills it for the calling process.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: valid pointer to a live `rusage`.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) } != 0 {
        return 0.0;
    }
    let t = |tv: libc::timeval| tv.tv_sec as f64 + tv.tv_usec as f64 * 1e-6;
    t(ru.ru_utime) + t(ru.ru_stime)
}

/// Prints `text` and a newline on standard output. A reader that went away (a closed pipe,
/// e.g. `| head`) is not an error: the output is simply not wanted any more. Any other write
/// error is returned, never a panic (`println!` panics on both).
pub fn print_stdout(text: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}

/// Prints a command's summary as pretty JSON on standard output ([`print_stdout`]) and, with
/// `path` (the command's `--summary`), writes the same text there.
pub fn emit_summary<T: serde::Serialize>(
    summary: &T,
    path: Option<&std::path::Path>,
) -> Result<(), String> {
    let json = serde_json::to_string_pretty(summary).map_err(|e| format!("summary: {e}"))?;
    print_stdout(&json).map_err(|e| format!("standard output: {e}"))?;
    if let Some(p) = path {
        std::fs::write(p, format!("{json}\n"))
            .map_err(|e| format!("--summary {}: {e}", p.display()))?;
    }
    Ok(())
}

/// Removes the variables cargo sets for the program it runs (`CARGO_PKG_*`, `OUT_DIR`, …):
/// some build scripts rerun when they change, so a nested `cargo build` would rebuild
/// half the dependency tree and leave it dirty for the next ordinary build.
pub fn without_cargo_run_env(cmd: &mut std::process::Command) {
    for (key, _) in std::env::vars_os() {
        let Some(k) = key.to_str() else { continue };
        if k.starts_with("CARGO_PKG_")
            || k.starts_with("CARGO_MANIFEST_")
            || k.starts_with("CARGO_CRATE_")
            || k.starts_with("CARGO_BIN_")
            || k == "CARGO_PRIMARY_PACKAGE"
            || k == "CARGO_TARGET_TMPDIR"
            || k == "CARGO_RUSTC_CURRENT_DIR"
            || k == "OUT_DIR"
        {
            cmd.env_remove(k);
        }
    }
}

/// The exit codes of both binaries, `h4-slave` and `h4-master`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExitStatus {
    /// 0: the command did its work (and its verdict, if it has one, passed).
    Ok = 0,
    /// 1: the run's verdict failed (an unstable session, a loopback that missed real time).
    VerdictFailed = 1,
    /// 2: a usage or input error (bad flag, unreadable or invalid file, transport refused).
    Error = 2,
    /// 130: SIGINT or SIGTERM stopped a run that had a fixed end before that end (the summary
    /// is still printed and written).
    Interrupted = 130,
}

impl From<ExitStatus> for std::process::ExitCode {
    fn from(status: ExitStatus) -> Self {
        std::process::ExitCode::from(status as u8)
    }
}

/// The exit codes as `--help` states them (both binaries' `after_help`).
pub const EXIT_CODES_HELP: &str = "Exit codes: 0 ok; 1 the run's verdict failed (unstable, or \
real time missed); 2 usage or input error; 130 interrupted (SIGINT/SIGTERM before the end of a \
run with a fixed duration).";

/// The exit code of a process loop that stopped in order: [`ExitStatus::Interrupted`] if it
/// had a fixed end (`--duration-s`) and a signal cut it short, else [`ExitStatus::Ok`] (a run
/// without a fixed end is meant to be stopped by a signal).
pub fn exit_after_run(fixed_end: bool) -> std::process::ExitCode {
    if fixed_end && signal_received() {
        ExitStatus::Interrupted.into()
    } else {
        ExitStatus::Ok.into()
    }
}

/// `--duration-s`: a positive finite number of seconds (0, negative, `nan` and `inf` are usage
/// errors, exit 2, not a run of no cycles).
pub fn positive_seconds(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!(
            "{v} s: expected a positive finite number of seconds"
        )),
        Err(e) => Err(format!("{text:?}: {e}")),
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn durations_must_be_positive_and_finite() {
        assert_eq!(super::positive_seconds("2.5"), Ok(2.5));
        for bad in ["0", "-1", "nan", "inf", "-inf", "", "ten"] {
            assert!(super::positive_seconds(bad).is_err(), "{bad}");
        }
    }
}
