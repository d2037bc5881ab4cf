//! The arm as the controller sees it ([`ArmDriver`]) and an honest simulation of the H-4
//! prototype behind that interface ([`SimArm`]).
//!
//! A real driver reads the four actuator encoders and the force/torque sensor and writes
//! four actuator position commands; so does the simulation. What the simulation models
//! (every number and its reasoning is in `docs/slave-simulation.md`):
//!
//! * four prismatic carriages, each with mass, Coulomb and viscous friction and a saturated
//!   motor force, under a 20 kHz PID position servo whose set-point is the 1 ms command;
//! * a finite structural stiffness (and a little damping) between each carriage and the
//!   platform, so the platform sits at `FK(q + f/k)`, deflecting under load as `Λ(x) F`
//!   predicts; the platform with its tool has mass and rotational inertia;
//! * penetration-based contact with an unknown [`Surface`] (plane, cylinder or sphere;
//!   Kelvin–Voigt spring–damper with regularised Coulomb friction);
//! * a six-axis force/torque sensor reporting `[Fx, Fy, Fz, My]` with Gaussian noise,
//!   bias, quantisation and a second-order Butterworth low-pass filter.
//!
//! Units: mm, rad, N, N·mm, seconds; masses are given in kg and converted to N·s²/mm.
//! Everything is deterministic from the seed; time advances only through
//! [`SimArm::advance`].

use h4_shared::kinematics::{Actuators, H4Params, Pose};
use h4_shared::rng::Rng;
use h4_shared::vec3::dot3;
use nalgebra::{Matrix4, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::filter::Butterworth2;

/// One reading of the arm's sensors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ArmReading {
    /// Time of the reading, ns (the simulated clock for [`SimArm`]).
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
}

/// The mechanical and servo parameters of the simulated arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// Plant actuator stiffness = the controller's assumed stiffness × this (0.1 to 10).
    pub stiffness_scale: f64,
    /// Extra relative deviation of each actuator's stiffness (−0.5 to 0.5): actuator i has
    /// assumed_i × stiffness_scale × (1 + stiffness_spread[i]).
    pub stiffness_spread: [f64; 4],
    /// Damping ratio of each actuator's structural spring (0 to 1).
    pub structural_damping_ratio: f64,
    /// Servo (inner loop) rate, Hz (1000 to 100000); the paper's dSpace ran 20 kHz.
    pub servo_rate_hz: f64,
    /// Moving mass of each carriage with its reflected motor inertia, kg.
    pub carriage_mass_kg: f64,
    /// Servo proportional gain, N/mm.
    pub servo_kp_n_per_mm: f64,
    /// Servo integral gain, N/(mm·s).
    pub servo_ki_n_per_mm_s: f64,
    /// Servo derivative gain (on the measured velocity), N·s/mm.
    pub servo_kd_n_s_per_mm: f64,
    /// Largest motor force, N (the servo output saturates here).
    pub motor_force_max_n: f64,
    /// Coulomb friction of each carriage, N.
    pub coulomb_friction_n: f64,
    /// Viscous friction of each carriage, N·s/mm.
    pub viscous_friction_n_s_per_mm: f64,
    /// Speed below which Coulomb friction is regularised (linear), mm/s.
    pub friction_velocity_mm_per_s: f64,
    /// Mass of the moving platform with sensor and tool, kg.
    pub tool_mass_kg: f64,
    /// Rotational inertia of the platform about y, kg·mm².
    pub tool_inertia_kg_mm2: f64,
    /// Viscous damping of the platform's motion (joints, air), N·s/mm.
    pub platform_damping_n_s_per_mm: f64,
    /// Encoder resolution, mm.
    pub encoder_resolution_mm: f64,
}

impl Default for PlantConfig {
    fn default() -> Self {
        PlantConfig {
            stiffness_scale: 1.0,
            stiffness_spread: [0.0; 4],
            structural_damping_ratio: 0.05,
            servo_rate_hz: 20_000.0,
            carriage_mass_kg: 4.0,
            servo_kp_n_per_mm: 4000.0,
            servo_ki_n_per_mm_s: 400_000.0,
            servo_kd_n_s_per_mm: 5.6,
            motor_force_max_n: 600.0,
            coulomb_friction_n: 8.0,
            viscous_friction_n_s_per_mm: 0.05,
            friction_velocity_mm_per_s: 0.2,
            tool_mass_kg: 1.0,
            tool_inertia_kg_mm2: 1000.0,
            platform_damping_n_s_per_mm: 0.02,
            encoder_resolution_mm: 0.0005,
        }
    }
}

/// The force/torque sensor's imperfections and its digital filter.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// Standard deviation of the Gaussian noise on each force axis per sample, N.
    pub noise_std_n: f64,
    /// Standard deviation of the Gaussian noise on My per sample, N·mm.
    pub noise_std_n_mm: f64,
    /// Force quantisation step, N (ATI mini45: 1/16 N).
    pub quantization_n: f64,
    /// Moment quantisation step, N·mm (ATI mini45: 1/752 N·m ≈ 1.33 N·mm).
    pub quantization_n_mm: f64,
    /// Constant bias on Fx, Fy, Fz, N.
    pub bias_n: [f64; 3],
    /// Constant bias on My, N·mm.
    pub bias_n_mm: f64,
    /// Sample rate of the A/D read-out, Hz.
    pub sample_rate_hz: f64,
    /// Cut-off of the 2nd-order Butterworth low-pass filter, Hz (≥ 0.45 × the sample rate
    /// disables it).
    pub filter_cutoff_hz: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        SensorConfig {
            noise_std_n: 0.1,
            noise_std_n_mm: 2.0,
            quantization_n: 0.0625,
            quantization_n_mm: 1.33,
            bias_n: [0.3, -0.2, 0.4],
            bias_n_mm: 3.0,
            sample_rate_hz: 1000.0,
            filter_cutoff_hz: 80.0,
        }
    }
}

