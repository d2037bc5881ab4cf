//! The safety monitor: the arm's ratings enforced outside the controller.
//!
//! [`SafetyMonitor::check`] runs every cycle after the controller has computed its command
//! and before the command reaches the arm ([`crate::teleop::SlaveTeleop::step`]). It judges
//! what the arm's sensors say, not what the controller intends:
//!
//! * the sensed force (the sensor's reading with its tare and the tool's weight removed)
//!   above the force limit in effect for [`FORCE_OVER_CYCLES`] cycles in a row, or above
//!   [`FORCE_PEAK_SHARE`] × the limit once;
//! * the tool point's speed (forward kinematics of the encoders, over
//!   [`SPEED_WINDOW_CYCLES`] cycles) above `speed_trip_share` × the rated speed;
//! * the measured pose leaving the workspace by more than the rated margin, or the forward
//!   kinematics failing on the encoders' reading;
//! * an actuator beyond its stroke by more than the margin, or faster than its rated speed;
//! * a sensor or encoder reading that is not finite, a force reading at or beyond the
//!   sensor's range (saturated), a force/torque reading that repeats bit for bit for
//!   `sensor_freeze_cycles` new samples (frozen; a driver whose sensor samples slower than
//!   the loop hands the same sample to several cycles, [`crate::arm::ArmDriver::wrench_is_new_sample`],
//!   and those repeats are not counted);
//! * a driver that stops answering (its reading's time does not move on).
//!
//! A trip makes the endpoint put the arm into its safe stop at once: the command of the trip
//! cycle is not sent (the arm keeps the last command it was given), the force set-point goes
//! to zero and the arm retracts along the sensed force and holds. Only the master's
//! acknowledgement re-arms it, and not while a persistent fault (a sensor or a driver fault)
//! lasts. The limits come from the arm file's `[ratings]`; the controller's (lower) limits
//! in effect are used where they are lower. The monitor allocates nothing and never panics.

use h4_shared::config::ArmRatings;
use h4_shared::kinematics::{Pose, Workspace, WorkspaceLimits};
use nalgebra::Vector4;
use serde::Serialize;

use crate::arm::ArmReading;

/// The sensed force may stay above the limit this many cycles in a row.
pub const FORCE_OVER_CYCLES: u32 = 2;
/// A sensed force above this share of the limit trips at once.
pub const FORCE_PEAK_SHARE: f64 = 1.2;
/// The speeds are measured over this many cycles (the encoders' quantisation and the
/// structure's ringing average out; a trip comes at most this late).
pub const SPEED_WINDOW_CYCLES: usize = 4;
/// The driver's reading may repeat its time this many cycles in a row.
pub const DRIVER_STALE_CYCLES: u32 = 2;

/// Why the monitor tripped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TripReason {
    /// The sensed force above the limit for [`FORCE_OVER_CYCLES`] cycles.
    ForceOverLimit,
    /// The sensed force above [`FORCE_PEAK_SHARE`] × the limit.
    ForcePeak,
    /// The tool point faster than its trip speed.
    ToolSpeed,
    /// The measured pose out of the workspace's margin (or no pose from the encoders).
    Workspace,
    /// An actuator beyond its stroke's margin.
    ActuatorPosition,
    /// An actuator faster than its rated speed.
    ActuatorSpeed,
    /// A reading that is not finite (NaN, infinite).
    SensorNonFinite,
    /// A force reading at or beyond the sensor's range.
    SensorSaturated,
    /// A force/torque reading that does not change.
    SensorFrozen,
    /// The driver's reading does not move on.
    DriverSilent,
}

impl TripReason {
    /// A fault of the arm's own sensors or driver: it lasts until the readings are sound
    /// again, and the master's acknowledgement is refused until then.
    pub fn persistent(self) -> bool {
        matches!(
            self,
            TripReason::SensorNonFinite
                | TripReason::SensorSaturated
                | TripReason::SensorFrozen
                | TripReason::DriverSilent
        )
    }

