//! Restart storms (issue 14): 20 SIGKILL/restart cycles of the master in a row against one
//! slave, then 20 of the slave against one master, over iceoryx2. Every restart re-pairs with
//! no jump of the arm's position or force (seen by a monitor node on the feedback);
//! iceoryx2's own node and service listing shows no leaked node or service, during the storm
//! and after it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::wire::{Feedback, SlaveState};
use h4_tests::procs::*;
use h4_transport::iceoryx2 as iox;

const CYCLES: usize = 20;
/// Largest move of the arm between two consecutive feedback messages (1 ms), mm: a jump is a
/// re-pairing that snaps the arm towards the master's pose.
const MAX_STEP_MM: f64 = 0.15;
/// Largest change of the measured force between two consecutive feedback messages, N: what
/// the largest allowed step does on the test's 20 N/mm wall.
const MAX_FORCE_STEP_N: f64 = MAX_STEP_MM * 20.0;
/// Largest change of the master's rendered force in one cycle across the slave storm, N.
const MAX_RENDERED_STEP_N: f64 = 2.5;

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

/// iceoryx2's files on this host: `/dev/shm/iox2_*` and everything under `/tmp/iceoryx2`.
fn iceoryx2_files() -> usize {
    fn count(dir: &std::path::Path) -> usize {
        std::fs::read_dir(dir).map_or(0, |entries| {
            entries
                .flatten()
                .map(|e| {
                    if e.path().is_dir() {
                        1 + count(&e.path())
                    } else {
                        1
                    }
                })
                .sum()
        })
    }
    let shm = std::fs::read_dir("/dev/shm").map_or(0, |entries| {
        entries
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with("iox2_"))
            .count()
    });
    shm + count(std::path::Path::new("/tmp/iceoryx2"))
}

/// The services one link of live processes holds: commands and feedback, each a
/// publish-subscribe service and the event service its publisher notifies
/// (`<prefix>/<arm>/<topic>/event`, the phase-locked wake-up).
const LINK_SERVICES: usize = 4;

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
    let files_before = iceoryx2_files();
    let mut sl = Running::spawn("slave", slave, &slave_args(&scratch, &[]), &scratch);
    let mut mon = spy(&scratch);
    let mut jumps = Jumps::default();
    observe(&mut mon, &mut jumps, 20.0, "slave feedback", |_| true);
    for i in 0..CYCLES {
        let mut ma = Running::spawn("master", master, &master_args(&scratch, &[]), &scratch);
        observe(
            &mut mon,
            &mut jumps,
            20.0,
            "paired with the new master",
            |fb| fb.state == SlaveState::Active as u8,
        );
        hold(&mut mon, &mut jumps, 300);
        ma.sigkill();
        observe(&mut mon, &mut jumps, 10.0, "safe state", |fb| {
            fb.state == SlaveState::SafeStop as u8
        });
        assert!(
            jumps.max_step_mm < MAX_STEP_MM,
            "master restart {i}: {} mm",
            jumps.max_step_mm
        );
    }
    // Slave, the last master's replacement, the monitor: the 20 dead masters were cleaned.
    let ms = scratch.path("master.json").display().to_string();
    let mut ma = Running::spawn(
        "master",
        master,
        &master_args(&scratch, &["--summary", &ms]),
        &scratch,
    );
    observe(&mut mon, &mut jumps, 20.0, "paired", |fb| {
        fb.state == SlaveState::Active as u8
    });
    no_leaks(&scratch.prefix, 3, LINK_SERVICES);
    eprintln!(
        "master storm: max step {:.4} mm, max force step {:.3} N over {} pairs",
        jumps.max_step_mm, jumps.max_force_step_n, jumps.pairs
    );
    assert!(
        jumps.max_force_step_n < MAX_FORCE_STEP_N,
        "{} N",
        jumps.max_force_step_n
    );
    assert!(jumps.pairs > 5_000, "{}", jumps.pairs);

    let mut jumps = Jumps::default();
    let mut killed_seq = u64::MAX;
    for i in 0..=CYCLES {
        if i > 0 {
            sl = Running::spawn("slave", slave, &slave_args(&scratch, &[]), &scratch);
        }
        // The new slave (its sequence numbers start again) commanded by the master.
        let mut new_slave = false;
        observe(&mut mon, &mut jumps, 20.0, "the new slave paired", |fb| {
            new_slave |= fb.seq < killed_seq;
            new_slave && fb.state == SlaveState::Active as u8
        });
        hold(&mut mon, &mut jumps, 300);
        if i == CYCLES {
            break;
        }
        sl.sigkill();
        killed_seq = jumps.prev.map_or(u64::MAX, |p| p.seq);
        jumps.prev = None;
        assert!(
            jumps.max_step_mm < MAX_STEP_MM,
            "slave restart {i}: {} mm",
            jumps.max_step_mm
        );
    }
    no_leaks(&scratch.prefix, 3, LINK_SERVICES);
    ma.stop();
    sl.stop();
    drop(mon);
    let m = read_json(std::path::Path::new(&ms));
    eprintln!(
        "slave storm: max step {:.4} mm, max force step {:.3} N; master: {m}",
        jumps.max_step_mm, jumps.max_force_step_n
    );
    assert!(
        jumps.max_force_step_n < MAX_FORCE_STEP_N,
        "{} N",
        jumps.max_force_step_n
    );
    // Nothing of a slave's force is rendered while faded out, and the master's rendered force
    // never steps across a slave replaced within its feedback timeout: the old slave's force
    // fades out while the new one's fades in (it stepped by up to 6 N before;
    // docs/processes.md, "Restart storms").
    assert!(f(&m, "max_force_while_faded_out_n") < 0.1, "{m:#}");
    // Judged between cycles that ran on time: after a host stall (29 ms on a loaded CI
    // machine) the handle has moved under the held force and its damping steps by 2.6 N,
    // with or without a re-pairing.
    assert!(
        f(&m, "max_rendered_force_step_outside_stalls_n") < MAX_RENDERED_STEP_N,
        "rendered force stepped: {m:#}"
    );
    assert!(u(&m, "feedback_received") > 1000, "{m:#}");
    // Everything stopped in order: nothing of this test's prefix is left, and iceoryx2's files
    // are back to where they were (other programs on the host may only have removed theirs).
    no_leaks(&scratch.prefix, 0, 0);
    let t = std::time::Instant::now();
    while iceoryx2_files() > files_before && t.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    assert!(
        iceoryx2_files() <= files_before,
        "iceoryx2 files: {} before the storm, {} after",
        files_before,
        iceoryx2_files()
    );
}