/// A surface's material: its contact stiffness, damping and friction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Contact stiffness along the normal, N/mm.
    pub stiffness_n_per_mm: f64,
    /// Damping ratio of the contact with the tool's mass (0 to 2).
    pub damping_ratio: f64,
    /// Coulomb friction coefficient between tool and surface.
    pub friction_coefficient: f64,
}

/// Named materials (values and sources in `docs/slave-simulation.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MaterialPreset {
    /// Cast epoxy/polyurethane tooling resin block on its fixture.
    Resin,
    /// Steel plate on its fixture.
    Steel,
    /// Aluminium plate on its fixture.
    Aluminium,
}

impl MaterialPreset {
    /// The preset's values.
    pub fn material(self) -> Material {
        match self {
            MaterialPreset::Resin => Material {
                stiffness_n_per_mm: 200.0,
                damping_ratio: 0.3,
                friction_coefficient: 0.15,
            },
            MaterialPreset::Steel => Material {
                stiffness_n_per_mm: 2000.0,
                damping_ratio: 0.05,
                friction_coefficient: 0.12,
            },
            MaterialPreset::Aluminium => Material {
                stiffness_n_per_mm: 1000.0,
                damping_ratio: 0.05,
                friction_coefficient: 0.15,
            },
        }
    }
}

/// The geometry of a rigid body's surface; the solid is on the side opposite the
/// outward normal (below a plane, inside a cylinder or a sphere).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SurfaceShape {
    /// The plane through `point_mm` with outward unit normal `normal`.
    Plane {
        /// A point of the plane, mm.
        point_mm: [f64; 3],
        /// Outward unit normal.
        normal: [f64; 3],
    },
    /// An infinite cylinder.
    Cylinder {
        /// A point of the axis, mm.
        axis_point_mm: [f64; 3],
        /// Unit direction of the axis.
        axis_dir: [f64; 3],
        /// Radius, mm.
        radius_mm: f64,
    },
    /// A sphere.
    Sphere {
        /// Centre, mm.
        centre_mm: [f64; 3],
        /// Radius, mm.
        radius_mm: f64,
    },
}

/// A body the tool can touch: shape and material. [`SimArm::set_surface`] swaps it at
/// run time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    /// Geometry.
    pub shape: SurfaceShape,
    /// Material.
    pub material: Material,
}

impl Surface {
    /// Penetration depth (> 0 inside the solid), mm, and the outward unit normal at the
    /// nearest surface point.
    #[inline]
    pub fn penetration(&self, p: &Vector3<f64>) -> (f64, Vector3<f64>) {
        match self.shape {
            SurfaceShape::Plane { point_mm, normal } => {
                let n = Vector3::from(normal);
                (-(n.dot(&(p - Vector3::from(point_mm)))), n)
            }
            SurfaceShape::Sphere {
                centre_mm,
                radius_mm,
            } => {
                let w = p - Vector3::from(centre_mm);
                let d = w.norm();
                if d > 1e-9 {
                    (radius_mm - d, w / d)
                } else {
                    (radius_mm, Vector3::z())
                }
            }
            SurfaceShape::Cylinder {
                axis_point_mm,
                axis_dir,
                radius_mm,
            } => {
                let u = Vector3::from(axis_dir);
                let w = p - Vector3::from(axis_point_mm);
                let w_perp = w - u * u.dot(&w);
                let d = w_perp.norm();
                if d > 1e-9 {
                    (radius_mm - d, w_perp / d)
                } else {
                    (radius_mm, Vector3::z())
                }
            }
        }
    }
}

