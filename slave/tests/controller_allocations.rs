//! The 1 kHz controller step allocates nothing: a counting global allocator watches
//! 10 000 steps of a force-controlled contact (approach, touch, tracking) with the
//! simulated arm in the loop.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use h4_shared::config;
use h4_shared::wire::Mode;
use h4_slave::controller::{ControllerInput, SlaveCommand, SlaveController, Status};
use h4_slave::experiment::ExperimentConfig;
use h4_slave::plant::{ArmDriver, SimArm};

struct Counting;

thread_local! {
    // Per thread: only the test's own thread is watched (the test harness's other threads
    // may allocate at any time, which made a global flag flaky under load).
    static ARMED: Cell<bool> = const { Cell::new(false) };
}
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

fn armed() -> bool {
    ARMED.try_with(Cell::get).unwrap_or(false)
}

fn set_armed(on: bool) {
    ARMED.with(|a| a.set(on));
}

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if armed() {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if armed() {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn ten_thousand_controller_steps_allocate_nothing() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/experiments/fig6b.toml"
    );
    let cfg: ExperimentConfig = config::load(std::path::Path::new(path), &[]).unwrap();
    let ws = cfg.arm.workspace();
    let p = cfg.surface.contact_point_mm;
    let start = h4_shared::Pose::new(p[0], p[1], p[2] + 2.0, 0.0);
    let mut arm = SimArm::new(
        ws.params,
        cfg.arm.actuator_stiffness_n_per_mm,
        cfg.plant,
        cfg.sensor,
        cfg.surface(),
        start,
        1,
    )
    .unwrap();
    let mut ctrl = SlaveController::new(ws, cfg.arm.stiffness().unwrap(), cfg.controller);
    let mut statuses = std::collections::BTreeSet::new();
    let mut steps = 0u64;
    for k in 0..10_000u64 {
        let reading = arm.read();
        let input = ControllerInput {
            actuators_mm: reading.actuators_mm,
            wrench: reading.wrench,
            command: SlaveCommand {
                mode: Mode::ForceGuided,
                pose: [p[0], p[1], p[2] - 20.0, 0.0],
                velocity: if k > 2000 {
                    [3.5, 0.0, 0.0, 0.0]
                } else {
                    [0.0; 4]
                },
                force_setpoint_n: 30.0,
                clutch: false,
            },
        };
        set_armed(true);
        let out = ctrl.step(&input, 1e-3);
        set_armed(false);
        steps += 1;
        statuses.insert(format!("{:?}", out.status));
        arm.command(&out.actuators_cmd_mm);
        arm.advance(1_000_000);
    }
    assert_eq!(steps, 10_000);
    // The run went through the interesting states, so the check covers them.
    assert!(
        statuses.contains(&format!("{:?}", Status::Approaching)),
        "{statuses:?}"
    );
    assert!(
        statuses.contains(&format!("{:?}", Status::Contact)),
        "{statuses:?}"
    );
    assert_eq!(
        ALLOCATIONS.load(Ordering::SeqCst),
        0,
        "the controller step allocated"
    );
    // The counter does see allocations (so the zero above means something).
    set_armed(true);
    let v = std::hint::black_box(vec![1u8; 16]);
    set_armed(false);
    drop(v);
    assert!(ALLOCATIONS.load(Ordering::SeqCst) > 0);
}
