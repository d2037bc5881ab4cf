//! The replay arm driver in the real processes (docs/drivers.md): `h4-slave run --arm replay
//! --replay FILE` plays a recorded arm back against `h4-master run` over iceoryx2.
//!
//! 1. `h4-slave run` (the default `--arm sim`) and `h4-master run` on the test session for
//!    3 s, the slave recording `/slave/cycle` (each cycle with the arm's reading).
//! 2. The same master against `h4-slave run --arm replay --replay` that recording, for 4 s:
//!    the slave runs (cycles, feedback the master accepts), every reading its controller
//!    got is one the recorded arm gave (its recording's `actuators_mm` and `wrench_sensor`
//!    are pairs of the first recording's), and past the recording's end the driver stops
//!    answering: the slave ends in its safe stop, counted as `driver_stale_stops` (every
//!    safe stop of the run is the driver's).
//!    Control: the first run, on the simulated arm, has no stale stop.
//! 3. A replay of a file that is not MCAP is refused before the run (exit 2, its reason).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;
use std::path::Path;

use h4_tests::procs::*;

/// The (actuators, wrench) readings of a slave process's recording, as bit patterns.
fn readings(path: &Path) -> Vec<[u64; 8]> {
    let bytes = std::fs::read(path).unwrap();
    let mut out = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic != "/slave/cycle" {
            continue;
        }
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        let mut r = [0u64; 8];
        for (i, key) in ["actuators_mm", "wrench_sensor"].iter().enumerate() {
            let a = v[key].as_array().unwrap_or_else(|| panic!("{key} in {v}"));
            for (j, x) in a.iter().enumerate() {
                r[4 * i + j] = x.as_f64().unwrap().to_bits();
            }
        }
        out.push(r);
    }
    out
}

#[test]
fn a_recorded_arm_plays_back_against_the_master() {
    let _g = serial();
    let (master, slave) = binaries();
    let scratch = Scratch::new("process-replay");
    let rec = scratch.path("sim.mcap").display().to_string();
    let sim_json = scratch.path("sim.json").display().to_string();
    let mut sim = Running::spawn(
        "slave-sim",
        slave,
        &slave_args(
            &scratch,
            &[
                "--duration-s",
                "3",
                "--record",
                &rec,
                "--summary",
                &sim_json,
            ],
        ),
        &scratch,
    );
    let mut m = Running::spawn(
        "master-1",
        master,
        &master_args(&scratch, &["--duration-s", "3"]),
        &scratch,
    );
    assert!(sim.wait(60.0), "the simulated slave failed: {}", sim.log());
    let _ = m.wait(60.0);
    let sim_summary = read_json(Path::new(&sim_json));
    assert_eq!(u(&sim_summary, "driver_stale_stops"), 0, "{sim_summary}");
    let recorded = readings(Path::new(&rec));
    assert!(recorded.len() > 2000, "{} recorded cycles", recorded.len());

    let out = scratch.path("replay.mcap").display().to_string();
    let replay_json = scratch.path("replay.json").display().to_string();
    let mut replay = Running::spawn(
        "slave-replay",
        slave,
        &slave_args(
            &scratch,
            &[
                "--arm",
                "replay",
                "--replay",
                &rec,
                "--duration-s",
                "4",
                "--record",
                &out,
                "--summary",
                &replay_json,
            ],
        ),
        &scratch,
    );
    let mut m = Running::spawn(
        "master-2",
        master,
        &master_args(&scratch, &["--duration-s", "4"]),
        &scratch,
    );
    assert!(
        replay.wait(60.0),
        "the replay slave failed: {}",
        replay.log()
    );
    let _ = m.wait(60.0);
    let s = read_json(Path::new(&replay_json));
    assert!(u(&s, "cycles") > 3000, "{s}");
    assert!(
        u(&s["gate"], "accepted") > 1000,
        "the master's commands reached it: {s}"
    );
    // Past the recording's end the driver is silent (a gap of 2 cycles or more in the
    // recording, where the recorded loop missed deadlines, is one too, and the master re-pairs
    // after it): every safe stop here is the driver's, and the run ends in one.
    assert!(u(&s, "driver_stale_stops") >= 1, "{s}");
    assert_eq!(u(&s, "safe_stops"), u(&s, "driver_stale_stops"), "{s}");
    assert_eq!(s["final_state"], "SafeStop", "{s}");
    let recorded: BTreeSet<[u64; 8]> = recorded.into_iter().collect();
    let played = readings(Path::new(&out));
    assert!(played.len() > 3000);
    let foreign = played.iter().filter(|r| !recorded.contains(*r)).count();
    assert_eq!(
        foreign,
        0,
        "{foreign} of {} readings were not the recorded arm's",
        played.len()
    );

    // A file that is not MCAP is refused before the run.
    let bad = scratch.path("not.mcap");
    std::fs::write(&bad, b"not an mcap file").unwrap();
    let bad = bad.display().to_string();
    let mut refused = Running::spawn(
        "slave-bad-replay",
        slave,
        &slave_args(
            &scratch,
            &["--arm", "replay", "--replay", &bad, "--duration-s", "1"],
        ),
        &scratch,
    );
    let status = refused.wait_status(30.0);
    assert_eq!(status.code(), Some(2), "{}", refused.log());
    assert!(
        refused.log().contains("not a readable MCAP file"),
        "{}",
        refused.log()
    );
}
