//! `docs/examples/outside_master.py`, the Python outside master written from docs/wire.md
//! alone (protocol 3), against the `h4-slave run` process over Zenoh: it runs to its end, each
//! of its bad messages is rejected under its reason (`gate.<reason>` in the slave's summary:
//! two `out_of_range`, one of each other reason but `wrong_session`), its one impossible echo
//! is refused and counted (`round_trip_echoes_refused` = 1, the command itself accepted), its
//! echoes give the slave a measured round trip (`round_trip_samples`, `rtt_measured_p50_ms`),
//! and the controller refused nothing it took (`commands_rejected_by_controller` = 0). The
//! control of the round trip is `tests/wire_outside_client_zenoh.rs`'s client that echoes
//! nothing. Python Zenoh: `python_with_zenoh_rosbags` (tests/python-ros2-requirements.txt).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::{
    Running, Scratch, binaries, free_port, python_with_zenoh_rosbags, read_json, workspace,
};

#[test]
fn the_python_example_master_speaks_protocol_3_to_the_slave_process() {
    let python = python_with_zenoh_rosbags();
    let (_, slave) = binaries();
    let scratch = Scratch::new("outside-master-py");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let summary = scratch.path("slave.json").display().to_string();
    let args: Vec<String> = [
        "run",
        "--transport",
        "zenoh",
        "--zenoh-listen",
        &endpoint,
        "--watchdog-ms",
        "200",
        "--summary",
        &summary,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut sl = Running::spawn("slave", slave, &args, &scratch);
    let script = workspace().join("docs/examples/outside_master.py");
    let py_args = vec![script.display().to_string(), endpoint.clone()];
    let mut py = Running::spawn("outside_master.py", python, &py_args, &scratch);
    let status = py.wait_status(120.0);
    let out = format!("{}{}", py.stdout(), py.log());
    assert!(
        status.success(),
        "outside_master.py failed: {out}\n{}",
        sl.log()
    );
    assert!(out.contains("end at"), "{out}");
    sl.stop();
    let v = read_json(&scratch.path("slave.json"));
    let g = &v["gate"];
    for (reason, n) in [
        ("wrong_version", 1),
        ("wrong_arm", 1),
        ("stale", 1),
        ("out_of_range", 2),
        ("implausible_energy", 1),
        ("reserved_bits", 1),
        ("length_mismatch", 1),
        ("wild_seq", 1),
        ("undecodable", 1),
        ("wrong_session", 0),
    ] {
        assert_eq!(g[reason].as_u64(), Some(n), "{reason}: {g:#}\n{out}");
    }
    assert_eq!(g["pairings"].as_u64(), Some(1), "{g:#}");
    assert!(g["accepted"].as_u64().unwrap() > 3000, "{g:#}");
    assert_eq!(v["round_trip_echoes_refused"].as_u64(), Some(1), "{v:#}");
    assert!(v["round_trip_samples"].as_u64().unwrap() > 1000, "{v:#}");
    assert!(v["rtt_measured_p50_ms"].as_f64().unwrap() > 0.0, "{v:#}");
    assert_eq!(
        v["commands_rejected_by_controller"].as_u64(),
        Some(0),
        "{v:#}"
    );
}
