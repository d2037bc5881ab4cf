//! A simulated H-4 family master arm behind the master's [`HapticDevice`] interface
//! ([`SimMasterArm`]).
//!
//! The simulated master is a smaller H-4 arm (its own [`H4Params`]) used as a desktop haptic
//! device: four carriages with mass and Coulomb + viscous friction drive the handle (the
//! platform, with its own mass and rotational inertia) through the legs. A wrench written to
//! the device is produced by the four motors as `τ = J⁻ᵀ F` (so the handle feels `Jᵀ τ = F`);
//! when one motor would exceed its force limit, the whole wrench is scaled down (its
//! direction kept, which keeps the saturation passive). The dynamics are integrated in the
//! task space, `M(x) ẍ = F_hand + Jᵀ(τ − τ_friction) − b ẋ` with `M = M_platform + Jᵀ M_c J`,
//! at `substeps` per 1 ms step. Units: mm, rad, N, N·mm, kg, s.

use h4_master::device::{DeviceState, HapticDevice, PrincipalMasses};
use h4_shared::config::{ConfigError, Section, check_range};
use h4_shared::kinematics::{H4Params, KinError, Pose};
use nalgebra::{Matrix4, Vector4};
use serde::{Deserialize, Serialize};

/// Parameters of the simulated master arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MasterArmConfig {
    /// Geometry of the master arm (an H-4 family arm), mm.
    pub geometry: H4Params,
    /// Handle pose at start `[x_mm, y_mm, z_mm, theta_rad]`.
    pub home_pose: [f64; 4],
    /// Moving mass of each carriage, kg.
    pub carriage_mass_kg: f64,
    /// Mass of the platform with the handle, kg.
    pub handle_mass_kg: f64,
    /// Rotational inertia of the platform about y, kg·mm².
    pub handle_inertia_kg_mm2: f64,
    /// Coulomb friction of each carriage, N.
    pub coulomb_friction_n: f64,
    /// Viscous friction of each carriage, N·s/mm.
    pub viscous_friction_n_s_per_mm: f64,
    /// Speed below which Coulomb friction is regularised (linear), mm/s.
    pub friction_velocity_mm_per_s: f64,
    /// Largest force of each motor, N.
    pub motor_force_max_n: f64,
    /// Integration substeps per 1 ms step.
    pub substeps: u32,
    /// Resolution of the handle's position encoders, mm (task space; 0: exact). The
    /// coupling sees only quantised positions.
    pub encoder_resolution_mm: f64,
    /// Cut-off of the first-order low-pass on the backward difference of the quantised
    /// positions that estimates the handle's velocity, Hz (0: the raw difference).
    pub velocity_filter_hz: f64,
    /// The handle's mass as the coupling knows it, as a share of the simulator's (a real
    /// device's mass is a datasheet figure, not exact; < 1 is the conservative side for
    /// the passivity controller's per-cycle bounds).
    pub mass_estimate_factor: f64,
}

impl Default for MasterArmConfig {
    fn default() -> Self {
        MasterArmConfig {
            geometry: H4Params::ALT,
            home_pose: [0.0, 0.0, -220.0, 0.0],
            carriage_mass_kg: 0.15,
            handle_mass_kg: 0.2,
            handle_inertia_kg_mm2: 200.0,
            coulomb_friction_n: 0.2,
            viscous_friction_n_s_per_mm: 0.002,
            friction_velocity_mm_per_s: 2.0,
            motor_force_max_n: 12.0,
            substeps: 10,
            encoder_resolution_mm: 0.002,
            velocity_filter_hz: 50.0,
            mass_estimate_factor: 0.8,
        }
    }
}

