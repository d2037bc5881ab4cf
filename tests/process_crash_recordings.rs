//! Crash-safe recordings (issue 14): SIGKILL of either process while recording leaves MCAP
//! files the public reader (Python `mcap`) opens, missing at most the last second; `h4-master
//! loopback` merges what it can and says what was lost (summary and stderr).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use h4_shared::wire::SlaveState;
use h4_tests::procs::*;

/// At most this much of a killed process's recording may be missing, ns.
const MAX_LOST_NS: u64 = 1_000_000_000;

/// A loopback recording into `rec`, in contact for at least a second; returns it, its slave.
fn recording_loopback(scratch: &Scratch, rec: &Path, summary: &Path) -> (Running, KillOnDrop) {
    let (master, _) = binaries();
    let (r, s) = (rec.display().to_string(), summary.display().to_string());
    let args = loopback_args("60", &["--record", &r, "--summary", &s]);
    let lb = Running::spawn("loopback", master, &args, scratch);
    let slave = KillOnDrop(child_of(lb.pid(), 30.0));
    let mut mon = monitor(&format!("h4-loopback-{}", lb.pid()));
    watch_until(&mut mon, 30.0, "contact (|F| > 5 N)", |fb| {
        fb.state == SlaveState::Active as u8 && force(fb) > 5.0
    });
    // Past a few checkpoints.
    std::thread::sleep(std::time::Duration::from_millis(1500));
    (lb, slave)
}

fn last_ns(v: &Value, path: &Path, topic: &str) -> u64 {
    v[path.display().to_string()]["last_log_time_ns"][topic]
        .as_u64()
        .unwrap_or_else(|| panic!("no {topic} in {path:?}: {v}"))
}

use serde_json::Value;

#[test]
fn sigkill_of_the_slave_while_recording_loses_at_most_a_second_and_loopback_says_so() {
    let _g = serial();
    let scratch = Scratch::new("crash-slave");
    let (rec, summary) = (scratch.path("run.mcap"), scratch.path("summary.json"));
    let (mut lb, slave) = recording_loopback(&scratch, &rec, &summary);
    let killed_ns = unix_now_ns();
    // SAFETY: plain syscall on the loopback's slave, alive (checked by the loop above).
    unsafe {
        libc::kill(slave.0, libc::SIGKILL);
    }
    let status = lb.wait_status(30.0);
    let log = lb.log();
    // Not a complete run: exit 1, the summary written all the same.
    assert_eq!(status.code(), Some(1), "{log}");
    let v = read_json(&summary);
    assert_eq!(v["complete"], false, "{v:#}");
    let r = &v["recording"];
    assert_eq!(r["slave_complete"], false, "{v:#}");
    assert_eq!(r["master_complete"], true, "{v:#}");
    let lost = r["lost"].as_array().expect("lost");
    assert!(!lost.is_empty(), "{v:#}");
    assert!(
        log.contains("recording: the slave process did not finish"),
        "{log}"
    );
    assert!(u(r, "slave_messages") > 1000, "{v:#}");
    // The merged file opens in the public reader, with the slave's cycles up to (at most a
    // second before) the kill.
    let read = read_with_python_mcap(&[&rec]);
    let last = last_ns(&read, &rec, "/slave/cycle");
    assert!(
        last + MAX_LOST_NS >= killed_ns,
        "the slave's recording ends {:.3} s before the kill",
        (killed_ns - last) as f64 / 1e9
    );
    assert!(last_ns(&read, &rec, "/master/cycle") >= last);
}

#[test]
fn sigkill_of_the_master_while_recording_leaves_readable_parts() {
    let _g = serial();
    let scratch = Scratch::new("crash-master");
    let (rec, summary) = (scratch.path("run.mcap"), scratch.path("summary.json"));
    let (mut lb, slave) = recording_loopback(&scratch, &rec, &summary);
    let killed_ns = unix_now_ns();
    lb.sigkill();
    // The slave, left without its parent, finishes its part in order.
    assert!(wait_gone(slave.0, 10.0), "the slave outlived the loopback");
    let master_part = scratch.path("run.master.part.mcap");
    let slave_part = scratch.path("run.slave.part.mcap");
    let read = read_with_python_mcap(&[&master_part, &slave_part]);
    let last = last_ns(&read, &master_part, "/master/cycle");
    assert!(
        last + MAX_LOST_NS >= killed_ns,
        "the master's recording ends {:.3} s before the kill",
        (killed_ns - last) as f64 / 1e9
    );
    assert!(last_ns(&read, &slave_part, "/slave/cycle") + MAX_LOST_NS >= killed_ns);
}