    /// The reason's name (as in the summary's `safety_trips`).
    pub fn name(self) -> &'static str {
        match self {
            TripReason::ForceOverLimit => "force_over_limit",
            TripReason::ForcePeak => "force_peak",
            TripReason::ToolSpeed => "tool_speed",
            TripReason::Workspace => "workspace",
            TripReason::ActuatorPosition => "actuator_position",
            TripReason::ActuatorSpeed => "actuator_speed",
            TripReason::SensorNonFinite => "sensor_non_finite",
            TripReason::SensorSaturated => "sensor_saturated",
            TripReason::SensorFrozen => "sensor_frozen",
            TripReason::DriverSilent => "driver_silent",
        }
    }
}

/// Trips counted by reason (`safety_trips` in the summary).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SafetyTrips {
    /// See [`TripReason::ForceOverLimit`].
    pub force_over_limit: u64,
    /// See [`TripReason::ForcePeak`].
    pub force_peak: u64,
    /// See [`TripReason::ToolSpeed`].
    pub tool_speed: u64,
    /// See [`TripReason::Workspace`].
    pub workspace: u64,
    /// See [`TripReason::ActuatorPosition`].
    pub actuator_position: u64,
    /// See [`TripReason::ActuatorSpeed`].
    pub actuator_speed: u64,
    /// See [`TripReason::SensorNonFinite`].
    pub sensor_non_finite: u64,
    /// See [`TripReason::SensorSaturated`].
    pub sensor_saturated: u64,
    /// See [`TripReason::SensorFrozen`].
    pub sensor_frozen: u64,
    /// See [`TripReason::DriverSilent`].
    pub driver_silent: u64,
}

impl SafetyTrips {
    /// Counts one trip.
    pub fn count(&mut self, r: TripReason) {
        let c = match r {
            TripReason::ForceOverLimit => &mut self.force_over_limit,
            TripReason::ForcePeak => &mut self.force_peak,
            TripReason::ToolSpeed => &mut self.tool_speed,
            TripReason::Workspace => &mut self.workspace,
            TripReason::ActuatorPosition => &mut self.actuator_position,
            TripReason::ActuatorSpeed => &mut self.actuator_speed,
            TripReason::SensorNonFinite => &mut self.sensor_non_finite,
            TripReason::SensorSaturated => &mut self.sensor_saturated,
            TripReason::SensorFrozen => &mut self.sensor_frozen,
            TripReason::DriverSilent => &mut self.driver_silent,
        };
        *c += 1;
    }

    /// The trips counted since `earlier` (an earlier copy of these counters), by reason.
    pub fn since(&self, earlier: &SafetyTrips) -> SafetyTrips {
        let d = |a: u64, b: u64| a.saturating_sub(b);
        SafetyTrips {
            force_over_limit: d(self.force_over_limit, earlier.force_over_limit),
            force_peak: d(self.force_peak, earlier.force_peak),
            tool_speed: d(self.tool_speed, earlier.tool_speed),
            workspace: d(self.workspace, earlier.workspace),
            actuator_position: d(self.actuator_position, earlier.actuator_position),
            actuator_speed: d(self.actuator_speed, earlier.actuator_speed),
            sensor_non_finite: d(self.sensor_non_finite, earlier.sensor_non_finite),
            sensor_saturated: d(self.sensor_saturated, earlier.sensor_saturated),
            sensor_frozen: d(self.sensor_frozen, earlier.sensor_frozen),
            driver_silent: d(self.driver_silent, earlier.driver_silent),
        }
    }

    /// All trips.
    pub fn total(&self) -> u64 {
        self.force_over_limit
            + self.force_peak
            + self.tool_speed
            + self.workspace
            + self.actuator_position
            + self.actuator_speed
            + self.sensor_non_finite
            + self.sensor_saturated
            + self.sensor_frozen
            + self.driver_silent
    }
}

