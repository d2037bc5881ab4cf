//! The tool's weight and inertia taken off the force sensor's reading, from the identified
//! tool model (`arm.tool`, written by `h4-slave identify`), never from the simulator's
//! values; and the reading turned from the sensor's frame (which turns with θ about y) into
//! the base frame.
//!
//! The sensor carries the tool beyond it: at rest it reads the tool's weight in its own
//! frame, plus its bias; accelerating, it reads `m (g − a)`. The model is the plant's
//! ([`sensor_load`]) with the identified mass, centre of mass and bias, the
//! controller's gravity vector and, for `a`, the commanded acceleration `command_latency_cycles`
//! old (the arm follows the command that much later).

use h4_shared::config::ToolModel;
use nalgebra::Vector4;

use super::params::ControllerParams;

/// Commanded positions kept for the acceleration (latency up to `HISTORY − 3` cycles).
const HISTORY: usize = 16;

/// The compensation's model and the commanded positions of the last cycles.
#[derive(Clone, Copy, Debug)]
pub(super) struct ToolCompensation {
    tool: ToolModel,
    /// Commanded tool positions, newest at `head`, mm.
    x_hist: [[f64; 3]; HISTORY],
    head: usize,
    filled: usize,
}

impl ToolCompensation {
    /// The compensation of `tool` (nothing if it was not identified).
    pub(super) fn new(tool: ToolModel) -> Self {
        ToolCompensation {
            tool,
            x_hist: [[0.0; 3]; HISTORY],
            head: 0,
            filled: 0,
        }
    }

    /// Books this cycle's commanded position (for the acceleration).
    pub(super) fn push_command(&mut self, x_mm: [f64; 3]) {
        self.head = (self.head + 1) % HISTORY;
        self.x_hist[self.head] = x_mm;
        self.filled = (self.filled + 1).min(HISTORY);
    }

    /// The commanded acceleration `lag` cycles ago, mm/s² (0 until the history has it).
    fn accel(&self, lag: usize, dt: f64) -> [f64; 3] {
        let lag = lag.min(HISTORY - 3);
        if self.filled < lag + 3 || dt <= 0.0 {
            return [0.0; 3];
        }
        let at = |back: usize| self.x_hist[(self.head + HISTORY - back) % HISTORY];
        let (a, b, c) = (at(lag), at(lag + 1), at(lag + 2));
        let mut acc = [0.0; 3];
        for i in 0..3 {
            acc[i] = (a[i] - 2.0 * b[i] + c[i]) / (dt * dt);
        }
        acc
    }

    /// The raw reading `raw` (sensor frame) with the identified bias and the tool's weight
    /// and inertia at `theta_rad` taken off (with `gravity_compensation` off: as read). The
    /// inertia only on the force-guided approach (`weight_only` false): in contact the
    /// command moves into the surface, not the tool, and a position-mode command's
    /// accelerations reach the tool through the servos' lag, which the model does not know
    /// (taking them off as commanded left a safe stop's release pressing); there only the
    /// weight is taken off.
    pub(super) fn remove(
        &self,
        raw: Vector4<f64>,
        theta_rad: f64,
        weight_only: bool,
        p: &ControllerParams,
        dt: f64,
    ) -> Vector4<f64> {
        if !(p.gravity_compensation && self.tool.identified) {
            return raw;
        }
        let a = if weight_only {
            [0.0; 3]
        } else {
            self.accel(p.command_latency_cycles as usize, dt)
        };
        let g = p.gravity_mm_per_s2;
        let load = sensor_load(
            &Vector4::zeros(),
            theta_rad,
            self.tool.mass_kg,
            self.tool.com_mm,
            [g[0] - a[0], g[1] - a[1], g[2] - a[2]],
        );
        let b = self.tool.sensor_bias_n;
        raw - load - Vector4::new(b[0], b[1], b[2], self.tool.sensor_bias_n_mm)
    }
}

/// The sensor-frame wrench `w` in the base frame (the sensor turned by `theta_rad` about y).
pub(super) fn to_base(w: Vector4<f64>, theta_rad: f64) -> Vector4<f64> {
    let (s, c) = theta_rad.sin_cos();
    Vector4::new(c * w[0] + s * w[2], w[1], -s * w[0] + c * w[2], w[3])
}

/// The load on the force sensor `[Fx, Fy, Fz, My]` in its frame (turned by `theta_rad` about
/// y from the base frame): the contact wrench `contact` (base frame) plus a payload of
/// `mass_kg` at `com_mm` (sensor frame) under `g_minus_a_mm_per_s2` (gravity minus the
/// platform's acceleration, base frame). The same model the controller's compensation and
/// `h4-slave identify` fit.
pub fn sensor_load(
    contact: &Vector4<f64>,
    theta_rad: f64,
    mass_kg: f64,
    com_mm: [f64; 3],
    g_minus_a_mm_per_s2: [f64; 3],
) -> Vector4<f64> {
    let (s, c) = theta_rad.sin_cos();
    let m = mass_kg * 1e-3;
    let fb = [
        contact[0] + m * g_minus_a_mm_per_s2[0],
        contact[1] + m * g_minus_a_mm_per_s2[1],
        contact[2] + m * g_minus_a_mm_per_s2[2],
    ];
    // The payload's load in the sensor's frame (x and z: My needs no more).
    let px = m * (c * g_minus_a_mm_per_s2[0] - s * g_minus_a_mm_per_s2[2]);
    let pz = m * (s * g_minus_a_mm_per_s2[0] + c * g_minus_a_mm_per_s2[2]);
    Vector4::new(
        c * fb[0] - s * fb[2],
        fb[1],
        s * fb[0] + c * fb[2],
        contact[3] + com_mm[2] * px - com_mm[0] * pz,
    )
}
