//! Pins a bug this test found: a feedback whose surface estimate is out of range
//! (`SurfaceOutOfRange`, protocol 3), refused by the Zenoh link's decoder, was counted as
//! `undecodable` (the link's `DecodeRejects` had no `out_of_range`), where docs/wire.md and
//! the vectors say `out_of_range`.
//!
//! The master's side of `tests/wire_vectors_at_the_slave.rs`: every invalid *feedback* vector
//! of `tests/data/wire_vectors.json` (a protocol-2 slave's 176-byte feedback, an unknown
//! contact state, the surface estimate's ranges, a NaN in it) goes, as raw bytes from an
//! outside Zenoh session, through the master's receive path (`MasterTeleop::poll_peer`: a real
//! Zenoh link end's decoder, then the receive gate) and must be counted once under the counter
//! the vector names (`gate.<counter>` in the master's summary) and nowhere else, and never
//! becomes the master's newest feedback (the one its commands echo). Control: the file's valid
//! in-contact feedback vector pairs the master (accepted, decoded to its fields), and the valid
//! feedback sent after each invalid vector is accepted, one count each.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::time::{Duration, Instant};

use h4_master::coupling::{CouplingConfig, ScaleConfig};
use h4_master::device::{DeviceState, HapticDevice, PrincipalMasses};
use h4_master::teleop::{MasterTeleop, MasterTeleopConfig};
use h4_shared::config::ArmConfig;
use h4_shared::passivity::PassivityParams;
use h4_shared::wire::{Feedback, SlaveState};
use h4_transport::gate::GateCounters;
use h4_transport::zenoh::{MasterZenohLink, ZenohConfig};
use serde_json::Value;
use zenoh::Wait;

const PERIOD_NS: u64 = 1_000_000;
/// The arm and the slave session of the file's feedback vectors.
const ARM: u16 = 3;
const SESSION: u64 = 0xA1B2_C3D4_E5F6_0718;
/// Longest any wait for the link may take before the test fails (a watchdog, not a timing
/// assertion).
const WATCHDOG: Duration = Duration::from_secs(30);

/// A handle held still; its readings' time moves on by 1 ms a read.
#[derive(Default)]
struct StillHandle {
    time_ns: u64,
}

impl HapticDevice for StillHandle {
    fn read(&mut self) -> DeviceState {
        self.time_ns += PERIOD_NS;
        DeviceState {
            time_ns: self.time_ns,
            effective_mass_kg: 0.5,
            principal_masses: PrincipalMasses::isotropic(0.5),
            ..DeviceState::default()
        }
    }
    fn write_wrench(&mut self, wrench: &[f64; 4]) -> [f64; 4] {
        *wrench
    }
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// The file's feedback vectors under `section` ("valid" or "invalid"): name, bytes, counter.
fn feedback_vectors(section: &str) -> Vec<(String, Vec<u8>, String)> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/wire_vectors.json");
    let file: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    file[section]
        .as_array()
        .unwrap()
        .iter()
        .filter(|v| v["kind"] == "feedback")
        .map(|v| {
            (
                v["name"].as_str().unwrap().to_string(),
                unhex(v["bytes"].as_str().unwrap()),
                v["counter"].as_str().unwrap_or("").to_string(),
            )
        })
        .collect()
}

/// A valid feedback of the vectors' slave session, with the energy fields of the session's
/// first (they never decrease).
fn marker(seq: u64, (energy_in_j, energy_out_j): (f64, f64)) -> Vec<u8> {
    let f = Feedback {
        session_id: SESSION,
        seq,
        send_time_ns: seq * PERIOD_NS,
        energy_in_j,
        energy_out_j,
        arm_id: ARM,
        state: SlaveState::Active as u8,
        ..Feedback::default()
    };
    let mut b = [0u8; Feedback::WIRE_SIZE];
    f.encode(&mut b);
    b.to_vec()
}

fn counter(c: &GateCounters, name: &str) -> u64 {
    serde_json::to_value(c).unwrap()[name]
        .as_u64()
        .unwrap_or_else(|| panic!("no gate counter named {name}"))
}

struct Rig {
    ep: MasterTeleop<StillHandle>,
    link: MasterZenohLink,
    now_ns: u64,
}

impl Rig {
    /// Polls the master's receive path until its newest accepted feedback is `seq`
    /// (watchdog-bounded).
    fn poll_until_taken(&mut self, seq: u64, what: &str) {
        let t = Instant::now();
        loop {
            self.ep.poll_peer(&mut self.link, self.now_ns);
            self.now_ns += PERIOD_NS;
            if self.ep.latest_feedback().map(|f| f.seq) == Some(seq) {
                return;
            }
            assert!(t.elapsed() < WATCHDOG, "watchdog: {what}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

#[test]
fn every_invalid_feedback_vector_is_counted_by_its_name_at_the_master_over_zenoh() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let link =
        MasterZenohLink::open(ARM, &ZenohConfig::listen_on_loopback(port)).expect("master end");
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
        .declare_publisher(format!("h4/{ARM}/feedback"))
        .wait()
        .expect("publisher");
    let send = |b: &[u8]| publisher.put(b.to_vec()).wait().expect("put");
    let cfg = MasterTeleopConfig {
        arm_id: ARM,
        coupling: CouplingConfig::default(),
        scale: ScaleConfig::default(),
        passivity: PassivityParams::default(),
        slave_arm: ArmConfig::default(),
        slave_anchor_pose: [0.0, 0.0, -245.0, 0.0],
        slave_max_speed_mm_per_s: 100.0,
    };
    let mut rig = Rig {
        ep: MasterTeleop::new(&cfg, StillHandle::default()),
        link,
        now_ns: 0,
    };
    // Pair with the file's valid in-contact feedback (its surface estimate included): the
    // control, accepted whole and taken as the newest feedback.
    let (_, valid, _) = feedback_vectors("valid")
        .into_iter()
        .find(|v| v.0 == "active feedback with faults, in contact")
        .expect("the in-contact feedback vector");
    let want = Feedback::decode(&valid).expect("a valid vector");
    let t = Instant::now();
    while rig.ep.gate_counters().accepted == 0 {
        send(&valid);
        rig.ep.poll_peer(&mut rig.link, rig.now_ns);
        rig.now_ns += PERIOD_NS;
        assert!(t.elapsed() < WATCHDOG, "watchdog: the link never came up");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(rig.ep.latest_feedback(), Some(&want));
    assert_eq!(rig.ep.gate_counters().rejected(), 0);
    // Markers after it: every copy of the vector still in flight is judged (stale) before the
    // first marker is taken (one publisher's samples arrive in order).
    let energies = (want.energy_in_j, want.energy_out_j);
    let mark = |seq: u64| marker(seq, energies);
    let mut seq = want.seq;
    seq += 1;
    send(&mark(seq));
    rig.poll_until_taken(seq, "the last pairing marker");
    let invalid = feedback_vectors("invalid");
    for (name, bytes, reason) in &invalid {
        let before = *rig.ep.gate_counters();
        send(bytes);
        seq += 1;
        send(&mark(seq));
        rig.poll_until_taken(seq, name);
        let after = *rig.ep.gate_counters();
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
    let names: Vec<&str> = invalid.iter().map(|v| v.0.as_str()).collect();
    assert!(
        names.contains(&"a protocol version 2 feedback") && invalid.len() >= 6,
        "{names:?}"
    );
    let c = *rig.ep.gate_counters();
    assert_eq!(c.wrong_version, 1, "the protocol-2 feedback: {c:?}");
    assert!(c.out_of_range >= 3, "the surface estimate's ranges: {c:?}");
}
