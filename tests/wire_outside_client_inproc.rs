//! An outside client, written from docs/wire.md alone (bytes encoded by hand, feedback parsed
//! by hand), talks to the slave's teleoperation endpoint over a byte-level in-process link
//! (the slave's end decodes exactly as the Zenoh link does). A correct command is accepted and
//! moves the arm; every bad message of issue 14's list (random bytes, truncated, wrong
//! version, reserved bits, length mismatch, x = 1e6 mm, z = −1e6 mm, a 1e6 N set-point,
//! `energy_in_j` = 1e6, seq 2⁶⁴−1, another arm, a duplicate, a second master) is rejected,
//! counted under its reason (and only there), flagged in the feedback, and never acted on:
//! the simulated arm, held 2 mm above a resin surface, neither moves nor presses.

#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "common/outside_client.rs"]
mod outside_client;

use h4_shared::config::ArmConfig;
use h4_shared::kinematics::Pose;
use h4_shared::wire::{Command, Feedback};
use h4_slave::controller::ControllerParams;
use h4_slave::teleop::{SlaveTeleop, TeleopParams};
use h4_slave_sim::plant::{
    MaterialPreset, PlantConfig, SensorConfig, ShapeKind, SimArm, SurfaceConfig,
};
use h4_slave_sim::world::SlaveWorld;
use h4_transport::gate::GateCounters;
use h4_transport::inproc::{self, DecodingEnd, RawEnd};
use outside_client::{Cmd, Fb, bad_messages};

const PERIOD_NS: u64 = 1_000_000;
const HOME: [f64; 4] = [0.0, 0.0, -258.0, 0.0];
const SESSION: u64 = 0x5EED_0000_0000_0001;

struct Rig {
    ep: SlaveTeleop<SimArm>,
    client: RawEnd,
    link: DecodingEnd<Feedback, Command>,
    now: u64,
    last_fb: Option<Fb>,
    reasons_seen: u32,
    max_dev_mm: f64,
    max_force_n: f64,
}

impl Rig {
    fn new() -> Self {
        let world = SlaveWorld {
            arm: ArmConfig::default(),
            surface: SurfaceConfig::new(
                ShapeKind::Plane,
                MaterialPreset::Resin,
                [0.0, 0.0, -260.0],
            ),
            sensor: SensorConfig::default(),
            plant: PlantConfig::default(),
            controller: ControllerParams::default(),
            cutting: None,
            fixtures: Default::default(),
        };
        let (arm, ctrl) = world.build(Pose::from(HOME), 1).unwrap();
        let p = TeleopParams {
            watchdog_ms: 10_000.0,
            ..TeleopParams::default()
        };
        let (client, link) = inproc::raw_pair(4096);
        Rig {
            ep: SlaveTeleop::new(p, ctrl, arm, PERIOD_NS).unwrap(),
            client,
            link,
            now: 0,
            last_fb: None,
            reasons_seen: 0,
            max_dev_mm: 0.0,
            max_force_n: 0.0,
        }
    }