/// Why a [`SimArm`] could not be built.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The initial pose has no inverse kinematics or Jacobian.
    #[error("initial pose: {0}")]
    Kinematics(#[from] h4_shared::KinError),
    /// A parameter is not usable.
    #[error("plant parameter {0} is not usable")]
    BadParameter(&'static str),
}

/// The simulated H-4 arm.
#[derive(Clone, Debug)]
pub struct SimArm {
    params: H4Params,
    cfg: PlantConfig,
    sensor_cfg: SensorConfig,
    surface: Surface,
    time_ns: u64,
    substep_ns: u64,
    substep_s: f64,
    remainder_ns: u64,
    substeps_per_linearisation: u32,
    substep_counter: u32,
    sensor_period_ns: u64,
    next_sensor_ns: u64,
    // Carriages.
    q: [f64; 4],
    qd: [f64; 4],
    integral: [f64; 4],
    command: [f64; 4],
    // Structure.
    k: [f64; 4],
    c_struct: [f64; 4],
    // Platform.
    pose: Pose,
    vel: Pose,
    inv_mass: Vector4<f64>,
    l0: Actuators,
    pose0: Pose,
    jac: Matrix4<f64>,
    // Contact.
    contact_wrench: Vector4<f64>,
    contact_damping: f64,
    penetration_mm: f64,
    // Sensor.
    rng: Rng,
    filters: [Butterworth2; 4],
    filtered: [f64; 4],
    kinematics_faults: u64,
    /// Tests only: run planes through the generic kernel (to compare the two).
    #[cfg(test)]
    generic_kernel: bool,
}

impl SimArm {
    /// An arm at rest at `initial_pose` (springs unloaded), whose controller assumes the
    /// per-actuator stiffness `assumed_stiffness_n_per_mm`; the plant's stiffness is that
    /// × `cfg.stiffness_scale` × (1 + spread).
    pub fn new(
        params: H4Params,
        assumed_stiffness_n_per_mm: [f64; 4],
        cfg: PlantConfig,
        sensor_cfg: SensorConfig,
        surface: Surface,
        initial_pose: Pose,
        seed: u64,
    ) -> Result<Self, SimError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(cfg.servo_rate_hz) || cfg.servo_rate_hz < 1000.0 {
            return Err(SimError::BadParameter("servo_rate_hz"));
        }
        if !positive(cfg.carriage_mass_kg) {
            return Err(SimError::BadParameter("carriage_mass_kg"));
        }
        if !positive(cfg.tool_mass_kg) || !positive(cfg.tool_inertia_kg_mm2) {
            return Err(SimError::BadParameter("tool_mass_kg"));
        }
        if !positive(sensor_cfg.sample_rate_hz) {
            return Err(SimError::BadParameter("sample_rate_hz"));
        }
        let substep_ns = (1e9 / cfg.servo_rate_hz).round() as u64;
        let substep_s = substep_ns as f64 * 1e-9;
        let sensor_period_ns = (1e9 / sensor_cfg.sample_rate_hz).round().max(1.0) as u64;
        let l = params.ik_checked(&initial_pose)?;
        let jac = params.jacobian(&initial_pose)?;
        let tool_mass = cfg.tool_mass_kg * 1e-3; // N·s²/mm
        let tool_inertia = cfg.tool_inertia_kg_mm2 * 1e-3; // N·mm·s²
        let mut k = [0.0; 4];
        let mut c_struct = [0.0; 4];
        for i in 0..4 {
            k[i] = assumed_stiffness_n_per_mm[i]
                * cfg.stiffness_scale
                * (1.0 + cfg.stiffness_spread[i]);
            if !positive(k[i]) {
                return Err(SimError::BadParameter("stiffness"));
            }
            // Each actuator carries roughly a quarter of the platform.
            c_struct[i] = 2.0 * cfg.structural_damping_ratio * (k[i] * 0.25 * tool_mass).sqrt();
        }
        let filters =
            [Butterworth2::new(sensor_cfg.filter_cutoff_hz, sensor_cfg.sample_rate_hz); 4];
        let mut arm = SimArm {
            params,
            cfg,
            sensor_cfg,
            surface,
            time_ns: 0,
            substep_ns,
            substep_s,
            remainder_ns: 0,
            substeps_per_linearisation: ((1_000_000 / substep_ns).max(1)) as u32,
            substep_counter: 0,
            sensor_period_ns,
            next_sensor_ns: 0,
            q: [l[0], l[1], l[2], l[3]],
            qd: [0.0; 4],
            integral: [0.0; 4],
            command: [l[0], l[1], l[2], l[3]],
            k,
            c_struct,
            pose: initial_pose,
            vel: Pose::zeros(),
            inv_mass: Vector4::new(
                1.0 / tool_mass,
                1.0 / tool_mass,
                1.0 / tool_mass,
                1.0 / tool_inertia,
            ),
            l0: l,
            pose0: initial_pose,
            jac,
            contact_wrench: Vector4::zeros(),
            contact_damping: 0.0,
            penetration_mm: 0.0,
            rng: Rng::fork(seed, 0x5E45),
            filters,
            filtered: [0.0; 4],
            kinematics_faults: 0,
            #[cfg(test)]
            generic_kernel: false,
        };
        arm.update_contact_damping();
        for (i, f) in arm.filters.iter_mut().enumerate() {
            let b = if i < 3 {
                sensor_cfg.bias_n[i]
            } else {
                sensor_cfg.bias_n_mm
            };
            f.reset(b);
            arm.filtered[i] = b;
        }
        Ok(arm)
    }

    fn update_contact_damping(&mut self) {
        let m = self.cfg.tool_mass_kg * 1e-3;
        let mat = self.surface.material;
        self.contact_damping =
            2.0 * mat.damping_ratio * (mat.stiffness_n_per_mm.max(0.0) * m).sqrt();
    }

    /// Replaces the surface (shape and material) at run time.
    pub fn set_surface(&mut self, surface: Surface) {
        self.surface = surface;
        self.update_contact_damping();
    }

    /// The current surface.
    pub fn surface(&self) -> &Surface {
        &self.surface
    }

    /// Simulated time, ns.
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }

    /// The platform's true pose (with the structure's deflection), for evaluation only.
    pub fn true_pose(&self) -> Pose {
        self.pose
    }

    /// The true contact wrench on the tool `[Fx, Fy, Fz, My]`, for evaluation only.
    pub fn true_contact_wrench(&self) -> Vector4<f64> {
        self.contact_wrench
    }

    /// The true penetration into the surface, mm (negative: distance above it).
    pub fn penetration_mm(&self) -> f64 {
        self.penetration_mm
    }

    /// The plant's actuator stiffness, N/mm.
    pub fn plant_stiffness_n_per_mm(&self) -> [f64; 4] {
        self.k
    }

    /// Count of re-linearisations that failed because the pose left the kinematics'
    /// domain (the previous linearisation is kept).
    pub fn kinematics_faults(&self) -> u64 {
        self.kinematics_faults
    }

    /// Steps the servo, structure, contact and sensor physics by `dt_ns` of simulated time.
    pub fn advance(&mut self, dt_ns: u64) {
        let total = self.remainder_ns + dt_ns;
        let mut steps = total / self.substep_ns;
        self.remainder_ns = total % self.substep_ns;
        while steps > 0 {
            if self.substep_counter == 0 {
                self.relinearise();
            }
            // Run substeps up to the next re-linearisation or sensor sample, whichever
            // comes first, in a kernel that keeps the state in registers.
            let to_lin = u64::from(self.substeps_per_linearisation - self.substep_counter);
            let to_sensor = self
                .next_sensor_ns
                .saturating_sub(self.time_ns)
                .div_ceil(self.substep_ns)
                .max(1);
            let n = steps.min(to_lin).min(to_sensor);
            self.substeps(n as u32);
            steps -= n;
            self.time_ns += n * self.substep_ns;
            self.substep_counter += n as u32;
            if self.substep_counter >= self.substeps_per_linearisation {
                self.substep_counter = 0;
            }
            if self.time_ns >= self.next_sensor_ns {
                self.sample_sensor();
                self.next_sensor_ns += self.sensor_period_ns;
            }
        }
    }

    fn relinearise(&mut self) {
        match (
            self.params.ik_raw(&self.pose),
            self.params.jacobian(&self.pose),
        ) {
            (Ok(l), Ok(j)) => {
                self.l0 = l;
                self.jac = j;
                self.pose0 = self.pose;
            }
            _ => self.kinematics_faults += 1,
        }
    }

    /// `n` servo periods with the Jacobian held: the inner loop of the simulation,
    /// specialised per surface shape.
    fn substeps(&mut self, n: u32) {
        match self.surface.shape {
            SurfaceShape::Plane { point_mm, normal } if !self.generic_kernel_forced() => {
                self.substeps_plane(n, point_mm, normal)
            }
            _ => {
                let s = self.surface;
                self.substeps_with(n, move |p: &Vector3<f64>| s.penetration(p));
            }
        }
    }

    #[cfg(test)]
    fn generic_kernel_forced(&self) -> bool {
        self.generic_kernel
    }

    #[cfg(not(test))]
    #[inline(always)]
    fn generic_kernel_forced(&self) -> bool {
        false
    }

    /// The kernel of [`SimArm::substeps`] for a plane: the same physics as
    /// [`SimArm::substeps_with`] (which the curved surfaces use), arranged for speed; only
    /// the rounding differs. The plane's normal is fixed, so the platform's velocity is kept
    /// in the plane's frame, `V = [v·n, v·t1, v·t2, θ̇]`: the contact reads its normal part
    /// and the friction solve scales its tangential part directly, the contact depth is the
    /// normal displacement, and every product with the Jacobian is one 4×4 matrix (`J` in
    /// that frame, projected once per block) on four-wide vectors, which the compiler
    /// vectorises. The leg rates of the tangential velocity are computed before the
    /// friction's square root is known and scaled after it, and the structural force is
    /// one multiply-add of the leg rate (`base`, the carriages' share, is known earlier).
    /// Measured variants (docs/slave-results.md, "Speed"): this one was the fastest; one
    /// that also propagated the velocity through a precomputed `M V` (a shorter chain,
    /// more arithmetic) and one with the fewest operations were both slower.
    fn substeps_plane(&mut self, n: u32, point_mm: [f64; 3], nrm: [f64; 3]) {
        let dt = self.substep_s;
        let cfg = self.cfg;
        let servo = CarriageServo::new(&cfg, dt);
        let damp = cfg.platform_damping_n_s_per_mm;
        let k = self.k;
        let cs = self.c_struct;
        let cmd = self.command;
        let mut q = self.q;
        let mut qd = self.qd;
        let mut integ = self.integral;
        let dt_over_m_tool = self.inv_mass[0] * dt;
        let m_tool_over_dt = 1.0 / dt_over_m_tool;
        let dt_over_inertia = self.inv_mass[3] * dt;

        // The plane's frame and the legs' Jacobian in it: `jb[c][r]` = d l_r / d V_c.
        let (t1, t2) = tangent_basis(nrm);
        let basis = [nrm, t1, t2];
        let mut jb = [[0.0f64; 4]; 4];
        for (c, col) in jb.iter_mut().enumerate() {
            for (r, v) in col.iter_mut().enumerate() {
                *v = if c < 3 {
                    self.jac[(r, 0)] * basis[c][0]
                        + self.jac[(r, 1)] * basis[c][1]
                        + self.jac[(r, 2)] * basis[c][2]
                } else {
                    self.jac[(r, 3)]
                };
            }
        }
        // Velocity change per period per newton of leg force r: `a[r][c]`.
        let per_mass = [
            dt_over_m_tool,
            dt_over_m_tool,
            dt_over_m_tool,
            dt_over_inertia,
        ];
        let mut decay = [0.0f64; 4];
        let mut a = [[0.0f64; 4]; 4];
        for c in 0..4 {
            decay[c] = 1.0 - damp * per_mass[c];
            for r in 0..4 {
                a[r][c] = jb[c][r] * per_mass[c];
            }
        }
        // Structural spring over one period: f = k (l + ld dt − q) + cs (ld − qd).
        let mut k_dt_cs = [0.0f64; 4];
        for i in 0..4 {
            k_dt_cs[i] = k[i] * dt + cs[i];
        }
        // State at the start of the block.
        let mut pose = [self.pose[0], self.pose[1], self.pose[2], self.pose[3]];
        let v3 = [self.vel[0], self.vel[1], self.vel[2]];
        let mut vb = [dot3(&v3, &nrm), dot3(&v3, &t1), dot3(&v3, &t2), self.vel[3]];
        let mut ld = [0.0f64; 4];
        let mut l = [0.0f64; 4];
        let mut f = [0.0f64; 4];
        for r in 0..4 {
            let mut acc = self.l0[r];
            let mut rate = 0.0;
            for (c, p) in pose.iter().enumerate() {
                acc += self.jac[(r, c)] * (p - self.pose0[c]);
                rate += self.jac[(r, c)] * self.vel[c];
            }
            l[r] = acc;
            ld[r] = rate;
            f[r] = k[r] * (l[r] - q[r]) + cs[r] * (ld[r] - qd[r]);
        }
        // Velocity before the contact forces of the first period.
        let mut w = [0.0f64; 4];
        for c in 0..4 {
            w[c] = vb[c] * decay[c]
                - ((a[0][c] * f[0] + a[1][c] * f[1]) + (a[2][c] * f[2] + a[3][c] * f[3]));
        }
        let depth0 = -(nrm[0] * (pose[0] - point_mm[0])
            + nrm[1] * (pose[1] - point_mm[1])
            + nrm[2] * (pose[2] - point_mm[2]));
        let mut disp = [0.0f64; 4];

        let material = self.surface.material;
        let k_env = material.stiffness_n_per_mm;
        let b_env = self.contact_damping;
        let mu = material.friction_coefficient;
        let reg = cfg.friction_velocity_mm_per_s;
        let mut pen = self.penetration_mm;
        let mut last_fn = 0.0;
        let mut last_slip = [0.0f64; 2];
        for _ in 0..n {
            // Carriages: PID servo on the encoder (derivative on the measurement,
            // anti-windup), the structural force f, friction.
            let mut base = [0.0f64; 4];
            for i in 0..4 {
                let pre = k[i] * (l[i] - q[i]);
                let v_new = servo.step(cmd[i], &mut q[i], &mut qd[i], &mut integ[i], f[i]);
                // The next period's structural force without the platform's share.
                base[i] = pre - k_dt_cs[i] * v_new;
            }
            // Contact at the tool point (Kelvin–Voigt, damping on the last velocity).
            let depth = depth0 - disp[0];
            pen = depth;
            let mut dv_n = 0.0;
            let mut removed = 0.0;
            last_fn = 0.0;
            if depth > 0.0 {
                let f_n = clamp_sel(k_env * depth - b_env * vb[0], 0.0, f64::INFINITY);
                dv_n = f_n * dt_over_m_tool;
                // Regularised Coulomb friction F_t = −μ F_n v_t / max(|v_t|, v₀), solved
                // for the velocity at the end of the period (backward Euler): `removed`
                // of the tangential velocity goes (see `substeps_with`).
                let s2 = w[1] * w[1] + w[2] * w[2];
                let reach = mu * dv_n;
                let edge = reg + reach;
                removed = if s2 >= edge * edge {
                    (reach / s2) * s2.sqrt()
                } else {
                    reach / edge
                };
                last_fn = f_n;
            }
            let v0 = w[0] + dv_n;
            let (w1, w2, w3) = (w[1], w[2], w[3]);
            last_slip = [w1 * removed, w2 * removed];
            // Leg rates J V (the tangential part's computed before the friction's square
            // root is known, then scaled), the structural forces and leg lengths of the
            // next period.
            for r in 0..4 {
                let fixed = jb[0][r] * v0 + jb[3][r] * w3;
                let slid = jb[1][r] * w1 + jb[2][r] * w2;
                ld[r] = fixed + (slid - removed * slid);
                f[r] = k_dt_cs[r] * ld[r] + base[r];
                l[r] += ld[r] * dt;
            }
            vb = [v0, w1 - removed * w1, w2 - removed * w2, w3];
            // The next period's velocity before contact: the legs act through Jᵀ
            // (explicit), plus joint/air damping.
            let mut w_next = [0.0f64; 4];
            for c in 0..4 {
                w_next[c] = vb[c] * decay[c]
                    - ((a[0][c] * f[0] + a[1][c] * f[1]) + (a[2][c] * f[2] + a[3][c] * f[3]));
            }
            for c in 0..4 {
                disp[c] += vb[c] * dt;
            }
            w = w_next;
        }
        for a in 0..3 {
            pose[a] += nrm[a] * disp[0] + t1[a] * disp[1] + t2[a] * disp[2];
        }
        pose[3] += disp[3];
        self.q = q;
        self.qd = qd;
        self.integral = integ;
        self.pose = Pose::from(pose);
        let mut vel = [0.0f64; 4];
        let mut fc = [0.0f64; 4];
        for a in 0..3 {
            vel[a] = nrm[a] * vb[0] + t1[a] * vb[1] + t2[a] * vb[2];
            fc[a] =
                nrm[a] * last_fn - (t1[a] * last_slip[0] + t2[a] * last_slip[1]) * m_tool_over_dt;
        }
        vel[3] = vb[3];
        self.vel = Pose::from(vel);
        self.penetration_mm = pen;
        self.contact_wrench = Vector4::from(fc);
    }

    #[inline(always)]
    fn substeps_with<F: Fn(&Vector3<f64>) -> (f64, Vector3<f64>)>(
        &mut self,
        n: u32,
        penetration: F,
    ) {
        let dt = self.substep_s;
        let cfg = self.cfg;
        let mut j = [[0.0f64; 4]; 4];
        for (r, row) in j.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = self.jac[(r, c)];
            }
        }
        let servo = CarriageServo::new(&cfg, dt);
        let damp = cfg.platform_damping_n_s_per_mm;
        let k = self.k;
        let cs = self.c_struct;
        let inv_mass = [
            self.inv_mass[0],
            self.inv_mass[1],
            self.inv_mass[2],
            self.inv_mass[3],
        ];
        let cmd = self.command;
        let mut q = self.q;
        let mut qd = self.qd;
        let mut integ = self.integral;
        let mut pose = [self.pose[0], self.pose[1], self.pose[2], self.pose[3]];
        let mut vel = [self.vel[0], self.vel[1], self.vel[2], self.vel[3]];
        let mut l = [0.0f64; 4];
        for (r, lr) in l.iter_mut().enumerate() {
            let mut acc = self.l0[r];
            for c in 0..4 {
                acc += j[r][c] * (pose[c] - self.pose0[c]);
            }
            *lr = acc;
        }
        let surface = self.surface;
        let k_env = surface.material.stiffness_n_per_mm;
        let b_env = self.contact_damping;
        let mu = surface.material.friction_coefficient;
        let reg = cfg.friction_velocity_mm_per_s;
        let mut fc = [0.0f64; 3];
        let mut pen = self.penetration_mm;
        let inv_m_tool = inv_mass[0];
        let m_tool_over_dt = 1.0 / (inv_m_tool * dt);
        // Products of constants taken out of the loop.
        let dt_over_m_tool = inv_m_tool * dt;
        let dt_over_inertia = inv_mass[3] * dt;
        // Leg rates the platform imposes (J held over the block).
        let mut ld = [0.0f64; 4];
        for r in 0..4 {
            ld[r] = j[r][0] * vel[0] + j[r][1] * vel[1] + j[r][2] * vel[2] + j[r][3] * vel[3];
        }
        for _ in 0..n {
            let mut f_act = [0.0f64; 4];
            for i in 0..4 {
                // Structural spring, positive when the platform pulls the carriage forward.
                let f = k[i] * (l[i] - q[i]) + cs[i] * (ld[i] - qd[i]);
                f_act[i] = f;
                servo.step(cmd[i], &mut q[i], &mut qd[i], &mut integ[i], f);
            }
            // Platform: the legs act through Jᵀ (explicit), plus joint/air damping.
            let mut gen_f = [0.0f64; 4];
            for (c, g) in gen_f.iter_mut().enumerate() {
                *g = -(j[0][c] * f_act[0]
                    + j[1][c] * f_act[1]
                    + j[2][c] * f_act[2]
                    + j[3][c] * f_act[3])
                    - vel[c] * damp;
            }
            vel[3] += gen_f[3] * dt_over_inertia;
            // Translational velocity before the contact forces.
            let mut vs = [
                vel[0] + gen_f[0] * dt_over_m_tool,
                vel[1] + gen_f[1] * dt_over_m_tool,
                vel[2] + gen_f[2] * dt_over_m_tool,
            ];
            // Contact at the tool point.
            let p = Vector3::new(pose[0], pose[1], pose[2]);
            let (depth, nrm) = penetration(&p);
            pen = depth;
            fc = [0.0; 3];
            if depth > 0.0 {
                let vn = vel[0] * nrm[0] + vel[1] * nrm[1] + vel[2] * nrm[2];
                let f_n = (k_env * depth - b_env * vn).max(0.0);
                let dv_n = f_n * dt_over_m_tool;
                for a in 0..3 {
                    vs[a] += nrm[a] * dv_n;
                }
                // Regularised Coulomb friction F_t = −μ F_n v_t / max(|v_t|, v₀), solved
                // for the velocity at the end of the period (backward Euler): below v₀ it
                // is a damper of μ F_n / v₀, far too stiff for an explicit step with the
                // tool's mass; solved implicitly, |F_t| ≤ μ F_n always holds.
                let vsn = vs[0] * nrm[0] + vs[1] * nrm[1] + vs[2] * nrm[2];
                let vt = [
                    vs[0] - nrm[0] * vsn,
                    vs[1] - nrm[1] * vsn,
                    vs[2] - nrm[2] * vsn,
                ];
                let s2 = vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2];
                let reach = mu * dv_n;
                let edge = reg + reach;
                // Sliding on (|v_t| − reach ≥ v₀): `reach` of the speed goes; below, the
                // damper regime. (reach / |v_t|² × |v_t|: the division and the square root
                // run side by side, off each other's latency.)
                let removed = if s2 >= edge * edge {
                    (reach / s2) * s2.sqrt()
                } else {
                    reach / edge
                };
                for a in 0..3 {
                    let dv_t = vt[a] * removed;
                    vs[a] -= dv_t;
                    fc[a] = nrm[a] * f_n - dv_t * m_tool_over_dt;
                }
            }
            vel[..3].copy_from_slice(&vs);
            for c in 0..4 {
                pose[c] += vel[c] * dt;
            }
            for r in 0..4 {
                ld[r] = j[r][0] * vel[0] + j[r][1] * vel[1] + j[r][2] * vel[2] + j[r][3] * vel[3];
                l[r] += ld[r] * dt;
            }
        }
        self.q = q;
        self.qd = qd;
        self.integral = integ;
        self.pose = Pose::from(pose);
        self.vel = Pose::from(vel);
        self.penetration_mm = pen;
        self.contact_wrench = Vector4::new(fc[0], fc[1], fc[2], 0.0);
    }

    fn sample_sensor(&mut self) {
        let s = &self.sensor_cfg;
        for i in 0..4 {
            let (bias, std, quant) = if i < 3 {
                (s.bias_n[i], s.noise_std_n, s.quantization_n)
            } else {
                (s.bias_n_mm, s.noise_std_n_mm, s.quantization_n_mm)
            };
            let noise = if std > 0.0 {
                std * self.rng.normal()
            } else {
                0.0
            };
            let mut raw = self.contact_wrench[i] + bias + noise;
            if quant > 0.0 {
                raw = quantize(raw, quant);
            }
            self.filtered[i] = self.filters[i].update(raw);
        }
    }
}

