//! No orphans (issue 14): when `h4-master loopback` dies (SIGKILL, SIGHUP) its `h4-slave`
//! child brings the arm to its safe state and exits, and nothing of the run stays behind in
//! the temporary directory; an output path that cannot be written is refused (exit 2) before
//! any run starts, in every run command of both binaries.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::wire::SlaveState;
use h4_tests::procs::*;

/// Starts a loopback, waits for the slave's contact (|F| > 5 N, seen by a monitor on the
/// loopback's own services), sends `sig` to the loopback; returns the loopback (reaped or
/// not), the slave's pid and the monitor.
fn loopback_in_contact(
    scratch: &Scratch,
    extra: &[&str],
) -> (
    Running,
    KillOnDrop,
    h4_transport::iceoryx2::Iceoryx2Monitor<h4_shared::wire::Feedback>,
) {
    let (master, _) = binaries();
    let lb = Running::spawn("loopback", master, &loopback_args("60", extra), scratch);
    let slave = KillOnDrop(child_of(lb.pid(), 30.0));
    let mut mon = monitor(&format!("h4-loopback-{}", lb.pid()));
    watch_until(&mut mon, 30.0, "contact (|F| > 5 N)", |fb| {
        fb.state == SlaveState::Active as u8 && force(fb) > 5.0
    });
    (lb, slave, mon)
}

#[test]
fn sigkill_of_the_loopback_brings_its_slave_to_the_safe_state_and_ends_it() {
    let _g = serial();
    let scratch = Scratch::new("orphan-kill");
    let (mut lb, slave, mut mon) = loopback_in_contact(&scratch, &[]);
    let lb_pid = lb.pid();
    lb.sigkill();
    let safe = watch_until(&mut mon, 10.0, "the slave's safe state", |fb| {
        fb.state == SlaveState::SafeStop as u8
    });
    assert!(force(&safe).is_finite());
    watch_until(&mut mon, 10.0, "force released (< 1 N)", |fb| {
        fb.state == SlaveState::SafeStop as u8 && force(fb) < 1.0
    });
    assert!(
        wait_gone(slave.0, 10.0),
        "the slave (pid {}) outlived its killed parent",
        slave.0
    );
    let tmp = std::env::temp_dir().join(format!("h4-loopback-{lb_pid}"));
    assert!(!tmp.exists(), "{} left behind", tmp.display());
}

#[test]
fn sighup_of_the_loopback_stops_both_in_order() {
    let _g = serial();
    let scratch = Scratch::new("orphan-hup");
    let summary = scratch.path("summary.json").display().to_string();
    let (mut lb, slave, _mon) = loopback_in_contact(&scratch, &["--summary", &summary]);
    lb.signal(libc::SIGHUP);
    let status = lb.wait_status(30.0);
    // Interrupted before its end: 130, with the summary written.
    assert_eq!(status.code(), Some(130), "{}", lb.log());
    assert!(wait_gone(slave.0, 10.0), "the slave outlived the loopback");
    let v = read_json(std::path::Path::new(&summary));
    let shutdown = &v["slave"]["shutdown"];
    assert_eq!(shutdown["safe"], true, "{v:#}");
    assert_eq!(shutdown["final_state"], "SafeStop", "{v:#}");
    assert!(f(shutdown, "final_force_n") < 0.5, "{v:#}");
}

#[test]
fn an_unwritable_summary_or_recording_is_an_error_before_the_run() {
    let _g = serial();
    let (master, slave) = binaries();
    let scratch = Scratch::new("orphan-paths");
    let bad = "/nonexistent-h4-dir/out";
    let is_dir = scratch.dir.display().to_string();
    let cases: Vec<(&str, &std::path::PathBuf, Vec<String>)> = vec![
        (
            "slave run --summary",
            slave,
            slave_args(&scratch, &["--duration-s", "30", "--summary", bad]),
        ),
        (
            "slave run --record",
            slave,
            slave_args(&scratch, &["--duration-s", "30", "--record", bad]),
        ),
        (
            "master run --summary",
            master,
            master_args(&scratch, &["--duration-s", "30", "--summary", bad]),
        ),
        (
            "master run --record",
            master,
            master_args(&scratch, &["--duration-s", "30", "--record", &is_dir]),
        ),
        (
            "loopback --summary",
            master,
            loopback_args("30", &["--summary", bad]),
        ),
        (
            "loopback --record",
            master,
            loopback_args("30", &["--record", bad]),
        ),
        (
            "sim --summary",
            master,
            s(&["sim", SESSION, "--summary", bad]),
        ),
    ];
    for (what, bin, args) in cases {
        let mut p = Running::spawn("refused", bin, &args, &scratch);
        let status = p.wait_status(20.0);
        let log = p.log();
        assert_eq!(status.code(), Some(2), "{what}: {log}");
        assert!(log.contains("cannot be written"), "{what}: {log}");
    }
}