    /// Sends `msgs`, runs one slave cycle, reads the feedback by hand.
    fn cycle(&mut self, msgs: &[&[u8]]) {
        for m in msgs {
            self.client.send(m);
        }
        self.ep.step(&mut self.link, self.now, 1e-3);
        self.ep.arm_mut().advance(PERIOD_NS);
        self.now += PERIOD_NS;
        while let Some(b) = self.client.recv() {
            let fb = Fb::parse(&b).expect("feedback as docs/wire.md describes it");
            self.reasons_seen |= fb.rejected_reasons;
            self.last_fb = Some(fb);
        }
        // The truth of the simulated arm, not what the slave reports.
        let p = self.ep.arm().true_pose();
        let dev = (0..3).map(|i| (p[i] - HOME[i]).powi(2)).sum::<f64>().sqrt();
        self.max_dev_mm = self.max_dev_mm.max(dev);
        let w = self.ep.arm().true_contact_wrench();
        self.max_force_n = self
            .max_force_n
            .max((w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt());
    }

    fn counters(&self) -> GateCounters {
        *self.ep.gate_counters()
    }
}

fn counter(c: &GateCounters, name: &str) -> u64 {
    serde_json::to_value(c).unwrap()[name].as_u64().unwrap()
}

#[test]
fn a_hand_encoded_command_is_accepted_and_acted_on() {
    let mut r = Rig::new();
    let mut seq = 0;
    for _ in 0..300 {
        seq += 1;
        r.cycle(&[&Cmd::position(SESSION, seq, HOME).bytes()]);
    }
    let fb = r.last_fb.unwrap();
    assert_eq!(fb.echo_seq, seq, "the slave echoes the last command");
    assert_eq!(fb.state, 1, "active");
    assert_eq!(r.counters().accepted, seq);
    assert_eq!(r.counters().rejected(), 0);
    assert_eq!(r.ep.gate().paired_session(), Some(SESSION));
    // A target 3 mm away in x: the arm goes there.
    let target = [HOME[0] + 3.0, HOME[1], HOME[2], HOME[3]];
    for _ in 0..1000 {
        seq += 1;
        r.cycle(&[&Cmd::position(SESSION, seq, target).bytes()]);
    }
    let x = r.ep.arm().true_pose()[0];
    assert!(
        (x - target[0]).abs() < 0.3,
        "the arm went to x = {x} mm, not 3 mm"
    );
    assert!(r.max_dev_mm > 2.0, "the motion detector sees it");
    // A target 3 mm into the resin, with energy the master may plausibly have put in (10 W,
    // under the slave's bound): the arm presses, and the force detector sees it.
    let mut energy_j = 0.0;
    for _ in 0..1000 {
        seq += 1;
        energy_j += 0.01;
        let c = Cmd {
            energy_in_j: energy_j,
            ..Cmd::position(SESSION, seq, [0.0, 0.0, -263.0, 0.0])
        };
        r.cycle(&[&c.bytes()]);
    }
    assert!(r.max_force_n > 5.0, "pressed only {} N", r.max_force_n);
    assert_eq!(r.counters().rejected(), 0, "{:?}", r.counters());
}

#[test]
fn every_bad_message_is_rejected_counted_by_reason_flagged_and_never_acted_on() {
    let mut r = Rig::new();
    let mut seq = 0;
    let rng = 0x9E37_79B9_7F4A_7C15u64;
    for _ in 0..300 {
        seq += 1;
        r.cycle(&[&Cmd::position(SESSION, seq, HOME).bytes()]);
    }
    // Settled at home.
    r.max_dev_mm = 0.0;
    r.max_force_n = 0.0;
    // Each case is built with a sequence number above the keep-alives of its batch.
    let bad_at =
        |seq: u64| bad_messages(&Cmd::position(SESSION, seq + 500, HOME), &mut rng.clone());
    let cases = bad_at(seq).len();
    const SENT: u64 = 300;
    const KEEPALIVE_EVERY: u64 = 50;
    for i in 0..cases {
        let b = &bad_at(seq)[i];
        let before = r.counters();
        r.reasons_seen = 0;
        let mut keepalives = 0;
        for k in 0..SENT {
            // Only the bad message, except a valid hold every 50 ms (the paired master stays
            // alive, so a second master cannot take over by silence).
            r.cycle(&[&b.bytes]);
            if k % KEEPALIVE_EVERY == KEEPALIVE_EVERY - 1 {
                seq += 1;
                r.cycle(&[&Cmd::position(SESSION, seq, HOME).bytes()]);
                keepalives += 1;
            }
        }
        let after = r.counters();
        assert_eq!(
            counter(&after, b.counter) - counter(&before, b.counter),
            SENT,
            "{}: counted under {}: {after:?}",
            b.name,
            b.counter
        );
        assert_eq!(
            after.rejected() - before.rejected(),
            SENT,
            "{}: only there",
            b.name
        );
        assert_eq!(after.accepted - before.accepted, keepalives, "{}", b.name);
        assert!(
            r.reasons_seen & b.bit != 0,
            "{}: flag {:#x} not in the feedback",
            b.name,
            b.bit
        );
        assert_eq!(r.reasons_seen & !b.bit, 0, "{}: other flags", b.name);
        assert!(
            r.max_dev_mm < 0.3,
            "{}: the arm moved {} mm",
            b.name,
            r.max_dev_mm
        );
        assert!(
            r.max_force_n < 1.0,
            "{}: the arm pressed {} N",
            b.name,
            r.max_force_n
        );
    }
    let fb = r.last_fb.unwrap();
    assert_eq!(u64::from(fb.rejected_count), r.counters().rejected());
    assert_eq!(r.counters().rejected(), SENT * cases as u64);
    // The energy of the 1e6 J message was not believed.
    assert!(
        r.ep.port().observed_j() < 1.0,
        "observer {} J",
        r.ep.port().observed_j()
    );
    assert_eq!(r.counters().pairings, 1);
    assert_eq!(r.ep.gate().paired_session(), Some(SESSION));
}
