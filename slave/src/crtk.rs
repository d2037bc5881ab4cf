//! An arm reached over ROS 2 (`h4-slave run --arm crtk`, issue 35): the [`ArmDriver`] over
//! the cells its subscriptions fill (`h4_transport::ros2::arm::ArmCells`; the Zenoh side is
//! `h4_transport::ros2::arm_io::ArmIo`, started by the command line).
//!
//! The arm speaks Cartesian poses (`measured_cp` / `servo_cp`, metres and a quaternion, in
//! its base frame); the slave's controller speaks actuator positions. The driver converts
//! with the H-4's closed-form kinematics of the world file's geometry:
//!
//! * **read**: the newest measured pose the subscription accepted (already in mm, rad; θ is
//!   the pose's rotation about y) goes through the inverse kinematics
//!   ([`H4Params::ik_checked`]) to the actuator positions the controller expects of encoders;
//!   a pose it cannot map (out of reach, the other assembly mode) is counted and not used.
//!   The wrench is the newest `measured_cf` (N, N·mm, base frame); a cycle with no new
//!   `measured_cf` repeats the last one and says so
//!   ([`ArmDriver::wrench_is_new_sample`]: the safety monitor's frozen-sensor rule counts
//!   new samples only).
//! * **freshness**: a pose or a wrench is fresh for `timeout_ns` (`--arm-timeout-ms`, default
//!   20 ms) after the cycle that first saw it, on the arm's clock (the loop's periods through
//!   [`ArmDriver::advance`]). While either is not fresh the arm is stale: the reading's time
//!   stops moving on, so the slave's safety monitor finds the driver silent and safe-stops
//!   (`driver_stale_stops`), as for any driver; the status tells the I/O thread, which says
//!   so on stderr.
//! * **command**: the actuator set-points go through the forward kinematics
//!   ([`H4Params::fk`]) to the platform pose left in the command cell for `servo_cp`; a
//!   non-finite set-point, or one with no forward kinematics, is counted and not sent.
//!
//! Nothing here allocates, waits or prints.

use std::sync::Arc;

use h4_shared::kinematics::{Actuators, H4Params, Pose};
use h4_transport::ros2::arm::{ArmCells, PoseCommand};

use crate::arm::{ArmDriver, ArmReading};

/// How the arm is read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CrtkArmConfig {
    /// A pose or wrench is fresh this long after the cycle that first saw it, ns.
    pub timeout_ns: u64,
    /// The arm's geometry (the world file's `arm.geometry`).
    pub params: H4Params,
}

/// The ROS 2 arm (see the module doc).
pub struct CrtkArm {
    cells: Arc<ArmCells>,
    cfg: CrtkArmConfig,
    now_ns: u64,
    seen: [u64; 2],
    actuators_mm: [f64; 4],
    pose_ns: Option<u64>,
    wrench: [f64; 4],
    wrench_ns: Option<u64>,
    wrench_new: bool,
    reading_ns: u64,
}

/// The actuator positions of platform pose `pose_mm_rad` (None: no checked inverse
/// kinematics).
pub fn actuators_of(params: &H4Params, pose_mm_rad: &[f64; 4]) -> Option<[f64; 4]> {
    let l = params.ik_checked(&Pose::from(*pose_mm_rad)).ok()?;
    Some([l[0], l[1], l[2], l[3]])
}

/// The platform pose of actuator positions `actuators_mm` (None: non-finite, or no forward
/// kinematics).
pub fn pose_of(params: &H4Params, actuators_mm: &[f64; 4]) -> Option<[f64; 4]> {
    let p = params.fk(&Actuators::from(*actuators_mm)).ok()?;
    Some([p[0], p[1], p[2], p[3]])
}

impl CrtkArm {
    /// The arm over `cells`; its actuators read `initial_actuators_mm` until the first pose
    /// arrives.
    pub fn new(cells: Arc<ArmCells>, cfg: CrtkArmConfig, initial_actuators_mm: [f64; 4]) -> Self {
        CrtkArm {
            cells,
            cfg,
            now_ns: 0,
            seen: [0; 2],
            actuators_mm: initial_actuators_mm,
            pose_ns: None,
            wrench: [0.0; 4],
            wrench_ns: None,
            wrench_new: false,
            reading_ns: 0,
        }
    }

    /// The cells (counters, status).
    pub fn cells(&self) -> &ArmCells {
        &self.cells
    }

    fn fresh(&self, at_ns: Option<u64>) -> bool {
        at_ns.is_some_and(|t| self.now_ns.saturating_sub(t) <= self.cfg.timeout_ns)
    }

