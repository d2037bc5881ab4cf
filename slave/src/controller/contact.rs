//! Contact in force-guided mode: the approach towards the commanded point (or, after a
//! loss, along the last normal), the touch that starts the force loop, and the loss of
//! contact.

use h4_shared::kinematics::Pose;
use nalgebra::Vector3;

use super::interface::Status;
use super::params::ControllerParams;

/// Share of `contact_threshold_n` that counts as contact when the force stays above it
/// for [`CONTACT_ONSET_CYCLES`] cycles (0.3 N at the default: ≈ 7 × the standard deviation
/// of the filtered sensor noise per axis).
const CONTACT_ONSET_FRACTION: f64 = 0.375;
/// Consecutive cycles above the onset level that count as contact.
const CONTACT_ONSET_CYCLES: u32 = 3;
/// Acceleration of the approach from rest, mm/s²: a velocity step would shake the tool
/// (0.6 kg × 2 mm/s in one 1 ms cycle: 1.2 N on the sensor, a false touch); at this rate the
/// tool's inertia shows ≈ 0.03 N and the default 2 mm/s are reached in 40 ms.
const APPROACH_ACCEL_MM_PER_S2: f64 = 50.0;

/// Whether the tool is in contact, and the counters that decide it.
#[derive(Clone, Copy, Debug)]
pub(super) struct ContactState {
    /// In contact: the force loop runs.
    pub(super) in_contact: bool,
    /// Contact was lost: re-approaching along the last normal.
    pub(super) lost: bool,
    /// Consecutive cycles with the normal force below `contact_lost_n`.
    below_cycles: u32,
    /// Consecutive approach cycles with the force above [`CONTACT_ONSET_FRACTION`] of the
    /// contact threshold.
    onset_cycles: u32,
    /// Cycles since the touch.
    pub(super) contact_cycles: u32,
    /// The approach's current speed (ramped up from rest), mm/s.
    approach_speed_mm_per_s: f64,
}

impl ContactState {
    /// Free, never touched.
    pub(super) fn new() -> Self {
        ContactState {
            in_contact: false,
            lost: false,
            below_cycles: 0,
            onset_cycles: 0,
            contact_cycles: 0,
            approach_speed_mm_per_s: 0.0,
        }
    }

    /// Out of force control: neither in contact nor re-approaching.
    pub(super) fn leave(&mut self) {
        self.in_contact = false;
        self.lost = false;
        self.approach_speed_mm_per_s = 0.0;
    }

    /// While approaching: whether the force against the approach, `f_push` (the force
    /// along the opposite of the motion), makes this cycle the touch, `noise_n` being the
    /// standard deviation of the sensor's noise along it (measured while taring). Contact:
    /// the force crosses the threshold (at least `noise_sigmas` × the noise), or it has
    /// stayed above 3/8 of it (at least 5/8 of `noise_sigmas` × the noise) for a few cycles
    /// in a row (a soft surface, on which the force builds up slowly: 0.8 N takes ≈ 80 ms
    /// of the approach on 5 N/mm). A stiff surface crosses the threshold itself within a
    /// cycle or two. Only the force against the motion counts: the noise of the two other
    /// axes cannot add to it. On a touch the state is in contact, its counters restarted.
    pub(super) fn touches(
        &mut self,
        f_push: f64,
        threshold_n: f64,
        noise_n: f64,
        noise_sigmas: f64,
    ) -> bool {
        let level = threshold_n.max(noise_sigmas * noise_n);
        let onset = (CONTACT_ONSET_FRACTION * threshold_n).max(0.625 * noise_sigmas * noise_n);
        if f_push > onset {
            self.onset_cycles = self.onset_cycles.saturating_add(1);
        } else {
            self.onset_cycles = 0;
        }
        if f_push > level || self.onset_cycles >= CONTACT_ONSET_CYCLES {
            self.onset_cycles = 0;
            self.approach_speed_mm_per_s = 0.0;
            self.in_contact = true;
            self.lost = false;
            self.below_cycles = 0;
            self.contact_cycles = 0;
            true
        } else {
            false
        }
    }

    /// The unit direction of the next approach step from `next`: towards `target`, or
    /// (after a loss) along the opposite of the last `normal`; zero at the target.
    pub(super) fn approach_direction(
        &self,
        next: &Pose,
        target: &[f64; 4],
        normal: &Vector3<f64>,
    ) -> Vector3<f64> {
        if self.lost && normal.norm() > 0.5 {
            return -normal.normalize();
        }
        let d = Vector3::new(
            target[0] - next[0],
            target[1] - next[1],
            target[2] - next[2],
        );
        let dn = d.norm();
        if dn > 1e-9 { d / dn } else { Vector3::zeros() }
    }

    /// One approach step from `next` at the approach speed: towards the commanded point
    /// `target`, or (after a loss) along the last `normal`. Returns the state to report.
    pub(super) fn approach(
        &mut self,
        next: &mut Pose,
        target: &[f64; 4],
        normal: &Vector3<f64>,
        p: &ControllerParams,
        dt: f64,
    ) -> Status {
        self.approach_speed_mm_per_s = (self.approach_speed_mm_per_s
            + APPROACH_ACCEL_MM_PER_S2 * dt)
            .min(p.approach_speed_mm_per_s);
        let step = self.approach_speed_mm_per_s * dt;
        let mv = if self.lost && normal.norm() > 0.5 {
            -normal * step
        } else {
            let d = Vector3::new(
                target[0] - next[0],
                target[1] - next[1],
                target[2] - next[2],
            );
            let dn = d.norm();
            if dn > 1e-12 {
                d * (step.min(dn) / dn)
            } else {
                Vector3::zeros()
            }
        };
        for i in 0..3 {
            next[i] += mv[i];
        }
        if self.lost {
            Status::ContactLost
        } else {
            Status::Approaching
        }
    }

    /// Counts a cycle in contact.
    pub(super) fn count_cycle(&mut self) {
        self.contact_cycles = self.contact_cycles.saturating_add(1);
    }

    /// Contact loss: the normal force `f_n` stayed below `contact_lost_n` for
    /// `contact_lost_cycles` while the set-point asks for more. Returns whether contact was
    /// lost this cycle.
    pub(super) fn loses(&mut self, f_n: f64, setpoint_n: f64, p: &ControllerParams) -> bool {
        if f_n < p.contact_lost_n && setpoint_n > p.contact_lost_n {
            self.below_cycles += 1;
            if self.below_cycles >= p.contact_lost_cycles {
                self.in_contact = false;
                self.lost = true;
                self.below_cycles = 0;
                return true;
            }
        } else {
            self.below_cycles = 0;
        }
        false
    }
}