impl Section for MasterArmConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        if h4_shared::config::recording() {
            for (_, field, requirement) in H4Params::RULES {
                h4_shared::config::record_rule(&f(&format!("geometry.{field}")), requirement);
            }
        }
        self.geometry
            .validate()
            .map_err(|e| ConfigError::OutOfRange {
                field: f("geometry"),
                value: String::new(),
                allowed: e.to_string(),
            })?;
        for (i, v) in self.home_pose.iter().enumerate() {
            check_range(&f(&format!("home_pose[{i}]")), *v, -1e3, 1e3, "mm / rad")?;
        }
        check_range(
            &f("carriage_mass_kg"),
            self.carriage_mass_kg,
            0.001,
            100.0,
            "kg",
        )?;
        check_range(
            &f("handle_mass_kg"),
            self.handle_mass_kg,
            0.001,
            100.0,
            "kg",
        )?;
        check_range(
            &f("handle_inertia_kg_mm2"),
            self.handle_inertia_kg_mm2,
            0.1,
            1e6,
            "kg·mm²",
        )?;
        check_range(
            &f("coulomb_friction_n"),
            self.coulomb_friction_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            &f("viscous_friction_n_s_per_mm"),
            self.viscous_friction_n_s_per_mm,
            0.0,
            10.0,
            "N·s/mm",
        )?;
        check_range(
            &f("friction_velocity_mm_per_s"),
            self.friction_velocity_mm_per_s,
            0.01,
            100.0,
            "mm/s",
        )?;
        check_range(
            &f("motor_force_max_n"),
            self.motor_force_max_n,
            0.0,
            1e3,
            "N",
        )?;
        check_range(&f("substeps"), f64::from(self.substeps), 1.0, 1000.0, "")?;
        check_range(
            &f("encoder_resolution_mm"),
            self.encoder_resolution_mm,
            0.0,
            1.0,
            "mm",
        )?;
        check_range(
            &f("velocity_filter_hz"),
            self.velocity_filter_hz,
            0.0,
            1e4,
            "Hz",
        )?;
        check_range(
            &f("mass_estimate_factor"),
            self.mass_estimate_factor,
            0.1,
            10.0,
            "",
        )
    }
}

/// The simulated master arm.
#[derive(Clone, Debug)]
pub struct SimMasterArm {
    cfg: MasterArmConfig,
    time_ns: u64,
    pose: Pose,
    vel: Pose,
    jac: Matrix4<f64>,
    motor_n: Vector4<f64>,
    hand_wrench: Vector4<f64>,
    clutch: bool,
    kinematics_faults: u64,
    principal_masses: PrincipalMasses,
    /// The encoders' reading (quantised pose) and the velocity estimated from it.
    sensed_pose: [f64; 4],
    sensed_vel: [f64; 4],
}

/// The longest step of the simulated device's physics and electronics, ns.
const STEP_NS: u64 = 1_000_000;

/// `x` quantised to `res` (0: exact).
fn quantise(x: f64, res: f64) -> f64 {
    if res > 0.0 {
        (x / res).round() * res
    } else {
        x
    }
}

/// The task-space mass matrix `M = M_platform + Jᵀ M_c J`, in N·s²/mm (kg × 1e-3).
fn mass_matrix(c: &MasterArmConfig, j: &Matrix4<f64>) -> Matrix4<f64> {
    let mc = c.carriage_mass_kg * 1e-3;
    let mp = c.handle_mass_kg * 1e-3;
    let ip = c.handle_inertia_kg_mm2 * 1e-3;
    Matrix4::from_diagonal(&Vector4::new(mp, mp, mp, ip)) + j.transpose() * j * mc
}

/// The principal effective translational masses from `M⁻¹` (unknown, 0, if not
/// computable).
fn principal_masses(inv_mass: &Matrix4<f64>) -> PrincipalMasses {
    PrincipalMasses::from_inverse_mass(inv_mass).unwrap_or_default()
}

impl SimMasterArm {
    /// A master arm at rest at its home pose.
    pub fn new(cfg: MasterArmConfig) -> Result<Self, KinError> {
        cfg.geometry.validate()?;
        let pose = Pose::from(cfg.home_pose);
        let jac = cfg.geometry.jacobian(&pose)?;
        cfg.geometry.ik_checked(&pose)?;
        let principal_masses = mass_matrix(&cfg, &jac)
            .try_inverse()
            .map_or_else(PrincipalMasses::default, |m| principal_masses(&m));
        Ok(SimMasterArm {
            cfg,
            time_ns: 0,
            pose,
            vel: Pose::zeros(),
            jac,
            motor_n: Vector4::zeros(),
            hand_wrench: Vector4::zeros(),
            clutch: false,
            kinematics_faults: 0,
            principal_masses,
            sensed_pose: [0.0; 4],
            sensed_vel: [0.0; 4],
        }
        .sensing_started())
    }

    fn sensing_started(mut self) -> Self {
        let r = self.cfg.encoder_resolution_mm;
        for i in 0..4 {
            let res = if i < 3 { r } else { 0.0 };
            self.sensed_pose[i] = quantise(self.pose[i], res);
        }
        self
    }

