//! Identification of the tool beyond the force sensor (`h4-slave identify`): the arm holds
//! a few poses in free space at different tilts θ about y, the sensor's reading is averaged
//! at each, and a linear least-squares fit of the sensor's model
//! ([`crate::plant::sensor_load`] plus a constant bias) gives the tool's mass, its centre of
//! mass (x and z in the sensor's frame; y does not show in `My`) and the sensor's bias.
//!
//! Turning the sensor against gravity is what separates the weight from the bias: at one
//! tilt they add up to one number. Works on any [`ArmDriver`]; the caller lets one control
//! period pass between cycles (`tick`).

use h4_shared::config::ToolModel;
use h4_shared::kinematics::{Pose, Workspace};
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use serde::Serialize;

use h4_slave::arm::ArmDriver;

/// The tilts held, rad (0 twice: the bias's drift over the routine shows in the residual).
pub const IDENTIFY_THETAS_RAD: [f64; 6] = [0.0, 0.5, 0.25, -0.25, -0.5, 0.0];
/// Time to move to the next pose (cosine profile), s.
const MOVE_S: f64 = 0.6;
/// Time to let the arm and the sensor's filter settle, s.
const SETTLE_S: f64 = 0.4;
/// Time the reading is averaged, s.
const AVERAGE_S: f64 = 0.5;

/// Why identification failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// A pose of the routine is outside the workspace.
    #[error("identification pose θ = {theta_rad} rad: {reason}")]
    Pose {
        /// The tilt.
        theta_rad: f64,
        /// The workspace's reason.
        reason: String,
    },
    /// The encoders' pose has no forward kinematics.
    #[error("measured pose: {0}")]
    Measured(String),
    /// The fit is singular (gravity zero or along y: tilting about y does not turn it).
    #[error("the poses do not separate weight and bias (gravity zero or along y?)")]
    Singular,
}

/// The result of an identification.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Identified {
    /// The identified tool (`identified = true`).
    pub tool: ToolModel,
    /// RMS of the force fit's residual, N.
    pub residual_n: f64,
    /// RMS of the moment fit's residual, N·mm.
    pub residual_n_mm: f64,
    /// Poses held.
    pub poses: usize,
    /// Control periods the routine took.
    pub cycles: u64,
}

/// Runs the routine on `arm` from its current pose `start` (the tilts of
/// [`IDENTIFY_THETAS_RAD`] at `start`'s position), `gravity_mm_per_s2` being gravity in the
/// base frame; `tick` lets one period of `dt_s` pass.
pub fn identify<A: ArmDriver>(
    arm: &mut A,
    ws: &Workspace,
    start: Pose,
    gravity_mm_per_s2: [f64; 3],
    dt_s: f64,
    mut tick: impl FnMut(&mut A),
) -> Result<Identified, IdentifyError> {
    let per = |s: f64| (s / dt_s).round().max(1.0) as u64;
    let mut cycles = 0u64;
    let mut from = start;
    let mut samples: Vec<(f64, Vector4<f64>)> = Vec::with_capacity(IDENTIFY_THETAS_RAD.len());
    for &theta in &IDENTIFY_THETAS_RAD {
        let to = Pose::new(start[0], start[1], start[2], theta);
        for pose in [from, to] {
            ws.ik(&pose).map_err(|e| IdentifyError::Pose {
                theta_rad: theta,
                reason: e.to_string(),
            })?;
        }
        let n_move = per(MOVE_S);
        for k in 1..=n_move {
            let s = 0.5 - 0.5 * (std::f64::consts::PI * k as f64 / n_move as f64).cos();
            let pose = from + (to - from) * s;
            if let Ok(l) = ws.ik(&pose) {
                arm.command(&[l[0], l[1], l[2], l[3]]);
            }
            tick(arm);
            cycles += 1;
        }
        for _ in 0..per(SETTLE_S) {
            tick(arm);
            cycles += 1;
        }
        let n_avg = per(AVERAGE_S);
        let (mut sum, mut theta_sum) = (Vector4::zeros(), 0.0);
        for _ in 0..n_avg {
            let r = arm.read();
            let q = Vector4::from(r.actuators_mm);
            let fk = ws
                .params
                .fk(&q)
                .map_err(|e| IdentifyError::Measured(e.to_string()))?;
            theta_sum += fk[3];
            sum += Vector4::from(r.wrench);
            tick(arm);
            cycles += 1;
        }
        samples.push((theta_sum / n_avg as f64, sum / n_avg as f64));
        from = to;
    }
    let mut out = fit(&samples, gravity_mm_per_s2)?;
    out.cycles = cycles;
    Ok(out)
}