/// The limits the monitor enforces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafetyLimits {
    /// The arm's ratings.
    pub ratings: ArmRatings,
    /// The force limit in effect (the controller's, at most the rating), N.
    pub force_limit_n: f64,
    /// The arm's workspace (the commands' limits; the monitor widens them by the margin).
    pub workspace: Workspace,
}

impl SafetyLimits {
    /// The limits of an arm rated `ratings`, its workspace `workspace`, the controller's
    /// force limit `controller_force_limit_n` (the lower of it and the rating holds).
    pub fn new(ratings: ArmRatings, workspace: Workspace, controller_force_limit_n: f64) -> Self {
        SafetyLimits {
            ratings,
            force_limit_n: controller_force_limit_n.min(ratings.force_limit_n),
            workspace,
        }
    }
}

/// The monitor's state over the cycles.
#[derive(Clone, Debug)]
pub struct SafetyMonitor {
    limits: SafetyLimits,
    /// The workspace widened by the margins.
    outer: Workspace,
    over_cycles: u32,
    last_wrench: Option<[f64; 4]>,
    frozen_cycles: u32,
    last_time_ns: Option<u64>,
    stale_cycles: u32,
    /// The last [`SPEED_WINDOW_CYCLES`] + 1 tool positions and actuator positions (a ring).
    poses: [[f64; 3]; SPEED_WINDOW_CYCLES + 1],
    actuators: [[f64; 4]; SPEED_WINDOW_CYCLES + 1],
    filled: usize,
    next: usize,
    /// The persistent fault seen in the last cycle, if any.
    persistent: Option<TripReason>,
}

impl SafetyMonitor {
    /// A monitor for `limits`.
    pub fn new(limits: SafetyLimits) -> Self {
        let r = &limits.ratings;
        let w = &limits.workspace.limits;
        let m = r.workspace_margin_mm;
        let outer = Workspace {
            params: limits.workspace.params,
            limits: WorkspaceLimits {
                theta_max_rad: w.theta_max_rad + r.workspace_margin_rad,
                min_singular_distance_mm: (w.min_singular_distance_mm - m).max(0.0),
                min_rail_clearance_mm: (w.min_rail_clearance_mm - m).max(0.0),
                stroke_min_mm: w.stroke_min_mm.map(|s| s - m),
                stroke_max_mm: w.stroke_max_mm.map(|s| s + m),
            },
        };
        SafetyMonitor {
            limits,
            outer,
            over_cycles: 0,
            last_wrench: None,
            frozen_cycles: 0,
            last_time_ns: None,
            stale_cycles: 0,
            poses: [[0.0; 3]; SPEED_WINDOW_CYCLES + 1],
            actuators: [[0.0; 4]; SPEED_WINDOW_CYCLES + 1],
            filled: 0,
            next: 0,
            persistent: None,
        }
    }

    /// The limits.
    pub fn limits(&self) -> &SafetyLimits {
        &self.limits
    }

    /// The persistent fault (sensor, driver) of the last cycle checked, if any: the
    /// master's acknowledgement is refused while it lasts.
    pub fn persistent_fault(&self) -> Option<TripReason> {
        self.persistent
    }

    /// Whether the driver's reading time has not moved on for [`DRIVER_STALE_CYCLES`]
    /// cycles; call once per cycle, before [`SafetyMonitor::check`].
    pub fn observe_time(&mut self, reading: &ArmReading) -> bool {
        if self.last_time_ns == Some(reading.time_ns) {
            self.stale_cycles = self.stale_cycles.saturating_add(1);
        } else {
            self.stale_cycles = 0;
        }
        self.last_time_ns = Some(reading.time_ns);
        self.stale_cycles >= DRIVER_STALE_CYCLES
    }

    /// Judges one cycle of `dt_s` seconds: the driver's `reading`, whether it is `silent`
    /// ([`SafetyMonitor::observe_time`]) and the sensed force `force_n` (the reading with
    /// its tare and the tool's weight removed). Returns the first rule broken, in the order
    /// of the module's list (the driver and the sensors first: what they say is not to be
    /// trusted otherwise). The reading's wrench is taken as a new sample of the sensor
    /// ([`SafetyMonitor::check_sample`] otherwise).
    pub fn check(
        &mut self,
        reading: &ArmReading,
        silent: bool,
        force_n: [f64; 3],
        dt_s: f64,
    ) -> Option<TripReason> {
        self.check_sample(reading, true, silent, force_n, dt_s)
    }