/// The carriages' servo and friction constants, taken out of the substep loops.
#[derive(Clone, Copy)]
struct CarriageServo {
    kp: f64,
    ki_dt: f64,
    kd: f64,
    u_max: f64,
    inv_v0: f64,
    fc_n: f64,
    fv: f64,
    dt: f64,
    dt_over_m_c: f64,
}

impl CarriageServo {
    fn new(cfg: &PlantConfig, dt: f64) -> Self {
        CarriageServo {
            kp: cfg.servo_kp_n_per_mm,
            ki_dt: cfg.servo_ki_n_per_mm_s * dt,
            kd: cfg.servo_kd_n_s_per_mm,
            u_max: cfg.motor_force_max_n,
            inv_v0: 1.0 / cfg.friction_velocity_mm_per_s,
            fc_n: cfg.coulomb_friction_n,
            fv: cfg.viscous_friction_n_s_per_mm,
            dt,
            dt_over_m_c: (1.0 / (cfg.carriage_mass_kg * 1e-3)) * dt,
        }
    }

    /// One servo period of a carriage: PID on the encoder (derivative on the measurement,
    /// anti-windup), the structural force `f_struct_n` (positive when the platform pulls the
    /// carriage forward), Coulomb and viscous friction. Returns the new velocity.
    #[inline(always)]
    fn step(&self, cmd: f64, q: &mut f64, qd: &mut f64, integ: &mut f64, f_struct_n: f64) -> f64 {
        let e = cmd - *q;
        let i_term = *integ + self.ki_dt * e;
        let u_raw = self.kp * e + i_term - self.kd * *qd;
        let u = clamp_sel(u_raw, -self.u_max, self.u_max);
        if u == u_raw {
            *integ = i_term;
        }
        let v = *qd;
        let friction = self.fc_n * clamp_sel(v * self.inv_v0, -1.0, 1.0) + self.fv * v;
        let v_new = (v + (u - friction) * self.dt_over_m_c) + f_struct_n * self.dt_over_m_c;
        *qd = v_new;
        *q += v_new * self.dt;
        v_new
    }
}

