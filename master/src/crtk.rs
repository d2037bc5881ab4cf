//! A haptic device reached over ROS 2 (`h4-master run --device crtk`, issue 35): the
//! [`HapticDevice`] over the cells its subscriptions fill
//! (`h4_transport::ros2::device::DeviceCells`; the Zenoh side is
//! `h4_transport::ros2::device_io::DeviceIo`, started by the command line).
//!
//! Each cycle ([`HapticDevice::begin_cycle`]) the device takes, without waiting, the newest
//! pose, velocity and buttons the subscriptions accepted (already checked and in mm, rad):
//!
//! * **the pose** is clamped into the mapped workspace ([`DeviceWorkspace`], a box in the
//!   device's frame) and each clamped pose is counted;
//! * **freshness**: a pose is fresh for `timeout_ns` (`--device-timeout-ms`, default 20 ms)
//!   after the cycle that first saw it. While no fresh pose arrives the device is silent: its
//!   readings' time stops moving on, so the endpoint counts the cycles
//!   (`device_stale_cycles`) and the coupling fades the rendered force to zero, as for any
//!   silent device; the device's status tells the I/O thread, which says so on stderr. A
//!   fresh pose fades the force back in;
//! * **the velocity** is the device's `measured_cv` while it is fresh, otherwise the finite
//!   difference of the last two poses (0 while silent);
//! * **the clutch** is the newest button message's.
//!
//! [`HapticDevice::write_wrench`] leaves the wrench in the command cell (a non-waiting
//! write; a non-finite wrench is sent as zero). Nothing here allocates, waits or prints.

use std::sync::Arc;

use h4_transport::ros2::device::{DeviceCells, WrenchCommand};

use crate::device::{DeviceState, HapticDevice, PrincipalMasses};

/// The part of the device's space that is mapped: poses outside it are clamped into it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviceWorkspace {
    /// Lowest `[x_mm, y_mm, z_mm, theta_rad]`.
    pub min_mm_rad: [f64; 4],
    /// Highest `[x_mm, y_mm, z_mm, theta_rad]`.
    pub max_mm_rad: [f64; 4],
}

impl DeviceWorkspace {
    /// The box `centre ± half`.
    pub fn around(centre_mm_rad: [f64; 4], half_mm_rad: [f64; 4]) -> Self {
        let mut min_mm_rad = [0.0; 4];
        let mut max_mm_rad = [0.0; 4];
        for i in 0..4 {
            min_mm_rad[i] = centre_mm_rad[i] - half_mm_rad[i].abs();
            max_mm_rad[i] = centre_mm_rad[i] + half_mm_rad[i].abs();
        }
        DeviceWorkspace {
            min_mm_rad,
            max_mm_rad,
        }
    }

    /// `pose` clamped into the box, and whether it had to be.
    pub fn clamp(&self, pose: &[f64; 4]) -> ([f64; 4], bool) {
        let mut out = *pose;
        let mut clamped = false;
        for (i, v) in out.iter_mut().enumerate() {
            let c = v.clamp(self.min_mm_rad[i], self.max_mm_rad[i]);
            clamped |= c != *v;
            *v = c;
        }
        (out, clamped)
    }
}

/// How the device is read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CrtkDeviceConfig {
    /// A pose is fresh this long after the cycle that first saw it, ns.
    pub timeout_ns: u64,
    /// The mapped workspace.
    pub workspace: DeviceWorkspace,
    /// The handle's effective mass, kg (0: unknown; `DeviceState::effective_mass_kg`).
    pub mass_kg: f64,
}

/// The ROS 2 device (see the module doc).
pub struct CrtkDevice {
    cells: Arc<DeviceCells>,
    cfg: CrtkDeviceConfig,
    now_ns: u64,
    seen: [u64; 3],
    pose: [f64; 4],
    pose_ns: Option<u64>,
    pose_velocity: [f64; 4],
    twist: [f64; 4],
    twist_ns: Option<u64>,
    clutch: bool,
    reading_ns: u64,
}

impl CrtkDevice {
    /// The device over `cells`; its pose is `initial_pose` until the first one arrives.
    pub fn new(cells: Arc<DeviceCells>, cfg: CrtkDeviceConfig, initial_pose: [f64; 4]) -> Self {
        CrtkDevice {
            cells,
            cfg,
            now_ns: 0,
            seen: [0; 3],
            pose: initial_pose,
            pose_ns: None,
            pose_velocity: [0.0; 4],
            twist: [0.0; 4],
            twist_ns: None,
            clutch: false,
            reading_ns: 0,
        }
    }

    /// The cells (counters, status).
    pub fn cells(&self) -> &DeviceCells {
        &self.cells
    }

    fn fresh(&self, at_ns: Option<u64>) -> bool {
        at_ns.is_some_and(|t| self.now_ns.saturating_sub(t) <= self.cfg.timeout_ns)
    }

    /// No fresh pose within the timeout (or none yet).
    pub fn silent(&self) -> bool {
        !self.fresh(self.pose_ns)
    }

