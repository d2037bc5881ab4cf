//! Faults injected into the real slave process while the operator pushes (issue 31):
//! `h4-slave run --inject-fault KIND@5+10` (the simulated arm fails for 10 s from 5 s of its
//! clock) against `h4-master run` over iceoryx2, on a session whose operator pushes into a
//! resin wall from 0.5 s, five times harder from 8 s, until 18 s.
//!
//! For each fault (`sensor-freeze`, `sensor-saturate`, `driver-silent`), from the slave's
//! summary (`fault_injection`, cycles on the arm's clock, 1 ms each):
//! * the slave was following the master when the fault struck, and was safe-stopped within
//!   2 cycles (2 ms) of it, by the safety monitor for the fault's reason;
//! * it stayed safe-stopped for the rest of the fault (the master's acknowledgement is
//!   refused while a sensor or driver fault lasts);
//! * it re-paired after the fault ended, on the master's acknowledgement;
//! * the true contact force stayed within 1.05 × the slave's limit over the whole run.
//!
//! Control: the frozen sensor with the monitor off (`--no-safety-monitor
//! --unsafe-test-override`): the slave follows the master through the fault, its force loop
//! on a reading that no longer moves, and the true force goes past the limit.
//!
//! One run each, no re-run. Nothing here asserts a wall-clock time.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;

use h4_tests::remote_procs::{Pair, PairSpec, Scratch};

/// The operator's push, long enough to outlast a 10 s fault.
const SESSION: &str = r#"
name = "fault-push"
seed = 4
duration_s = 20.0

[environment]
material = "resin"
gap_mm = 3.0

[coupling]
model = false
contact_damping_n_s_per_mm = 0.7

[[operator.intent]]
at_s = 0.0
target_mm = [0.0, 0.0, 0.0]
move_s = 0.5

[[operator.intent]]
at_s = 0.5
target_mm = [0.0, 0.0, -4.0]
move_s = 0.8
push_n = [0.0, 0.0, -8.0]
push_ramp_s = 0.6

[[operator.intent]]
at_s = 8.0
target_mm = [0.0, 0.0, -6.0]
move_s = 0.8
push_n = [0.0, 0.0, -40.0]
push_ramp_s = 1.0

[[operator.intent]]
at_s = 18.0
target_mm = [0.0, 0.0, 2.0]
move_s = 0.6

[slave.controller]
max_accel_mm_per_s2 = 10000.0
"#;

const DURATION_S: f64 = 20.0;
const FAULT: &str = "@5+10";

struct Outcome {
    name: String,
    slave: h4_slave_sim::server::SimRunSummary,
    log: String,
}

fn run(scratch: &Scratch, session: &str, kind: &str, monitor: bool) -> Outcome {
    let name = format!("{kind}{}", if monitor { "" } else { "-unmonitored" });
    let mut slave_args = vec![
        "--iceoryx2-prefix".to_string(),
        format!("{}-{name}", scratch.prefix),
        "--inject-fault".into(),
        format!("{kind}{FAULT}"),
    ];
    let mut overrides = vec![];
    if !monitor {
        slave_args.push("--no-safety-monitor".into());
        // The master's session marks the control (`Pair` adds the override to both).
        overrides.push("slave.safety_monitor=false".to_string());
    }
    let spec = PairSpec {
        tag: &name,
        session,
        overrides,
        duration_s: DURATION_S,
        master_args: vec![
            "--iceoryx2-prefix".to_string(),
            format!("{}-{name}", scratch.prefix),
        ],
        slave_args,
    };
    let mut pair = Pair::start(&spec, scratch, |_, bin| Command::new(bin)).unwrap();
    let (_m, s) = pair.finish().unwrap();
    Outcome {
        log: pair.slave.log(),
        name,
        slave: s,
    }
}

#[test]
fn a_frozen_saturated_or_silent_arm_safe_stops_within_2_ms_and_repairs_after_it() {
    let scratch = Scratch::new("process-faults").unwrap();
    let session = scratch.path("fault-push.toml");
    std::fs::write(&session, SESSION).unwrap();
    let session = session.display().to_string();
    // Two pairs at a time (each two 1 kHz loops).
    let runs: Vec<Outcome> = [
        ("sensor-freeze", true),
        ("sensor-saturate", true),
        ("driver-silent", true),
        ("sensor-freeze", false),
    ]
    .chunks(2)
    .flat_map(|c| {
        let (scratch, session) = (&scratch, session.as_str());
        std::thread::scope(|s| {
            let h: Vec<_> = c
                .iter()
                .map(|&(k, m)| s.spawn(move || run(scratch, session, k, m)))
                .collect();
            h.into_iter().map(|h| h.join().unwrap()).collect::<Vec<_>>()
        })
    })
    .collect();
    let mut failures = Vec::new();
    println!(
        "| fault | monitor | state before | safe stop after (cycles) | trips during | active cycles during | re-paired after (cycles) | max true force N (limit) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for o in &runs {
        let s = &o.slave;
        let Some(f) = s.fault_injection.as_ref() else {
            failures.push(format!("{}: no fault_injection in the summary", o.name));
            continue;
        };
        let monitored = !o.name.ends_with("-unmonitored");
        println!(
            "| {} | {} | {} | {:?} | {} | {} | {:?} | {:.1} ({}) |",
            f.kind,
            if monitored { "on" } else { "off" },
            f.state_before,
            f.safe_stop_after_cycles,
            serde_json::to_string(&f.trips_during).unwrap(),
            f.cycles_active_during,
            f.repaired_after_cycles,
            s.max_force_n,
            s.force_limit_n,
        );
        let mut fail = |why: String| failures.push(format!("{}: {why}\n{}", o.name, o.log));
        if f.state_before != "active" {
            fail(format!(
                "the slave was {} when the fault struck (not following the master)",
                f.state_before
            ));
        }
        if !monitored {
            // The control: the harm the monitor prevents.
            if s.max_force_n <= 1.05 * s.force_limit_n {
                fail(format!(
                    "control: without the monitor the frozen sensor kept the true force at {:.1} N (≤ 1.05 × {} N)",
                    s.max_force_n, s.force_limit_n
                ));
            }
            continue;
        }
        match f.safe_stop_after_cycles {
            Some(c) if c <= 2 => {}
            other => fail(format!("safe stop after {other:?} cycles (≤ 2 asked)")),
        }
        let (reason, count) = match f.kind.as_str() {
            "sensor-freeze" => ("sensor_frozen", f.trips_during.sensor_frozen),
            "sensor-saturate" => ("sensor_saturated", f.trips_during.sensor_saturated),
            _ => ("driver_silent", f.trips_during.driver_silent),
        };
        if count == 0 {
            fail(format!("no {reason} trip during the fault"));
        }
        // Only the cycles before the trip followed the master.
        if f.cycles_active_during > f.safe_stop_after_cycles.unwrap_or(u64::MAX) {
            fail(format!(
                "followed the master for {} cycles of the fault (re-armed during it?)",
                f.cycles_active_during
            ));
        }
        if f.repaired_after_cycles.is_none() {
            fail("never re-paired after the fault".into());
        }
        if s.max_force_n.is_nan() || s.max_force_n > 1.05 * s.force_limit_n {
            fail(format!(
                "true force {:.1} N > 1.05 × the {} N limit",
                s.max_force_n, s.force_limit_n
            ));
        }
        if f.max_true_force_n.is_nan() || f.max_true_force_n > s.max_force_n {
            fail(format!(
                "the fault's peak {} N is not in the run's {} N",
                f.max_true_force_n, s.max_force_n
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}
