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
        }
    }

    /// Out of force control: neither in contact nor re-approaching.
    pub(super) fn leave(&mut self) {
        self.in_contact = false;
        self.lost = false;
    }

    /// While approaching: whether the force magnitude `f_mag` makes this cycle the touch.
    /// Contact: the force crosses the threshold, or it has stayed above 3/8 of it for a few
    /// cycles in a row (a soft surface, on which the force builds up slowly: 0.8 N takes
    /// ≈ 80 ms of the approach on 5 N/mm). A stiff surface crosses the threshold itself
    /// within a cycle or two. On a touch the state is in contact, its counters restarted.
    pub(super) fn touches(&mut self, f_mag: f64, threshold_n: f64) -> bool {
        if f_mag > CONTACT_ONSET_FRACTION * threshold_n {
            self.onset_cycles = self.onset_cycles.saturating_add(1);
        } else {
            self.onset_cycles = 0;
        }
        if f_mag > threshold_n || self.onset_cycles >= CONTACT_ONSET_CYCLES {
            self.onset_cycles = 0;
            self.in_contact = true;
            self.lost = false;
            self.below_cycles = 0;
            self.contact_cycles = 0;
            true
        } else {
            false
        }
    }

    /// One approach step from `next` at the approach speed: towards the commanded point
    /// `target`, or (after a loss) along the last `normal`. Returns the state to report.
    pub(super) fn approach(
        &self,
        next: &mut Pose,
        target: &[f64; 4],
        normal: &Vector3<f64>,
        p: &ControllerParams,
        dt: f64,
    ) -> Status {
        let step = p.approach_speed_mm_per_s * dt;
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