    fn take_pose(&mut self) {
        let Some((v, r)) = self.cells.pose.try_newer_than(self.seen[0]) else {
            return;
        };
        self.seen[0] = v;
        let (pose, clamped) = self.cfg.workspace.clamp(&r.pose_mm_rad);
        if clamped {
            self.cells.status.clamped();
        }
        if let Some(t) = self.pose_ns {
            let dt_s = self.now_ns.saturating_sub(t) as f64 * 1e-9;
            if dt_s > 0.0 {
                for (i, v) in self.pose_velocity.iter_mut().enumerate() {
                    *v = (pose[i] - self.pose[i]) / dt_s;
                }
            }
        }
        self.pose = pose;
        self.pose_ns = Some(self.now_ns);
    }

    fn take_inputs(&mut self) {
        self.take_pose();
        if let Some((v, r)) = self.cells.twist.try_newer_than(self.seen[1]) {
            self.seen[1] = v;
            self.twist = r.velocity_mm_rad_per_s;
            self.twist_ns = Some(self.now_ns);
        }
        if let Some((v, r)) = self.cells.buttons.try_newer_than(self.seen[2]) {
            self.seen[2] = v;
            self.clutch = r.clutch;
        }
    }
}

impl HapticDevice for CrtkDevice {
    fn begin_cycle(&mut self, now_ns: u64, _dt_s: f64) {
        self.now_ns = now_ns;
        self.take_inputs();
        let silent = self.silent();
        self.cells.status.set_silent(silent);
        if !silent {
            self.reading_ns = now_ns;
        }
    }

    fn read(&mut self) -> DeviceState {
        let velocity = if self.silent() {
            [0.0; 4]
        } else if self.fresh(self.twist_ns) {
            self.twist
        } else {
            self.pose_velocity
        };
        DeviceState {
            time_ns: self.reading_ns,
            pose: self.pose,
            velocity,
            clutch: self.clutch,
            effective_mass_kg: self.cfg.mass_kg,
            principal_masses: PrincipalMasses::isotropic(self.cfg.mass_kg),
        }
    }