/// Gravity per kilogram in the sensor's frame at tilt `theta`, N/kg.
fn gravity_in_sensor(theta: f64, g: [f64; 3]) -> [f64; 3] {
    let (s, c) = theta.sin_cos();
    [
        1e-3 * (c * g[0] - s * g[2]),
        1e-3 * g[1],
        1e-3 * (s * g[0] + c * g[2]),
    ]
}

/// The least-squares fit of the averaged readings `(θ, [Fx, Fy, Fz, My])`: forces
/// `F = m g_s(θ) + b`, moment `My = (m c_z) g_sx − (m c_x) g_sz + b_M`.
pub fn fit(samples: &[(f64, Vector4<f64>)], g: [f64; 3]) -> Result<Identified, IdentifyError> {
    // Forces: unknowns [m, bx, by, bz].
    let mut a4 = Matrix4::zeros();
    let mut y4 = Vector4::zeros();
    // Moment: unknowns [m cz, m cx, bM].
    let mut a3 = Matrix3::zeros();
    let mut y3 = Vector3::zeros();
    for (theta, w) in samples {
        let gs = gravity_in_sensor(*theta, g);
        for axis in 0..3 {
            let mut row = Vector4::zeros();
            row[0] = gs[axis];
            row[1 + axis] = 1.0;
            a4 += row * row.transpose();
            y4 += row * w[axis];
        }
        let row = Vector3::new(gs[0], -gs[2], 1.0);
        a3 += row * row.transpose();
        y3 += row * w[3];
    }
    let x4 = a4.lu().solve(&y4).ok_or(IdentifyError::Singular)?;
    let x3 = a3.lu().solve(&y3).ok_or(IdentifyError::Singular)?;
    let mass = x4[0];
    if !(mass.is_finite() && mass.abs() > 1e-6) {
        return Err(IdentifyError::Singular);
    }
    let (mut r_f, mut r_m) = (0.0, 0.0);
    for (theta, w) in samples {
        let gs = gravity_in_sensor(*theta, g);
        for axis in 0..3 {
            let e = w[axis] - (mass * gs[axis] + x4[1 + axis]);
            r_f += e * e;
        }
        let e = w[3] - (x3[0] * gs[0] - x3[1] * gs[2] + x3[2]);
        r_m += e * e;
    }
    let n = samples.len().max(1) as f64;
    Ok(Identified {
        tool: ToolModel {
            identified: true,
            mass_kg: mass,
            com_mm: [x3[1] / mass, 0.0, x3[0] / mass],
            sensor_bias_n: [x4[1], x4[2], x4[3]],
            sensor_bias_n_mm: x3[2],
        },
        residual_n: (r_f / (3.0 * n)).sqrt(),
        residual_n_mm: (r_m / n).sqrt(),
        poses: samples.len(),
        cycles: 0,
    })
}

/// `text` (an arm file) with its `[tool]` table replaced by `tool` (appended if absent);
/// every other line kept as it was.
pub fn write_tool_section(text: &str, tool: &ToolModel, note: &str) -> String {
    let mut out = String::with_capacity(text.len() + 512);
    let mut skipping = false;
    for line in text.lines() {
        let t = line.trim_start();
        if t.starts_with('[') {
            skipping = t.starts_with("[tool]");
        }
        if !skipping {
            out.push_str(line);
            out.push('\n');
        }
    }
    while out.ends_with("\n\n") {
        out.pop();
    }
    let c = tool.com_mm;
    let b = tool.sensor_bias_n;
    out.push_str(&format!(
        "\n[tool]\n# {note}\nidentified = true\nmass_kg = {:.4}\ncom_mm = [{:.2}, {:.2}, {:.2}]\n\
         sensor_bias_n = [{:.3}, {:.3}, {:.3}]\nsensor_bias_n_mm = {:.2}\n",
        tool.mass_kg, c[0], c[1], c[2], b[0], b[1], b[2], tool.sensor_bias_n_mm
    ));
    out
}
