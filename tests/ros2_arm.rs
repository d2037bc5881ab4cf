//! `h4-slave run --arm crtk`: an arm reached only through ROS 2 (rmw_zenoh's wire format),
//! commanded by `h4-master run` (the simulated master arm and operator of the wall-push
//! session) over iceoryx2.
//!
//! The arm is an outside implementation, `tests/python/ros2_arm.py` (Python eclipse-zenoh and
//! rosbags, no ROS): it publishes `measured_cp` and `measured_cf`, follows `servo_cp` as a
//! first-order servo, and a spring wall under the world file's contact point gives the force.
//! Asserted, both directions: `servo_cp` arrives decoded by rosbags, in metres (around the
//! world's start pose), with a unit quaternion, the `arm_base` frame, one publisher in
//! sequence; the slave pressed into the wall (the arm's force came back); five samples of
//! each kind of bad input (truncated CDR, a wrong type on the key, NaN pose and wrench, a
//! second publisher 40 mm off) are refused and counted under their reasons in the slave's
//! summary and never acted on (no safe stop, no trip and no jump in `servo_cp` while the arm
//! speaks: a second publisher's pose acted on would jump 40 mm); then the arm falls silent
//! and the slave safe-stops for it (`driver_stale_stops`, `ros2_arm.stale_events`, the stderr
//! line): the control is the same run's first four seconds, when the arm spoke and nothing
//! stopped. The arm's `measured_cf` comes at 500 Hz, slower than the slave's 1 kHz loop:
//! the cycles between two samples repeat the last one, which the safety monitor must not
//! take for a frozen sensor (it did, and the slave held a safe stop from the start: the
//! pinned bug; the negative control, a truly frozen sensor's identical new samples, is the
//! unit test `repeats_of_a_slow_sensors_sample_are_not_frozen_but_identical_new_samples_are`
//! in `slave/src/safety.rs`). The run also records (`--record --record-ros2`): the slave's
//! five CRTK topics are in the recording and outside decoders read them
//! (`tests/python/ros2_mcap.py`).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::{
    Running, Scratch, binaries, free_port, master_args, python_with_zenoh_rosbags, read_json,
    serial, slave_args, wait_for_log, workspace,
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

fn fl(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} not a number in {v}"))
}

