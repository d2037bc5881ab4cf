//! A session over ROS 2 (issue 35): `h4-master run` → iceoryx2 → `h4-slave run --arm crtk`
//! → `h4-slave ros2-standin` (the simulated arm behind CRTK arm topics: every arm-side byte
//! in rmw_zenoh's format), the wall-push session's first push (7 s) on resin and on
//! aluminium with no link delay; and the whole session with the device's side over ROS 2
//! too (`h4-master ros2-standin` → `h4-master run --device crtk`), ignored: not stable yet.
//!
//! Asserted for each wall: stable by the criteria on both run summaries
//! (`remote_procs::judge`: forces finite, the slave's force within 1.05 × its limit, the
//! rendered force within the coupling's, both passivity observers ≥ −1 mJ, round trips
//! completed); the simulated arm's true contact force (the stand-in's plant, not the
//! sensor) within the same limit; the wall touched; nothing refused on any ROS 2 topic, no
//! stale arm and no frozen sensor; and the held force of the push (the mean over the settled
//! contact in the slave's recording, the compensated sensor force) within
//! [`HELD_TOLERANCE`] of the simulated session's (`h4-master sim` of the same session and
//! overrides, its detector's `hold_force_n[0]`).
//!
//! Negative control: the same processes with the protection off (no passivity control, no
//! local model, no local damping: the real delay matrix's control) on aluminium must fail
//! the same criteria.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;
use std::time::{Duration, Instant};

use h4_master::server::MasterRunSummary;
use h4_slave_sim::server::SimRunSummary;
use h4_tests::procs::{free_port, serial};
use h4_tests::record::slave_cycles;
use h4_tests::remote_procs::{
    self, Pair, PairSpec, Running, Scratch, TRUE_FORCE_SHARE, binaries, judge, read_summary,
    session, slave_config, workspace,
};
use serde_json::Value;

const SESSION: &str = "config/sessions/wall-push.toml";
/// The first push: approach, push with 6 N, hold, release at 6 s.
const DURATION_S: f64 = 7.0;
/// The held force over ROS 2 may differ from the simulated session's by this share (the
/// issue's 10 %).
const HELD_TOLERANCE: f64 = 0.10;
/// A cycle with more force than this is in contact, N (the detector's threshold).
const CONTACT_N: f64 = 0.5;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Wall {
    Resin,
    Aluminium,
}

fn overrides(wall: Wall, protected: bool) -> Vec<String> {
    let material = match wall {
        Wall::Resin => "resin",
        Wall::Aluminium => "aluminium",
    };
    let mut o = vec![
        format!("environment.material={material}"),
        "environment.stiffness_n_per_mm=0".into(),
        format!("duration_s={DURATION_S}"),
    ];
    if !protected {
        o.extend([
            "passivity.enabled=false".into(),
            "coupling.model=false".into(),
            "coupling.master_damping_n_s_per_mm=0".into(),
            "coupling.contact_damping_n_s_per_mm=0".into(),
        ]);
    }
    o
}

/// What one session over ROS 2 left.
struct Outcome {
    master: MasterRunSummary,
    slave: SimRunSummary,
    arm: Value,
    device: Value,
    held_n: Option<f64>,
    log: String,
}