    /// The handle's true state (the simulator's, for the operator's hand, which is
    /// physics; the coupling reads the device through [`HapticDevice::read`]).
    pub fn true_state(&self) -> DeviceState {
        DeviceState {
            time_ns: self.time_ns,
            pose: [self.pose[0], self.pose[1], self.pose[2], self.pose[3]],
            velocity: [self.vel[0], self.vel[1], self.vel[2], self.vel[3]],
            clutch: self.clutch,
            effective_mass_kg: self.principal_masses.mass_kg[0],
            principal_masses: self.principal_masses,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MasterArmConfig {
        &self.cfg
    }

    /// The operator's hand: the wrench it applies to the handle and whether it holds the
    /// clutch button.
    pub fn set_hand(&mut self, wrench: [f64; 4], clutch: bool) {
        if wrench.iter().all(|w| w.is_finite()) {
            self.hand_wrench = Vector4::from(wrench);
        }
        self.clutch = clutch;
    }

    /// The motors' forces, N.
    pub fn motor_forces_n(&self) -> [f64; 4] {
        [
            self.motor_n[0],
            self.motor_n[1],
            self.motor_n[2],
            self.motor_n[3],
        ]
    }

    /// Re-linearisations that failed (the pose left the kinematics' domain).
    pub fn kinematics_faults(&self) -> u64 {
        self.kinematics_faults
    }

    /// Advances the physics by `dt_ns`, in steps of at most 1 ms (each with `substeps`
    /// integration steps, a re-linearisation and an encoder reading, as the device's own
    /// electronics run whatever the host does): a host that stalled for 30 ms moves the
    /// handle through 30 such steps with the last force written held.
    pub fn advance(&mut self, dt_ns: u64) {
        let mut left = dt_ns;
        while left > 0 {
            let step = left.min(STEP_NS);
            self.advance_step(step);
            left -= step;
        }
    }

    /// One step of at most 1 ms.
    fn advance_step(&mut self, dt_ns: u64) {
        if let Ok(j) = self.cfg.geometry.jacobian(&self.pose) {
            self.jac = j;
        } else {
            self.kinematics_faults += 1;
        }
        let j = self.jac;
        let c = &self.cfg;
        let Some(inv_mass) = mass_matrix(c, &j).try_inverse() else {
            self.kinematics_faults += 1;
            return;
        };
        self.principal_masses = principal_masses(&inv_mass);
        let motor = j.transpose() * self.motor_n;
        let n = c.substeps.max(1);
        let dt = dt_ns as f64 * 1e-9 / f64::from(n);
        let inv_v0 = 1.0 / c.friction_velocity_mm_per_s.max(1e-6);
        for _ in 0..n {
            let ld = j * self.vel;
            let fr = ld.map(|v| {
                c.coulomb_friction_n * (v * inv_v0).clamp(-1.0, 1.0)
                    + c.viscous_friction_n_s_per_mm * v
            });
            let gen_f = self.hand_wrench + motor - j.transpose() * fr;
            self.vel += inv_mass * gen_f * dt;
            self.pose += self.vel * dt;
        }
        self.time_ns += dt_ns;
        self.sense(dt_ns as f64 * 1e-9);
    }

    /// The encoders read the new pose (quantised); the velocity estimate is the backward
    /// difference of two readings through a first-order low-pass (`velocity_filter_hz`):
    /// one reading per cycle, no knowledge of the true velocity.
    fn sense(&mut self, dt_s: f64) {
        if dt_s <= 0.0 {
            return;
        }
        let r = self.cfg.encoder_resolution_mm;
        let hz = self.cfg.velocity_filter_hz;
        let a = if hz > 0.0 {
            1.0 - (-2.0 * std::f64::consts::PI * hz * dt_s).exp()
        } else {
            1.0
        };
        for i in 0..4 {
            let res = if i < 3 { r } else { 0.0 };
            let q = quantise(self.pose[i], res);
            let raw = (q - self.sensed_pose[i]) / dt_s;
            self.sensed_pose[i] = q;
            self.sensed_vel[i] += a * (raw - self.sensed_vel[i]);
        }
    }
}

impl HapticDevice for SimMasterArm {
    fn advance(&mut self, dt_ns: u64) {
        SimMasterArm::advance(self, dt_ns);
    }
    /// What a real device gives: the encoders' quantised pose, the velocity estimated
    /// from them, and the mass as the datasheet knows it (`mass_estimate_factor` of the
    /// simulator's).
    fn read(&mut self) -> DeviceState {
        DeviceState {
            time_ns: self.time_ns,
            pose: self.sensed_pose,
            velocity: self.sensed_vel,
            clutch: self.clutch,
            effective_mass_kg: self.principal_masses.mass_kg[0] * self.cfg.mass_estimate_factor,
            principal_masses: self.principal_masses.scaled(self.cfg.mass_estimate_factor),
        }
    }

    fn write_wrench(&mut self, wrench: &[f64; 4]) -> [f64; 4] {
        if !wrench.iter().all(|w| w.is_finite()) {
            self.motor_n = Vector4::zeros();
            return [0.0; 4];
        }
        let Ok(inv) = self.cfg.geometry.jacobian_inverse(&self.pose) else {
            self.motor_n = Vector4::zeros();
            return [0.0; 4];
        };
        let f = Vector4::from(*wrench);
        let tau = inv.transpose() * f;
        let peak = tau.amax();
        let scale = if peak > self.cfg.motor_force_max_n {
            self.cfg.motor_force_max_n / peak
        } else {
            1.0
        };
        self.motor_n = tau * scale;
        let out = f * scale;
        [out[0], out[1], out[2], out[3]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rendered_force_moves_a_free_handle_and_saturates_keeping_direction() {
        let mut arm = SimMasterArm::new(MasterArmConfig::default()).unwrap();
        let out = arm.write_wrench(&[0.0, 0.0, 5.0, 0.0]);
        assert_eq!(out, [0.0, 0.0, 5.0, 0.0]);
        for _ in 0..50 {
            arm.advance(1_000_000);
        }
        let s = arm.read();
        assert!(s.velocity[2] > 10.0, "{s:?}");
        assert!(s.pose[0].abs() < 1e-6, "{s:?}");
        let big = arm.write_wrench(&[300.0, 0.0, 600.0, 0.0]);
        assert!(
            big[2] < 600.0 && (big[0] / big[2] - 0.5).abs() < 1e-9,
            "{big:?}"
        );
        assert!(arm.motor_forces_n().iter().all(|t| t.abs() <= 12.0 + 1e-9));
    }

    /// The principal masses are ascending, their directions orthonormal, and the force
    /// `M a` along each direction gives that direction's acceleration (the masses are
    /// the handle's, not a label).
    #[test]
    fn principal_masses_are_the_handles_along_orthonormal_directions() {
        let pm = SimMasterArm::new(MasterArmConfig::default())
            .unwrap()
            .true_state()
            .principal_masses;
        // The shipped arm: lightest sideways (y), heaviest along the platform's axis.
        assert!(
            pm.axes[0][1].abs() > 0.99 && pm.axes[2][2].abs() > 0.99,
            "{pm:?}"
        );
        assert!(
            pm.mass_kg[0] > 0.0 && pm.mass_kg[0] <= pm.mass_kg[1] && pm.mass_kg[1] <= pm.mass_kg[2]
        );
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| pm.axes[i][k] * pm.axes[j][k]).sum();
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((d - want).abs() < 1e-9, "{pm:?}");
            }
        }
        // A 1 N push along each direction, from rest, without friction's share: the
        // velocity after 1 ms is 1 N / m along it.
        let cfg = MasterArmConfig {
            coulomb_friction_n: 0.0,
            viscous_friction_n_s_per_mm: 0.0,
            ..MasterArmConfig::default()
        };
        for (a, m) in pm.axes.iter().zip(pm.mass_kg.iter()) {
            let mut arm = SimMasterArm::new(cfg).unwrap();
            arm.set_hand([a[0], a[1], a[2], 0.0], false);
            arm.advance(1_000_000);
            let v = arm.true_state().velocity;
            let along = v[0] * a[0] + v[1] * a[1] + v[2] * a[2];
            // mm/s = N / kg · s · 1e3
            let want = 1.0 / m * 1e-3 * 1e3;
            assert!((along - want).abs() < 0.02 * want, "{along} vs {want}");
        }
    }

    /// A stalled host: the device keeps its 1 ms steps (its own electronics), so a 30 ms
    /// advance is thirty 1 ms steps, not one coarse one.
    #[test]
    fn a_long_advance_is_the_same_as_one_millisecond_steps() {
        let mut one = SimMasterArm::new(MasterArmConfig::default()).unwrap();
        let mut many = one.clone();
        for a in [&mut one, &mut many] {
            a.set_hand([0.5, -0.3, 2.0, 0.0], false);
            a.write_wrench(&[0.0, 1.0, -1.0, 0.0]);
        }
        one.advance(30_000_000);
        for _ in 0..30 {
            many.advance(1_000_000);
        }
        assert_eq!(one.true_state(), many.true_state());
        assert_eq!(one.read(), many.read());
    }

    #[test]
    fn friction_stops_the_handle() {
        let mut arm = SimMasterArm::new(MasterArmConfig::default()).unwrap();
        arm.set_hand([0.0, 0.0, 3.0, 0.0], false);
        for _ in 0..20 {
            arm.advance(1_000_000);
        }
        arm.set_hand([0.0; 4], false);
        for _ in 0..500 {
            arm.advance(1_000_000);
        }
        assert!(arm.read().velocity[2].abs() < 0.5, "{:?}", arm.read());
    }
}
