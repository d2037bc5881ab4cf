//! The live view (`--foxglove-ws`), checked with a real WebSocket client that speaks the
//! Foxglove WebSocket protocol (subprotocol `foxglove.sdk.v1`: JSON `advertise` of channels
//! with their schemas, a JSON `subscribe`, binary `messageData` frames: opcode 1, subscription
//! id u32 LE, log time u64 LE, payload), written here from the protocol's documentation, not
//! with the server's own crate.
//!
//! * `a_topic_is_advertised_with_its_schema_and_streams_decimated_json`: the library alone,
//!   on a simulated 1 kHz producer.
//! * `loopback_serves_both_processes_live`: `h4-master loopback --foxglove-ws` serves the
//!   master's `/master/cycle` at the given port and the slave's `/slave/cycle` at the next one.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use serde_json::Value;
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket};

/// One advertised channel.
#[derive(Debug, Clone)]
struct Channel {
    id: u64,
    encoding: String,
    schema_name: String,
    schema_encoding: String,
    schema: String,
}

struct Client {
    ws: WebSocket<TcpStream>,
    channels: BTreeMap<String, Channel>,
}

impl Client {
    /// Connects, retrying while the server is not up yet (a process starting).
    fn connect(addr: &str, patience: Duration) -> Client {
        let start = Instant::now();
        let stream = loop {
            match TcpStream::connect(addr) {
                Ok(s) => break s,
                Err(e) if start.elapsed() < patience => {
                    let _ = e;
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => panic!("no live view at {addr}: {e}"),
            }
        };
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        let mut req = format!("ws://{addr}").into_client_request().unwrap();
        req.headers_mut()
            .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
        let (ws, resp) = tungstenite::client(req, stream).expect("WebSocket handshake");
        assert_eq!(
            resp.headers()
                .get("Sec-WebSocket-Protocol")
                .and_then(|v| v.to_str().ok()),
            Some("foxglove.sdk.v1"),
            "the server must agree to the Foxglove subprotocol"
        );
        Client {
            ws,
            channels: BTreeMap::new(),
        }
    }

    /// Reads until `topics` are all advertised.
    fn wait_for_topics(&mut self, topics: &[&str]) {
        while !topics.iter().all(|t| self.channels.contains_key(*t)) {
            match self.ws.read().expect("reading advertisements") {
                Message::Text(text) => self.note(&text),
                Message::Binary(_) | Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => {}
                Message::Close(c) => panic!("server closed before advertising: {c:?}"),
            }
        }
    }

    fn note(&mut self, text: &str) {
        let v: Value = serde_json::from_str(text).expect("server text frames are JSON");
        if v["op"] == "advertise" {
            for c in v["channels"].as_array().expect("advertise.channels") {
                let s = |k: &str| c[k].as_str().unwrap_or_default().to_string();
                self.channels.insert(
                    s("topic"),
                    Channel {
                        id: c["id"].as_u64().expect("channel id"),
                        encoding: s("encoding"),
                        schema_name: s("schemaName"),
                        schema_encoding: s("schemaEncoding"),
                        schema: s("schema"),
                    },
                );
            }
        }
    }

    fn subscribe(&mut self, subscription_id: u32, topic: &str) {
        let channel_id = self.channels[topic].id;
        let msg = serde_json::json!({
            "op": "subscribe",
            "subscriptions": [{ "id": subscription_id, "channelId": channel_id }],
        });
        self.ws.send(Message::text(msg.to_string())).unwrap();
    }

    /// The next `n` message-data frames: (subscription id, log time ns, JSON payload).
    fn messages(&mut self, n: usize) -> Vec<(u32, u64, Value)> {
        let mut out = Vec::new();
        while out.len() < n {
            match self.ws.read().expect("reading messages") {
                Message::Binary(b) if b.first() == Some(&1) => {
                    assert!(b.len() >= 13, "messageData frame too short: {}", b.len());
                    let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                    let t = u64::from_le_bytes(b[5..13].try_into().unwrap());
                    let payload: Value = serde_json::from_slice(&b[13..]).expect("payload is JSON");
                    out.push((sub, t, payload));
                }
                Message::Text(text) => self.note(&text),
                Message::Close(c) => panic!("server closed: {c:?}"),
                _ => {}
            }
        }
        out
    }
}

#[derive(serde::Serialize, schemars::JsonSchema, Clone, Copy)]
struct Sample {
    /// Cycle number.
    cycle: u64,
    /// A force, N.
    force_n: f64,
}

#[test]
fn a_topic_is_advertised_with_its_schema_and_streams_decimated_json() {
    let server = h4_telemetry::live::LiveServer::start("127.0.0.1:0", "test").unwrap();
    let mut topic = server
        .topic::<Sample>("/test/sample", "h4.TestSample", 1000.0, 100.0)
        .unwrap();
    let mut client = Client::connect(server.addr(), Duration::from_secs(5));
    client.wait_for_topics(&["/test/sample"]);
    let ch = client.channels["/test/sample"].clone();
    assert_eq!(ch.encoding, "json");
    assert_eq!(ch.schema_name, "h4.TestSample");
    assert_eq!(ch.schema_encoding, "jsonschema");
    let schema: Value = serde_json::from_str(&ch.schema).unwrap();
    assert!(schema["properties"]["force_n"].is_object(), "{schema}");
    client.subscribe(7, "/test/sample");

    // A 1 kHz producer (not paced: the decimation counts cycles, not time). Messages sent
    // before the subscription reached the server are not delivered, so it keeps producing
    // until the client has what it needs.
    let producer = std::thread::spawn(move || {
        for cycle in 0..400_000u64 {
            topic.push(
                1_000_000_000 + cycle * 1_000_000,
                Sample {
                    cycle,
                    force_n: cycle as f64 * 0.01,
                },
            );
            if cycle % 100 == 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        topic.dropped()
    });
    let msgs = client.messages(20);
    for (sub, t, v) in &msgs {
        assert_eq!(*sub, 7);
        let cycle = v["cycle"].as_u64().unwrap();
        assert_eq!(
            cycle % 10,
            9,
            "one in ten cycles (100 Hz of 1 kHz): {cycle}"
        );
        assert_eq!(
            *t,
            1_000_000_000 + cycle * 1_000_000,
            "log time is the cycle's time"
        );
        assert!((v["force_n"].as_f64().unwrap() - cycle as f64 * 0.01).abs() < 1e-9);
    }
    let cycles: Vec<u64> = msgs
        .iter()
        .map(|m| m.2["cycle"].as_u64().unwrap())
        .collect();
    assert!(
        cycles.windows(2).all(|w| w[1] > w[0]),
        "in order: {cycles:?}"
    );
    drop(client);
    let _dropped = producer.join().unwrap();
}

/// Every series of the shipped layout (`config/foxglove/h4-teleop.json`) names a field the
/// processes really publish, checked against the schemas they advertise.
/// Every series of the shipped layout `file` (config/foxglove/) names a topic the clients
/// were offered and a field of its schema.
fn check_layout(root: &std::path::Path, file: &str, clients: &[&Client]) {
    let text = std::fs::read_to_string(root.join("config/foxglove").join(file)).unwrap();
    let layout: Value = serde_json::from_str(&text).unwrap();
    let mut checked = 0;
    for (panel, cfg) in layout["configById"].as_object().unwrap() {
        let paths: Vec<String> = match cfg["paths"].as_array() {
            Some(p) => p
                .iter()
                .map(|p| p["value"].as_str().unwrap().to_string())
                .collect(),
            None => vec![cfg["topicPath"].as_str().unwrap().to_string()],
        };
        for path in paths {
            let (topic, field) = path.split_once('.').unwrap_or((&path, ""));
            let ch = clients
                .iter()
                .find_map(|c| c.channels.get(topic))
                .unwrap_or_else(|| panic!("{panel}: topic {topic} is not published"));
            let field = field.split('[').next().unwrap();
            if !field.is_empty() {
                let schema: Value = serde_json::from_str(&ch.schema).unwrap();
                assert!(
                    schema["properties"][field].is_object(),
                    "{panel}: {topic} has no field {field}"
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 10, "the layout shows {checked} series");
}

#[derive(Debug)]
struct Child(std::process::Child);

impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn free_port_pair() -> u16 {
    // Two consecutive free ports (the master's and the slave's).
    for _ in 0..50 {
        let a = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = a.local_addr().unwrap().port();
        if port < u16::MAX && std::net::TcpListener::bind(("127.0.0.1", port + 1)).is_ok() {
            return port;
        }
    }
    panic!("no two consecutive free ports");
}

#[test]
fn loopback_serves_both_processes_live() {
    let port = free_port_pair();
    let dir = std::env::temp_dir().join(format!("h4-live-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let root = h4_tests::bins::workspace();
    let child = std::process::Command::new(&h4_tests::bins::binaries().0)
        .current_dir(&root)
        .args(["loopback", "--duration-s", "6", "--foxglove-ws"])
        .arg(format!("127.0.0.1:{port}"))
        .arg("--summary")
        .arg(dir.join("summary.json"))
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut child = Child(child);

    let mut master = Client::connect(&format!("127.0.0.1:{port}"), Duration::from_secs(20));
    master.wait_for_topics(&["/master/cycle"]);
    master.subscribe(1, "/master/cycle");
    let mut slave = Client::connect(&format!("127.0.0.1:{}", port + 1), Duration::from_secs(20));
    slave.wait_for_topics(&["/slave/cycle"]);
    slave.subscribe(2, "/slave/cycle");

    check_layout(&root, "h4-teleop.json", &[&master, &slave]);

    let m = master.messages(30);
    for key in [
        "pose",
        "rendered_wrench",
        "slave_force_n",
        "energy_observed_j",
    ] {
        assert!(
            !m[0].2[key].is_null(),
            "master message lacks {key}: {}",
            m[0].2
        );
    }
    // The round trip is null until the first echo (the loop's first cycles), then a number.
    assert!(m[0].2.get("round_trip_us").is_some(), "{}", m[0].2);
    let rtt_us = m[29].2["round_trip_us"].as_f64();
    assert!(
        rtt_us.is_some_and(|r| r > 0.0 && r < 100_000.0),
        "no round trip 30 messages in: {}",
        m[29].2
    );
    let s = slave.messages(30);
    for key in [
        "measured_pose",
        "force_true_n",
        "force_measured_n",
        "state",
        "energy_observed_j",
    ] {
        assert!(
            !s[0].2[key].is_null(),
            "slave message lacks {key}: {}",
            s[0].2
        );
    }
    // Decimated to one cycle in ten of the 1 kHz loops: consecutive messages are ten periods
    // apart in the loop's own clock (time_ns, the wake-up time: less only by the loop's
    // lateness, so 5 ms is the bound; undecimated they would be 1 ms apart). More is allowed:
    // a loop that missed deadlines (a loaded host) or a message dropped makes a longer gap.
    let gaps: Vec<u64> = s
        .windows(2)
        .map(|w| w[1].2["time_ns"].as_u64().unwrap() - w[0].2["time_ns"].as_u64().unwrap())
        .collect();
    assert!(
        gaps.iter().all(|&g| g >= 5_000_000),
        "messages closer than decimation allows: {gaps:?}"
    );
    drop(master);
    drop(slave);
    let status = child.0.wait().unwrap();
    assert!(
        status.code().is_some(),
        "loopback ended by a signal: {status:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A cutting loopback (`config/sessions/cut-pocket.toml`): the slave process also serves
/// `/slave/cut` (schema `h4.CutCycle`, the recording's cut record), decimated like the
/// cycles, with the tool's tip in the workpiece frame and the volume removed so far, which
/// never decreases; every series of `config/foxglove/h4-cutting.json` names a published
/// field.
#[test]
fn a_cutting_slave_serves_the_cut_live() {
    let port = free_port_pair();
    let root = h4_tests::bins::workspace();
    let child = std::process::Command::new(&h4_tests::bins::binaries().0)
        .current_dir(&root)
        .args(["loopback", "--duration-s", "5", "--config"])
        .arg(root.join("config/sessions/cut-pocket.toml"))
        .arg("--foxglove-ws")
        .arg(format!("127.0.0.1:{port}"))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut child = Child(child);
    let mut master = Client::connect(&format!("127.0.0.1:{port}"), Duration::from_secs(20));
    master.wait_for_topics(&["/master/cycle"]);
    let mut slave = Client::connect(&format!("127.0.0.1:{}", port + 1), Duration::from_secs(20));
    slave.wait_for_topics(&["/slave/cycle", "/slave/cut"]);
    // The cutting layout's every series is published, the cut's and the turntable's included.
    check_layout(&root, "h4-cutting.json", &[&master, &slave]);
    slave.subscribe(3, "/slave/cut");
    let m = slave.messages(40);
    for key in [
        "tool_tip_in_workpiece_mm",
        "cutting_force_n",
        "removed_mm3",
        "spindle_torque_n_mm",
        "stalled",
    ] {
        assert!(
            !m[0].2[key].is_null(),
            "cut message lacks {key}: {}",
            m[0].2
        );
    }
    let removed: Vec<f64> = m
        .iter()
        .map(|x| x.2["removed_mm3"].as_f64().unwrap())
        .collect();
    assert!(
        removed.windows(2).all(|w| w[1] >= w[0]),
        "removed volume decreased: {removed:?}"
    );
    drop(slave);
    drop(master);
    let _ = child.0.kill();
    let _ = child.0.wait();
}