#[test]
fn a_python_ros2_arm_follows_the_slave_and_its_bad_input_is_refused_by_reason() {
    let _guard = serial();
    let python = python_with_zenoh_rosbags();
    let (master_bin, slave_bin) = binaries();
    let scratch = Scratch::new("ros2-arm");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let slave_summary = scratch.path("slave.json");
    let rec = scratch.path("slave.mcap");
    let sa = slave_args(
        &scratch,
        &[
            "--arm",
            "crtk",
            "--ros2-connect",
            &endpoint,
            "--summary",
            &slave_summary.display().to_string(),
            "--record",
            &rec.display().to_string(),
            "--record-ros2",
        ],
    );
    // The world file slave_args wrote: the arm rests `gap_mm` above the contact point of a
    // level plane, where the Python arm's wall is.
    let world: h4_slave_sim::experiment::ExperimentConfig =
        h4_shared::config::load(&scratch.path("world.toml"), &[]).unwrap();
    let p = world.surface.contact_point_mm;
    assert_eq!(world.surface.tilt_deg, 0.0, "a level wall");
    let start = [p[0], p[1], p[2] + world.approach.gap_mm];
    let script = workspace().join("tests/python/ros2_arm.py");
    let arm_args = vec![
        script.display().to_string(),
        "--listen".into(),
        endpoint.clone(),
        "--start-mm".into(),
        format!("{},{},{}", start[0], start[1], start[2]),
        "--wall-z-mm".into(),
        p[2].to_string(),
        "--wall-n-per-mm".into(),
        h4_tests::procs::WALL_N_PER_MM.into(),
        "--timeout-s".into(),
        "60".into(),
    ];
    let mut arm = Running::spawn("arm", python, &arm_args, &scratch);
    wait_for_log(&arm, "ready", 60.0);
    let mut slave = Running::spawn("slave", slave_bin, &sa, &scratch);
    let master_summary = scratch.path("master.json");
    let ma = master_args(
        &scratch,
        &[
            "--duration-s",
            "6",
            "--summary",
            &master_summary.display().to_string(),
        ],
    );
    let mut master = Running::spawn("master", master_bin, &ma, &scratch);
    assert!(arm.wait(90.0), "the arm did not finish: {}", arm.log());
    assert!(
        master.wait(60.0),
        "the master did not stop: {}",
        master.log()
    );
    slave.stop();
    let log = slave.log();
    let out: Value = serde_json::from_str(arm.stdout().trim())
        .unwrap_or_else(|e| panic!("arm JSON: {e}\n{}\n{}", arm.stdout(), arm.log()));
    let s = read_json(&slave_summary);

    // Arm → slave: poses and wrenches accepted (at most those sent, most of them).
    let sent = &out["sent"];
    for (field, what) in [
        ("poses_accepted", "good_poses"),
        ("wrenches_accepted", "good_wrenches"),
    ] {
        let accepted = u(&s, &["ros2_arm", field]);
        let good = u(sent, &[what]);
        assert!(
            accepted <= good && accepted * 10 >= good * 9,
            "{field}: {accepted} of {good}\n{log}"
        );
    }
    // Bad input: each kind refused and counted under its reason, nothing else refused.
    let r = &s["ros2_rejected"];
    for reason in ["truncated", "wrong_type", "non_finite", "second_publisher"] {
        assert_eq!(u(r, &[reason]), u(sent, &[reason]), "{reason}: {r}");
        assert!(u(sent, &[reason]) >= 5);
    }
    assert_eq!(u(r, &["bad_attachment"]), 0, "{r}");
    assert_eq!(u(&s, &["ros2_arm", "unreachable_poses"]), 0, "{s}");
    assert_eq!(u(&s, &["ros2_arm", "refused_commands"]), 0, "{s}");

    // Slave → arm: servo_cp decoded by rosbags, one publisher, in sequence, the arm's frame,
    // SI units: metres around the start pose (mm / 1000), a unit quaternion, stamps of now.
    let commands = u(&out, &["commands"]);
    assert!(commands >= 2000, "{commands} servo_cp\n{log}");
    assert_eq!(u(&out, &["decoded"]), commands, "{}", out["decode_errors"]);
    assert_eq!(out["gids"].as_array().unwrap().len(), 1, "{}", out["gids"]);
    assert_eq!(out["seq_increasing_by_one"], true);
    assert_eq!(out["frame_ids"], serde_json::json!(["arm_base"]));
    let first: Vec<f64> = serde_json::from_value(out["first_command_m"].clone()).unwrap();
    for (got_m, want_mm) in first.iter().zip(start.iter()) {
        assert!(
            (got_m - want_mm / 1000.0).abs() < 0.5e-3,
            "first servo_cp {first:?} m, start {start:?} mm"
        );
    }
    let z_min_m = fl(&out, "command_z_min_m");
    assert!(
        z_min_m < p[2] / 1000.0 && z_min_m > (p[2] - 20.0) / 1000.0,
        "servo_cp z down to {z_min_m} m; the wall at {} mm",
        p[2]
    );
    assert!(fl(&out, "quaternion_norm_error_max") < 1e-9, "{out}");
    assert_eq!(out["stamps_increasing"], true);
    assert!(fl(&out, "stamp_age_max_s") < 1.0, "{out}");
    // The arm's force came back: the slave pressed into the wall.
    assert!(fl(&out, "max_force_n") > 1.0, "{out}");
    assert!(fl(&s, "max_measured_force_n") > 1.0, "{s}");
    // Never acted on: no jump in the set-points (a second publisher's pose is 40 mm off),
    // and the only safe stop is the silent arm's.
    assert!(
        fl(&out, "max_command_step_m") < 2e-3,
        "servo_cp jumped {} m\n{log}",
        out["max_command_step_m"]
    );

    // The silent arm: the slave safe-stopped for it, once, counted and said.
    assert_eq!(u(&s, &["driver_stale_stops"]), 1, "{s}");
    assert_eq!(u(&s, &["safe_stops"]), 1, "{s}");
    assert_eq!(u(&s, &["ros2_arm", "stale_events"]), 1, "{s}");
    assert!(
        log.contains("arm stale: no fresh pose on /arm/measured_cp or wrench on /arm/measured_cf within 20 ms"),
        "{log}"
    );
    assert!(log.contains("h4-slave run: ROS 2 arm on /arm:"), "{log}");
    // No safe stop while the arm spoke: the slow sensor's repeats were not a frozen sensor.
    assert_eq!(u(&s, &["safety_trips", "sensor_frozen"]), 0, "{s}");

    // `--record-ros2` with `--arm crtk`: the slave's CRTK topics, decoded from the recording.
    let script = workspace().join("tests/python/ros2_mcap.py");
    let check_args = vec![script.display().to_string(), rec.display().to_string()];
    let mut check = Running::spawn("check", python, &check_args, &scratch);
    assert!(check.wait(120.0), "the checker failed: {}", check.log());
    let rec_out: Value = serde_json::from_str(check.stdout().trim())
        .unwrap_or_else(|e| panic!("checker JSON: {e}\n{}", check.stdout()));
    let topics = rec_out["topics"].as_object().unwrap();
    let mut names: Vec<&str> = topics.keys().map(String::as_str).collect();
    names.sort_unstable();
    assert_eq!(
        names,
        [
            "/h4/measured_cf",
            "/h4/measured_cp",
            "/h4/measured_cv",
            "/h4/operating_state",
            "/h4/setpoint_cf"
        ],
        "{rec_out}"
    );
    for (topic, t) in topics {
        let n = t["messages"].as_u64().unwrap();
        assert!(n > 100, "{topic}: {n} messages");
        assert_eq!(t["decoded_mcap_ros2"].as_u64(), Some(n), "{topic}: {t}");
        assert_eq!(t["decoded_rosbags"].as_u64(), Some(n), "{topic}: {t}");
        assert_eq!(t["non_finite"].as_u64(), Some(0), "{topic}: {t}");
    }
    assert_eq!(rec_out["other_topics"]["/slave/cycle"], "jsonschema");
}
