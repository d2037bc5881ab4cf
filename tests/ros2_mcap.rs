//! `--record-ros2` (issue 35, MCAP): `h4-master loopback --record FILE --record-ros2` records
//! the slave's five and the master's two CRTK topics beside the cycles, as ROS 2 messages
//! (message encoding `cdr`, schemas `ros2msg`), and outside readers open them without ROS
//! (`tests/python/ros2_mcap.py`): PyPI `mcap` with `mcap_ros2.decoder` decodes every message
//! from its schema text alone, rosbags decodes every message with the types it parses from
//! the same text and, for the geometry_msgs types, with its built-in Jazzy definitions, whose
//! fields the schema text must match. Checked: poses in metres with unit quaternions, every
//! value finite, `header.frame_id` set, header stamps and log times strictly increasing, the
//! count near `--ros2-rate-hz` × the recorded span. Negative control: the same run without
//! `--record-ros2` records no ROS 2 channel (and the checker then finds none).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::{
    Running, Scratch, binaries, loopback_args, python_with_zenoh_rosbags, s, serial, workspace,
};
use serde_json::Value;

const SLAVE: [(&str, &str); 5] = [
    ("/h4/measured_cp", "geometry_msgs/msg/PoseStamped"),
    ("/h4/measured_cv", "geometry_msgs/msg/TwistStamped"),
    ("/h4/measured_cf", "geometry_msgs/msg/WrenchStamped"),
    ("/h4/setpoint_cf", "geometry_msgs/msg/WrenchStamped"),
    ("/h4/operating_state", "crtk_msgs/msg/OperatingState"),
];
const MASTER: [(&str, &str); 2] = [
    ("/h4_master/measured_cp", "geometry_msgs/msg/PoseStamped"),
    ("/h4_master/servo_cf", "geometry_msgs/msg/WrenchStamped"),
];

/// Runs loopback for `duration_s` recording into `rec.mcap` with `extra` flags, then the
/// Python checker on the file; returns its JSON and loopback's log.
fn record_and_check(tag: &str, duration_s: &str, extra: &[&str]) -> (Value, String) {
    let python = python_with_zenoh_rosbags();
    let (master_bin, _) = binaries();
    let scratch = Scratch::new(tag);
    let rec = scratch.path("rec.mcap");
    let mut a = loopback_args(duration_s, &["--record", &rec.display().to_string()]);
    a.extend(s(extra));
    let mut lb = Running::spawn("loopback", master_bin, &a, &scratch);
    let _ = lb.wait(120.0);
    let log = lb.log();
    assert!(rec.exists(), "no recording\n{log}");
    let script = workspace().join("tests/python/ros2_mcap.py");
    let args = vec![script.display().to_string(), rec.display().to_string()];
    let mut check = Running::spawn("check", python, &args, &scratch);
    assert!(
        check.wait(120.0),
        "the checker failed: {}\n{log}",
        check.log()
    );
    let out = serde_json::from_str(check.stdout().trim())
        .unwrap_or_else(|e| panic!("checker JSON: {e}\n{}\n{}", check.stdout(), check.log()));
    (out, log)
}

