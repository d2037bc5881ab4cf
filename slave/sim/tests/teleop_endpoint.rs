//! The slave's endpoint over the simulated arm: the spindle stall, the watchdog's safe
//! stop and re-pairing, and bad commands (moved from the product crate's unit tests: the
//! product crate does not depend on the simulator).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::config::ArmConfig;
use h4_shared::kinematics::Pose;
use h4_shared::wire::*;
use h4_slave::arm::{ArmDriver, ArmReading};
use h4_slave::controller::{ControllerParams, SlaveController};
use h4_slave::teleop::*;
use h4_slave_sim::plant::{
    MaterialPreset, PlantConfig, SensorConfig, ShapeKind, SimArm, SurfaceConfig,
};
use h4_slave_sim::world::SlaveWorld;
use h4_transport::Link;
use h4_transport::inproc::{self, InprocEnd};

const PERIOD_NS: u64 = 1_000_000;

fn endpoint(passivity: bool) -> SlaveTeleop<SimArm> {
    let (p, ctrl, arm) = parts(passivity);
    SlaveTeleop::new(p, ctrl, arm, PERIOD_NS).unwrap()
}

fn parts(passivity: bool) -> (TeleopParams, SlaveController, SimArm) {
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
    let mut p = TeleopParams::default();
    p.passivity.enabled = passivity;
    // Passivity off (the tests of the gate and the watchdog alone) is a safety layer off.
    p.safety.unsafe_test_override = !passivity;
    (p, ctrl, arm)
}

fn command(seq: u64, now_ns: u64, z: f64) -> Command {
    Command {
        seq,
        send_time_ns: now_ns,
        pose: [0.0, 0.0, z, 0.0],
        mode: Mode::Position as u8,
        protocol_version: PROTOCOL_VERSION,
        ..Command::default()
    }
}

struct Rig {
    ep: SlaveTeleop<SimArm>,
    master: InprocEnd<Command, Feedback>,
    slave: InprocEnd<Feedback, Command>,
    now: u64,
    seq: u64,
    reasons: u32,
    /// Commands carry the safe-stop acknowledgement.
    ack: bool,
}

impl Rig {
    fn cycle(&mut self, send: Option<f64>) -> TeleopCycle {
        if let Some(z) = send {
            self.seq += 1;
            let mut c = command(self.seq, self.now, z);
            if self.ack {
                c.flags |= CMD_FLAG_ACK_SAFE_STOP;
                c.energy_in_j = 1e-4;
            } else {
                c.energy_in_j = 5.0;
            }
            self.master.publish(&c).unwrap();
        }
        let c = self.ep.step(&mut self.slave, self.now, 1e-3);
        while let Some(fb) = self.master.try_recv().unwrap() {
            self.reasons |= fb.rejected_reasons;
        }
        self.ep.arm_mut().advance(PERIOD_NS);
        self.now += PERIOD_NS;
        c
    }
}

/// The simulated arm with a spindle drive whose stall the test sets.
struct StallingArm {
    arm: SimArm,
    stalled: bool,
}

impl ArmDriver for StallingArm {
    fn read(&mut self) -> ArmReading {
        self.arm.read()
    }
    fn command(&mut self, actuators_mm: &[f64; 4]) {
        self.arm.command(actuators_mm);
    }
    fn spindle_stalled(&self) -> bool {
        self.stalled
    }
}