/// `x` limited to `[lo, hi]` as two selects (`maxsd`/`minsd`, no branch; `f64::clamp`
/// branches, and `f64::max`/`min` add NaN handling).
#[inline(always)]
fn clamp_sel(x: f64, lo: f64, hi: f64) -> f64 {
    let y = if x > lo { x } else { lo };
    if y < hi { y } else { hi }
}

/// Two unit vectors that complete the unit vector `n` to a right-handed orthonormal frame
/// `(n, t1, t2)`: `t1` from the axis least aligned with `n`.
fn tangent_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let mut axis = 0;
    for i in 1..3 {
        if n[i].abs() < n[axis].abs() {
            axis = i;
        }
    }
    let mut e = [0.0; 3];
    e[axis] = 1.0;
    let d = n[axis];
    let t = [e[0] - n[0] * d, e[1] - n[1] * d, e[2] - n[2] * d];
    let norm = dot3(&t, &t).sqrt();
    let t1 = [t[0] / norm, t[1] / norm, t[2] / norm];
    let t2 = [
        n[1] * t1[2] - n[2] * t1[1],
        n[2] * t1[0] - n[0] * t1[2],
        n[0] * t1[1] - n[1] * t1[0],
    ];
    (t1, t2)
}

/// `value` rounded to a multiple of `step` (ties to even), without a libm call: adding and
/// subtracting 1.5 × 2⁵² rounds any |x| < 2⁵¹ exactly, the same on every platform.
#[inline]
fn quantize(value: f64, step: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    let x = value / step;
    if x.abs() < 1e15 {
        ((x + MAGIC) - MAGIC) * step
    } else {
        value
    }
}

