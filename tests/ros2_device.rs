//! `h4-master run --device crtk`: a haptic device reached only through ROS 2 (rmw_zenoh's wire
//! format), paired with `h4-slave run --arm sim` over iceoryx2.
//!
//! 1. An outside device, `tests/python/ros2_device.py` (Python eclipse-zenoh and rosbags, no
//!    ROS), publishes `measured_cp` and renders `servo_cf`: its poses press the slave into the
//!    wall and the contact force comes back on `servo_cf` (both directions); it injects five
//!    samples of each kind of bad input (truncated CDR, a wrong type on the key, a NaN pose, a
//!    second publisher), each refused and counted under its reason in the master's summary
//!    while the good stream goes on (the control); poses outside the mapped workspace are
//!    clamped and counted; then it falls silent, and the force it receives fades to zero, the
//!    summary and the stderr line say so (the control: the force was there while it spoke).
//! 2. The stand-in (`h4-master ros2-standin`: the simulated master arm and scripted
//!    operator behind CRTK topics) → `h4-master run --device crtk` → slave: the wall-push
//!    session's first push, stable by the criteria (`remote_procs::judge`); ignored
//!    for now: it is not stable yet (see the test).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::{
    Running, SESSION, Scratch, WALL_N_PER_MM, binaries, free_port, master_args,
    python_with_zenoh_rosbags, read_json, s, serial, slave_args, wait_for_log, workspace,
};
use serde_json::Value;

fn u(v: &Value, path: &[&str]) -> u64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_u64()
        .unwrap_or_else(|| panic!("{path:?} not a count in {v}"))
}

#[test]
fn a_python_ros2_device_drives_the_master_and_its_bad_input_is_refused_by_reason() {
    let _guard = serial();
    let python = python_with_zenoh_rosbags();
    let (master_bin, slave_bin) = binaries();
    let scratch = Scratch::new("ros2-device");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let script = workspace().join("tests/python/ros2_device.py");
    let peer_args = vec![
        script.display().to_string(),
        "--listen".into(),
        endpoint.clone(),
        "--timeout-s".into(),
        "60".into(),
    ];
    let mut peer = Running::spawn("device", python, &peer_args, &scratch);
    wait_for_log(&peer, "ready", 60.0);

    let slave_summary = scratch.path("slave.json");
    let sa = slave_args(
        &scratch,
        &["--summary", &slave_summary.display().to_string()],
    );
    let mut slave = Running::spawn("slave", slave_bin, &sa, &scratch);
    let master_summary = scratch.path("master.json");
    let ma = master_args(
        &scratch,
        &[
            "--device",
            "crtk",
            "--ros2-connect",
            &endpoint,
            // The device's frame has its rest pose at the origin; z ± 6 mm maps, so the
            // peer's 7 mm press is clamped.
            "--device-workspace-centre",
            "0,0,0,0",
            "--device-workspace-half",
            "80,80,6,1",
            "--duration-s",
            "6",
            "--summary",
            &master_summary.display().to_string(),
        ],
    );
    let mut master = Running::spawn("master", master_bin, &ma, &scratch);
    assert!(peer.wait(90.0), "the device did not finish: {}", peer.log());
    assert!(
        master.wait(60.0),
        "the master did not stop: {}",
        master.log()
    );
    slave.stop();
    let log = master.log();
    let out: Value = serde_json::from_str(peer.stdout().trim())
        .unwrap_or_else(|e| panic!("device JSON: {e}\n{}\n{}", peer.stdout(), peer.log()));
    let m = read_json(&master_summary);

    // Device → master: the poses arrived and were accepted (all but those sent before the
    // master's subscription existed may be counted; every good one after the first command).
    let sent = &out["sent"];
    let good = u(sent, &["good"]);
    let accepted = u(&m, &["ros2_device", "poses_accepted"]);
    assert!(
        accepted >= good && accepted <= good + u(sent, &["before_start"]),
        "accepted {accepted} of {good} good poses (+ {} before the start)\n{log}",
        sent["before_start"]
    );
    // Bad input: each kind refused and counted under its reason, nothing else refused.
    let r = &m["ros2_rejected"];
    for reason in ["truncated", "wrong_type", "non_finite", "second_publisher"] {
        assert_eq!(u(r, &[reason]), u(sent, &[reason]), "{reason}: {r}");
        assert!(u(sent, &[reason]) >= 5);
    }
    assert_eq!(u(r, &["bad_attachment"]), 0, "{r}");
    // Outside the mapped workspace: clamped and counted; no pose inside was (at most the
    // ones sent outside, at least one of them seen by the loop).
    let clamped = u(&m, &["ros2_device", "clamped_poses"]);
    assert!(
        clamped >= 1 && clamped <= u(sent, &["outside"]),
        "{clamped} clamped of {} outside",
        sent["outside"]
    );

    // Master → device: servo_cf decoded by rosbags, one publisher, in sequence, the
    // master's frame; while the device pressed into the wall, the contact force came back.
    let commands = u(&out, &["commands"]);
    assert!(commands >= 2000, "{commands} servo_cf\n{log}");
    assert_eq!(u(&out, &["decoded"]), commands, "{}", out["decode_errors"]);
    assert_eq!(out["gids"].as_array().unwrap().len(), 1, "{}", out["gids"]);
    assert_eq!(out["seq_increasing_by_one"], true);
    assert_eq!(out["frame_ids"], serde_json::json!(["h4_device_base"]));
    let held = out["max_force_n_while_held"].as_f64().unwrap();
    assert!(
        held > 1.0,
        "no contact force rendered while pressing: {held} N\n{log}"
    );
    let s_sum = read_json(&slave_summary);
    assert!(
        s_sum["max_force_n"].as_f64().unwrap() > 1.0,
        "the slave never touched the wall: {s_sum}"
    );

    // Silent device: the force the device receives fades to zero (commands still flow),
    // counted and said.
    assert!(u(&out, &["commands_last_200ms"]) > 50, "{out}");
    let last = out["max_force_n_last_200ms"].as_f64().unwrap();
    assert!(
        last < 1e-3,
        "still {last} N after the device fell silent (was {held} N)"
    );
    assert_eq!(u(&m, &["ros2_device", "silences"]), 1, "{m}");
    assert!(u(&m, &["device_stale_cycles"]) > 500, "{m}");
    assert_eq!(m["final_fade"].as_f64(), Some(0.0));
    assert!(
        log.contains("device silent: no fresh pose on /h4_device/measured_cp within 20 ms"),
        "{log}"
    );
    assert!(
        log.contains("h4-master run: ROS 2 device on /h4_device:"),
        "{log}"
    );
}

