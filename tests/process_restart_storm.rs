//! Restart storms (issue 14): 20 SIGKILL/restart cycles of the master in a row against one
//! slave, then 20 of the slave against one master, over iceoryx2. Every restart re-pairs with
//! no jump of the arm's position or force (seen by a monitor node on the feedback) and no jump
//! of the master's rendered force; iceoryx2's own node and service listing shows no leaked
//! node or service, during the storm and after it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::wire::{Feedback, SlaveState};
use h4_tests::procs::*;
use h4_transport::iceoryx2 as iox;

const CYCLES: usize = 20;
/// Largest move of the arm between two consecutive feedback messages (1 ms), mm: a jump is a
/// re-pairing that snaps the arm towards the master's pose.
const MAX_STEP_MM: f64 = 0.15;
/// Largest change of the measured force between two consecutive feedback messages, N.
const MAX_FORCE_STEP_N: f64 = 2.0;

/// The largest steps between consecutive feedback messages of one slave (consecutive
/// sequence numbers; a new slave starts a new series).
#[derive(Default)]
struct Jumps {
    prev: Option<Feedback>,
    max_step_mm: f64,
    max_force_step_n: f64,
    pairs: u64,
}

impl Jumps {
    fn see(&mut self, fb: &Feedback) {
        if let Some(p) = self.prev
            && fb.seq == p.seq + 1
        {
            let d: f64 = (0..3).map(|i| (fb.pose[i] - p.pose[i]).powi(2)).sum();
            self.max_step_mm = self.max_step_mm.max(d.sqrt());
            self.max_force_step_n = self.max_force_step_n.max((force(fb) - force(&p)).abs());
            self.pairs += 1;
        }
        self.prev = Some(*fb);
    }
}

/// Reads feedback (every message through `jumps`) until `pred` holds.
fn observe(
    mon: &mut impl FeedbackSource,
    jumps: &mut Jumps,
    limit_s: f64,
    what: &str,
    mut pred: impl FnMut(&Feedback) -> bool,
) {
    watch_until(mon, limit_s, what, |fb| {
        jumps.see(fb);
        pred(fb)
    });
}

fn hold(mon: &mut impl FeedbackSource, jumps: &mut Jumps, ms: u64) {
    let t = std::time::Instant::now();
    while t.elapsed().as_millis() < u128::from(ms) {
        while let Some(fb) = mon.next_feedback() {
            jumps.see(&fb);
        }
        std::thread::sleep(std::time::Duration::from_micros(500));
    }
}

fn no_leaks(prefix: &str, alive: usize, services: usize) {
    let r = iox::resources(prefix).expect("iceoryx2 listing");
    assert_eq!(r.dead_nodes, 0, "dead nodes left: {r:?}");
    assert_eq!(r.alive_nodes, alive, "{r:?}");
    assert_eq!(r.services.len(), services, "{r:?}");
}

#[test]
fn twenty_kills_of_each_side_repair_without_jumps_or_leaks() {
    let _g = serial();
    let (master, slave) = binaries();
    let scratch = Scratch::new("storm");
    let mut sl = Running::spawn("slave", slave, &slave_args(&scratch, &[]), &scratch);
    let mut mon = spy(&scratch);
    let mut jumps = Jumps::default();
    observe(&mut mon, &mut jumps, 20.0, "slave feedback", |_| true);
    for i in 0..CYCLES {
        let mut ma = Running::spawn("master", master, &master_args(&scratch, &[]), &scratch);
        observe(&mut mon, &mut jumps, 20.0, "paired with the new master", |fb| {
            fb.state == SlaveState::Active as u8
        });
        hold(&mut mon, &mut jumps, 300);
        ma.sigkill();
        observe(&mut mon, &mut jumps, 10.0, "safe state", |fb| {
            fb.state == SlaveState::SafeStop as u8
        });
        assert!(jumps.max_step_mm < MAX_STEP_MM, "master restart {i}: {} mm", jumps.max_step_mm);
    }
    // Slave, the last master's replacement, the monitor: the 20 dead masters were cleaned.
    let ms = scratch.path("master.json").display().to_string();
    let mut ma = Running::spawn(
        "master",
        master,
        &master_args(&scratch, &["--summary", &ms]),
        &scratch,
    );
    observe(&mut mon, &mut jumps, 20.0, "paired", |fb| fb.state == SlaveState::Active as u8);
    no_leaks(&scratch.prefix, 3, 2);
    eprintln!(
        "master storm: max step {:.4} mm, max force step {:.3} N over {} pairs",
        jumps.max_step_mm, jumps.max_force_step_n, jumps.pairs
    );
    assert!(jumps.max_force_step_n < MAX_FORCE_STEP_N, "{} N", jumps.max_force_step_n);
    assert!(jumps.pairs > 5_000, "{}", jumps.pairs);

    let mut jumps = Jumps::default();
    for i in 0..=CYCLES {
        if i > 0 {
            sl = Running::spawn("slave", slave, &slave_args(&scratch, &[]), &scratch);
        }
        observe(&mut mon, &mut jumps, 20.0, "the new slave paired", |fb| {
            fb.state == SlaveState::Active as u8
        });
        hold(&mut mon, &mut jumps, 300);
        if i == CYCLES {
            break;
        }
        sl.sigkill();
        jumps.prev = None;
        assert!(jumps.max_step_mm < MAX_STEP_MM, "slave restart {i}: {} mm", jumps.max_step_mm);
    }
    no_leaks(&scratch.prefix, 3, 2);
    ma.stop();
    sl.stop();
    drop(mon);
    let m = read_json(std::path::Path::new(&ms));
    eprintln!(
        "slave storm: max step {:.4} mm, max force step {:.3} N; master: {m}",
        jumps.max_step_mm, jumps.max_force_step_n
    );
    assert!(jumps.max_force_step_n < MAX_FORCE_STEP_N, "{} N", jumps.max_force_step_n);
    assert!(u(&m, "feedback_restored") >= CYCLES as u64, "{m:#}");
    assert!(f(&m, "max_rendered_force_step_n") < MAX_FORCE_STEP_N, "{m:#}");
    // Everything stopped in order: nothing of this test's prefix is left.
    no_leaks(&scratch.prefix, 0, 0);
}
