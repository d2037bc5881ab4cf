//! The master's and the slave's 1 kHz steps allocate nothing: a counting global allocator
//! around many lockstep cycles of an impaired session (delay, jitter, loss, contact).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, Session};
use h4_shared::alloc_count::{CountingAllocator, allocations_in, count_allocations};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

/// A shipped session under a light impairment (10 ms delay, 3 ms jitter, 5 % loss), run for
/// `warm_up` cycles (the first messages through the link's queues, the approach).
fn impaired_session(file: &str, warm_up: usize) -> Session {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../config/sessions")
        .join(file);
    let o: Vec<String> = ["link.delay_ms=10", "link.jitter_ms=3", "link.loss=0.05"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let cfg = session::load(&path, &o).unwrap();
    let mut s = Session::new(&cfg).unwrap();
    for _ in 0..warm_up {
        s.cycle().unwrap();
    }
    s
}

/// Allocations over `n` cycles of `s`.
fn allocations_over(s: &mut Session, n: usize) -> u64 {
    let (count, ()) = count_allocations(|| {
        for _ in 0..n {
            s.cycle().unwrap();
        }
    });
    count
}

#[test]
fn master_and_slave_steps_allocate_nothing() {
    // Warm up (first messages through the link's queues), then count through approach,
    // contact and hold.
    let mut s = impaired_session("wall-push.toml", 200);
    let (n, max_force) = count_allocations(|| {
        let mut max_force = 0.0f64;
        for _ in 0..4000 {
            let (_m, sl) = s.cycle().unwrap();
            max_force = max_force.max(sl.out.wrench_measured[2].abs());
        }
        max_force
    });
    assert!(
        max_force > 2.0,
        "no contact in the counted cycles: {max_force} N"
    );
    assert_eq!(n, 0, "{n} allocations in 4000 cycles");
    // The counter works: an allocation is counted.
    let counted = allocations_in(|| drop(Vec::<u64>::with_capacity(std::hint::black_box(8))));
    assert!(counted > 0);
}

/// The cutting plant (stock sweep, engagement, cutting force) and the fixtures allocate
/// nothing either: cycles of the pocket session while the tool cuts along the floor.
#[test]
fn cutting_cycles_allocate_nothing() {
    let mut s = impaired_session("cut-pocket.toml", 2500);
    let removed_before = s.slave.arm().cut().unwrap().report().removed_mm3;
    let n = allocations_over(&mut s, 4000);
    let removed = s.slave.arm().cut().unwrap().report().removed_mm3 - removed_before;
    assert!(
        removed > 10.0,
        "nothing cut in the counted cycles: {removed} mm³"
    );
    assert!(
        s.slave.controller().fixture_activity().1 > 0,
        "the floor never acted"
    );
    assert_eq!(n, 0, "{n} allocations in 4000 cutting cycles");
}

/// The turntable (its servo, the workpiece-frame cut, the synchronous fixture and its
/// program) allocates nothing: cycles of the profile session while the part turns under the
/// tool.
#[test]
fn turntable_cycles_allocate_nothing() {
    let mut s = impaired_session("cut-profile.toml", 2500);
    let angle = |s: &Session| {
        s.slave
            .arm()
            .cut()
            .unwrap()
            .turntable()
            .unwrap()
            .angle_rad()
    };
    let (removed_before, angle_before) =
        (s.slave.arm().cut().unwrap().report().removed_mm3, angle(&s));
    let n = allocations_over(&mut s, 4000);
    let removed = s.slave.arm().cut().unwrap().report().removed_mm3 - removed_before;
    assert!(
        removed > 10.0,
        "nothing cut in the counted cycles: {removed} mm³"
    );
    assert!(angle(&s) - angle_before > 1.5, "the table did not turn");
    assert_eq!(n, 0, "{n} allocations in 4000 turntable cycles");
}

/// The mesh fixture (the part's distance grid queried every cycle, the tool's envelope
/// projected out of it) allocates nothing: cycles of the dome session while the fixture
/// holds the ball off the part and the tool cuts.
#[test]
fn mesh_fixture_cycles_allocate_nothing() {
    let mut s = impaired_session("cut-mesh-dome.toml", 2500);
    let removed_before = s.slave.arm().cut().unwrap().report().removed_mm3;
    let (n, held) = count_allocations(|| {
        let mut held = 0u32;
        for _ in 0..4000 {
            s.cycle().unwrap();
            held += u32::from(s.slave.controller().mesh_fixture_active());
        }
        held
    });
    let removed = s.slave.arm().cut().unwrap().report().removed_mm3 - removed_before;
    assert!(
        removed > 10.0,
        "nothing cut in the counted cycles: {removed} mm³"
    );
    assert!(
        held > 100,
        "the mesh fixture held the tool in {held} cycles"
    );
    assert_eq!(n, 0, "{n} allocations in 4000 mesh-fixture cycles");
}

/// The mesh fixture on the turntable (the pawn session: the part turned by the table's
/// measured angle every cycle) allocates nothing: cycles while the table turns, the fixture
/// holds the ball off the part and the tool cuts.
#[test]
fn mesh_fixture_on_the_turntable_allocates_nothing() {
    let mut s = impaired_session("cut-mesh-pawn.toml", 20_000);
    let angle = |s: &Session| {
        s.slave
            .arm()
            .cut()
            .unwrap()
            .turntable()
            .unwrap()
            .angle_rad()
    };
    let removed_before = s.slave.arm().cut().unwrap().report().removed_mm3;
    let angle_before = angle(&s);
    let (n, held) = count_allocations(|| {
        let mut held = 0u32;
        for _ in 0..4000 {
            s.cycle().unwrap();
            held += u32::from(s.slave.controller().mesh_fixture_active());
        }
        held
    });
    let removed = s.slave.arm().cut().unwrap().report().removed_mm3 - removed_before;
    assert!(
        removed > 1.0,
        "nothing cut in the counted cycles: {removed} mm³"
    );
    assert!(angle(&s) - angle_before > 3.0, "the table did not turn");
    assert!(
        held > 100,
        "the mesh fixture held the tool in {held} cycles"
    );
    assert_eq!(
        n, 0,
        "{n} allocations in 4000 turntable mesh-fixture cycles"
    );
}
