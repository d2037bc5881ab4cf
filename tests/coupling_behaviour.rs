//! The coupling's features end to end, through the whole-session simulation (operator,
//! master arm, link, slave teleop endpoint and plant, on the simulated clock): clutch and
//! indexing, motion scaling, force scaling, force saturation, workspace mapping, and the
//! force-guided (cutting) mode's set-point and guidance.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::operator::IntentSegment;
use h4_master_sim::session::{self, Session, SessionConfig, SimMasterCycle};
use h4_shared::kinematics::Pose;
use h4_slave::teleop::TeleopCycle;

fn load(name: &str, overrides: &[&str]) -> SessionConfig {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    session::load(&dir.join(name), &o).unwrap()
}

/// [`load`] with `--unsafe-test-override`: a negative control that turns a safety layer off.
fn load_unsafe(name: &str, overrides: &[&str]) -> SessionConfig {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    session::load_with(&dir.join(name), &o, true).unwrap()
}

fn seg(
    at_s: f64,
    target_mm: [f64; 3],
    move_s: f64,
    push_n: [f64; 3],
    clutch: bool,
) -> IntentSegment {
    IntentSegment {
        at_s,
        target_mm,
        move_s,
        push_n,
        push_ramp_s: 0.3,
        clutch,
        theta_rad: 0.0,
    }
}

/// What the tests read of one cycle.
#[derive(Clone, Copy, Debug)]
struct Rec {
    t_s: f64,
    handle_mm: [f64; 3],
    hand_n: [f64; 3],
    rendered_n: [f64; 3],
    saturated: bool,
    workspace_limited: bool,
    clutch: bool,
    slave_target_mm: [f64; 4],
    setpoint_n: f64,
    slave_measured_mm: [f64; 3],
    slave_force_n: [f64; 3],
    true_force_n: [f64; 3],
    /// A feedback message was accepted this cycle.
    fresh: bool,
}

fn run(cfg: &SessionConfig) -> Vec<Rec> {
    let mut s = Session::new(cfg).unwrap();
    let n = (cfg.duration_s * 1000.0).round() as usize;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let (m, t): (SimMasterCycle, TeleopCycle) = s.cycle().unwrap();
        let w = s.slave.arm().true_contact_wrench();
        out.push(Rec {
            t_s: (k + 1) as f64 * 1e-3,
            handle_mm: [m.handle.pose[0], m.handle.pose[1], m.handle.pose[2]],
            hand_n: [m.hand.wrench[0], m.hand.wrench[1], m.hand.wrench[2]],
            rendered_n: [
                m.rendered_wrench[0],
                m.rendered_wrench[1],
                m.rendered_wrench[2],
            ],
            saturated: m.step.saturated,
            workspace_limited: m.step.workspace_limited,
            clutch: m.handle.clutch,
            slave_target_mm: m.step.slave_target,
            setpoint_n: m.step.setpoint_n,
            slave_measured_mm: [
                t.out.measured_pose[0],
                t.out.measured_pose[1],
                t.out.measured_pose[2],
            ],
            slave_force_n: [
                t.out.wrench_measured[0],
                t.out.wrench_measured[1],
                t.out.wrench_measured[2],
            ],
            true_force_n: [w[0], w[1], w[2]],
            fresh: m.fresh,
        });
    }
    out
}

fn at(r: &[Rec], t_s: f64) -> Rec {
    r[((t_s * 1000.0).round() as usize).saturating_sub(1)]
}

fn window(r: &[Rec], from_s: f64, to_s: f64) -> &[Rec] {
    &r[(from_s * 1000.0) as usize..(to_s * 1000.0) as usize]
}

fn mean(r: &[Rec], f: impl Fn(&Rec) -> f64) -> f64 {
    r.iter().map(f).sum::<f64>() / r.len() as f64
}

