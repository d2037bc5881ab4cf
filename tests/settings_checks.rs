//! Settings checked before a run, through the binaries: an implausible `scale.force` is
//! refused with its reason (or warned about); `--realtime try|enforce|off` in a process that
//! may and one that may not (its CAP_SYS_NICE and CAP_IPC_LOCK dropped, its rtprio and
//! memlock limits at zero) use SCHED_FIFO and lock memory; the default configuration files are
//! found from another working directory.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command as Proc, Stdio};

use h4_tests::procs::*;
use serde_json::Value;

/// Runs `bin args` in `cwd`, optionally without the privileges real time needs; returns the
/// exit code, stdout and stderr (watchdog: 60 s).
fn run(bin: &Path, args: &[&str], cwd: &Path, unprivileged: bool) -> (i32, String, String) {
    let mut cmd = Proc::new(bin);
    cmd.args(args)
        .current_dir(cwd)
        .env("H4_PROGRESS", "off")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if unprivileged {
        // SAFETY: only async-signal-safe syscalls between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                // Out of the bounding set: root's capabilities after exec lack them. (Without
                // CAP_SETPCAP this fails, and the process had neither capability anyway.)
                libc::prctl(libc::PR_CAPBSET_DROP, 23, 0, 0, 0); // CAP_SYS_NICE
                libc::prctl(libc::PR_CAPBSET_DROP, 14, 0, 0, 0); // CAP_IPC_LOCK
                let zero = libc::rlimit {
                    rlim_cur: 0,
                    rlim_max: 0,
                };
                libc::setrlimit(libc::RLIMIT_RTPRIO, &zero);
                libc::setrlimit(libc::RLIMIT_MEMLOCK, &zero);
                Ok(())
            });
        }
    }
    let child = cmd.spawn().unwrap();
    let pid = child.id() as i32;
    let watchdog = std::thread::spawn(move || {
        for _ in 0..600 {
            std::thread::sleep(std::time::Duration::from_millis(100));
            // SAFETY: signal 0 probes; the pid is our child until it is reaped below.
            if unsafe { libc::kill(pid, 0) } != 0 {
                return;
            }
        }
        // SAFETY: plain syscall on our own child.
        unsafe {
            libc::kill(pid, libc::SIGKILL);
        }
    });
    let out = child.wait_with_output().unwrap();
    let _ = watchdog.join();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn an_implausible_force_scale_is_refused_with_its_reason() {
    let (master, _) = binaries();
    let ws = workspace();
    let session = "config/sessions/wall-push.toml";
    let (code, out, err) = run(
        master,
        &["sim", session, "--set", "scale.force=100"],
        &ws,
        false,
    );
    assert_eq!(code, 2, "{err}");
    assert!(out.is_empty(), "no run, no summary: {out}");
    assert!(err.contains("refused: scale.force = 100"), "{err}");
    assert!(err.contains("coupling.force_limit_n = 30 N"), "{err}");
    // The bound is the session's own: with a higher force limit the same scale runs.
    let (code, _, err) = run(
        master,
        &[
            "sim",
            session,
            "--set",
            "scale.force=40",
            "--set",
            "coupling.force_limit_n=60",
        ],
        &ws,
        false,
    );
    assert_ne!(code, 2, "{err}");
    // loopback refuses before any process starts.
    let _g = serial();
    let (code, _, err) = run(
        master,
        &["loopback", "--duration-s", "2", "--set", "scale.force=100"],
        &ws,
        false,
    );
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("refused: scale.force = 100"), "{err}");
    assert!(!err.contains("waiting for a slave"), "{err}");
    // A push the slave's force guard must cap: a warning, and the run goes on.
    let (code, _, err) = run(
        master,
        &["sim", session, "--set", "scale.force=0.05"],
        &ws,
        false,
    );
    assert!(code == 0 || code == 1, "{err}");
    assert!(
        err.contains("h4-master sim: warning: scale.force = 0.05"),
        "{err}"
    );
}

fn realtime_of(summary: &str) -> Value {
    let v: Value = serde_json::from_str(summary).unwrap();
    v["realtime"].clone()
}

/// `--realtime` on a slave process alone (no master: it idles for 0.5 s).
#[test]
fn realtime_try_enforce_and_off() {
    let _g = serial();
    let (_, slave) = binaries();
    let ws = workspace();
    let scratch = Scratch::new("realtime");
    let base = [
        "run",
        "--duration-s",
        "0.5",
        "--iceoryx2-prefix",
        scratch.prefix.as_str(),
    ];
    let with = |extra: &[&'static str]| {
        let mut a: Vec<&str> = base.to_vec();
        a.extend_from_slice(extra);
        a
    };
    // Not permitted: `try` says so in one line per setting and runs; `enforce` refuses.
    let (code, out, err) = run(slave, &with(&[]), &ws, true);
    assert_eq!(code, 0, "{err}");
    let notes: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("h4-slave run: real time: "))
        .collect();
    assert_eq!(notes.len(), 2, "{err}");
    assert!(
        notes.iter().any(|l| l.contains("SCHED_FIFO not permitted")),
        "{err}"
    );
    assert!(
        notes.iter().any(|l| l.contains("mlockall not permitted")),
        "{err}"
    );
    let rt = realtime_of(&out);
    assert_eq!(rt["mode"], "try");
    assert_eq!(rt["sched_fifo_priority"], Value::Null);
    assert_eq!(rt["memory_locked"], false);
    let (code, out, err) = run(slave, &with(&["--realtime", "enforce"]), &ws, true);
    assert_eq!(code, 2, "{err}");
    assert!(out.is_empty(), "{out}");
    assert!(
        err.contains("--realtime enforce: ") && err.contains("not permitted"),
        "{err}"
    );
    // Off: nothing asked, nothing said; naming a priority with it is a usage error.
    let (code, out, err) = run(slave, &with(&["--realtime", "off"]), &ws, true);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("real time:"), "{err}");
    assert_eq!(realtime_of(&out)["mode"], "off");
    let (code, _, err) = run(
        slave,
        &with(&["--realtime", "off", "--fifo-priority", "10"]),
        &ws,
        false,
    );
    assert_eq!(code, 2, "{err}");
    // Permitted (this suite runs as root in CI): `enforce` gets both, at the priority asked.
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } == 0 {
        let (code, out, err) = run(
            slave,
            &with(&["--realtime", "enforce", "--fifo-priority", "20"]),
            &ws,
            false,
        );
        assert_eq!(code, 0, "{err}");
        let rt = realtime_of(&out);
        assert_eq!(rt["sched_fifo_priority"], 20, "{rt}");
        assert_eq!(rt["memory_locked"], true, "{rt}");
        assert!(!err.contains("real time:"), "{err}");
    }
}

/// The default session and world files are found from the repository, whatever the working
/// directory: `cd master && h4-master loopback` works, and so does a slave started in /.
#[test]
fn defaults_are_found_from_another_directory() {
    let _g = serial();
    let (master, slave) = binaries();
    let scratch = Scratch::new("cwd");
    let (code, out, err) = run(
        slave,
        &[
            "run",
            "--duration-s",
            "0.3",
            "--realtime",
            "off",
            "--iceoryx2-prefix",
            scratch.prefix.as_str(),
        ],
        Path::new("/"),
        false,
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"cycles\""), "{out}");
    let (code, out, err) = run(
        master,
        &["loopback", "--duration-s", "1.5"],
        &workspace().join("master"),
        false,
    );
    assert!(code == 0 || code == 1, "exit {code}: {err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["name"], "wall-push", "{v:#}");
    assert!(v["cycles"].as_u64().unwrap() > 500, "{v:#}");
}
