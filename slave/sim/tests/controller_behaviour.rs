//! The controller's modes with the simulated arm in the loop: position mode follows within
//! its limits and rejects poses outside the workspace (the actuators hold); a lost contact
//! is detected and re-approached without a jump; a safe stop ramps the force to zero,
//! retracts along the normal and holds.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::Pose;
use h4_shared::config;
use h4_shared::wire::Mode;
use h4_slave::controller::{
    ControllerInput, ControllerOutput, Rejection, SlaveCommand, SlaveController, Status,
};
use h4_slave_sim::experiment::ExperimentConfig;
use h4_slave_sim::plant::{ArmDriver, SimArm, Surface, SurfaceShape};

struct Rig {
    arm: SimArm,
    ctrl: SlaveController,
    cfg: ExperimentConfig,
}

impl Rig {
    /// The rig on fig7b's realistic sensor and plant, plus `extra`.
    fn new(extra: &[&str]) -> Rig {
        Rig::seeded(extra, 3)
    }

    /// The rig with the sensor noise drawn from `seed`.
    fn seeded(extra: &[&str], seed: u64) -> Rig {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/experiments/fig7b.toml"
        );
        let overrides: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        let cfg: ExperimentConfig = config::load(std::path::Path::new(path), &overrides).unwrap();
        let p = cfg.surface.contact_point_mm;
        let (arm, ctrl) = cfg
            .world()
            .build(Pose::new(p[0], p[1], p[2] + 2.0, 0.0), seed)
            .unwrap();
        Rig { arm, ctrl, cfg }
    }

    fn step(&mut self, command: SlaveCommand) -> ControllerOutput {
        let r = self.arm.read();
        let out = self.ctrl.step(
            &ControllerInput {
                actuators_mm: r.actuators_mm,
                wrench: r.wrench,
                command,
            },
            1e-3,
        );
        self.arm.command(&out.actuators_cmd_mm);
        self.arm.advance(1_000_000);
        out
    }

    fn press(&self, force_n: f64, speed: f64) -> SlaveCommand {
        let p = self.cfg.surface.contact_point_mm;
        SlaveCommand {
            mode: Mode::ForceGuided,
            pose: [p[0], p[1], p[2] - 20.0, 0.0],
            velocity: [speed, 0.0, 0.0, 0.0],
            force_setpoint_n: force_n,
            clutch: false,
        }
    }

    fn true_normal_force(&self) -> f64 {
        let w = self.arm.true_contact_wrench();
        w[2]
    }
}