    fn write_wrench(&mut self, wrench: &[f64; 4]) -> [f64; 4] {
        let w = if wrench.iter().all(|v| v.is_finite()) {
            *wrench
        } else {
            [0.0; 4]
        };
        self.cells.command.offer(WrenchCommand {
            stamp_unix_ns: 0,
            wrench_n_nmm: w,
        });
        w
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use h4_transport::ros2::device::{ButtonsReading, PoseReading, TwistReading};

    const MS: u64 = 1_000_000;

    fn device() -> CrtkDevice {
        let cfg = CrtkDeviceConfig {
            timeout_ns: 20 * MS,
            workspace: DeviceWorkspace::around([0.0, 0.0, -200.0, 0.0], [50.0, 50.0, 50.0, 1.0]),
            mass_kg: 0.2,
        };
        CrtkDevice::new(DeviceCells::shared(), cfg, [0.0, 0.0, -200.0, 0.0])
    }

    fn pose(d: &CrtkDevice, p: [f64; 4]) {
        d.cells.pose.put(PoseReading {
            pose_mm_rad: p,
            stamp_ns: 0,
        });
    }

    fn cycle(d: &mut CrtkDevice, t_ns: u64) -> DeviceState {
        d.begin_cycle(t_ns, 1e-3);
        d.read()
    }

    /// A pose read is the device's pose; a pose outside the box is clamped onto it and
    /// counted; one inside is not (control).
    #[test]
    fn poses_outside_the_workspace_are_clamped_and_counted() {
        let mut d = device();
        pose(&d, [10.0, 0.0, -190.0, 0.1]);
        assert_eq!(cycle(&mut d, MS).pose, [10.0, 0.0, -190.0, 0.1]);
        assert_eq!(d.cells.status.clamped_poses(), 0);
        pose(&d, [80.0, -70.0, -200.0, 2.0]);
        assert_eq!(cycle(&mut d, 2 * MS).pose, [50.0, -50.0, -200.0, 1.0]);
        assert_eq!(d.cells.status.clamped_poses(), 1);
        // A non-new cell is not read again, nor counted again.
        cycle(&mut d, 3 * MS);
        assert_eq!(d.cells.status.clamped_poses(), 1);
    }

    /// Fresh poses keep the reading's time moving on; without one for longer than the
    /// timeout the time stops (the endpoint then fades the force) and the status says
    /// silent, counted once; a new pose makes it answer again. Control: at the timeout
    /// exactly it is still fresh.
    #[test]
    fn a_silent_device_stops_its_readings_time() {
        let mut d = device();
        assert!(d.silent(), "silent before the first pose");
        pose(&d, [0.0, 0.0, -200.0, 0.0]);
        assert_eq!(cycle(&mut d, MS).time_ns, MS);
        assert_eq!(
            cycle(&mut d, 21 * MS).time_ns,
            21 * MS,
            "fresh at the timeout"
        );
        assert!(!d.cells.status.silent());
        let r = cycle(&mut d, 22 * MS);
        assert_eq!(r.time_ns, 21 * MS, "the time stops once silent");
        assert_eq!(r.velocity, [0.0; 4]);
        assert_eq!(cycle(&mut d, 30 * MS).time_ns, 21 * MS);
        assert!(d.cells.status.silent());
        assert_eq!(d.cells.status.silences(), 1);
        pose(&d, [0.0, 0.0, -200.0, 0.0]);
        assert_eq!(cycle(&mut d, 31 * MS).time_ns, 31 * MS);
        assert!(!d.cells.status.silent());
        assert_eq!(d.cells.status.silences(), 1);
    }

    /// The velocity is `measured_cv` while fresh, else the poses' finite difference.
    #[test]
    fn velocity_from_the_twist_or_the_poses() {
        let mut d = device();
        pose(&d, [0.0, 0.0, -200.0, 0.0]);
        cycle(&mut d, MS);
        pose(&d, [1.0, 0.0, -200.0, 0.0]);
        let v = cycle(&mut d, 2 * MS).velocity;
        assert!((v[0] - 1000.0).abs() < 1e-9, "{v:?}");
        d.cells.twist.put(TwistReading {
            velocity_mm_rad_per_s: [5.0, 0.0, 0.0, 0.0],
        });
        d.cells.buttons.put(ButtonsReading { clutch: true });
        let r = cycle(&mut d, 3 * MS);
        assert_eq!(r.velocity, [5.0, 0.0, 0.0, 0.0]);
        assert!(r.clutch);
    }

    /// In the endpoint: a device that stops publishing has its rendered force faded to zero
    /// (the stale cycles counted from the second cycle past the timeout), and faded back in
    /// when poses return. Control: the same run with poses throughout keeps the fade at 1.
    #[test]
    fn a_silent_ros2_device_fades_the_rendering_out() {
        use crate::coupling::{CouplingConfig, ScaleConfig};
        use crate::teleop::{MasterTeleop, MasterTeleopConfig};
        use h4_shared::config::ArmConfig;
        use h4_shared::passivity::PassivityParams;
        use h4_shared::wire::{Feedback, SlaveState};
        use h4_transport::Link;
        let run = |gap: Option<std::ops::Range<u64>>| {
            let cfg = MasterTeleopConfig {
                arm_id: 0,
                coupling: CouplingConfig::default(),
                scale: ScaleConfig::default(),
                passivity: PassivityParams::default(),
                slave_arm: ArmConfig::default(),
                slave_anchor_pose: [0.0, 0.0, -245.0, 0.0],
                slave_max_speed_mm_per_s: 100.0,
            };
            let mut ep = MasterTeleop::new(&cfg, device());
            let (mut master_end, mut slave_end) = h4_transport::inproc::pair(1024);
            let mut fades = Vec::new();
            for k in 1..=600u64 {
                let t_ns = k * MS;
                if !gap.as_ref().is_some_and(|g| g.contains(&k)) {
                    pose(ep.device(), [0.0, 0.0, -200.0, 0.0]);
                }
                slave_end
                    .publish(&Feedback {
                        seq: k,
                        send_time_ns: t_ns,
                        state: SlaveState::Active as u8,
                        ..Feedback::default()
                    })
                    .unwrap();
                fades.push(ep.step(&mut master_end, t_ns, 1e-3).step.fade);
                while slave_end.try_recv().unwrap().is_some() {}
            }
            let silences = ep.device().cells().status.silences();
            (fades, ep.counters().device_stale_cycles, silences)
        };
        let (fresh, fresh_stale, fresh_silences) = run(None);
        assert_eq!((fresh_stale, fresh_silences), (0, 0));
        assert!(fresh[100..].iter().all(|&f| f == 1.0));
        // No pose from cycle 200 to 399: the last one (199) is fresh up to cycle 219.
        let (gap, stale, silences) = run(Some(200..400));
        assert_eq!(silences, 1);
        // Silent from cycle 220 to 399 (180 cycles); stale from its second, 179.
        assert_eq!(stale, 179);
        assert_eq!(gap[218], 1.0, "still fresh within the timeout");
        assert_eq!(gap[390], 0.0, "faded out while silent");
        assert_eq!(gap[599], 1.0, "faded back in");
    }

    /// The wrench goes to the command cell; a NaN one goes out as zero.
    #[test]
    fn wrenches_go_to_the_command_cell() {
        let mut d = device();
        assert_eq!(d.write_wrench(&[1.0, 2.0, 3.0, 4.0]), [1.0, 2.0, 3.0, 4.0]);
        let (v, c) = d.cells.command.newer_than(0).unwrap();
        assert_eq!(c.wrench_n_nmm, [1.0, 2.0, 3.0, 4.0]);
        assert_eq!(d.write_wrench(&[f64::NAN, 0.0, 0.0, 0.0]), [0.0; 4]);
        assert_eq!(
            d.cells.command.newer_than(v).unwrap().1.wrench_n_nmm,
            [0.0; 4]
        );
    }
}