/// The largest cycle-to-cycle change of the slave target, mm.
fn largest_target_step_mm(r: &[Rec]) -> f64 {
    r.windows(2)
        .map(|w| {
            (0..3)
                .map(|i| (w[1].slave_target_mm[i] - w[0].slave_target_mm[i]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// Free space (the wall 40 mm below), two 6 mm strokes down with the clutch held on the
/// way back up between them.
fn indexing(scale: f64, delay_ms: f64) -> Vec<Rec> {
    let mut cfg = load(
        "wall-push.toml",
        &[
            "duration_s=9",
            "environment.gap_mm=40",
            &format!("scale.motion={scale}"),
            &format!("link.delay_ms={delay_ms}"),
        ],
    );
    cfg.operator.intent = vec![
        seg(0.0, [0.0; 3], 0.5, [0.0; 3], false),
        seg(0.5, [0.0, 0.0, -6.0], 0.8, [0.0; 3], false),
        seg(3.0, [0.0, 0.0, -6.0], 0.1, [0.0; 3], true),
        seg(3.2, [0.0, 0.0, 0.0], 0.8, [0.0; 3], true),
        seg(5.5, [0.0, 0.0, 0.0], 0.1, [0.0; 3], false),
        seg(5.7, [0.0, 0.0, -6.0], 0.8, [0.0; 3], false),
    ];
    run(&cfg)
}

/// The cycles where the clutch goes down and comes up again.
fn clutch_edges(r: &[Rec]) -> (usize, usize) {
    let down = r.iter().position(|x| x.clutch).expect("clutch pressed");
    let up = down
        + r[down..]
            .iter()
            .position(|x| !x.clutch)
            .expect("clutch released");
    (down, up)
}

#[test]
fn clutch_holds_the_slave_and_reanchors_without_a_jump() {
    for delay_ms in [0.0, 25.0] {
        let r = indexing(1.0, delay_ms);
        let (down, up) = clutch_edges(&r);
        // While clutched the handle goes back up and the slave target does not move.
        let held = &r[down..up];
        let handle_up = held.last().unwrap().handle_mm[2] - held[0].handle_mm[2];
        assert!(handle_up > 1.0, "{handle_up}");
        let z0 = held[0].slave_target_mm[2];
        let moved = held
            .iter()
            .map(|x| (x.slave_target_mm[2] - z0).abs())
            .fold(0.0, f64::max);
        assert!(moved < 1e-9, "slave target moved {moved} mm while clutched");
        // No jump anywhere, the release included: at most what the handle's speed gives
        // in a cycle.
        let step = largest_target_step_mm(&r);
        assert!(step < 0.05, "largest slave target step {step} mm");
        // Indexing: the two strokes of the handle's actual travel add up at the slave.
        let end = *r.last().unwrap();
        let travel = (r[down - 1].handle_mm[2] - r[0].handle_mm[2])
            + (end.handle_mm[2] - r[up - 1].handle_mm[2]);
        let slave = end.slave_target_mm[2] - r[0].slave_target_mm[2];
        assert!(
            (slave - travel).abs() < 0.02,
            "delay {delay_ms}: slave {slave} mm, handle strokes {travel} mm"
        );
        // Indexing gained range: the slave went further than the handle's net travel.
        let net = end.handle_mm[2] - r[0].handle_mm[2];
        assert!(slave < net - 1.0, "slave {slave} mm, handle net {net} mm");
        // And the slave arm got there (free space: position tracking).
        let err = end.slave_measured_mm[2] - end.slave_target_mm[2];
        assert!(err.abs() < 0.1, "delay {delay_ms}: tracking error {err} mm");
    }
}

#[test]
fn motion_scale_scales_the_slave_motion() {
    for scale in [0.5, 2.0] {
        let r = indexing(scale, 0.0);
        let (down, _) = clutch_edges(&r);
        let travel = r[down - 1].handle_mm[2] - r[0].handle_mm[2];
        let slave = r[down - 1].slave_target_mm[2] - r[0].slave_target_mm[2];
        assert!(travel < -3.0, "{travel}");
        assert!(
            (slave - scale * travel).abs() < 0.01,
            "scale {scale}: slave {slave} mm for {travel} mm of handle"
        );
    }
}

/// The wall push with 0 delay: the mean of `f` over the second push's hold.
fn hold_mean(r: &[Rec], f: impl Fn(&Rec) -> f64) -> f64 {
    mean(window(r, 10.0, 12.8), f)
}

/// At `scale.force` 0.25 and 0.5 (the shipped sessions' value). Above 0.5, where the learnt
/// stiffness times the scale exceeds the model's stiffness cap, the slave can press harder
/// than the operator feels (docs/sessions.md, "Known limits").
#[test]
fn force_scale_scales_the_force_the_operator_feels() {
    for scale in [0.25, 0.5] {
        let cfg = load(
            "wall-push.toml",
            &[&format!("scale.force={scale}"), "coupling.force_limit_n=30"],
        );
        let r = run(&cfg);
        let slave = hold_mean(&r, |x| x.slave_force_n[2]);
        let truth = hold_mean(&r, |x| x.true_force_n[2]);
        assert!(
            (truth - slave).abs() < 0.05 * slave,
            "sensor {slave} N, true {truth} N"
        );
        let rendered = hold_mean(&r, |x| x.rendered_n[2]);
        let hand = hold_mean(&r, |x| x.hand_n[2]);
        println!(
            "scale {scale}: slave {slave:.2} true {truth:.2} rendered {rendered:.2} hand {hand:.2}"
        );
        // What the operator feels is the slave's force times the scale ...
        assert!(
            (rendered - scale * slave).abs() < 0.1 * (scale * slave).abs(),
            "scale {scale}: rendered {rendered} N, slave {slave} N"
        );
        // ... and it balances the hand's push at rest, so the slave presses with the push
        // divided by the scale.
        assert!(
            (rendered + hand).abs() < 0.05 * hand.abs(),
            "scale {scale}: rendered {rendered} N, hand {hand} N"
        );
    }
}

#[test]
fn rendered_force_saturates_at_the_limit() {
    let cfg = load("wall-push.toml", &["coupling.force_limit_n=4"]);
    let r = run(&cfg);
    let largest = r
        .iter()
        .map(|x| x.rendered_n.iter().map(|v| v * v).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    assert!(largest <= 4.0 + 1e-9, "{largest}");
    assert!(r.iter().any(|x| x.saturated));
    // Unsaturated the same push renders more than the limit.
    let free = run(&load("wall-push.toml", &[]));
    let largest_free = free
        .iter()
        .map(|x| x.rendered_n.iter().map(|v| v * v).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    assert!(largest_free > 5.0, "{largest_free}");
    assert!(!free.iter().any(|x| x.saturated));
}

#[test]
fn targets_outside_the_workspace_are_pulled_back_inside() {
    // Motion scale 8: a 40 mm move of the handle along y asks for 320 mm at the slave.
    let mut cfg = load(
        "wall-push.toml",
        &["duration_s=4", "environment.gap_mm=40", "scale.motion=8"],
    );
    cfg.operator.intent = vec![
        seg(0.0, [0.0; 3], 0.5, [0.0; 3], false),
        seg(0.5, [0.0, 40.0, 0.0], 2.0, [0.0; 3], false),
    ];
    let ws = cfg.slave.arm.workspace();
    let r = run(&cfg);
    assert!(r.iter().any(|x| x.workspace_limited));
    for x in &r {
        let p = Pose::from(x.slave_target_mm);
        assert!(
            ws.ik(&p).is_ok(),
            "target outside the workspace at {} s: {p:?}",
            x.t_s
        );
    }
    let step = largest_target_step_mm(&r);
    assert!(step < 1.0, "largest slave target step {step} mm");
    // The slave went as far as it can, not nowhere.
    let reach = at(&r, 4.0).slave_target_mm[1] - r[0].slave_target_mm[1];
    let asked = 8.0 * (at(&r, 4.0).handle_mm[1] - r[0].handle_mm[1]);
    assert!(reach > 100.0 && reach < asked - 50.0, "{reach} of {asked}");
    let s = session::run(&cfg, None).unwrap();
    assert_eq!(s.slave_rejected_cycles, 0);
}

#[test]
fn force_guided_slave_holds_the_set_point_the_operator_pushes() {
    let cfg = load("cutting-guided.toml", &[]);
    let r = run(&cfg);
    let x0_slave = r[0].slave_measured_mm[0];
    let x0_handle = r[0].handle_mm[0];
    let mut sets = Vec::new();
    // Windows of steady pushing: before the cut, along it, pushed harder, on the way back.
    for (from, to) in [(2.0, 3.0), (4.0, 7.0), (8.0, 8.5), (9.0, 11.0)] {
        let w = window(&r, from, to);
        let set = mean(w, |x| x.setpoint_n);
        // The slave's implicit force loop holds the set-point the operator's push into the
        // guide spring sets (its contact force, measured and true, pushes up: +z).
        let force = mean(w, |x| x.slave_force_n[2]);
        let truth = mean(w, |x| x.true_force_n[2]);
        assert!(set > 3.0, "{from}-{to} s: set-point {set} N");
        assert!(
            (force - set).abs() < 0.05 * set && (truth - set).abs() < 0.05 * set,
            "{from}-{to} s: set-point {set} N, slave measures {force} N, true {truth} N"
        );
        // What the hand feels is the guide spring: set-point × scale.force.
        let felt = mean(w, |x| x.rendered_n[2]);
        assert!(
            (felt - set * cfg.scale.force).abs() < 0.05 * set * cfg.scale.force,
            "{from}-{to} s: felt {felt} N for a set-point of {set} N"
        );
        sets.push(set);
    }
    // Pushing harder raised the set-point.
    assert!(sets[2] > sets[1] + 2.0, "{sets:?}");
    // Guidance: the slave moved along the surface the way the handle did, out 20 mm and
    // back to 5 mm (it follows with a lag: docs/sessions.md).
    let x = |t: f64| {
        (
            at(&r, t).slave_measured_mm[0] - x0_slave,
            at(&r, t).handle_mm[0] - x0_handle,
        )
    };
    let (out_slave, out_handle) = x(8.5);
    let (back_slave, back_handle) = x(11.2);
    assert!(
        out_handle > 15.0 && back_handle < out_handle - 10.0,
        "{out_handle} {back_handle}"
    );
    assert!(
        out_slave > 0.7 * out_handle,
        "out: slave {out_slave} mm, handle {out_handle} mm"
    );
    assert!(
        back_slave < out_slave - 0.5 * (out_handle - back_handle),
        "back: slave {back_slave} mm from {out_slave} mm, handle {back_handle} from {out_handle}"
    );
    // In contact all along the cut.
    assert!(
        window(&r, 2.0, 11.0)
            .iter()
            .all(|x| x.true_force_n[2] > 2.0)
    );
}

/// A session driven by a recorded master trajectory from a file (JSON lines): the handle
/// follows it, and a bad line is named by its number.
#[test]
fn replayed_trajectory_from_a_file_drives_the_session() {
    let dir = std::env::temp_dir().join(format!("h4-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("trajectory.jsonl");
    // Down 5 mm over 1 s and hold, in free space (wall 40 mm below).
    let mut text = String::new();
    for k in 0..=40 {
        let t = k as f64 * 0.1;
        let z = -5.0 * (t.min(1.0));
        text.push_str(&format!(
            "{{\"t_s\": {t}, \"position_mm\": [0.0, 0.0, {z}]}}\n"
        ));
    }
    std::fs::write(&path, &text).unwrap();
    let mut cfg = load("wall-push.toml", &["duration_s=4", "environment.gap_mm=40"]);
    cfg.operator.replay_file = Some(path.clone());
    let r = run(&cfg);
    let moved = at(&r, 4.0).handle_mm[2] - r[0].handle_mm[2];
    // (The hand's 0.4 N/mm arm against the handle's Coulomb friction leaves up to ≈ 1.5 mm.)
    assert!(
        moved < -3.0 && moved > -5.5,
        "handle moved {moved} mm of -5"
    );
    let slave = at(&r, 4.0).slave_target_mm[2] - r[0].slave_target_mm[2];
    assert!((slave - moved).abs() < 0.02, "{slave} {moved}");
    // A malformed line: the error names the file and the line.
    std::fs::write(
        &path,
        format!("{text}{{\"t_s\": 5.0, \"position\": [0, 0, 0]}}\n"),
    )
    .unwrap();
    let err = match Session::new(&cfg) {
        Ok(_) => panic!("bad replay file accepted"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains("trajectory.jsonl") && err.contains("42"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 12: the true force never exceeds the slave's limit at any approach speed the master
/// can command. The operator of `wall-push.toml` throws the handle 10 mm down (7 mm past the
/// wall) in 0.8 s down to 20 ms (the hand's own dynamics then set the speed), onto resin,
/// aluminium and steel, at 0, 50 and 500 ms round trip: the true contact force stays below
/// the slave controller's limit, and below 40 N (half of it) in every case measured
/// (2026-12-02: 27 N at most, at 500 ms).
#[test]
fn first_touch_stays_below_the_limit_at_any_approach_speed() {
    let mut worst = (0.0, String::new());
    for move_s in [0.8, 0.2, 0.05, 0.02] {
        for k in ["200", "1000", "2000"] {
            for delay in ["0", "25", "250"] {
                let stiffness = format!("environment.stiffness_n_per_mm={k}");
                let d = format!("link.delay_ms={delay}");
                let mut cfg = load("wall-push.toml", &[stiffness.as_str(), d.as_str()]);
                let push = cfg.operator.intent[1];
                assert_eq!(push.at_s, 0.5, "wall-push.toml's approach segment moved");
                cfg.operator.intent[1] = IntentSegment {
                    target_mm: [0.0, 0.0, -10.0],
                    move_s,
                    ..push
                };
                let limit = cfg.slave.controller.force_limit_n;
                let s = session::run(&cfg, None).unwrap();
                let label = format!("move_s {move_s} s, {k} N/mm, one-way {delay} ms");
                assert!(
                    s.max_force_n <= limit && s.max_force_n <= 0.5 * limit,
                    "{label}: true force {:.1} N (limit {limit} N)",
                    s.max_force_n
                );
                if s.max_force_n > worst.0 {
                    worst = (s.max_force_n, label);
                }
            }
        }
    }
    println!("worst first touch: {:.1} N ({})", worst.0, worst.1);
    // Control: without the contact hand-over and the passivity layer the same throw onto
    // steel passes the bound (measured 80-95 N): the bound can fail, and what keeps the
    // force down is those layers, not the throw being gentle.
    for delay in ["0", "25"] {
        let d = format!("link.delay_ms={delay}");
        let mut cfg = load_unsafe(
            "wall-push.toml",
            &[
                "environment.stiffness_n_per_mm=2000",
                d.as_str(),
                "slave.contact.enabled=false",
                "passivity.enabled=false",
            ],
        );
        cfg.operator.intent[1] = IntentSegment {
            target_mm: [0.0, 0.0, -10.0],
            move_s: 0.05,
            ..cfg.operator.intent[1]
        };
        let limit = cfg.slave.controller.force_limit_n;
        let s = session::run(&cfg, None).unwrap();
        assert!(
            s.max_force_n > 0.5 * limit,
            "control (no hand-over, no passivity, one-way {delay} ms): only {:.1} N",
            s.max_force_n
        );
    }
}

/// Wall-push on steel with one 200 ms link blackout at 4.0 s, in the middle of the first
/// hold (`extra` overrides after the cell's).
fn blackout_mid_hold(extra: &[&str]) -> Vec<Rec> {
    let mut o = vec![
        "environment.stiffness_n_per_mm=2000",
        "link.blackout_ms=200",
        "link.blackout_every_ms=4000",
        "duration_s=6",
    ];
    o.extend_from_slice(extra);
    run(&load("wall-push.toml", &o))
}

/// A 200 ms link blackout while the operator holds a push on steel: the slave's 20 ms
/// watchdog trips into its safe stop, which holds the contact force through it
/// (`slave.controller.safe_stop_hold_s`), and the master brakes the handle instead of
/// letting the operator's push run it into where the wall was (`coupling.brake_on_loss`).
/// After the re-pairing the true force is where it was, and it never left. Controls, each
/// layer off on its own: without the hold the slave lets go of the wall (the true force
/// falls to near zero during the blackout); without the brake the handle runs millimetres
/// in, and the slave presses harder after the re-pairing.
#[test]
fn a_blackout_mid_hold_rides_through_on_steel() {
    let stats = |r: &[Rec]| {
        let before = mean(window(r, 3.5, 3.95), |x| x.true_force_n[2]);
        let during_min = window(r, 4.0, 4.3)
            .iter()
            .map(|x| x.true_force_n[2])
            .fold(f64::INFINITY, f64::min);
        let after_max = window(r, 4.2, 5.5)
            .iter()
            .map(|x| x.true_force_n[2])
            .fold(0.0, f64::max);
        let handle_in_mm = at(r, 3.95).handle_mm[2] - at(r, 4.35).handle_mm[2];
        (before, during_min, after_max, handle_in_mm)
    };
    let (before, during_min, after_max, handle_in_mm) = stats(&blackout_mid_hold(&[]));
    println!(
        "ride-through: held {before:.2} N, min during {during_min:.2} N, max after {after_max:.2} N, handle in {handle_in_mm:.3} mm"
    );
    assert!(before > 7.0, "no hold before the blackout: {before:.2} N");
    assert!(
        during_min > 0.8 * before,
        "the contact force fell to {during_min:.2} N of {before:.2} N"
    );
    assert!(
        after_max < 1.25 * before,
        "force after the re-pairing {after_max:.2} N for {before:.2} N held"
    );
    assert!(handle_in_mm < 1.0, "handle moved {handle_in_mm:.3} mm in");
    // Control: no hold, the slave ramps down and lets go.
    let (b0, d0, _, _) = stats(&blackout_mid_hold(&["slave.controller.safe_stop_hold_s=0"]));
    println!("no hold: held {b0:.2} N, min during {d0:.2} N");
    assert!(
        d0 < 0.3 * b0,
        "without the hold the force stayed at {d0:.2} N"
    );
    // Control: no brake, the operator's push runs the handle in.
    let (b1, _, a1, h1) = stats(&blackout_mid_hold(&["coupling.brake_on_loss=false"]));
    println!("no brake: held {b1:.2} N, max after {a1:.2} N, handle in {h1:.3} mm");
    assert!(
        h1 > 2.0 * handle_in_mm.max(0.5),
        "handle moved only {h1:.3} mm"
    );
}

/// The slave closes a gap between where it is commanded and where the master is (the
/// catch-up on its first command, a re-anchoring, drift) at most at
/// `passivity.drift_speed_max_mm_per_s`: the gap is a path the master's handle did not
/// move it along, so it may hold a surface. Steel, 1 s one way with 200 ms of jitter and 5 %
/// loss (seed 4): the first command the slave accepts is 10 mm ahead of it. Each layer on
/// its own and the controls (measured 2026-12-02): both layers 21 N; the drift bound alone
/// (with the old 100 000 mm/s² trajectory limit) 42 N; wall-push's 10 000 mm/s² trajectory
/// limit alone 41 N; neither: the slave closes the gap at its 60 mm/s speed limit and hits
/// the steel at 97 N, above its 80 N limit.
#[test]
fn a_catch_up_never_hits_a_surface_at_full_speed() {
    let cell = [
        "environment.stiffness_n_per_mm=2000",
        "link.delay_ms=1000",
        "link.jitter_ms=200",
        "link.loss=0.05",
        "seed=4",
    ];
    let run = |extra: &[&str]| {
        let mut o = cell.to_vec();
        o.extend_from_slice(extra);
        let cfg = load("wall-push.toml", &o);
        (
            session::run(&cfg, None).unwrap().max_force_n,
            cfg.slave.controller.force_limit_n,
        )
    };
    let (both, limit) = run(&[]);
    println!("both layers: true force max {both:.1} N");
    assert!(both < 0.75 * limit, "{both:.1} N");
    let fast = "slave.controller.max_accel_mm_per_s2=100000";
    let unbounded = "passivity.drift_speed_max_mm_per_s=0";
    let (drift_alone, _) = run(&[fast]);
    println!("drift bound alone: true force max {drift_alone:.1} N");
    assert!(drift_alone < 0.75 * limit, "{drift_alone:.1} N");
    let (accel_alone, _) = run(&[unbounded]);
    println!("trajectory limit alone: true force max {accel_alone:.1} N");
    assert!(
        accel_alone > 1.5 * both,
        "control: without the drift bound only {accel_alone:.1} N (with it {both:.1} N)"
    );
    let (neither, _) = run(&[fast, unbounded]);
    println!("neither: true force max {neither:.1} N");
    assert!(neither > limit, "control: only {neither:.1} N");
}

/// A steel touch at the fastest speed the master can command (issue 31): the operator's hand
/// throws the handle 40 mm down in 50 ms (800 mm/s, far beyond the arm's rated 100 mm/s) onto
/// a steel wall 20 mm below, pushing with 30 N, on seeds 1–6.
/// The master commands the slave target at ≥ 80 % of the rated speed before the touch (the
/// test's control: the throw is the fastest command there is, not a slow approach; the
/// slave's own approach, slower behind its passivity port, is printed), and the true
/// contact force stays within 1.05 × the slave's limit.
#[test]
fn a_steel_touch_at_the_fastest_commanded_speed_keeps_the_force_within_the_limit() {
    for seed in 1..=6 {
        let mut cfg = load(
            "wall-push.toml",
            &[
                "environment.material=steel",
                "environment.stiffness_n_per_mm=0",
                "environment.gap_mm=20",
                &format!("seed={seed}"),
                "duration_s=3",
            ],
        );
        cfg.operator.intent = vec![
            seg(0.0, [0.0, 0.0, 0.0], 0.3, [0.0; 3], false),
            seg(0.5, [0.0, 0.0, -40.0], 0.05, [0.0, 0.0, -30.0], false),
            seg(2.5, [0.0, 0.0, 2.0], 0.3, [0.0; 3], false),
        ];
        let limit = cfg.slave.controller.force_limit_n;
        let rated = cfg.slave.arm.ratings.max_speed_mm_per_s;
        let r = run(&cfg);
        let peak = r
            .iter()
            .map(|x| norm(x.true_force_n))
            .fold(
                0.0,
                |a: f64, b| if b.is_nan() { f64::NAN } else { a.max(b) },
            );
        // The slave's speed before its first touch (z over 5 ms windows).
        let touch = r.iter().position(|x| norm(x.true_force_n) > 1.0).unwrap();
        let speed = r[..touch]
            .windows(6)
            .map(|w| (w[5].slave_measured_mm[2] - w[0].slave_measured_mm[2]).abs() / 5e-3)
            .fold(0.0, f64::max);
        let target_speed = r[..touch]
            .windows(6)
            .map(|w| (w[5].slave_target_mm[2] - w[0].slave_target_mm[2]).abs() / 5e-3)
            .fold(0.0, f64::max);
        println!(
            "seed {seed}: commanded {target_speed:.1} mm/s, slave approach {speed:.1} mm/s (rated {rated}), true force peak {peak:.2} N (limit {limit})"
        );
        assert!(
            peak <= 1.05 * limit,
            "seed {seed}: true force {peak:.2} N > 1.05 × {limit} N"
        );
        assert!(
            target_speed >= 0.8 * rated,
            "seed {seed}: the master commanded only {target_speed:.1} mm/s"
        );
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The wall-push cell of issue 32's rendered-force targets: a wall of `k` N/mm, a round trip
/// of `rtt_ms` (told to the slave, as the matrix does) with `loss` of the messages lost, seed
/// `seed`, then `extra`.
fn render_cell(k: &str, rtt_ms: f64, loss: f64, seed: u64, extra: &[&str]) -> SessionConfig {
    let mut o = vec![
        format!("environment.stiffness_n_per_mm={k}"),
        format!("link.delay_ms={}", rtt_ms / 2.0),
        format!("slave.contact.round_trip_ms={rtt_ms}"),
        format!("link.loss={loss}"),
        format!("seed={seed}"),
    ];
    o.extend(extra.iter().map(|s| s.to_string()));
    let o: Vec<&str> = o.iter().map(|s| s.as_str()).collect();
    load("wall-push.toml", &o)
}

/// The cells of issue 32's rendered-force targets: resin (200 N/mm) and aluminium
/// (1000 N/mm), 0 ms without loss and 100 ms with 5 % loss.
const RENDER_CELLS: [(&str, f64, f64); 4] = [
    ("200", 0.0, 0.0),
    ("200", 100.0, 0.05),
    ("1000", 0.0, 0.0),
    ("1000", 100.0, 0.05),
];

/// Issue 32, a rendered force without chatter: in every hold of wall-push the rendered
/// force's content above 20 Hz (`rendered_hf_rms_n`) on resin and on aluminium, at 0 ms and at
/// 100 ms round trip with 5 % loss, seeds 1–3, is at most 0.06 N RMS (the target is
/// 0.05 N: the 0 ms cells miss it by up to 5 %, see docs/results.md); the cells stay stable
/// with both holds found and the master's observer at −1 mJ or above. Before the damping's
/// velocity window (`coupling.damping_window_mm`) a hold read 0.25 N, almost all of it the
/// local damping rendering the encoders' flicker. Control: the window off, the same cells read
/// more than 0.2 N.
#[test]
fn the_rendered_force_in_a_hold_carries_no_chatter() {
    let mut worst = (0.0, String::new());
    for (k, rtt, loss) in RENDER_CELLS {
        for seed in 1..=3 {
            let s = session::run(&render_cell(k, rtt, loss, seed, &[]), None).unwrap();
            let label = format!("{k} N/mm, {rtt} ms, loss {loss}, seed {seed}");
            println!(
                "{label}: rendered above 20 Hz {:.4} N RMS (true force {:.4} N), observer min {:.4} mJ, holds {:?}",
                s.rendered_hf_rms_n,
                s.true_hf_rms_n,
                s.energy_min_j * 1e3,
                s.hold_force_n
            );
            assert!(s.stable, "{label}: {:?}", s.unstable_reasons);
            assert_eq!(s.hold_force_n.len(), 2, "{label}");
            assert!(
                s.energy_min_j >= -1e-3,
                "{label}: observer {} J",
                s.energy_min_j
            );
            assert!(
                s.rendered_hf_rms_n <= 0.06,
                "{label}: rendered force {:.4} N RMS above 20 Hz",
                s.rendered_hf_rms_n
            );
            if s.rendered_hf_rms_n > worst.0 {
                worst = (s.rendered_hf_rms_n, label);
            }
        }
    }
    println!("worst: {:.4} N RMS ({})", worst.0, worst.1);
    for (k, rtt, loss) in [RENDER_CELLS[0], RENDER_CELLS[1]] {
        let cfg = render_cell(
            k,
            rtt,
            loss,
            1,
            &["coupling.damping_window_mm=0", "coupling.force_filter_hz=0"],
        );
        let s = session::run(&cfg, None).unwrap();
        println!(
            "control, no window, {k} N/mm, {rtt} ms: {:.4} N RMS",
            s.rendered_hf_rms_n
        );
        assert!(
            s.rendered_hf_rms_n > 0.2,
            "control ({k} N/mm, {rtt} ms): only {:.4} N RMS",
            s.rendered_hf_rms_n
        );
    }
}

/// The settled cycles of wall-push's two holds (intent at rest from 1.3 s and 7.8 s, the
/// detector's 1 s settling skipped, to the releases at 6 s and 13 s).
const HOLDS_S: [(f64, f64); 2] = [(2.3, 5.95), (8.8, 12.95)];

/// The largest change of the rendered force from one cycle to the next in the settled holds,
/// over the cycles that follow a cycle without feedback (a lost message), N.
fn largest_step_after_a_loss_n(r: &[Rec]) -> (f64, usize) {
    let mut largest = 0.0_f64;
    let mut losses = 0;
    for (from, to) in HOLDS_S {
        let lo = (from * 1000.0) as usize;
        let hi = (to * 1000.0) as usize;
        for k in lo.max(2)..hi {
            if r[k - 1].fresh {
                continue;
            }
            losses += 1;
            let d: [f64; 3] = std::array::from_fn(|i| r[k].rendered_n[i] - r[k - 1].rendered_n[i]);
            largest = largest.max(norm(d));
        }
    }
    (largest, losses)
}

/// Issue 32: a lost feedback does not step the rendered force. Resin and aluminium at 100 ms
/// round trip with 5 % loss, seeds 1–3: over the hundreds of lost feedback messages in the
/// settled holds, the rendered force changes by at most 0.25 N in the cycle after one
/// (the issue measured bursts of 0.5–1 N: the damping's flicker). Control: without the
/// damping's window the same cell steps by more than 0.3 N.
#[test]
fn a_lost_feedback_does_not_step_the_rendered_force() {
    for (k, rtt, loss) in [RENDER_CELLS[1], RENDER_CELLS[3]] {
        for seed in 1..=3 {
            let r = run(&render_cell(k, rtt, loss, seed, &[]));
            let (step, losses) = largest_step_after_a_loss_n(&r);
            println!(
                "{k} N/mm, seed {seed}: {losses} lost feedback in the holds, largest step after one {step:.3} N"
            );
            assert!(losses > 100, "{k} N/mm, seed {seed}: only {losses} losses");
            assert!(step <= 0.25, "{k} N/mm, seed {seed}: step {step:.3} N");
        }
    }
    let r = run(&render_cell(
        RENDER_CELLS[1].0,
        RENDER_CELLS[1].1,
        RENDER_CELLS[1].2,
        1,
        &["coupling.damping_window_mm=0", "coupling.force_filter_hz=0"],
    ));
    let (step, _) = largest_step_after_a_loss_n(&r);
    println!("control, no window: largest step after a loss {step:.3} N");
    assert!(step > 0.3, "control: only {step:.3} N");
}
