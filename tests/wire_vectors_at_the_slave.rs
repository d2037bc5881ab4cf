//! Pins issue 31's bug: a protocol-1 command (120 bytes) that reached the slave over Zenoh was
//! counted as `undecodable` (for its size), where docs/wire.md and
//! `tests/data/wire_vectors.json` say `wrong_version`. Every invalid vector of the file goes,
//! as raw bytes, through the slave's receive path (`SlaveTeleop::step` draining a real Zenoh
//! link end, and the byte-level in-process link) and must be counted once under the counter
//! the vector names (`gate.<counter>` in the slave's summary), and nowhere else; over the
//! in-process link the next feedback also carries the counter's bit.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::time::{Duration, Instant};

use h4_shared::config::ArmConfig;
use h4_shared::kinematics::Pose;
use h4_shared::wire::{Command, Feedback, Mode, RejectReason};
use h4_slave::controller::ControllerParams;
use h4_slave::teleop::{SlaveTeleop, TeleopParams};
use h4_slave_sim::plant::{
    MaterialPreset, PlantConfig, SensorConfig, ShapeKind, SimArm, SurfaceConfig,
};
use h4_slave_sim::world::SlaveWorld;
use h4_transport::Link;
use h4_transport::gate::GateCounters;
use h4_transport::inproc;
use h4_transport::zenoh::{SlaveZenohLink, ZenohConfig};
use serde_json::Value;
use zenoh::Wait;

const PERIOD_NS: u64 = 1_000_000;
const SESSION: u64 = 0x0031_0000_0000_0001;
/// Longest any wait for the link may take before the test fails (a watchdog, not a timing
/// assertion).
const WATCHDOG: Duration = Duration::from_secs(30);

/// The invalid vectors: name, bytes, the counter each must land in.
fn invalid_vectors() -> Vec<(String, Vec<u8>, String)> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/wire_vectors.json");
    let file: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    file["invalid"]
        .as_array()
        .unwrap()
        .iter()
        // The feedback vectors are the master's to refuse (tests/wire_vectors_at_the_master.rs).
        .filter(|v| v["kind"] == "command")
        .map(|v| {
            let hex = v["bytes"].as_str().unwrap();
            let bytes = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                .collect();
            (
                v["name"].as_str().unwrap().to_string(),
                bytes,
                v["counter"]
                    .as_str()
                    .expect("each vector names its counter")
                    .to_string(),
            )
        })
        .collect()
}

fn endpoint() -> SlaveTeleop<SimArm> {
    let world = SlaveWorld {
        arm: ArmConfig::default(),
        surface: SurfaceConfig::new(ShapeKind::Plane, MaterialPreset::Resin, [0.0, 0.0, -260.0]),
        sensor: SensorConfig::default(),
        plant: PlantConfig::default(),
        controller: ControllerParams::default(),
        cutting: None,
        fixtures: Default::default(),
    };
    let (arm, ctrl) = world.build(Pose::new(0.0, 0.0, -250.0, 0.0), 1).unwrap();
    let p = TeleopParams {
        // The test waits for a real link between cycles: no safe stop meanwhile.
        watchdog_ms: 100_000.0,
        ..TeleopParams::default()
    };
    SlaveTeleop::new(p, ctrl, arm, PERIOD_NS).unwrap()
}

/// A valid hold command of the test's session.
fn marker(seq: u64) -> Vec<u8> {
    let c = Command {
        session_id: SESSION,
        seq,
        send_time_ns: seq * PERIOD_NS,
        pose: [0.0, 0.0, -250.0, 0.0],
        mode: Mode::Hold as u8,
        ..Command::default()
    };
    let mut b = [0u8; Command::WIRE_SIZE];
    c.encode(&mut b);
    b.to_vec()
}

fn counter(c: &GateCounters, name: &str) -> u64 {
    serde_json::to_value(c).unwrap()[name]
        .as_u64()
        .unwrap_or_else(|| panic!("no gate counter named {name}"))
}

/// The slave endpoint on `link`, stepped on a simulated clock; `send` puts raw bytes on the
/// wire as an outside client would.
struct Rig<L> {
    ep: SlaveTeleop<SimArm>,
    link: L,
    now_ns: u64,
    seq: u64,
}

impl<L: Link<Feedback, Command>> Rig<L> {
    fn step(&mut self) {
        self.ep.step(&mut self.link, self.now_ns, 1e-3);
        self.ep.arm_mut().advance(PERIOD_NS);
        self.now_ns += PERIOD_NS;
    }