fn dist(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn position_mode_follows_within_limits_and_rejects_outside_the_workspace() {
    let mut rig = Rig::new(&["surface.contact_point_mm=[-30.0, 0.0, -340.0]"]);
    let max_speed = rig.cfg.controller.max_speed_mm_per_s;
    let target = [10.0, 20.0, -240.0, 0.1];
    let cmd = SlaveCommand {
        mode: Mode::Position,
        pose: target,
        ..SlaveCommand::default()
    };
    let mut prev: Option<[f64; 4]> = None;
    let mut last = None;
    for _ in 0..3000 {
        let out = rig.step(cmd);
        if let Some(p) = prev {
            assert!(dist(&p, &out.commanded_pose) <= max_speed * 1e-3 + 1e-9);
        }
        prev = Some(out.commanded_pose);
        last = Some(out);
    }
    let out = last.unwrap();
    assert_eq!(out.status, Status::Free);
    assert!(
        dist(&out.commanded_pose, &target) < 1e-3,
        "{:?}",
        out.commanded_pose
    );
    let pose = rig.arm.true_pose();
    assert!(
        (pose[0] - 10.0).abs() < 0.05 && (pose[2] + 240.0).abs() < 0.05,
        "{pose:?}"
    );

    // Out of reach (z above the singular line): rejected with a reason, actuators hold.
    let held = out.actuators_cmd_mm;
    let bad = SlaveCommand {
        pose: [0.0, 0.0, 50.0, 0.0],
        ..cmd
    };
    let out = rig.step(bad);
    assert_eq!(out.status, Status::Rejected);
    assert!(
        matches!(out.rejection, Some(Rejection::Workspace(_))),
        "{:?}",
        out.rejection
    );
    assert_eq!(out.actuators_cmd_mm, held);
    let out = rig.step(SlaveCommand {
        velocity: [f64::NAN, 0.0, 0.0, 0.0],
        ..cmd
    });
    assert_eq!(out.rejection, Some(Rejection::NonFiniteInput));
    assert_eq!(out.actuators_cmd_mm, held);
    let out = rig.step(SlaveCommand {
        mode: Mode::ForceGuided,
        force_setpoint_n: 1e4,
        ..cmd
    });
    assert!(matches!(
        out.rejection,
        Some(Rejection::SetpointOutOfRange { .. })
    ));
    assert_eq!(out.actuators_cmd_mm, held);
}

#[test]
fn lost_contact_is_reapproached_without_a_jump() {
    // The ideal sensor (no payload on it, no weight, no latency); the realistic one:
    // `recontact_after_a_drop_keeps_the_first_touch_targets_with_a_real_sensor`.
    let mut rig = Rig::new(&[
        "plant.payload_mass_kg=0",
        "plant.gravity_mm_per_s2=[0,0,0]",
        "plant.command_latency_s=0",
        "controller.command_latency_cycles=0",
        "sensor.bias_drift_n_per_sqrt_s=0",
        "controller.gravity_compensation=false",
    ]);
    let max_speed = rig.cfg.controller.max_speed_mm_per_s;
    for _ in 0..2500 {
        rig.step(rig.press(20.0, 3.5));
    }
    assert!((rig.true_normal_force() - 20.0).abs() < 1.0);
    // The surface drops by 3 mm under the tool (a step in the part).
    drop_surface(&mut rig, 3.0);
    let mut saw_lost = false;
    let mut regained_at = None;
    let mut prev: Option<[f64; 4]> = None;
    let mut peak: f64 = 0.0;
    for k in 0..4000 {
        let out = rig.step(rig.press(20.0, 3.5));
        if let Some(p) = prev {
            assert!(
                dist(&p, &out.commanded_pose) <= max_speed * 1e-3 + 1e-9,
                "jump at {k}"
            );
        }
        prev = Some(out.commanded_pose);
        saw_lost |= out.status == Status::ContactLost;
        if saw_lost && regained_at.is_none() && out.status == Status::Contact {
            regained_at = Some(k);
        }
        if regained_at.is_some() {
            peak = peak.max(rig.true_normal_force());
        }
    }
    assert!(saw_lost, "contact loss not detected");
    let k = regained_at.expect("contact not regained");
    assert!(k < 3000, "re-approach took {k} ms");
    assert!(peak < 20.0 * 1.1, "re-contact peak {peak} N");
    assert!(
        (rig.true_normal_force() - 20.0).abs() < 1.0,
        "{}",
        rig.true_normal_force()
    );
}

/// What a re-contact after a drop of the surface did: the peak true force once the
/// controller touched again, when it settled within the first touch's band (ms after the
/// re-touch, `None` if not within the run), the final true force.
#[derive(Debug)]
struct Recontact {
    peak_n: f64,
    settled_ms: Option<usize>,
    final_n: f64,
}

/// Drops the rig's plane surface by `mm` under the tool (a step in the part).
fn drop_surface(rig: &mut Rig, mm: f64) {
    let Surface { shape, material } = *rig.arm.surface();
    let SurfaceShape::Plane { point_mm, normal } = shape else {
        panic!("plane expected")
    };
    rig.arm.set_surface(Surface {
        shape: SurfaceShape::Plane {
            point_mm: [point_mm[0], point_mm[1], point_mm[2] - mm],
            normal,
        },
        material,
    });
}

/// Presses `setpoint_n` on fig7b's steel with `extra`, drops the surface by 3 mm under the
/// tool, and follows the loss, the re-approach and the re-contact.
fn recontact_after_a_drop(extra: &[&str], seed: u64, setpoint_n: f64) -> Recontact {
    let mut rig = Rig::seeded(extra, seed);
    for _ in 0..2500 {
        rig.step(rig.press(setpoint_n, 3.5));
    }
    drop_surface(&mut rig, 3.0);
    let band = (0.05 * setpoint_n).max(0.5);
    let mut saw_lost = false;
    let mut regained_at = None;
    let mut last_outside: usize = 0;
    let mut peak: f64 = 0.0;
    let mut k_end = 0;
    for k in 0..4000 {
        let out = rig.step(rig.press(setpoint_n, 3.5));
        saw_lost |= out.status == Status::ContactLost;
        let touching = matches!(out.status, Status::Contact | Status::ForceLimited);
        if saw_lost && regained_at.is_none() && touching {
            regained_at = Some(k);
        }
        if regained_at.is_some() {
            let f = rig.true_normal_force();
            peak = peak.max(f);
            if (f - setpoint_n).abs() > band {
                last_outside = k;
            }
        }
        k_end = k;
    }
    assert!(saw_lost, "contact loss not detected");
    let k0 = regained_at.expect("contact not regained");
    Recontact {
        peak_n: peak,
        settled_ms: (last_outside + 500 < k_end).then(|| last_outside.saturating_sub(k0)),
        final_n: rig.true_normal_force(),
    }
}

/// Re-contact after a 3 mm drop on steel with the realistic sensor (payload on the sensor,
/// one period of latency, bias drift) at 0.1 and 0.3 N σ, the plant's stiffness ×0.7 and
/// ×1.3, four seeds: the re-contact keeps the first touch's targets (overshoot ≤ 5 %,
/// settling ≤ 150 ms, measured on the true force; before the fix 10–20 % and 180–690 ms:
/// the payload ringing after the drop cut the loop gains and dragged the stiffness
/// estimate, and both carried over to the re-contact). Control: the same measurement
/// catches a controller whose compliance is wrong (estimator off, steel taken for
/// 50 N/mm), whose re-contact overshoots far.
#[test]
fn recontact_after_a_drop_keeps_the_first_touch_targets_with_a_real_sensor() {
    let mut all = Vec::new();
    let mut worst = (0.0f64, 0usize);
    for noise in ["0.1", "0.3"] {
        for scale in ["0.7", "1.3"] {
            for seed in 1..=4 {
                let n = format!("sensor.noise_std_n={noise}");
                let s = format!("plant.stiffness_scale={scale}");
                let r = recontact_after_a_drop(&[&n, &s], seed, 20.0);
                let over_pct = 100.0 * (r.peak_n - 20.0).max(0.0) / 20.0;
                let settled = r.settled_ms.unwrap_or(usize::MAX);
                worst = (worst.0.max(over_pct), worst.1.max(settled));
                if over_pct > 5.0 || settled > 150 || (r.final_n - 20.0).abs() > 1.0 {
                    all.push(format!("σ {noise} ×{scale} seed {seed}: {r:?}"));
                }
            }
        }
    }
    eprintln!(
        "re-contact: worst overshoot {:.1} %, settling {} ms",
        worst.0, worst.1
    );
    assert!(all.is_empty(), "{}", all.join("\n"));
    let wrong = recontact_after_a_drop(
        &[
            "plant.stiffness_scale=1.3",
            "controller.estimate_env_stiffness=false",
            "controller.initial_env_stiffness_n_per_mm=50",
        ],
        1,
        20.0,
    );
    assert!(wrong.peak_n > 1.25 * 20.0, "control: {wrong:?}");
}

#[test]
fn safe_stop_ramps_force_down_retracts_and_holds() {
    let mut rig = Rig::new(&[]);
    for _ in 0..2000 {
        rig.step(rig.press(30.0, 0.0));
    }
    assert!((rig.true_normal_force() - 30.0).abs() < 1.0);
    rig.ctrl.safe_stop();
    assert!(rig.ctrl.is_safe_stopped());
    let mut prev_force = rig.true_normal_force();
    let mut rising = 0;
    for _ in 0..150 {
        let out = rig.step(rig.press(30.0, 5.0));
        assert_eq!(out.status, Status::SafeStop);
        let f = rig.true_normal_force();
        if f > prev_force + 0.5 {
            rising += 1;
        }
        prev_force = f;
    }
    assert_eq!(rising, 0, "force must not rise during the ramp");
    for _ in 0..3000 {
        rig.step(rig.press(30.0, 5.0));
    }
    assert_eq!(rig.true_normal_force(), 0.0);
    let gap = -rig.arm.penetration_mm();
    let retract = rig.cfg.controller.safe_stop_retract_mm;
    assert!(gap > 0.5 * retract && gap < retract + 0.5, "gap {gap} mm");
    let before = rig.arm.true_pose();
    let out = rig.step(rig.press(30.0, 5.0));
    assert_eq!(out.status, Status::Holding);
    for _ in 0..500 {
        rig.step(rig.press(30.0, 5.0));
    }
    let after = rig.arm.true_pose();
    assert!((after - before).norm() < 1e-3, "moved while holding");
}

/// Once safe-stopped (retracted, holding), the arm still keeps its force limit: a surface
/// that advances into the held tool (a workpiece on a moving fixture, 2 mm/s for 4 s) is
/// backed away from at the limit. Control: with the limit moved out of the way the same
/// advance presses far past it (the guard is what holds it).
#[test]
fn a_safe_stopped_arm_backs_away_from_a_surface_that_advances_into_it() {
    let peak_for = |extra: &[&str]| {
        let mut rig = Rig::new(extra);
        for _ in 0..2000 {
            rig.step(rig.press(30.0, 0.0));
        }
        rig.ctrl.safe_stop();
        for _ in 0..4000 {
            rig.step(rig.press(30.0, 0.0));
        }
        assert_eq!(rig.true_normal_force(), 0.0, "not retracted");
        let mut surface = *rig.arm.surface();
        let mut peak: f64 = 0.0;
        for _ in 0..4000 {
            if let SurfaceShape::Plane { point_mm, normal } = &mut surface.shape {
                for (p, n) in point_mm.iter_mut().zip(normal.iter()) {
                    *p += n * 2.0e-3;
                }
            }
            rig.arm.set_surface(surface);
            let out = rig.step(rig.press(30.0, 0.0));
            assert!(matches!(out.status, Status::SafeStop | Status::Holding));
            peak = peak.max(rig.true_normal_force());
        }
        peak
    };
    let limit = 80.0;
    let guarded = peak_for(&[]);
    println!("a surface advancing into the safe-stopped arm: {guarded:.2} N against {limit} N");
    assert!(
        guarded <= 1.05 * limit,
        "{guarded} N against a {limit} N limit"
    );
    assert!(
        guarded > 0.5 * limit,
        "the surface never reached the tool: {guarded} N"
    );
    let unguarded = peak_for(&["controller.force_limit_n=1000"]);
    assert!(unguarded > 2.0 * limit, "control: {unguarded} N");
}

/// A position-mode push into a surface (teleoperation, position–force coupling) is not in
/// force control: a safe stop must still release the force, back away and hold, not hold the
/// arm pressed into the surface.
#[test]
fn safe_stop_out_of_a_position_mode_push_releases_the_force() {
    let mut rig = Rig::new(&["surface.stiffness_n_per_mm=20"]);
    let p = rig.cfg.surface.contact_point_mm;
    let push = SlaveCommand {
        mode: Mode::Position,
        pose: [p[0], p[1], p[2] - 1.5, 0.0],
        velocity: [0.0; 4],
        force_setpoint_n: 0.0,
        clutch: false,
    };
    for _ in 0..3000 {
        rig.step(push);
    }
    let pressed = rig.true_normal_force();
    assert!(pressed > 5.0, "the push should press: {pressed} N");
    rig.ctrl.safe_stop();
    let mut peak: f64 = pressed;
    for _ in 0..3000 {
        let out = rig.step(push);
        assert!(matches!(out.status, Status::SafeStop | Status::Holding));
        peak = peak.max(rig.true_normal_force());
    }
    assert!(
        peak < pressed + 1.0,
        "force rose to {peak} N during the release"
    );
    assert_eq!(rig.true_normal_force(), 0.0, "still pressing");
    let gap = -rig.arm.penetration_mm();
    let retract = rig.cfg.controller.safe_stop_retract_mm;
    assert!(gap > 0.5 * retract, "gap {gap} mm");
    let before = rig.arm.true_pose();
    for _ in 0..500 {
        assert_eq!(rig.step(push).status, Status::Holding);
    }
    assert!(
        (rig.arm.true_pose() - before).norm() < 1e-3,
        "moved while holding"
    );
}

/// Position mode runs no force law, yet the force limit holds: a position command far into a
/// steel surface (a teleoperated push) stops at the limit on the true force. With the limit
/// moved out of the way, the same push goes far past it (the guard is what holds it).
#[test]
fn position_mode_push_into_steel_keeps_the_force_limit() {
    let peak_for = |extra: &[&str]| {
        let mut rig = Rig::new(extra);
        let p = rig.cfg.surface.contact_point_mm;
        let push = SlaveCommand {
            mode: Mode::Position,
            pose: [p[0], p[1], p[2] - 5.0, 0.0],
            velocity: [0.0; 4],
            force_setpoint_n: 0.0,
            clutch: false,
        };
        let mut peak: f64 = 0.0;
        for _ in 0..3000 {
            rig.step(push);
            peak = peak.max(rig.true_normal_force());
        }
        (peak, rig.cfg.controller.force_limit_n)
    };
    let (peak, limit) = peak_for(&[]);
    assert!(peak > 0.5 * limit, "the push should press hard: {peak} N");
    assert!(
        peak <= limit,
        "true force {peak} N over the {limit} N limit"
    );
    let (unguarded, _) = peak_for(&["controller.force_limit_n=1000"]);
    assert!(
        unguarded > 1.5 * limit,
        "without the limit the push reaches {unguarded} N"
    );
}