impl ArmDriver for SimArm {
    fn read(&mut self) -> ArmReading {
        let res = self.cfg.encoder_resolution_mm;
        let mut act = self.q;
        if res > 0.0 {
            for a in act.iter_mut() {
                *a = quantize(*a, res);
            }
        }
        ArmReading {
            time_ns: self.time_ns,
            actuators_mm: act,
            wrench: self.filtered,
        }
    }

    fn command(&mut self, actuators_mm: &[f64; 4]) {
        if actuators_mm.iter().all(|a| a.is_finite()) {
            self.command = *actuators_mm;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(z: f64, k: f64) -> Surface {
        Surface {
            shape: SurfaceShape::Plane {
                point_mm: [0.0, 0.0, z],
                normal: [0.0, 0.0, 1.0],
            },
            material: Material {
                stiffness_n_per_mm: k,
                damping_ratio: 0.3,
                friction_coefficient: 0.0,
            },
        }
    }

    fn quiet_sensor() -> SensorConfig {
        SensorConfig {
            noise_std_n: 0.0,
            noise_std_n_mm: 0.0,
            quantization_n: 0.0,
            quantization_n_mm: 0.0,
            bias_n: [0.0; 3],
            bias_n_mm: 0.0,
            ..SensorConfig::default()
        }
    }

    /// Pressing into a plane: the static force equals (Λ + 1/k_env)⁻¹ × the commanded
    /// depth, i.e. the platform deflects as the compliance matrix predicts.
    #[test]
    fn static_deflection_matches_compliance_matrix() {
        let params = H4Params::PROTOTYPE;
        let pose0 = Pose::new(0.0, 0.0, -250.0, 0.0);
        let k_env = 200.0;
        let mut arm = SimArm::new(
            params,
            [100.0; 4],
            PlantConfig::default(),
            quiet_sensor(),
            plane(-250.0, k_env),
            pose0,
            1,
        )
        .unwrap();
        let target = Pose::new(0.0, 0.0, -250.5, 0.0);
        let l = params.ik_checked(&target).unwrap();
        arm.command(&[l[0], l[1], l[2], l[3]]);
        arm.advance(2_000_000_000);
        let k = h4_shared::ActuatorStiffness::uniform(100.0).unwrap();
        let lam = params.compliance(&arm.true_pose(), &k).unwrap();
        let fz = arm.true_contact_wrench()[2];
        let expected = 0.5 / (lam[(2, 2)] + 1.0 / k_env);
        assert!(
            (fz - expected).abs() < 0.02 * expected,
            "fz {fz} expected {expected}"
        );
        let reading = arm.read();
        assert!((reading.wrench[2] - fz).abs() < 0.05, "{reading:?}");
        // Encoders read the commanded carriage positions, not the deflected legs.
        assert!((reading.actuators_mm[0] - l[0]).abs() < 2e-3);
    }

    /// Friction never exceeds the Coulomb bound μ F_n, however abruptly the tool starts to
    /// slide (an explicit step of the regularised law's stiff damper did: tangential forces
    /// of several times μ F_n, aliased by the sensor into a steady offset).
    #[test]
    fn friction_never_exceeds_the_coulomb_bound() {
        let params = H4Params::PROTOTYPE;
        let pose0 = Pose::new(0.0, 0.0, -250.0, 0.0);
        let mu = 0.3;
        let mut surface = plane(-250.0, 1000.0);
        surface.material.friction_coefficient = mu;
        let mut arm = SimArm::new(
            params,
            [100.0; 4],
            PlantConfig::default(),
            quiet_sensor(),
            surface,
            pose0,
            1,
        )
        .unwrap();
        let mut worst: f64 = 0.0;
        let mut slid = false;
        // Press in, then jerk sideways along x and y, back and forth.
        for k in 0..600u32 {
            let t = f64::from(k) * 1e-3;
            let side = if k < 100 { 0.0 } else { 0.4 * (t * 40.0).sin() };
            let target = Pose::new(side, 0.5 * side, -250.3, 0.0);
            let l = params.ik_checked(&target).unwrap();
            arm.command(&[l[0], l[1], l[2], l[3]]);
            for _ in 0..20 {
                arm.advance(50_000);
                let w = arm.true_contact_wrench();
                let f_n = w[2];
                let f_t = (w[0] * w[0] + w[1] * w[1]).sqrt();
                if f_n > 1.0 {
                    worst = worst.max(f_t / (mu * f_n));
                    slid |= f_t > 0.9 * mu * f_n;
                }
            }
        }
        assert!(slid, "the tool never slid: the test proves nothing");
        assert!(worst <= 1.0 + 1e-9, "|F_t| reached {worst} × μ F_n");
    }

    /// The plane kernel is the generic kernel's physics rearranged: pressing into a tilted
    /// plane with friction and jerking sideways (sliding and sticking), both give the same
    /// motion and forces to rounding.
    #[test]
    fn plane_kernel_matches_the_generic_kernel() {
        let params = H4Params::PROTOTYPE;
        let pose0 = Pose::new(0.0, 0.0, -250.0, 0.0);
        let t = 10f64.to_radians();
        let surface = Surface {
            shape: SurfaceShape::Plane {
                point_mm: [0.0, 0.0, -250.0],
                normal: [t.sin(), 0.0, t.cos()],
            },
            material: Material {
                stiffness_n_per_mm: 500.0,
                damping_ratio: 0.2,
                friction_coefficient: 0.3,
            },
        };
        let make = |generic: bool| {
            let mut arm = SimArm::new(
                params,
                [100.0; 4],
                PlantConfig::default(),
                quiet_sensor(),
                surface,
                pose0,
                1,
            )
            .unwrap();
            arm.generic_kernel = generic;
            arm
        };
        let (mut fast, mut generic) = (make(false), make(true));
        let (mut worst_f, mut worst_x): (f64, f64) = (0.0, 0.0);
        let mut peak_f: f64 = 0.0;
        for k in 0..800u32 {
            let s = f64::from(k) * 1e-3;
            let side = if k < 150 { 0.0 } else { 0.5 * (s * 30.0).sin() };
            let target = Pose::new(side, 0.4 * side, -250.4, 0.02 * side);
            let l = params.ik_checked(&target).unwrap();
            for arm in [&mut fast, &mut generic] {
                arm.command(&[l[0], l[1], l[2], l[3]]);
                arm.advance(1_000_000);
            }
            let (wa, wb) = (fast.true_contact_wrench(), generic.true_contact_wrench());
            let (pa, pb) = (fast.true_pose(), generic.true_pose());
            peak_f = peak_f.max(wb.norm());
            worst_f = worst_f.max((wa - wb).norm());
            worst_x = worst_x.max((pa - pb).norm());
        }
        assert!(peak_f > 50.0, "the contact was not loaded: {peak_f} N");
        assert!(worst_f < 1e-6 * peak_f, "forces differ by {worst_f} N");
        assert!(worst_x < 1e-9, "poses differ by {worst_x} mm");
    }

    #[test]
    fn surfaces_report_penetration_and_normal() {
        let s = Surface {
            shape: SurfaceShape::Sphere {
                centre_mm: [0.0, 0.0, -400.0],
                radius_mm: 100.0,
            },
            material: MaterialPreset::Steel.material(),
        };
        let (pen, n) = s.penetration(&Vector3::new(0.0, 0.0, -301.0));
        assert!((pen - 1.0).abs() < 1e-12 && (n.z - 1.0).abs() < 1e-12);
        let c = Surface {
            shape: SurfaceShape::Cylinder {
                axis_point_mm: [0.0, 0.0, -400.0],
                axis_dir: [0.0, 1.0, 0.0],
                radius_mm: 100.0,
            },
            material: MaterialPreset::Resin.material(),
        };
        let (pen, n) = c.penetration(&Vector3::new(0.0, 55.0, -295.0));
        assert!((pen + 5.0).abs() < 1e-12 && (n.z - 1.0).abs() < 1e-12);
    }
}
