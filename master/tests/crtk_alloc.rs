//! The ROS 2 device's side of the 1 kHz loop allocates nothing: a counting global allocator
//! around many master cycles over `h4_master::crtk::CrtkDevice`, with a pose, velocity and
//! button arriving in its cells every cycle (as the subscriptions write them) and through a
//! silence and its return.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_master::coupling::{CouplingConfig, ScaleConfig};
use h4_master::crtk::{CrtkDevice, CrtkDeviceConfig, DeviceWorkspace};
use h4_master::teleop::{MasterTeleop, MasterTeleopConfig};
use h4_shared::alloc_count::{CountingAllocator, allocations_in, count_allocations};
use h4_shared::config::ArmConfig;
use h4_shared::passivity::PassivityParams;
use h4_shared::wire::{Feedback, SlaveState};
use h4_transport::Link;
use h4_transport::ros2::device::{ButtonsReading, DeviceCells, PoseReading, TwistReading};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn ros2_device_cycles_allocate_nothing() {
    const MS: u64 = 1_000_000;
    let cells = DeviceCells::shared();
    let device = CrtkDevice::new(
        std::sync::Arc::clone(&cells),
        CrtkDeviceConfig {
            timeout_ns: 20 * MS,
            workspace: DeviceWorkspace::around([0.0, 0.0, -200.0, 0.0], [5.0, 80.0, 80.0, 1.0]),
            mass_kg: 0.3,
        },
        [0.0, 0.0, -200.0, 0.0],
    );
    let cfg = MasterTeleopConfig {
        arm_id: 0,
        coupling: CouplingConfig::default(),
        scale: ScaleConfig::default(),
        passivity: PassivityParams::default(),
        slave_arm: ArmConfig::default(),
        slave_anchor_pose: [0.0, 0.0, -245.0, 0.0],
        slave_max_speed_mm_per_s: 100.0,
    };
    let mut ep = MasterTeleop::new(&cfg, device);
    let (mut master_end, mut slave_end) = h4_transport::inproc::pair(1024);
    let mut cycle = |k: u64| {
        let t_ns = k * MS;
        // Silent from cycle 2000 to 2199; the x motion leaves the 5 mm box (clamped).
        if !(2000..2200).contains(&k) {
            let x_mm = 10.0 * (k as f64 * 1e-3).sin();
            cells.pose.put(PoseReading {
                pose_mm_rad: [x_mm, 0.0, -200.0, 0.0],
                stamp_ns: 0,
            });
            cells.twist.put(TwistReading::default());
            cells.buttons.put(ButtonsReading {
                clutch: k % 1000 < 10,
            });
        }
        slave_end
            .publish(&Feedback {
                seq: k,
                send_time_ns: t_ns,
                state: SlaveState::Active as u8,
                ..Feedback::default()
            })
            .unwrap();
        ep.step(&mut master_end, t_ns, 1e-3);
        while slave_end.try_recv().unwrap().is_some() {}
    };
    for k in 1..=100 {
        cycle(k);
    }
    let (n, ()) = count_allocations(|| {
        for k in 101..=3000 {
            cycle(k);
        }
    });
    assert_eq!(n, 0, "{n} allocations in 2900 cycles");
    // The counted cycles went through a silence and clamped poses.
    assert_eq!(cells.status.silences(), 1);
    assert!(cells.status.clamped_poses() > 0);
    assert!(cells.command.newer_than(0).is_some());
    // The counter works: an allocation is counted.
    let counted = allocations_in(|| drop(Vec::<u64>::with_capacity(std::hint::black_box(8))));
    assert_eq!(counted, 1);
}