    /// [`SafetyMonitor::check`] for a reading whose wrench is a `new_wrench` sample of the
    /// sensor or (false) the previous sample handed out again by a driver whose sensor
    /// samples slower than the loop: only new samples count towards the frozen sensor (a
    /// sensor that sends the same bits in new samples is frozen; one that sends no new
    /// samples is the driver's staleness, [`SafetyMonitor::observe_time`]).
    pub fn check_sample(
        &mut self,
        reading: &ArmReading,
        new_wrench: bool,
        silent: bool,
        force_n: [f64; 3],
        dt_s: f64,
    ) -> Option<TripReason> {
        let r = self.limits.ratings;
        let persistent = self.sensor_fault(reading, new_wrench, silent, &r);
        self.persistent = persistent;
        if persistent.is_some() {
            self.over_cycles = 0;
            self.filled = 0;
            return persistent;
        }
        // The force (the reading is finite here; a compensation that is not is a NaN too).
        let f =
            (force_n[0] * force_n[0] + force_n[1] * force_n[1] + force_n[2] * force_n[2]).sqrt();
        if !f.is_finite() {
            self.persistent = Some(TripReason::SensorNonFinite);
            return self.persistent;
        }
        let limit = self.limits.force_limit_n;
        if f > FORCE_PEAK_SHARE * limit {
            self.over_cycles = 0;
            return Some(TripReason::ForcePeak);
        }
        if f > limit {
            self.over_cycles += 1;
            if self.over_cycles >= FORCE_OVER_CYCLES {
                self.over_cycles = 0;
                return Some(TripReason::ForceOverLimit);
            }
        } else {
            self.over_cycles = 0;
        }
        self.motion(reading, dt_s, &r)
    }

    /// The sensor and driver checks.
    fn sensor_fault(
        &mut self,
        reading: &ArmReading,
        new_wrench: bool,
        silent: bool,
        r: &ArmRatings,
    ) -> Option<TripReason> {
        if silent {
            return Some(TripReason::DriverSilent);
        }
        if !reading
            .wrench
            .iter()
            .chain(&reading.actuators_mm)
            .all(|v| v.is_finite())
        {
            self.last_wrench = None;
            self.frozen_cycles = 0;
            return Some(TripReason::SensorNonFinite);
        }
        if reading.wrench[..3]
            .iter()
            .any(|v| v.abs() >= r.sensor_range_n)
        {
            return Some(TripReason::SensorSaturated);
        }
        if new_wrench {
            let same = self.last_wrench.is_some_and(|w| {
                w.iter()
                    .zip(&reading.wrench)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            });
            self.frozen_cycles = if same { self.frozen_cycles + 1 } else { 0 };
            self.last_wrench = Some(reading.wrench);
        }
        if self.frozen_cycles >= r.sensor_freeze_cycles {
            return Some(TripReason::SensorFrozen);
        }
        None
    }