    /// No fresh pose or no fresh wrench within the timeout (or none yet).
    pub fn stale(&self) -> bool {
        !(self.fresh(self.pose_ns) && self.fresh(self.wrench_ns))
    }

    fn take_inputs(&mut self) {
        if let Some((v, r)) = self.cells.pose.try_newer_than(self.seen[0]) {
            self.seen[0] = v;
            match actuators_of(&self.cfg.params, &r.pose_mm_rad) {
                Some(l) => {
                    self.actuators_mm = l;
                    self.pose_ns = Some(self.now_ns);
                }
                None => self.cells.status.unreachable(),
            }
        }
        self.wrench_new = false;
        if let Some((v, r)) = self.cells.wrench.try_newer_than(self.seen[1]) {
            self.seen[1] = v;
            self.wrench = r.wrench_n_nmm;
            self.wrench_ns = Some(self.now_ns);
            self.wrench_new = true;
        }
    }
}

impl ArmDriver for CrtkArm {
    fn read(&mut self) -> ArmReading {
        self.take_inputs();
        let stale = self.stale();
        self.cells.status.set_stale(stale);
        if !stale {
            self.reading_ns = self.now_ns;
        }
        ArmReading {
            time_ns: self.reading_ns,
            actuators_mm: self.actuators_mm,
            wrench: self.wrench,
        }
    }

    fn command(&mut self, actuators_mm: &[f64; 4]) {
        match pose_of(&self.cfg.params, actuators_mm) {
            Some(pose_mm_rad) => {
                self.cells.command.offer(PoseCommand { pose_mm_rad });
            }
            None => self.cells.status.refused_command(),
        }
    }

    fn advance(&mut self, dt_ns: u64) {
        self.now_ns = self.now_ns.saturating_add(dt_ns);
    }