#[test]
fn a_spindle_stall_safe_stops_and_the_master_cannot_clear_it_while_it_lasts() {
    let (p, ctrl, arm) = parts(true);
    let arm = StallingArm {
        arm,
        stalled: false,
    };
    let mut ep = SlaveTeleop::new(p, ctrl, arm, PERIOD_NS).unwrap();
    let (mut master, mut slave) = inproc::pair(64);
    let (mut now, mut seq) = (0, 0);
    let mut cycle = |ep: &mut SlaveTeleop<StallingArm>, ack: bool| {
        seq += 1;
        let mut c = command(seq, now, -251.0);
        if ack {
            c.flags |= CMD_FLAG_ACK_SAFE_STOP;
        }
        master.publish(&c).unwrap();
        let out = ep.step(&mut slave, now, 1e-3);
        while master.try_recv().unwrap().is_some() {}
        ep.arm_mut().arm.advance(PERIOD_NS);
        now += PERIOD_NS;
        out
    };
    for _ in 0..100 {
        assert_eq!(cycle(&mut ep, false).state, SlaveState::Active);
    }
    // The spindle stalls: a safe stop at once, with the link alive.
    ep.arm_mut().stalled = true;
    let c = cycle(&mut ep, false);
    assert_eq!(c.state, SlaveState::SafeStop);
    assert_eq!(ep.counters().safe_stops, 1);
    assert_eq!(ep.counters().spindle_stall_stops, 1);
    let z_stalled = c.out.commanded_pose[2];
    // The master acknowledges, as it does once it has faded out: refused while the
    // spindle stays stalled; meanwhile the tool lifts (to come clear of the stock).
    let mut z = z_stalled;
    for _ in 0..500 {
        let c = cycle(&mut ep, true);
        assert_eq!(c.state, SlaveState::SafeStop);
        assert!(!c.repaired);
        assert!(c.out.commanded_pose[2] >= z - 1e-9, "the lift went down");
        z = c.out.commanded_pose[2];
    }
    assert!(z > z_stalled + 1.0, "lifted only {} mm", z - z_stalled);
    assert_eq!(ep.counters().repairs, 0);
    // The spindle runs again: the next acknowledgement re-pairs.
    ep.arm_mut().stalled = false;
    let repaired = (0..5).any(|_| cycle(&mut ep, true).repaired);
    assert!(repaired);
    assert_eq!(ep.state(), SlaveState::Active);
    assert_eq!(ep.counters().spindle_stall_stops, 1);
}

#[test]
fn watchdog_safe_stop_and_repair_without_jump() {
    let (master, slave) = inproc::pair(64);
    let mut r = Rig {
        ep: endpoint(true),
        master,
        slave,
        now: 0,
        seq: 0,
        reasons: 0,
        ack: false,
    };
    assert_eq!(r.ep.state(), SlaveState::Idle);
    // Follow a slow downward ramp.
    let mut z = -250.0;
    for _ in 0..500 {
        z -= 0.004;
        let c = r.cycle(Some(z));
        assert_eq!(c.state, SlaveState::Active);
    }
    // Silence: the watchdog trips at 20 ms, not before.
    let mut tripped_at = None;
    for k in 1..=40 {
        let c = r.cycle(None);
        if c.tripped {
            tripped_at = Some(k);
        }
    }
    let k = tripped_at.expect("watchdog never tripped");
    assert!((19..=21).contains(&k), "tripped after {k} silent cycles");
    assert_eq!(r.ep.state(), SlaveState::SafeStop);
    assert_eq!(r.ep.counters().safe_stops, 1);
    let held = r.cycle(None).out.commanded_pose;
    assert!(r.cycle(None).fault_flags & FAULT_COMMAND_TIMEOUT != 0);
    // Commands without the master's acknowledgement do not re-engage the arm, and
    // their (old ledger's) energy is not taken.
    let observed = r.ep.port().observed_j();
    for _ in 0..100 {
        let c = r.cycle(Some(-230.0));
        assert!(!c.repaired);
        assert_eq!(c.state, SlaveState::SafeStop);
        assert!((c.out.commanded_pose[2] - held[2]).abs() < 0.2);
    }
    assert_eq!(r.ep.port().observed_j(), observed);
    assert_eq!(r.ep.counters().unacknowledged_in_safe_stop, 100);
    // The master comes back 20 mm away and acknowledges: re-paired on a new ledger
    // (the old ledger's 5 J are gone), and the commanded pose moves gradually (no
    // jump).
    r.ack = true;
    let mut prev = held;
    let mut repaired = false;
    for _ in 0..300 {
        let c = r.cycle(Some(-230.0));
        repaired |= c.repaired;
        let step = (c.out.commanded_pose[2] - prev[2]).abs();
        assert!(step < 0.2, "jump of {step} mm");
        prev = c.out.commanded_pose;
    }
    assert!(repaired);
    assert_eq!(r.ep.counters().repairs, 1);
    assert_eq!(r.ep.counters().new_pairings, 1);
    assert!(r.ep.port().observed_j() <= 1e-4 + 1e-12);
    assert_eq!(r.ep.state(), SlaveState::Active);
    assert!(prev[2] > held[2] + 1.0, "did not move towards the master");
    assert_eq!(r.ep.counters().feedback_published, r.ep.counters().cycles);
}

