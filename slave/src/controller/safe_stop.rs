//! The safe stop a watchdog asks for: in contact the arm stops moving and holds its force
//! set-point for `safe_stop_hold_s` (a link that comes back within it re-pairs with the
//! tool still on the surface), then ramps the set-point to zero (still force-guided),
//! retracts along the contact normal and holds; pressed into
//! something in position mode, it first backs away along the measured force.

use h4_shared::kinematics::Pose;
use h4_shared::wire::Mode;
use nalgebra::Vector3;

use super::interface::{SlaveCommand, Status};
use super::params::ControllerParams;

#[derive(Clone, Copy, Debug, PartialEq)]
enum SafeStopPhase {
    Inactive,
    /// In contact: the set-point `from_n` held for `hold_s`, then ramped to zero over
    /// `remaining_s`.
    RampDown {
        hold_s: f64,
        remaining_s: f64,
        from_n: f64,
    },
    Retract {
        remaining_mm: f64,
    },
    /// Pressed against something without force control (position mode): back away along
    /// the measured force until it falls below the contact threshold.
    Release {
        moved_mm: f64,
    },
    Done,
}

/// The phase of the safe stop.
#[derive(Clone, Copy, Debug)]
pub(super) struct SafeStop {
    phase: SafeStopPhase,
}

/// What the safe stop does with this cycle.
pub(super) enum SafeStopStep {
    /// No safe stop: the command as given.
    Inactive,
    /// Ramping the force down: this force-guided command instead of the one given.
    RampDown(SlaveCommand),
    /// Retracting, releasing or holding: the command moves to `next`, out of contact.
    Move {
        /// The next commanded pose.
        next: Pose,
        /// The state to report.
        status: Status,
    },
}

impl SafeStop {
    /// Not stopping.
    pub(super) fn new() -> Self {
        SafeStop {
            phase: SafeStopPhase::Inactive,
        }
    }

    /// True while a safe stop is in progress or holding.
    pub(super) fn active(&self) -> bool {
        !matches!(self.phase, SafeStopPhase::Inactive)
    }

    /// Starts a safe stop (no effect while one is active): in contact, the set-point ramps
    /// down from `setpoint_n`; otherwise the arm is released in [`SafeStop::step`], where
    /// the measured force is known.
    pub(super) fn start(&mut self, in_contact: bool, setpoint_n: f64, hold_s: f64, ramp_s: f64) {
        self.phase = if in_contact {
            SafeStopPhase::RampDown {
                hold_s,
                remaining_s: ramp_s,
                from_n: setpoint_n,
            }
        } else {
            SafeStopPhase::Release { moved_mm: 0.0 }
        };
    }

    /// True while the safe stop still holds the contact force it started with (its hold,
    /// before the ramp down): the contact can be taken up again as it was.
    pub(super) fn holding_contact(&self) -> bool {
        matches!(self.phase, SafeStopPhase::RampDown { hold_s, .. } if hold_s > 0.0)
    }

    /// True once the safe stop has finished moving and holds.
    pub(super) fn done(&self) -> bool {
        matches!(self.phase, SafeStopPhase::Done)
    }

    /// From the hold, retracts `mm` more along the normal the next steps are given.
    pub(super) fn retract_more(&mut self, mm: f64) {
        if self.done() {
            self.phase = SafeStopPhase::Retract { remaining_mm: mm };
        }
    }

    /// Leaves the safe stop.
    pub(super) fn clear(&mut self) {
        self.phase = SafeStopPhase::Inactive;
    }