fn wait_for_line(r: &Running, needle: &str, limit_s: f64) {
    let t = Instant::now();
    while !r.log().contains(needle) {
        assert!(
            t.elapsed().as_secs_f64() < limit_s,
            "no {needle:?} within {limit_s} s:\n{}",
            r.log()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The mean force over the longest stretch of contact in `forces_n` (one per ms), less its
/// first `settle_s` and its last 0.3 s (the release), N; None without 0.5 s of it.
fn held_force_n(forces_n: &[f64], settle_s: f64) -> Option<f64> {
    let (mut best, mut start) = ((0, 0), None);
    for (i, f) in forces_n.iter().chain([&0.0]).enumerate() {
        match (start, *f > CONTACT_N) {
            (None, true) => start = Some(i),
            (Some(s), false) => {
                if i - s > best.1 - best.0 {
                    best = (s, i);
                }
                start = None;
            }
            _ => {}
        }
    }
    let from = best.0 + (settle_s * 1e3) as usize;
    let to = best.1.saturating_sub(300);
    (to > from + 500).then(|| forces_n[from..to].iter().sum::<f64>() / (to - from) as f64)
}

fn spawn(name: &str, bin: &std::path::Path, args: &[String], scratch: &Scratch) -> Running {
    let mut c = Command::new(bin);
    c.args(args);
    Running::spawn(name, c, scratch).unwrap()
}

/// The processes of the session with `overrides`: the arm's side over ROS 2 always, the
/// device's too if `device_over_ros2` (else `--device sim`, the master's own simulated arm).
fn over_ros2(tag: &str, overrides: &[String], device_over_ros2: bool) -> Outcome {
    let scratch = Scratch::new(tag).unwrap();
    let (master_bin, slave_bin) = binaries().unwrap();
    let (world, _) = slave_config(&scratch, tag, SESSION, overrides).unwrap();
    let arm_ep = format!("tcp/127.0.0.1:{}", free_port());
    let dev_ep = format!("tcp/127.0.0.1:{}", free_port());
    let arm_summary = scratch.path(&format!("{tag}-arm.json"));
    let dev_summary = scratch.path(&format!("{tag}-device.json"));
    let p = |x: &std::path::Path| x.display().to_string();
    // Each stand-in listens (a peer, as the Python peers do); the product's side connects.
    // Nothing else on the ROS 2 side: `--ros2-connect` to a closed port.
    let mut arm = spawn(
        &format!("{tag}-arm"),
        slave_bin,
        &[
            "ros2-standin".into(),
            "--config".into(),
            p(&world),
            "--listen".into(),
            arm_ep.clone(),
            "--ros2-connect".into(),
            "tcp/127.0.0.1:1".into(),
            "--fifo-priority".into(),
            "5".into(),
            "--summary".into(),
            p(&arm_summary),
        ],
        &scratch,
    );
    wait_for_line(&arm, "listening", 30.0);
    let device_args = [
        "ros2-standin".into(),
        "--config".into(),
        SESSION.into(),
        "--listen".into(),
        dev_ep.clone(),
        "--ros2-connect".into(),
        "tcp/127.0.0.1:1".into(),
        "--summary".into(),
        p(&dev_summary),
    ];
    let mut device = device_over_ros2
        .then(|| spawn(&format!("{tag}-device"), master_bin, &device_args, &scratch));
    if let Some(d) = &device {
        wait_for_line(d, "listening", 30.0);
    }
    let mut master_args = vec!["--iceoryx2-prefix".into(), scratch.prefix.clone()];
    if device_over_ros2 {
        master_args.extend([
            "--device".into(),
            "crtk".into(),
            "--ros2-connect".into(),
            dev_ep,
            // The simulated master arm's mass estimate (0.35 kg × 0.8), as `--device sim`
            // tells the coupling.
            "--device-mass-kg".into(),
            "0.28".into(),
        ]);
    }
    let spec = PairSpec {
        tag,
        session: SESSION,
        overrides: overrides.to_vec(),
        duration_s: DURATION_S,
        slave_args: vec![
            "--arm".into(),
            "crtk".into(),
            "--ros2-connect".into(),
            arm_ep,
            "--iceoryx2-prefix".into(),
            scratch.prefix.clone(),
        ],
        master_args,
    };
    let mut pair = Pair::start(&spec, &scratch, |_, bin| Command::new(bin)).unwrap();
    let finished = pair.finish();
    let stopped = [device.as_mut().map_or(Ok(()), Running::stop), arm.stop()];
    let log = format!(
        "--- master\n{}\n--- slave\n{}\n--- device\n{}\n--- arm\n{}",
        pair.master.log(),
        pair.slave.log(),
        device.as_ref().map(Running::log).unwrap_or_default(),
        arm.log()
    );
    let (master, slave) = finished.unwrap_or_else(|e| panic!("{e}\n{log}"));
    for s in stopped {
        s.unwrap_or_else(|e| panic!("a stand-in: {e}\n{log}"));
    }
    let forces: Vec<f64> = slave_cycles(&pair.slave_record)
        .unwrap()
        .iter()
        .map(|c| c.force_true_n)
        .collect();
    let settle_s = session(SESSION, overrides).unwrap().detector.hold_settle_s;
    Outcome {
        master,
        slave,
        arm: read_summary(&arm_summary).unwrap(),
        device: device
            .map(|_| read_summary(&dev_summary).unwrap())
            .unwrap_or(Value::Null),
        held_n: held_force_n(&forces, settle_s),
        log,
    }
}

/// `h4-master sim` of the session with `overrides`: its first hold's mean true force, N.
fn simulated_held_n(tag: &str, overrides: &[String]) -> f64 {
    let scratch = Scratch::new(tag).unwrap();
    let (master_bin, _) = binaries().unwrap();
    let summary = scratch.path("sim.json");
    let mut c = Command::new(master_bin);
    c.arg("sim").arg(SESSION);
    for o in overrides {
        c.arg("--set").arg(o);
    }
    let out = c
        .arg("--summary")
        .arg(&summary)
        .current_dir(workspace())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "h4-master sim: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: Value = read_summary(&summary).unwrap();
    assert_eq!(s["stable"], true, "the simulated session: {s}");
    s["hold_force_n"][0].as_f64().unwrap()
}

fn count(v: &Value, path: &[&str]) -> u64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_u64()
        .unwrap_or_else(|| panic!("{path:?} not a count in {v}"))
}

fn stable_push(wall: Wall, device_over_ros2: bool) {
    let _guard = serial();
    let tag = format!("ros2-session-{wall:?}-{device_over_ros2}").to_lowercase();
    let o = overrides(wall, true);
    let sim_n = simulated_held_n(&format!("{tag}-sim"), &o);
    let r = over_ros2(&tag, &o, device_over_ros2);
    // A loop the host starved (more than 1 % of its deadlines missed) says so in every
    // failure: its physics then describe the host, not the ROS 2 path (not excused).
    let log = &format!(
        "starved by the host: {}\n{}",
        remote_procs::starved(&r.master, &r.slave),
        r.log
    );
    let held_n = r
        .held_n
        .unwrap_or_else(|| panic!("no settled contact\n{log}"));
    let cfg = session(SESSION, &o).unwrap();
    let why = judge(&r.master, &r.slave, &cfg);
    println!(
        "{wall:?} over ROS 2: held {:.2} N (simulated {sim_n:.2} N), slave max {:.2} N, true \
         max {:.2} N, rendered max {:.2} N, observers {:.3} / {:.3} mJ, deadline misses {} / {}",
        held_n,
        r.slave.max_force_n,
        r.arm["max_true_force_n"],
        r.master.max_rendered_force_n,
        r.master.energy_min_j * 1e3,
        r.slave.energy_min_j * 1e3,
        r.master.run.deadline_misses,
        r.slave.run.deadline_misses
    );
    assert!(why.is_empty(), "unstable: {why:?}\n{log}");
    let true_max_n = r.arm["max_true_force_n"].as_f64().unwrap();
    assert!(
        true_max_n <= TRUE_FORCE_SHARE * r.slave.force_limit_n,
        "the arm's true force {true_max_n} N\n{log}"
    );
    assert!(r.slave.max_force_n > 2.0, "the wall not touched\n{log}");
    assert!(
        (held_n - sim_n).abs() <= HELD_TOLERANCE * sim_n,
        "held {held_n:.2} N over ROS 2, {sim_n:.2} N simulated\n{log}"
    );
    // Every ROS 2 sample taken: nothing refused on any of the six topics' subscriptions.
    assert_eq!(
        r.master.ros2_rejected.total(),
        0,
        "{:?}",
        r.master.ros2_rejected
    );
    assert_eq!(
        r.slave.ros2_rejected.total(),
        0,
        "{:?}",
        r.slave.ros2_rejected
    );
    let sides: &[(&str, &Value)] = if device_over_ros2 {
        &[("arm", &r.arm), ("device", &r.device)]
    } else {
        &[("arm", &r.arm)]
    };
    for &(who, v) in sides {
        let rej = &v["ros2_rejected"];
        let total: u64 = rej
            .as_object()
            .unwrap()
            .values()
            .map(|x| x.as_u64().unwrap())
            .sum();
        assert_eq!(total, 0, "{who}: {rej}");
        assert!(count(v, &["commands_accepted"]) > 3000, "{who}: {v}");
    }
    assert_eq!(r.slave.driver_stale_stops, 0, "{log}");
    assert_eq!(r.slave.safety_trips.sensor_frozen, 0, "{log}");
    if device_over_ros2 {
        assert_eq!(r.master.ros2_device.as_ref().unwrap().silences, 0, "{log}");
    }
    assert_eq!(count(&r.arm, &["unreachable_commands"]), 0, "{}", r.arm);
}

#[test]
fn the_arm_side_over_ros2_pushes_resin_stably() {
    stable_push(Wall::Resin, false);
}

#[test]
fn the_arm_side_over_ros2_pushes_aluminium_stably() {
    stable_push(Wall::Aluminium, false);
}

/// Not yet passing (issue 35): with the device's side over ROS 2 too (both stand-ins), in its
/// one run (2026-12-08) the master's observer fell to −53.5 mJ with the rendered force at its
/// 30 N limit and the push held 21.2 N (9.4 N simulated), while the slave's observer stayed
/// at −0.001 mJ (docs/ros2.md, "The whole session over ROS 2"), as in `tests/ros2_device.rs`'s
/// ignored test: the device's own round trip. Run it with `--ignored`.
#[test]
#[ignore = "unstable over the device stand-in's ROS 2 path so far (see the doc comment)"]
fn the_whole_session_over_ros2_pushes_resin_stably() {
    stable_push(Wall::Resin, true);
}

/// The control: the protection off, on aluminium, over the same processes as the arm-side
/// tests: the same criteria must fail (the judge can see an unstable session on this path).
#[test]
fn without_its_protection_the_session_over_ros2_is_judged_unstable() {
    let _guard = serial();
    let o = overrides(Wall::Aluminium, false);
    let r = over_ros2("ros2-session-control", &o, false);
    let cfg = session(SESSION, &o).unwrap();
    let why = judge(&r.master, &r.slave, &cfg);
    println!(
        "control over ROS 2: slave max {:.2} N, rendered max {:.2} N, observers {:.3} / {:.3} \
         mJ: {why:?}",
        r.slave.max_force_n,
        r.master.max_rendered_force_n,
        r.master.energy_min_j * 1e3,
        r.slave.energy_min_j * 1e3
    );
    assert!(r.slave.max_force_n > 2.0, "the wall not touched\n{}", r.log);
    assert!(
        !why.is_empty(),
        "the unprotected session was judged stable\n{}",
        r.log
    );
}