    /// `measured_cf` arrives at the arm's rate, not the loop's: between two samples the
    /// reading repeats the last one, which is not a new sample.
    fn wrench_is_new_sample(&self) -> bool {
        self.wrench_new
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use h4_transport::ros2::arm::WrenchReading;
    use h4_transport::ros2::device::PoseReading;
    use h4_transport::ros2::msgs::{PoseStamped, Ros2Message};
    use h4_transport::ros2::units;

    const MS: u64 = 1_000_000;
    const HOME: [f64; 4] = [0.0, 0.0, -245.0, 0.0];

    fn arm() -> CrtkArm {
        let cfg = CrtkArmConfig {
            timeout_ns: 20 * MS,
            params: H4Params::PROTOTYPE,
        };
        let home = actuators_of(&H4Params::PROTOTYPE, &HOME).unwrap();
        CrtkArm::new(ArmCells::shared(), cfg, home)
    }

    fn measured(a: &CrtkArm, pose: [f64; 4], wrench: [f64; 4]) {
        a.cells.pose.put(PoseReading {
            pose_mm_rad: pose,
            stamp_ns: 0,
        });
        a.cells.wrench.put(WrenchReading {
            wrench_n_nmm: wrench,
            stamp_ns: 0,
        });
    }

    fn cycle(a: &mut CrtkArm) -> ArmReading {
        a.advance(MS);
        a.read()
    }

    fn close4(a: &[f64; 4], b: &[f64; 4], tol: f64) -> bool {
        a.iter().zip(b.iter()).all(|(x, y)| (x - y).abs() <= tol)
    }

    /// A pose in metres (as `measured_cp` carries it) → the driver's actuator reading → the
    /// command the driver sends for those actuators → `servo_cp` in metres: the same pose.
    /// Control: the actuators are those of the pose, not of the home pose.
    #[test]
    fn pose_to_actuators_to_pose_round_trips_through_ros_units() {
        for pose in [
            [0.0, 0.0, -250.0, 0.0],
            [12.0, -8.0, -240.0, 0.2],
            [-20.0, 15.0, -300.0, -0.35],
        ] {
            let mut a = arm();
            let ros = units::pose_to_ros(&pose);
            let msg = PoseStamped {
                pose: ros,
                ..PoseStamped::default()
            };
            let decoded = PoseStamped::decode(&msg.encode().unwrap()).unwrap();
            measured(
                &a,
                PoseReading::from_msg(&decoded).pose_mm_rad,
                [0.0, 0.0, 3.0, 0.0],
            );
            let r = cycle(&mut a);
            let want = actuators_of(&H4Params::PROTOTYPE, &pose).unwrap();
            assert!(close4(&r.actuators_mm, &want, 1e-9), "{r:?}");
            let home = actuators_of(&H4Params::PROTOTYPE, &HOME).unwrap();
            if pose != HOME {
                assert!(!close4(&r.actuators_mm, &home, 1e-3));
            }
            assert_eq!(r.wrench, [0.0, 0.0, 3.0, 0.0]);
            a.command(&r.actuators_mm);
            let (_, c) = a.cells.command.newer_than(0).unwrap();
            let out = c.msg(0, "arm_base");
            assert!(
                (out.pose.position.z - pose[2] / 1000.0).abs() < 1e-12,
                "{out:?}"
            );
            assert!(close4(&units::pose_from_ros(&out.pose), &pose, 1e-9));
        }
    }

    /// Fresh poses and wrenches keep the reading's time moving on; once either is older than
    /// the timeout the time stops (the monitor then finds the driver silent), the status
    /// says stale, counted once; a fresh pair makes it answer again. Control: at the timeout
    /// exactly it is still fresh, and a wrench alone does not keep a silent pose fresh.
    #[test]
    fn an_arm_without_fresh_measurements_stops_its_readings_time() {
        let mut a = arm();
        assert!(a.stale(), "stale before the first pose");
        measured(&a, HOME, [0.0; 4]);
        assert_eq!(cycle(&mut a).time_ns, MS);
        for _ in 0..20 {
            cycle(&mut a);
        }
        assert_eq!(a.read().time_ns, 21 * MS, "fresh at the timeout");
        assert!(!a.cells.status.stale());
        assert_eq!(cycle(&mut a).time_ns, 21 * MS, "the time stops once stale");
        assert!(a.cells.status.stale());
        // Wrenches alone: still stale (the pose is old).
        a.cells.wrench.put(WrenchReading::default());
        assert_eq!(cycle(&mut a).time_ns, 21 * MS);
        assert_eq!(a.cells.status.stale_events(), 1);
        measured(&a, HOME, [0.0; 4]);
        assert_eq!(cycle(&mut a).time_ns, 24 * MS);
        assert!(!a.cells.status.stale());
        assert_eq!(a.cells.status.stale_events(), 1);
    }

    /// A wrench is a new sample in the cycle that takes it and not in the cycles that repeat
    /// it (the arm publishes slower than the loop); control: each new one is flagged again.
    #[test]
    fn a_repeated_wrench_is_not_a_new_sample() {
        let mut a = arm();
        let mut flags = Vec::new();
        for k in 0..6 {
            if k % 3 == 0 {
                measured(&a, HOME, [0.0, 0.0, f64::from(k), 0.0]);
            }
            let r = cycle(&mut a);
            flags.push(a.wrench_is_new_sample());
            assert_eq!(r.wrench[2], f64::from(k - k % 3));
        }
        assert_eq!(flags, [true, false, false, true, false, false]);
    }

    /// A pose the inverse kinematics cannot map is counted and not used: the actuators keep
    /// the last good pose's and the pose does not count as fresh.
    #[test]
    fn unreachable_poses_are_counted_and_not_used() {
        let mut a = arm();
        measured(&a, [0.0, 0.0, -250.0, 0.0], [0.0; 4]);
        let good = cycle(&mut a).actuators_mm;
        // Above the base: the other assembly mode; far below: out of the legs' reach.
        for bad in [[0.0, 0.0, 250.0, 0.0], [0.0, 0.0, -900.0, 0.0]] {
            measured(&a, bad, [0.0; 4]);
            assert_eq!(cycle(&mut a).actuators_mm, good);
        }
        assert_eq!(a.cells.status.unreachable_poses(), 2);
        for _ in 0..30 {
            a.cells.wrench.put(WrenchReading::default());
            a.cells.pose.put(PoseReading {
                pose_mm_rad: [0.0, 0.0, -900.0, 0.0],
                stamp_ns: 0,
            });
            cycle(&mut a);
        }
        assert!(a.stale(), "unreachable poses are not fresh ones");
    }

    /// Set-points with no forward kinematics (NaN, l1 < l2) are counted and not sent; a good
    /// one is (control).
    #[test]
    fn bad_set_points_are_refused_and_counted() {
        let mut a = arm();
        a.command(&[f64::NAN, 0.0, 0.0, 0.0]);
        let home = actuators_of(&H4Params::PROTOTYPE, &HOME).unwrap();
        a.command(&[home[1], home[0], home[2], home[3]]);
        assert_eq!(a.cells.command.newer_than(0), None);
        assert_eq!(a.cells.status.refused_commands(), 2);
        a.command(&home);
        let (_, c) = a.cells.command.newer_than(0).unwrap();
        assert!(close4(&c.pose_mm_rad, &HOME, 1e-9));
    }
}