    /// One cycle of the safe stop: `cmd` is the command given, `x_cmd` the commanded pose,
    /// `normal` the contact normal (a release turns it to the measured force `f3`).
    pub(super) fn step(
        &mut self,
        cmd: &SlaveCommand,
        x_cmd: &Pose,
        normal: &mut Vector3<f64>,
        f3: Vector3<f64>,
        p: &ControllerParams,
        dt: f64,
    ) -> SafeStopStep {
        match self.phase {
            SafeStopPhase::Inactive => SafeStopStep::Inactive,
            // Contact lost while ramping down: nothing is left to ramp, and force control
            // without contact would approach the surface again. Hold where the tool is
            // (already off the surface; a retract along a normal estimated before the loss
            // could point into it).
            SafeStopPhase::RampDown { .. } if f3.norm() < p.contact_threshold_n => {
                self.phase = SafeStopPhase::Done;
                SafeStopStep::Move {
                    next: *x_cmd,
                    status: Status::Holding,
                }
            }
            SafeStopPhase::RampDown {
                hold_s,
                remaining_s,
                from_n,
            } => {
                let holding = hold_s > 0.0;
                let rem = if holding {
                    remaining_s
                } else {
                    remaining_s - dt
                };
                let frac = (rem / p.safe_stop_ramp_s.max(1e-6)).clamp(0.0, 1.0);
                let mut eff = *cmd;
                eff.mode = Mode::ForceGuided;
                eff.force_setpoint_n = from_n * frac;
                eff.velocity = [0.0; 4];
                eff.pose = [x_cmd[0], x_cmd[1], x_cmd[2], x_cmd[3]];
                eff.clutch = false;
                self.phase = if !holding && rem <= 0.0 {
                    SafeStopPhase::Retract {
                        remaining_mm: p.safe_stop_retract_mm,
                    }
                } else {
                    SafeStopPhase::RampDown {
                        hold_s: hold_s - dt,
                        remaining_s: rem,
                        from_n,
                    }
                };
                SafeStopStep::RampDown(eff)
            }
            SafeStopPhase::Retract { remaining_mm } => {
                let step = (p.approach_speed_mm_per_s * 2.0 * dt).min(remaining_mm);
                let n = if normal.norm() > 0.5 {
                    *normal
                } else {
                    Vector3::z()
                };
                let mut next = *x_cmd;
                for i in 0..3 {
                    next[i] += n[i] * step;
                }
                let rem = remaining_mm - step;
                self.phase = if rem <= 1e-9 {
                    SafeStopPhase::Done
                } else {
                    SafeStopPhase::Retract { remaining_mm: rem }
                };
                SafeStopStep::Move {
                    next,
                    status: Status::SafeStop,
                }
            }
            SafeStopPhase::Release { moved_mm } => {
                let mut next = *x_cmd;
                let status = self.release(moved_mm, &mut next, normal, f3, p, dt);
                SafeStopStep::Move { next, status }
            }
            SafeStopPhase::Done => SafeStopStep::Move {
                next: *x_cmd,
                status: Status::Holding,
            },
        }
    }

    /// The release phase, `moved_mm` along the force so far: back away while the force is
    /// above the contact threshold (at most `safe_stop_release_max_mm`), then retract.
    fn release(
        &mut self,
        moved_mm: f64,
        next: &mut Pose,
        normal: &mut Vector3<f64>,
        f3: Vector3<f64>,
        p: &ControllerParams,
        dt: f64,
    ) -> Status {
        let f_mag = f3.norm();
        if f_mag > p.contact_threshold_n && moved_mm < p.safe_stop_release_max_mm {
            // Back away along the measured force, as fast as a retract.
            let step = p.approach_speed_mm_per_s * 2.0 * dt;
            *normal = f3 / f_mag;
            for i in 0..3 {
                next[i] += normal[i] * step;
            }
            self.phase = SafeStopPhase::Release {
                moved_mm: moved_mm + step,
            };
            Status::SafeStop
        } else if moved_mm > 0.0 {
            // Free: the usual retract along the last force direction, then hold.
            self.phase = SafeStopPhase::Retract {
                remaining_mm: p.safe_stop_retract_mm,
            };
            Status::SafeStop
        } else {
            self.phase = SafeStopPhase::Done;
            Status::Holding
        }
    }
}