    /// Steps until the gate's newest accepted command is `seq` (watchdog-bounded).
    fn step_until_taken(&mut self, seq: u64, what: &str) {
        let t = Instant::now();
        loop {
            self.step();
            if self.ep.gate().latest().map(|c| c.seq) == Some(seq) {
                return;
            }
            assert!(t.elapsed() < WATCHDOG, "watchdog: {what}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Pairs with the test's session, then sends each vector followed by a valid command
    /// (whose acceptance means the vector was judged) and checks the counters.
    fn judge_every_vector(&mut self, send: &mut dyn FnMut(&[u8])) -> usize {
        let t = Instant::now();
        while self.ep.gate_counters().accepted == 0 {
            self.seq += 1;
            send(&marker(self.seq));
            self.step();
            assert!(t.elapsed() < WATCHDOG, "watchdog: the link never came up");
            std::thread::sleep(Duration::from_millis(5));
        }
        // Every marker sent so far has arrived (one publisher's samples arrive in order).
        self.seq += 1;
        send(&marker(self.seq));
        self.step_until_taken(self.seq, "the last pairing marker");
        let vectors = invalid_vectors();
        for (name, bytes, reason) in &vectors {
            let before = *self.ep.gate_counters();
            send(bytes);
            self.seq += 1;
            send(&marker(self.seq));
            self.step_until_taken(self.seq, name);
            let after = *self.ep.gate_counters();
            assert_eq!(
                after.accepted,
                before.accepted + 1,
                "{name}: the marker only"
            );
            assert_eq!(
                counter(&after, reason) - counter(&before, reason),
                1,
                "{name}: counted under {reason}? {after:?}"
            );
            assert_eq!(
                after.rejected() - before.rejected(),
                1,
                "{name}: counted only there: {after:?}"
            );
        }
        vectors.len()
    }
}

#[test]
fn every_invalid_vector_is_counted_by_its_name_over_zenoh() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let link = SlaveZenohLink::open(0, &ZenohConfig::listen_on_loopback(port)).expect("slave end");
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"client\"").unwrap();
    config
        .insert_json5("connect/endpoints", &format!("[\"tcp/127.0.0.1:{port}\"]"))
        .unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let client = zenoh::open(config).wait().expect("client session");
    let publisher = client
        .declare_publisher("h4/0/command")
        .wait()
        .expect("publisher");
    let mut rig = Rig {
        ep: endpoint(),
        link,
        now_ns: 0,
        seq: 0,
    };
    let mut send = |b: &[u8]| publisher.put(b.to_vec()).wait().expect("put");
    let judged = rig.judge_every_vector(&mut send);
    assert!(judged >= 20, "only {judged} vectors");
    let c = rig.ep.gate_counters();
    assert!(c.wrong_version >= 3, "the version vectors: {c:?}");
    assert_eq!(c.pairings, 1);
}

#[test]
fn every_invalid_vector_is_counted_by_its_name_and_flagged_over_the_byte_link() {
    let (mut client, link) = inproc::raw_pair(64);
    let mut rig = Rig {
        ep: endpoint(),
        link,
        now_ns: 0,
        seq: 0,
    };
    client.send(&marker(1));
    rig.seq = 1;
    rig.step_until_taken(1, "pairing");
    let vectors = invalid_vectors();
    for (name, bytes, reason) in &vectors {
        let before = *rig.ep.gate_counters();
        while client.recv().is_some() {}
        client.send(bytes);
        rig.seq += 1;
        client.send(&marker(rig.seq));
        rig.step();
        let after = *rig.ep.gate_counters();
        assert_eq!(after.accepted, before.accepted + 1, "{name}");
        assert_eq!(
            counter(&after, reason) - counter(&before, reason),
            1,
            "{name}: counted under {reason}? {after:?}"
        );
        assert_eq!(after.rejected() - before.rejected(), 1, "{name}");
        let fb = client.recv().expect("feedback");
        let bits = u32::from_le_bytes(fb[168..172].try_into().unwrap());
        let bit = RejectReason::ALL
            .iter()
            .find(|r| r.name() == reason)
            .unwrap()
            .bit();
        assert_eq!(
            bits, bit,
            "{name}: rejected_reasons {bits:#x}, want {bit:#x}"
        );
    }
    assert!(vectors.len() >= 20);
}
