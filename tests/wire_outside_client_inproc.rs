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
use outside_client::{BIT_OUT_OF_RANGE, BIT_STALE, Cmd, Fb, bad_messages};

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
        Self::with(ArmConfig::default(), 10_000.0)
    }

    /// The rig with the slave arm `arm` and the slave's watchdog at `watchdog_ms`.
    fn with(arm: ArmConfig, watchdog_ms: f64) -> Self {
        let world = SlaveWorld {
            arm,
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
            watchdog_ms,
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

/// docs/wire.md, "Safe stop and the acknowledgement" and `echo_seq`, as an outside master
/// sees them on the wire. `echo_seq` is the `seq` of the last command the slave took in the
/// cycle (the newest of several, not a rejected one after it) and stays as it was in a cycle
/// that took none. After a safe stop (here the watchdog's), commands without the
/// acknowledgement are accepted by the gate but not followed (state stays 2, `echo_seq` stays,
/// fault bit 0 stays set): the negative control. The first command carrying
/// `CMD_FLAG_ACK_SAFE_STOP` re-arms the slave in the cycle it arrives (state 1, bit 0 clear,
/// echoed); acknowledgements that go on while active (the master's round trip) change
/// nothing, and commands without it then keep the slave active.
#[test]
fn a_safe_stop_re_arms_on_the_first_acknowledged_command_and_echo_seq_names_the_last_taken() {
    const ACK: u16 = 1 << 1;
    const FAULT_COMMAND_TIMEOUT: u16 = 1 << 0;
    let mut r = Rig::with(ArmConfig::default(), 20.0);
    let mut seq = 0;
    let pos = |seq| Cmd::position(SESSION, seq, HOME);
    for _ in 0..300 {
        seq += 1;
        r.cycle(&[&pos(seq).bytes()]);
        assert_eq!(r.last_fb.unwrap().echo_seq, seq, "one command per cycle");
    }
    // Two in one cycle: the newest is echoed.
    r.cycle(&[&pos(seq + 1).bytes(), &pos(seq + 2).bytes()]);
    seq += 2;
    assert_eq!(r.last_fb.unwrap().echo_seq, seq);
    // A rejected command alone (out of the workspace): the echo stays.
    let mut far = pos(seq + 1);
    far.pose[0] = 1e6;
    r.cycle(&[&far.bytes()]);
    assert_eq!(r.last_fb.unwrap().echo_seq, seq);
    assert_eq!(r.last_fb.unwrap().rejected_reasons, BIT_OUT_OF_RANGE);
    // An accepted command, then a rejected one (a duplicate) in the same cycle: the accepted
    // one is echoed, not the last received.
    seq += 2;
    r.cycle(&[&pos(seq).bytes(), &pos(seq).bytes()]);
    assert_eq!(r.last_fb.unwrap().echo_seq, seq);
    assert_eq!(r.last_fb.unwrap().rejected_reasons, BIT_STALE);
    // A cycle without a command: the echo stays.
    r.cycle(&[]);
    let fb = r.last_fb.unwrap();
    assert_eq!((fb.echo_seq, fb.state), (seq, 1));
    // Silence: the watchdog's safe stop (20 ms).
    for _ in 0..25 {
        r.cycle(&[]);
    }
    let fb = r.last_fb.unwrap();
    assert_eq!(fb.state, 2, "safe stop");
    assert!(fb.fault_flags & FAULT_COMMAND_TIMEOUT != 0);
    let followed = seq;
    // Negative control: commands without the acknowledgement are accepted by the gate but
    // neither followed nor echoed; the safe stop holds.
    let accepted = r.counters().accepted;
    for _ in 0..100 {
        seq += 1;
        r.cycle(&[&pos(seq).bytes()]);
        let fb = r.last_fb.unwrap();
        assert_eq!(fb.state, 2, "re-armed without the acknowledgement");
        assert_eq!(
            fb.echo_seq, followed,
            "an unacknowledged command was followed"
        );
        assert!(fb.fault_flags & FAULT_COMMAND_TIMEOUT != 0);
        assert_eq!(fb.rejected_reasons, 0);
    }
    assert_eq!(r.counters().accepted, accepted + 100);
    assert_eq!(r.ep.counters().unacknowledged_in_safe_stop, 100);
    // The master acknowledges in every command while the feedback says state 2: the first
    // acknowledged command re-arms the slave in its own cycle.
    seq += 1;
    r.cycle(&[&Cmd {
        flags: ACK,
        ..pos(seq)
    }
    .bytes()]);
    let fb = r.last_fb.unwrap();
    assert_eq!(fb.state, 1, "re-armed by the acknowledgement");
    assert_eq!(fb.echo_seq, seq, "the acknowledged command is followed");
    assert_eq!(fb.fault_flags & FAULT_COMMAND_TIMEOUT, 0);
    assert_eq!(r.ep.counters().repairs, 1);
    // The acknowledgements in flight (a round trip's worth) change nothing.
    for _ in 0..5 {
        seq += 1;
        r.cycle(&[&Cmd {
            flags: ACK,
            ..pos(seq)
        }
        .bytes()]);
        let fb = r.last_fb.unwrap();
        assert_eq!((fb.state, fb.echo_seq, fb.rejected_reasons), (1, seq, 0));
    }
    // Having seen state 1, the master stops acknowledging: the slave stays active.
    for _ in 0..100 {
        seq += 1;
        r.cycle(&[&pos(seq).bytes()]);
        let fb = r.last_fb.unwrap();
        assert_eq!((fb.state, fb.echo_seq), (1, seq));
    }
    assert_eq!(r.ep.counters().repairs, 1);
    assert_eq!(r.counters().pairings, 1);
}

/// docs/wire.md, "The limits of a command", with the shipped arm file
/// (config/arms/prototype.toml) and the default controller limits: each probe is one
/// position command, accepted or rejected as `out_of_range` (never clamped), one cycle each.
#[test]
fn a_command_outside_the_arms_limits_is_rejected_as_out_of_range_not_clamped() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/arms/prototype.toml");
    let arm: ArmConfig = h4_shared::config::load(&path, &[]).unwrap();
    let mut r = Rig::with(arm, 10_000.0);
    let mut seq = 0;
    for _ in 0..50 {
        seq += 1;
        r.cycle(&[&Cmd::position(SESSION, seq, HOME).bytes()]);
    }
    // (x, y, z, theta), then speed and set-point probes; true = accepted.
    let theta_max = 1.047_197_551_196_597_6;
    let poses: [([f64; 4], bool); 12] = [
        ([0.0, 0.0, -250.0, 1.047], true),
        ([0.0, 0.0, -250.0, theta_max + 1e-4], false),
        ([0.0, 0.0, -250.0, -1.047], true),
        ([0.0, 0.0, -250.0, -theta_max - 1e-4], false),
        // 10 mm from the singular line e z + h y = 0 (at y = 0, theta = 0: z = -10).
        ([0.0, 0.0, -10.01, 0.0], true),
        ([0.0, 0.0, -9.99, 0.0], false),
        // Rail clearance 20 mm: at x = y = theta = 0, z down to -373.03 mm.
        ([0.0, 0.0, -373.0, 0.0], true),
        ([0.0, 0.0, -373.1, 0.0], false),
        // Stroke ±650 mm: at z = -250, x up to ±372.42 mm.
        ([372.0, 0.0, -250.0, 0.0], true),
        ([373.0, 0.0, -250.0, 0.0], false),
        ([-372.0, 0.0, -250.0, 0.0], true),
        ([-373.0, 0.0, -250.0, 0.0], false),
    ];
    let mut probes: Vec<(String, Cmd, bool)> = poses
        .iter()
        .map(|(p, ok)| (format!("pose {p:?}"), Cmd::position(SESSION, 0, *p), *ok))
        .collect();
    let hold_far = Cmd {
        mode: 0,
        pose: [0.0, 0.0, -1e6, 0.0],
        ..Cmd::position(SESSION, 0, HOME)
    };
    probes.push(("hold mode ignores the pose".into(), hold_far, true));
    for (v, ok) in [(100.0, true), (100.01, false)] {
        let c = Cmd {
            velocity: [0.6 * v, 0.0, -0.8 * v, 5.0],
            ..Cmd::position(SESSION, 0, HOME)
        };
        probes.push((format!("speed {v} mm/s"), c, ok));
    }
    for (f, ok) in [(80.0, true), (80.01, false), (0.0, true), (-0.01, false)] {
        let c = Cmd {
            mode: 2,
            force_setpoint_n: f,
            ..Cmd::position(SESSION, 0, HOME)
        };
        probes.push((format!("set-point {f} N"), c, ok));
    }
    for (name, probe, ok) in probes {
        let before = r.counters();
        seq += 1;
        r.cycle(&[&Cmd { seq, ..probe }.bytes()]);
        let after = r.counters();
        let fb = r.last_fb.unwrap();
        if ok {
            assert_eq!(after.accepted, before.accepted + 1, "{name}: {after:?}");
            assert_eq!(fb.echo_seq, seq, "{name}");
        } else {
            assert_eq!(
                after.out_of_range,
                before.out_of_range + 1,
                "{name}: {after:?}"
            );
            assert_eq!(after.rejected(), before.rejected() + 1, "{name}");
            assert_eq!(fb.rejected_reasons, BIT_OUT_OF_RANGE, "{name}");
            assert_ne!(fb.echo_seq, seq, "{name}: followed");
        }
        // Back home before the next probe.
        seq += 1;
        r.cycle(&[&Cmd::position(SESSION, seq, HOME).bytes()]);
    }
}

/// Protocol 3, from docs/wire.md alone: the outside master echoes the newest feedback it has,
/// held back 40 cycles (a 40 ms round trip: the feedback sent at cycle k is echoed by the
/// command the slave takes at cycle k + 40), and the slave measures that round trip itself;
/// pressed onto the resin block, its feedback reports the contact, a unit normal along +z and
/// a positive stiffness. Control: echoes withheld (zero), the slave has no measurement and
/// uses its fallback, counted in `round_trip_fallback_cycles`.
#[test]
fn the_slave_measures_the_round_trip_an_outside_master_echoes_and_reports_its_surface() {
    let run = |echo: bool| {
        let mut r = Rig::new();
        let mut received: Vec<Fb> = Vec::new();
        for seq in 1..=300u64 {
            let mut c = Cmd::position(SESSION, seq, HOME);
            if echo && received.len() > 40 {
                let f = received[received.len() - 41];
                (c.echo_seq, c.echo_send_time_ns) = (f.seq, f.send_time_ns);
            }
            r.cycle(&[&c.bytes()]);
            received.push(r.last_fb.unwrap());
        }
        r
    };
    let r = run(true);
    let (rtt_ms, measured) = r.ep.round_trip_in_use_ms();
    assert!(measured);
    // The echo of the feedback sent at cycle k arrives with the command of cycle k + 41 (the
    // feedback of a cycle is read after it): 41 ms on the slave's clock, exactly.
    assert_eq!(rtt_ms, 41.0);
    assert_eq!(r.ep.round_trip().jitter_ms(), Some(0.0));
    assert_eq!(r.ep.counters().round_trip_echoes_refused, 0);
    let fb = r.last_fb.unwrap();
    assert_eq!(fb.contact_state, 1, "free space 2 mm above the block");
    let control = run(false);
    assert_eq!(control.ep.round_trip_in_use_ms(), (0.0, false));
    assert_eq!(control.ep.round_trip().samples(), 0);
    assert!(control.ep.counters().round_trip_fallback_cycles >= 299);
    assert_eq!(r.ep.counters().round_trip_fallback_cycles, 41);
    // Pressed 3 mm into the block (its surface at z = −260 mm).
    let mut r = r;
    for seq in 301..=1300u64 {
        r.cycle(&[&Cmd::position(SESSION, seq, [0.0, 0.0, -263.0, 0.0]).bytes()]);
    }
    let fb = r.last_fb.unwrap();
    assert_eq!(fb.contact_state, 2, "{fb:?}");
    let n = fb.contact_normal;
    assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-6);
    assert!(n[2] > 0.99, "outward normal of a horizontal block: {n:?}");
    assert!((fb.contact_point_mm[2] + 260.0).abs() < 2.0, "{fb:?}");
    assert!(fb.contact_stiffness_n_per_mm > 0.0, "{fb:?}");
}