    /// The pose, stroke and speed checks on the encoders' reading.
    fn motion(&mut self, reading: &ArmReading, dt_s: f64, r: &ArmRatings) -> Option<TripReason> {
        let l = reading.actuators_mm;
        let lim = &self.outer.limits;
        if (0..4).any(|i| l[i] < lim.stroke_min_mm[i] || l[i] > lim.stroke_max_mm[i]) {
            self.filled = 0;
            return Some(TripReason::ActuatorPosition);
        }
        let la = Vector4::from(l);
        let pose: Pose = match self.outer.params.fk(&la) {
            Ok(p) => p,
            Err(_) => {
                self.filled = 0;
                return Some(TripReason::Workspace);
            }
        };
        if self.outer.check(&pose, &la).is_err() {
            self.filled = 0;
            return Some(TripReason::Workspace);
        }
        // The speeds over the window.
        let slot = self.next;
        self.poses[slot] = [pose[0], pose[1], pose[2]];
        self.actuators[slot] = l;
        self.next = (slot + 1) % (SPEED_WINDOW_CYCLES + 1);
        self.filled = (self.filled + 1).min(SPEED_WINDOW_CYCLES + 1);
        if self.filled <= SPEED_WINDOW_CYCLES || dt_s.is_nan() || dt_s <= 0.0 {
            return None;
        }
        // The oldest entry is the one to be overwritten next.
        let old = self.next;
        let window_s = dt_s * SPEED_WINDOW_CYCLES as f64;
        let (p0, p1) = (self.poses[old], self.poses[slot]);
        let d2 = (0..3).map(|i| (p1[i] - p0[i]).powi(2)).sum::<f64>();
        if d2.sqrt() / window_s > r.speed_trip_share * r.max_speed_mm_per_s {
            self.filled = 0;
            return Some(TripReason::ToolSpeed);
        }
        let (a0, a1) = (self.actuators[old], self.actuators[slot]);
        if (0..4).any(|i| (a1[i] - a0[i]).abs() / window_s > r.actuator_speed_max_mm_per_s) {
            self.filled = 0;
            return Some(TripReason::ActuatorSpeed);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use h4_shared::config::ArmConfig;

    fn monitor() -> (SafetyMonitor, ArmReading, Workspace) {
        let arm = ArmConfig::default();
        let ws = arm.workspace();
        let start = Pose::new(0.0, 0.0, -250.0, 0.0);
        let l = ws.ik(&start).expect("start pose");
        let reading = ArmReading {
            time_ns: 0,
            actuators_mm: [l[0], l[1], l[2], l[3]],
            wrench: [0.1, -0.2, 0.3, 1.0],
        };
        (
            SafetyMonitor::new(SafetyLimits::new(arm.ratings, ws, 80.0)),
            reading,
            ws,
        )
    }

    /// Steps the monitor `n` cycles with a reading that moves on and a changing noise.
    fn run(
        m: &mut SafetyMonitor,
        r: &mut ArmReading,
        force: [f64; 3],
        n: usize,
    ) -> Option<TripReason> {
        for _ in 0..n {
            r.time_ns += 1_000_000;
            r.wrench[0] = 0.1 + 1e-3 * ((r.time_ns / 1_000_000) % 7) as f64;
            let silent = m.observe_time(r);
            if let Some(t) = m.check(r, silent, force, 1e-3) {
                return Some(t);
            }
        }
        None
    }

    #[test]
    fn a_sound_arm_at_rest_and_at_the_limit_never_trips() {
        let (mut m, mut r, _) = monitor();
        assert_eq!(run(&mut m, &mut r, [0.0, 0.0, 5.0], 1000), None);
        // Exactly at the limit is within it.
        assert_eq!(run(&mut m, &mut r, [0.0, 0.0, 80.0], 1000), None);
    }

    #[test]
    fn force_above_the_limit_trips_on_the_second_cycle_and_a_peak_at_once() {
        let (mut m, mut r, _) = monitor();
        run(&mut m, &mut r, [0.0, 0.0, 5.0], 10);
        // One cycle above: not yet (the control: a single sample over the limit).
        assert_eq!(run(&mut m, &mut r, [0.0, 0.0, 80.5], 1), None);
        assert_eq!(run(&mut m, &mut r, [0.0, 0.0, 5.0], 1), None);
        assert_eq!(run(&mut m, &mut r, [0.0, 0.0, 80.5], 1), None);
        assert_eq!(
            run(&mut m, &mut r, [0.0, 0.0, 80.5], 1),
            Some(TripReason::ForceOverLimit)
        );
        let (mut m, mut r, _) = monitor();
        assert_eq!(
            run(&mut m, &mut r, [0.0, 96.5, 0.0], 1),
            Some(TripReason::ForcePeak)
        );
        // A lowered limit (a session's 30 N) is the one in effect.
        let arm = ArmConfig::default();
        let mut m = SafetyMonitor::new(SafetyLimits::new(arm.ratings, arm.workspace(), 30.0));
        assert_eq!(
            run(&mut m, &mut r, [0.0, 0.0, 31.0], 2),
            Some(TripReason::ForceOverLimit)
        );
        // ... and a controller limit above the rating does not raise it.
        let mut m = SafetyMonitor::new(SafetyLimits::new(arm.ratings, arm.workspace(), 1000.0));
        assert_eq!(
            run(&mut m, &mut r, [0.0, 0.0, 81.0], 2),
            Some(TripReason::ForceOverLimit)
        );
    }

    #[test]
    fn non_finite_saturated_and_frozen_sensors_trip_and_persist() {
        let (mut m, mut r, _) = monitor();
        run(&mut m, &mut r, [0.0; 3], 10);
        let mut bad = r;
        bad.time_ns += 1_000_000;
        bad.wrench[2] = f64::NAN;
        assert_eq!(
            m.check(&bad, false, [0.0; 3], 1e-3),
            Some(TripReason::SensorNonFinite)
        );
        assert!(m.persistent_fault().is_some_and(TripReason::persistent));
        // A NaN from the compensation (the reading itself finite) is caught as well.
        assert_eq!(
            run(&mut m, &mut r, [f64::NAN, 0.0, 0.0], 1),
            Some(TripReason::SensorNonFinite)
        );
        assert_eq!(run(&mut m, &mut r, [0.0; 3], 10), None);
        assert_eq!(m.persistent_fault(), None);
        let mut sat = r;
        sat.time_ns += 1_000_000;
        sat.wrench[1] = -145.0;
        assert_eq!(
            m.check(&sat, false, [0.0; 3], 1e-3),
            Some(TripReason::SensorSaturated)
        );
        // Frozen: the same reading with fresh times; the second repeat trips.
        let (mut m, mut r, _) = monitor();
        run(&mut m, &mut r, [0.0; 3], 10);
        let mut trips = Vec::new();
        for _ in 0..3 {
            r.time_ns += 1_000_000;
            trips.push(m.check(&r, false, [0.0; 3], 1e-3));
        }
        assert_eq!(
            trips,
            [
                None,
                Some(TripReason::SensorFrozen),
                Some(TripReason::SensorFrozen)
            ]
        );
    }

    /// A sensor sampled slower than the loop (a ROS 2 arm's `measured_cf` at 250 Hz): the
    /// driver hands each sample to four cycles, flagged not new, and the repeats do not
    /// count as frozen while the new samples change. Negative control: the same cadence with
    /// new samples that repeat bit for bit (a truly frozen sensor) trips at the second
    /// repeat of a new sample, as at 1 kHz.
    #[test]
    fn repeats_of_a_slow_sensors_sample_are_not_frozen_but_identical_new_samples_are() {
        let (mut m, mut r, _) = monitor();
        for k in 0..400u32 {
            r.time_ns += 1_000_000;
            let new = k % 4 == 0;
            if new {
                r.wrench[0] = 0.1 + 1e-3 * f64::from((k / 4) % 5);
            }
            assert_eq!(
                m.check_sample(&r, new, false, [0.0; 3], 1e-3),
                None,
                "cycle {k}"
            );
        }
        // The same repeats all called new samples: the old rule, which trips.
        let (mut m, mut r, _) = monitor();
        let mut first = None;
        for k in 0..40u32 {
            r.time_ns += 1_000_000;
            if k % 4 == 0 {
                r.wrench[0] = 0.1 + 1e-3 * f64::from((k / 4) % 5);
            }
            if let Some(t) = m.check_sample(&r, true, false, [0.0; 3], 1e-3) {
                first = Some((k, t));
                break;
            }
        }
        assert_eq!(first, Some((2, TripReason::SensorFrozen)));
        // Frozen: new samples, the same bits; the second repeat trips, the cycles in between
        // (not new) neither trip earlier nor clear it.
        let (mut m, mut r, _) = monitor();
        run(&mut m, &mut r, [0.0; 3], 10);
        let mut trips = Vec::new();
        for k in 0..12u32 {
            r.time_ns += 1_000_000;
            trips.push(m.check_sample(&r, k % 4 == 0, false, [0.0; 3], 1e-3));
        }
        let frozen = Some(TripReason::SensorFrozen);
        assert_eq!(
            trips[..4],
            [None; 4],
            "the first repeat (cycle 0), then not new"
        );
        assert_eq!(
            trips[4..],
            [frozen; 8],
            "the second (cycle 4) trips: {trips:?}"
        );
    }

    #[test]
    fn a_silent_driver_trips() {
        let (mut m, mut r, _) = monitor();
        run(&mut m, &mut r, [0.0; 3], 10);
        let mut out = Vec::new();
        for _ in 0..3 {
            let silent = m.observe_time(&r);
            out.push(m.check(&r, silent, [0.0; 3], 1e-3));
        }
        assert_eq!(
            out,
            [
                None,
                Some(TripReason::DriverSilent),
                Some(TripReason::DriverSilent)
            ]
        );
    }

    #[test]
    fn speed_workspace_and_stroke_trip_and_a_rated_motion_does_not() {
        let (mut m, mut r, ws) = monitor();
        // 100 mm/s along x (the rated speed) for 50 cycles: within 1.5 ×.
        let step = |m: &mut SafetyMonitor, r: &mut ArmReading, x: f64| {
            let l = ws.ik(&Pose::new(x, 0.0, -250.0, 0.0)).expect("pose");
            r.actuators_mm = [l[0], l[1], l[2], l[3]];
            r.time_ns += 1_000_000;
            r.wrench[0] += 1e-3;
            m.check(r, false, [0.0; 3], 1e-3)
        };
        for k in 0..50 {
            assert_eq!(step(&mut m, &mut r, 0.1 * k as f64), None, "cycle {k}");
        }
        // 200 mm/s: trips within the window.
        let mut tripped = None;
        for k in 0..10 {
            tripped = tripped.or(step(&mut m, &mut r, 5.0 + 0.2 * k as f64));
        }
        assert_eq!(tripped, Some(TripReason::ToolSpeed));
        // Out of the workspace by more than the margin: theta beyond 60° + 0.05 rad.
        let (mut m, mut r, _) = monitor();
        let p = Pose::new(0.0, 0.0, -250.0, 1.2);
        let l = ws.params.ik_raw(&p).expect("raw");
        r.actuators_mm = [l[0], l[1], l[2], l[3]];
        assert_eq!(
            run(&mut m, &mut r, [0.0; 3], 1),
            Some(TripReason::Workspace)
        );
        // Within the margin (60° + 0.02 rad): no trip.
        let p = Pose::new(0.0, 0.0, -250.0, 60f64.to_radians() + 0.02);
        let l = ws.params.ik_raw(&p).expect("raw");
        r.actuators_mm = [l[0], l[1], l[2], l[3]];
        let mut m2 = monitor().0;
        assert_eq!(run(&mut m2, &mut r, [0.0; 3], 1), None);
        // An actuator beyond its stroke.
        r.actuators_mm[0] = 700.0;
        assert_eq!(
            run(&mut m2, &mut r, [0.0; 3], 1),
            Some(TripReason::ActuatorPosition)
        );
    }

    #[test]
    fn every_reason_has_a_name_and_persistence() {
        let mut t = SafetyTrips::default();
        t.count(TripReason::ForcePeak);
        t.count(TripReason::SensorFrozen);
        assert_eq!(t.total(), 2);
        assert!(TripReason::SensorFrozen.persistent());
        assert!(!TripReason::ForcePeak.persistent());
        assert_eq!(TripReason::ToolSpeed.name(), "tool_speed");
    }
}