#[test]
fn record_ros2_writes_crtk_topics_that_outside_ros2_decoders_read() {
    let _guard = serial();
    let rate_hz = 100.0;
    let (out, log) = record_and_check("ros2-mcap", "4", &["--record-ros2"]);
    let topics = out["topics"].as_object().unwrap();
    let expected: Vec<(&str, &str)> = SLAVE.iter().chain(MASTER.iter()).copied().collect();
    assert_eq!(
        topics.len(),
        expected.len(),
        "ROS 2 topics: {:?}\n{log}",
        topics.keys().collect::<Vec<_>>()
    );
    // The JSON cycles are still there beside them.
    assert_eq!(out["other_topics"]["/slave/cycle"], "jsonschema", "{out}");
    assert_eq!(out["other_topics"]["/master/cycle"], "jsonschema", "{out}");
    for (topic, ty) in expected {
        let t = &topics[topic];
        let frame = if topic.starts_with("/h4_master/") {
            "h4_master_base"
        } else {
            "h4_base"
        };
        assert_eq!(t["schema_name"], ty, "{topic}");
        assert_eq!(t["schema_encoding"], "ros2msg", "{topic}");
        assert_eq!(t["message_encoding"], "cdr", "{topic}");
        assert_eq!(t["errors"], Value::Array(vec![]), "{topic}: {t}");
        let n = t["messages"].as_u64().unwrap();
        assert!(n > 0, "{topic}: no messages\n{log}");
        assert_eq!(t["decoded_mcap_ros2"].as_u64(), Some(n), "{topic}");
        assert_eq!(t["decoded_rosbags"].as_u64(), Some(n), "{topic}");
        assert_eq!(t["agree"], true, "{topic}: the decoders disagree");
        assert_eq!(t["non_finite"].as_u64(), Some(0), "{topic}");
        assert_eq!(t["frame_ids"], serde_json::json!([frame]), "{topic}");
        assert_eq!(t["stamps_increasing"], true, "{topic}");
        assert_eq!(t["log_times_increasing"], true, "{topic}");
        assert_eq!(t["stamp_equals_log_time"], true, "{topic}");
        // The schema's geometry_msgs and std_msgs types are the official ones, field for field.
        let official = t["matches_official"].as_object().unwrap();
        assert!(
            official.contains_key("std_msgs/msg/Header"),
            "{topic}: {official:?}"
        );
        assert!(
            official.values().all(|v| v == true),
            "{topic}: {official:?}"
        );
        if ty.starts_with("geometry_msgs/") {
            assert!(official.contains_key(ty), "{topic}: {official:?}");
            assert_eq!(t["decoded_official"].as_u64(), Some(n), "{topic}");
        }
        // Sampled at the telemetry rate: about rate × span messages (a late wake-up on a
        // loaded host loses a few, none are doubled).
        let span_s = (t["last_log_time_ns"].as_u64().unwrap()
            - t["first_log_time_ns"].as_u64().unwrap()) as f64
            / 1e9;
        assert!(span_s > 2.0, "{topic}: span {span_s} s of a 4 s run");
        let expected_n = rate_hz * span_s + 1.0;
        assert!(
            (n as f64) <= expected_n * 1.05 && (n as f64) >= expected_n * 0.7,
            "{topic}: {n} messages over {span_s:.3} s at {rate_hz} Hz"
        );
        if ty.ends_with("PoseStamped") {
            let q = t["last_quaternion_norm"].as_f64().unwrap();
            assert!((q - 1.0).abs() < 1e-9, "{topic}: |q| = {q}");
            let p: Vec<f64> = t["last_position_m"]
                .as_array()
                .unwrap()
                .iter()
                .map(|c| c.as_f64().unwrap())
                .collect();
            // Metres: the H-4's workspace is a few hundred mm across, the tool not at the base.
            assert!(
                p.iter().all(|c| c.abs() < 1.0),
                "{topic}: not metres: {p:?}"
            );
            assert!(
                p.iter().any(|c| c.abs() > 1e-3),
                "{topic}: at the origin: {p:?}"
            );
        }
    }
    // Following the master (ENABLED); at the end, when the master has gone, the slave's safe
    // stop (PAUSED) may be the last sample recorded.
    let states = &topics["/h4/operating_state"]["states"];
    let states: Vec<&str> = states
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(states.contains(&"ENABLED"), "{states:?}");
    assert!(
        states.iter().all(|s| ["ENABLED", "PAUSED"].contains(s)),
        "{states:?}"
    );
    assert_eq!(topics["/h4/operating_state"]["last_is_homed"], true);
}

/// Negative control: without `--record-ros2` the recording holds the JSON cycles only.
#[test]
fn without_record_ros2_the_recording_has_no_ros2_channel() {
    let _guard = serial();
    let (out, log) = record_and_check("ros2-mcap-off", "2", &[]);
    assert_eq!(
        out["topics"].as_object().map(serde_json::Map::len),
        Some(0),
        "{out}\n{log}"
    );
    assert_eq!(out["other_topics"]["/slave/cycle"], "jsonschema", "{out}");
}