#[test]
fn bad_commands_are_counted_not_followed() {
    let (master, slave) = inproc::pair(64);
    // Passivity off: the target is passed to the controller as the link asks.
    let mut r = Rig {
        ep: endpoint(false),
        master,
        slave,
        now: 0,
        seq: 0,
        reasons: 0,
        ack: false,
    };
    for _ in 0..200 {
        r.cycle(Some(-250.0));
    }
    // Wrong arm and wrong version: rejected by the gate.
    let mut wrong_arm = command(1000, r.now, -240.0);
    wrong_arm.arm_id = 7;
    r.master.publish(&wrong_arm).unwrap();
    let mut wrong_version = command(1001, r.now, -240.0);
    wrong_version.protocol_version = PROTOCOL_VERSION + 1;
    r.master.publish(&wrong_version).unwrap();
    let c = r.cycle(None);
    assert!(!c.fresh);
    assert_eq!(r.ep.gate_counters().rejected(), 2);
    // Outside the workspace: the gate rejects it as out of range (issue 14: before
    // anything acts on it), and the feedback reports the reason.
    let c = r.cycle(Some(-2000.0));
    assert!(!c.fresh, "{c:?}");
    assert_eq!(r.ep.gate_counters().out_of_range, 1);
    assert_eq!(r.ep.gate_counters().rejected(), 3);
    assert!((c.out.commanded_pose[2] + 250.0).abs() < 0.5);
    use h4_shared::wire::RejectReason;
    assert_eq!(
        r.reasons,
        RejectReason::WrongArm.bit()
            | RejectReason::WrongVersion.bit()
            | RejectReason::OutOfRange.bit()
    );
}

/// The simulated arm whose driver can stop answering: frozen, it repeats its last reading
/// (its time no longer moves on).
struct FreezingArm {
    arm: SimArm,
    frozen: bool,
    last: Option<ArmReading>,
}

impl ArmDriver for FreezingArm {
    fn read(&mut self) -> ArmReading {
        match (self.frozen, self.last) {
            (true, Some(r)) => r,
            _ => {
                let r = self.arm.read();
                self.last = Some(r);
                r
            }
        }
    }
    fn command(&mut self, actuators_mm: &[f64; 4]) {
        self.arm.command(actuators_mm);
    }
    fn advance(&mut self, dt_ns: u64) {
        self.arm.advance(dt_ns);
    }
}

/// A driver that stops answering (no fresh reading for 2 cycles) puts the slave in its safe
/// stop at its second stale cycle, counted; the master cannot clear it while the driver
/// stays silent, and can once it answers again. Control: the same run without the freeze
/// never stops.
#[test]
fn a_silent_driver_safe_stops_until_it_answers_again() {
    let run = |freeze: bool| {
        let (p, ctrl, arm) = parts(true);
        let arm = FreezingArm {
            arm,
            frozen: false,
            last: None,
        };
        let mut ep = SlaveTeleop::new(p, ctrl, arm, PERIOD_NS).unwrap();
        let (mut master, mut slave) = inproc::pair(64);
        let (mut now, mut seq) = (0, 0);
        let mut states = Vec::new();
        for k in 0..1200 {
            ep.arm_mut().frozen = freeze && (300..600).contains(&k);
            seq += 1;
            let mut c = command(seq, now, -251.0);
            if k >= 400 {
                // The master acknowledges the safe stop from here on.
                c.flags |= CMD_FLAG_ACK_SAFE_STOP;
                c.energy_in_j = 1e-4;
            }
            master.publish(&c).unwrap();
            let out = ep.step(&mut slave, now, 1e-3);
            while master.try_recv().unwrap().is_some() {}
            ep.arm_mut().advance(PERIOD_NS);
            now += PERIOD_NS;
            states.push(out.state);
        }
        (states, *ep.counters())
    };
    let (states, k) = run(false);
    assert!(states[10..].iter().all(|s| *s == SlaveState::Active));
    assert_eq!((k.safe_stops, k.driver_stale_stops), (0, 0));

    let (states, k) = run(true);
    assert_eq!(
        states[300],
        SlaveState::Active,
        "the first repeated reading is one cycle old"
    );
    assert_eq!(
        states[301],
        SlaveState::SafeStop,
        "the second trips the safe stop"
    );
    assert!(
        states[301..600].iter().all(|s| *s == SlaveState::SafeStop),
        "acks refused while silent"
    );
    assert_eq!(
        states[1199],
        SlaveState::Active,
        "re-paired once the driver answers"
    );
    assert_eq!((k.safe_stops, k.driver_stale_stops, k.repairs), (1, 1, 1));
}
