//! The simulated haptic device of `h4-master sim` and `h4-master run --device sim`: the
//! simulated master arm ([`SimMasterArm`]) with the simulated operator's hand on it
//! ([`Operator`]). To the master's endpoint it is one [`HapticDevice`]: the hand acts at the
//! start of every cycle ([`HapticDevice::begin_cycle`]), goes on through a stalled host's
//! missed periods ([`HapticDevice::stalled`]), and its wrench is the device's diagnostics
//! ([`HapticDevice::hand_wrench`]).

use h4_master::device::{DeviceState, HapticDevice};
use h4_shared::kinematics::KinError;

use crate::arm::{MasterArmConfig, SimMasterArm};
use crate::operator::{HandConfig, HandOutput, Operator, Script};

/// Most missed periods [`SimHandDevice::stalled`] replays one by one (10 s at 1 kHz).
pub const MAX_STALL_CATCH_UP_MS: u64 = 10_000;

/// The simulated master arm with the operator's hand on it.
pub struct SimHandDevice {
    arm: SimMasterArm,
    operator: Operator,
    hand: HandOutput,
}

impl SimHandDevice {
    /// The arm of `master` at its home pose, held by a hand of `hand` following `script`.
    pub fn new(
        master: MasterArmConfig,
        hand: HandConfig,
        script: Script,
    ) -> Result<Self, KinError> {
        let arm = SimMasterArm::new(master)?;
        Ok(SimHandDevice {
            arm,
            operator: Operator::new(hand, script, master.home_pose),
            hand: HandOutput::default(),
        })
    }

    /// The simulated master arm.
    pub fn arm(&self) -> &SimMasterArm {
        &self.arm
    }

    /// The simulated master arm, mutable.
    pub fn arm_mut(&mut self) -> &mut SimMasterArm {
        &mut self.arm
    }

    /// The operator.
    pub fn operator(&self) -> &Operator {
        &self.operator
    }

    /// The hand's newest output.
    pub fn hand(&self) -> HandOutput {
        self.hand
    }

    /// The operator's hand alone, for `dt_s` at `now_ns`: it is physics and acts on the
    /// handle's true state, also while the loop itself does not run (a host stall: the
    /// device holds the last wrench written, the hand goes on).
    pub fn hand_step(&mut self, now_ns: u64, dt_s: f64) -> HandOutput {
        let before = self.arm.true_state();
        let hand = self
            .operator
            .step(now_ns as f64 * 1e-9, &before.pose, &before.velocity, dt_s);
        self.arm.set_hand(hand.wrench, hand.clutch);
        self.hand = hand;
        hand
    }
}

impl HapticDevice for SimHandDevice {
    fn read(&mut self) -> DeviceState {
        self.arm.read()
    }

    fn write_wrench(&mut self, wrench: &[f64; 4]) -> [f64; 4] {
        self.arm.write_wrench(wrench)
    }

    fn begin_cycle(&mut self, now_ns: u64, dt_s: f64) {
        self.hand_step(now_ns, dt_s);
    }

    /// The missed periods: the device held the last wrench written while the hand went
    /// on, a period at a time (at most [`MAX_STALL_CATCH_UP_MS`] of them; through a longer
    /// stall's rest the hand's last wrench is held too).
    fn stalled(&mut self, now_ns: u64, period_ns: u64, missed: u64) {
        if missed == 0 {
            return;
        }
        let dt_s = period_ns as f64 * 1e-9;
        let steps = missed.min(MAX_STALL_CATCH_UP_MS);
        let rest = missed - steps;
        if rest > 0 {
            self.arm.advance(rest * period_ns);
        }
        for k in (1..=steps).rev() {
            self.hand_step(now_ns.saturating_sub(k * period_ns), dt_s);
            self.arm.advance(period_ns);
        }
    }

    fn advance(&mut self, dt_ns: u64) {
        self.arm.advance(dt_ns);
    }

    fn hand_wrench(&self) -> Option<[f64; 4]> {
        Some(self.hand.wrench)
    }
}