/// Not yet passing (issue 35): in a debug build on a loaded 2-vCPU host the master's
/// observer fell to −4.4 mJ (floor −1 mJ) with the rendered force at its 30 N limit from
/// the second push's hold, where `--device sim` on the same session renders about 5 N. The
/// suspect: the device side's own round trip (pose out, force back across two 1 kHz loops
/// and two polling threads, at least two cycles) inside the coupling's contact damping;
/// polling at 5 kHz did not fix it. Run it with `--ignored`.
#[test]
#[ignore = "unstable over the stand-in's ROS 2 path so far (see the doc comment)"]
fn the_ros2_standin_through_device_crtk_pushes_the_wall_stably() {
    let _guard = serial();
    let (master_bin, slave_bin) = binaries();
    let scratch = Scratch::new("ros2-standin");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let slave_summary = scratch.path("slave.json");
    let sa = slave_args(
        &scratch,
        &["--summary", &slave_summary.display().to_string()],
    );
    let mut slave = Running::spawn("slave", slave_bin, &sa, &scratch);
    // The stand-in listens (a peer, as the Python device does); the master connects.
    let standin_summary = scratch.path("standin.json");
    let mut sta = s(&["ros2-standin", "--config", SESSION, "--set"]);
    sta.push(format!("environment.stiffness_n_per_mm={WALL_N_PER_MM}"));
    sta.extend(s(&[
        "--ros2-connect",
        "tcp/127.0.0.1:1",
        "--duration-s",
        "5.5",
    ]));
    sta.extend(s(&["--summary", &standin_summary.display().to_string()]));
    sta.extend(s(&["--listen", &endpoint]));
    let mut standin = Running::spawn("standin", master_bin, &sta, &scratch);
    wait_for_log(&standin, "listening", 30.0);
    let master_summary = scratch.path("master.json");
    let ma = master_args(
        &scratch,
        &[
            "--device",
            "crtk",
            "--ros2-connect",
            &endpoint,
            // The simulated master arm's mass estimate (0.35 kg × 0.8), as `--device sim`
            // tells the coupling: without it the contact damping's step bound is off.
            "--device-mass-kg",
            "0.28",
            "--duration-s",
            "5",
            "--summary",
            &master_summary.display().to_string(),
        ],
    );
    let mut master = Running::spawn("master", master_bin, &ma, &scratch);
    assert!(
        master.wait(60.0),
        "the master did not stop: {}",
        master.log()
    );
    assert!(
        standin.wait(30.0),
        "the stand-in did not stop: {}",
        standin.log()
    );
    slave.stop();
    let log = format!("{}\n{}", master.log(), standin.log());
    let m: h4_master::server::MasterRunSummary =
        serde_json::from_value(read_json(&master_summary)).unwrap();
    let sl: h4_slave_sim::server::SimRunSummary =
        serde_json::from_value(read_json(&slave_summary)).unwrap();
    let st = read_json(&standin_summary);
    let session = h4_master_sim::session::load_with(
        &workspace().join(SESSION),
        &[format!("environment.stiffness_n_per_mm={WALL_N_PER_MM}")],
        false,
    )
    .unwrap();
    let why = h4_tests::remote_procs::judge(&m, &sl, &session);
    assert!(why.is_empty(), "unstable: {why:?}\n{log}");
    // The first push (at 0.5 s to 6 s of the script) reached the wall and came back.
    assert!(
        sl.max_force_n > 2.0,
        "slave force {} N\n{log}",
        sl.max_force_n
    );
    assert!(m.max_rendered_force_n > 1.0, "{log}");
    assert!(
        st["max_rendered_force_n"].as_f64().unwrap() > 1.0,
        "the stand-in rendered no force: {st}"
    );
    // Nothing refused on either side; the device never fell silent.
    assert_eq!(m.ros2_rejected.total(), 0, "{:?}", m.ros2_rejected);
    assert_eq!(st["ros2_rejected"]["truncated"].as_u64(), Some(0));
    let d = m.ros2_device.unwrap();
    assert_eq!(d.silences, 0, "{log}");
    assert!(
        d.poses_accepted > 3000 && d.twists_accepted > 3000 && d.buttons_accepted > 3000,
        "{d:?}"
    );
}
