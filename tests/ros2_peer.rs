//! An outside ROS 2 peer (Python eclipse-zenoh and rosbags, no ROS: `tests/python/ros2_peer.py`)
//! sees what `h4-master loopback --ros2` publishes as rmw_zenoh would: it subscribes to the
//! slave's five and the master's two CRTK topics by keys it builds itself (type hashes from
//! rosbags), checks every sample's 33-byte attachment, decodes every payload with rosbags, and
//! lists the liveliness tokens; this test asserts on the JSON it prints. Negative control: the
//! slave's `measured_cp` under a wrong type hash receives nothing while the right key receives
//! every sample.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::{
    Running, Scratch, binaries, free_port, loopback_args, python_with_zenoh_rosbags, s, serial,
    wait_for_log, workspace,
};
use serde_json::Value;

const SLAVE: [(&str, &str); 5] = [
    ("measured_cp", "geometry_msgs/msg/PoseStamped"),
    ("measured_cv", "geometry_msgs/msg/TwistStamped"),
    ("measured_cf", "geometry_msgs/msg/WrenchStamped"),
    ("setpoint_cf", "geometry_msgs/msg/WrenchStamped"),
    ("operating_state", "crtk_msgs/msg/OperatingState"),
];
const MASTER: [(&str, &str); 2] = [
    ("measured_cp", "geometry_msgs/msg/PoseStamped"),
    ("servo_cf", "geometry_msgs/msg/WrenchStamped"),
];

fn dds(type_name: &str) -> String {
    let p: Vec<&str> = type_name.split('/').collect();
    format!("{}::{}::dds_::{}_", p[0], p[1], p[2])
}

#[test]
fn a_python_ros2_peer_receives_and_decodes_every_crtk_topic_of_loopback() {
    let _guard = serial();
    let python = python_with_zenoh_rosbags();
    let (master_bin, _) = binaries();
    let scratch = Scratch::new("ros2-peer");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let script = workspace().join("tests/python/ros2_peer.py");
    let peer_args = vec![
        script.display().to_string(),
        "--listen".into(),
        endpoint.clone(),
        "--min-samples".into(),
        "50".into(),
        "--timeout-s".into(),
        "60".into(),
    ];
    let mut peer = Running::spawn("peer", python, &peer_args, &scratch);
    wait_for_log(&peer, "ready", 60.0);

    let summary = scratch.path("loopback.json");
    let mut a = loopback_args("4", &["--ros2", "--ros2-connect", &endpoint]);
    a.extend(s(&["--summary", &summary.display().to_string()]));
    let mut lb = Running::spawn("loopback", master_bin, &a, &scratch);
    assert!(peer.wait(90.0), "the peer did not finish: {}", peer.log());
    let _ = lb.wait(60.0);
    let log = lb.log();
    let out: Value = serde_json::from_str(peer.stdout().trim())
        .unwrap_or_else(|e| panic!("peer JSON: {e}\n{}\n{}", peer.stdout(), peer.log()));

    // Every topic: ≥ 50 samples, each with a valid attachment, each decoded by rosbags.
    let mut gids = Vec::new();
    for (ns, frame, topics) in [
        ("h4", "h4_base", &SLAVE[..]),
        ("h4_master", "h4_master_base", &MASTER[..]),
    ] {
        for (leaf, ty) in topics {
            let hash = out["rihs01"][ty].as_str().unwrap();
            let key = format!("0/{ns}/{leaf}/{}/{hash}", dds(ty));
            let t = &out["topics"][&key];
            let n = t["samples"].as_u64().unwrap();
            assert!(n >= 50, "{key}: {n} samples\n{log}");
            assert_eq!(
                t["decoded"].as_u64(),
                Some(n),
                "{key}: {}",
                t["decode_errors"]
            );
            assert_eq!(t["attachment_errors"].as_u64(), Some(0), "{key}");
            assert_eq!(t["non_finite"].as_u64(), Some(0), "{key}");
            assert!(t["seq_first"].as_i64().unwrap() >= 1, "{key}");
            assert_eq!(t["seq_increasing_by_one"], true, "{key}");
            assert_eq!(t["attachment_stamp_matches_header"], true, "{key}");
            assert_eq!(t["last"]["frame_id"], frame, "{key}");
            let g = t["gids"].as_array().unwrap();
            assert_eq!(g.len(), 1, "{key}: one publisher, one GID: {g:?}");
            gids.push(g[0].as_str().unwrap().to_owned());
            if ty.ends_with("PoseStamped") {
                let q = t["last"]["quaternion_norm"].as_f64().unwrap();
                assert!((q - 1.0).abs() < 1e-9, "{key}: |q| = {q}");
                // Metres: the H-4's workspace is a few hundred mm across.
                for c in t["last"]["position_m"].as_array().unwrap() {
                    assert!(c.as_f64().unwrap().abs() < 1.0, "{key}: not in metres: {t}");
                }
            }
        }
    }
    gids.sort();
    gids.dedup();
    assert_eq!(gids.len(), 7, "every publisher its own GID");
    let states = &out["topics"][&format!(
        "0/h4/operating_state/{}/{}",
        dds(SLAVE[4].1),
        out["rihs01"][SLAVE[4].1].as_str().unwrap()
    )]["last"];
    assert_eq!(states["state"], "ENABLED", "{states}");
    assert_eq!(states["is_homed"], true);

    // Negative control: the same topic under another type's hash receives nothing.
    assert_eq!(
        out["wrong_hash_samples"].as_u64(),
        Some(0),
        "{}",
        out["wrong_hash_key"]
    );

    // The graph: both nodes and all seven publishers announced, as rmw_zenoh lays them out.
    let tokens: Vec<&str> = out["tokens"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap())
        .collect();
    let has = |part: &str| tokens.iter().any(|t| t.contains(part));
    assert!(has("/0/0/NN/%/%h4/h4_slave"), "{tokens:#?}");
    assert!(has("/0/0/NN/%/%h4_master/h4_master"), "{tokens:#?}");
    for (ns, node, topics) in [
        ("h4", "h4_slave", &SLAVE[..]),
        ("h4_master", "h4_master", &MASTER[..]),
    ] {
        for (leaf, ty) in topics {
            let part = format!(
                "/MP/%/%{ns}/{node}/%{ns}%{leaf}/{}/{}/",
                dds(ty),
                out["rihs01"][ty].as_str().unwrap()
            );
            assert!(has(&part), "no token with {part}: {tokens:#?}");
        }
    }
    assert!(
        tokens.iter().all(|t| t.starts_with("@ros2_lv/0/")),
        "{tokens:#?}"
    );

    // Both processes said what they published.
    assert!(log.contains("h4-master loopback: ROS 2:"), "{log}");
    assert!(log.contains("h4-slave run: ROS 2:"), "{log}");
}
