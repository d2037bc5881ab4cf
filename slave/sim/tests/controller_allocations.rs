//! The 1 kHz controller step allocates nothing: a counting global allocator watches
//! 10 000 steps of a force-controlled contact (approach, touch, tracking) with the
//! simulated arm in the loop.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::alloc_count::{CountingAllocator, count_allocations};
use h4_shared::config;
use h4_shared::wire::Mode;
use h4_slave::arm::ArmDriver;
use h4_slave::controller::{ControllerInput, SlaveCommand, Status};
use h4_slave_sim::experiment::ExperimentConfig;

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn ten_thousand_controller_steps_allocate_nothing() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/experiments/fig6b.toml"
    );
    let cfg: ExperimentConfig = config::load(std::path::Path::new(path), &[]).unwrap();
    let p = cfg.surface.contact_point_mm;
    let start = h4_shared::Pose::new(p[0], p[1], p[2] + 2.0, 0.0);
    let (mut arm, mut ctrl) = cfg.world().build(start, 1).unwrap();
    let mut statuses = std::collections::BTreeSet::new();
    let mut steps = 0u64;
    let mut allocations = 0u64;
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
        let (n, out) = count_allocations(|| ctrl.step(&input, 1e-3));
        allocations += n;
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
    assert_eq!(allocations, 0, "the controller step allocated");
    // The counter does see allocations (so the zero above means something).
    let (seen, v) = count_allocations(|| std::hint::black_box(vec![1u8; 16]));
    drop(v);
    assert!(seen > 0);
}
