//! The driver boundary: what the slave controller needs of an arm. A real robot's driver
//! implements [`ArmDriver`] (read the four actuator encoders and the force/torque sensor,
//! write four actuator position set-points); so does the simulation,
//! `h4_slave_sim::plant::SimArm`, and the replay driver, `h4_slave_sim::replay::ReplayArm`.
//! docs/drivers.md says how to add one.

use serde::Serialize;

/// One reading of the arm's sensors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ArmReading {
    /// Time of the reading, ns (the driver's clock: the simulated clock for the simulated
    /// arm). A reading whose time does not move on is not fresh.
    pub time_ns: u64,
    /// Actuator positions from the encoders, mm (carriage positions: they do not see the
    /// structure's deflection).
    pub actuators_mm: [f64; 4],
    /// Wrench on the tool `[Fx_n, Fy_n, Fz_n, My_n_mm]` in the base frame, as the sensor
    /// reports it after its digital low-pass filter (bias not removed).
    pub wrench: [f64; 4],
}

/// What the slave controller needs of an arm: a real robot's driver implements this.
pub trait ArmDriver {
    /// The latest encoder positions and (filtered) force/torque reading.
    fn read(&mut self) -> ArmReading;
    /// New position set-points for the four actuator servos, mm. The driver may refuse
    /// non-finite values (the simulation keeps the previous set-point).
    fn command(&mut self, actuators_mm: &[f64; 4]);
    /// The turntable's angle from its encoder, rad; `None` when the arm has no turntable
    /// (the default).
    fn turntable_rad(&self) -> Option<f64> {
        None
    }
    /// A new angle set-point for the turntable's servo, rad (ignored without a turntable;
    /// the driver may refuse non-finite values).
    fn command_turntable(&mut self, _angle_rad: f64) {}
    /// The spindle drive reports a stall (the cut needs more torque than it has: the spindle
    /// stopped under load); false without a spindle (the default). The slave answers with a
    /// safe stop that the master cannot clear while the stall lasts.
    fn spindle_stalled(&self) -> bool {
        false
    }
    /// `dt_ns` of the arm's own time pass between two reads: a simulated arm integrates its
    /// physics (the server calls this after every cycle, and for the periods a stalled host
    /// missed); a real arm runs on its own (the default: nothing).
    fn advance(&mut self, _dt_ns: u64) {}
    /// Whether the last [`ArmDriver::read`]'s wrench is a new sample of the force/torque
    /// sensor (true, the default: a sensor sampled every cycle) or the previous one handed
    /// out again (a sensor that samples slower than the loop, e.g. a ROS 2 arm's
    /// `measured_cf`). The safety monitor counts a frozen sensor over new samples only.
    fn wrench_is_new_sample(&self) -> bool {
        true
    }
}
