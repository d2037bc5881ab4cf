//! An honest simulation of the H-4 prototype behind the driver boundary
//! ([`h4_slave::arm::ArmDriver`]): [`SimArm`].
//!
//! A real driver reads the four actuator encoders and the force/torque sensor and writes
//! four actuator position commands; so does the simulation. What the simulation models
//! (every number and its reasoning is in `docs/slave-simulation.md`):
//!
//! * four prismatic carriages (`servo`), each with mass, Coulomb and viscous friction and a saturated
//!   motor force, under a 20 kHz PID position servo whose set-point is the 1 ms command;
//! * a finite structural stiffness (and a little damping) between each carriage and the
//!   platform, so the platform sits at `FK(q + f/k)`, deflecting under load as `Λ(x) F`
//!   predicts; the platform with its tool has mass and rotational inertia (`kernel`);
//! * penetration-based contact with an unknown [`Surface`] (`surface`) (plane, cylinder or sphere;
//!   Kelvin–Voigt spring–damper with regularised Coulomb friction);
//! * a six-axis force/torque sensor between the platform and the tool, reporting
//!   `[Fx, Fy, Fz, My]` in its own frame (which turns with θ about y): the contact wrench
//!   plus the payload's weight and inertia (`payload_mass_kg` at `payload_com_mm`, gravity
//!   `gravity_mm_per_s2` along the machine's vertical axis, the platform's acceleration
//!   over each sample period), with Gaussian noise, a drifting bias, quantisation and a
//!   second-order Butterworth low-pass filter (`sensor`);
//! * a read-to-command latency: a command takes effect `command_latency_s` after it is
//!   written (one 1 ms period by default, as in the paper's dSpace loop).
//!
//! Units: mm, rad, N, N·mm, seconds; masses are given in kg and converted to N·s²/mm.
//! Everything is deterministic from the seed; time advances only through
//! [`SimArm::advance`].

mod config;
pub mod cutting;
mod kernel;
mod sensor;
mod servo;
mod surface;

pub use config::PlantConfig;
pub use h4_slave::arm::{ArmDriver, ArmReading};
pub use sensor::{AdcAperture, SensorConfig};
pub use surface::{
    Axis, Material, MaterialPreset, ShapeKind, Surface, SurfaceConfig, SurfaceShape,
};

use h4_shared::kinematics::{Actuators, H4Params, Pose};
use nalgebra::{Matrix4, Vector4};

use sensor::{ForceSensor, quantize};

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

/// Most commands in flight (a longer latency than this many writes drops the oldest in
/// flight, which takes effect at once).
const PENDING_MAX: usize = 16;

/// Time the plant runs before time 0 to settle under gravity, ns.
const SETTLE_NS: u64 = 400_000_000;

/// The load on the force sensor (the controller's model: one model for the plant, the
/// compensation and `h4-slave identify`).
pub use h4_slave::controller::sensor_load;

/// The simulated H-4 arm.
#[derive(Clone, Debug)]
pub struct SimArm {
    params: H4Params,
    cfg: PlantConfig,
    surface: Surface,
    time_ns: u64,
    substep_ns: u64,
    substep_s: f64,
    remainder_ns: u64,
    substeps_per_linearisation: u32,
    substep_counter: u32,
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
    /// The contact force summed over the servo periods since the last sensor sample, N
    /// (with [`SimArm::load_periods`], the sensor's period mean).
    load_sum_n: [f64; 3],
    /// Servo periods in `load_sum_n`.
    load_periods: u32,
    contact_damping: f64,
    penetration_mm: f64,
    sensor: ForceSensor,
    /// The platform's velocity at the last sensor sample (for its acceleration), mm/s.
    vel_at_sample: [f64; 3],
    /// Commands written, not yet in effect: (time they take effect, ns; set-points).
    pending: [(u64, [f64; 4]); PENDING_MAX],
    pending_len: usize,
    /// Read-to-command latency, ns.
    latency_ns: u64,
    kinematics_faults: u64,
    /// The cut, when the arm carries a spindle over a workpiece (boxed: built once).
    cut: Option<Box<cutting::CutState>>,
    /// A fault injected on purpose (`h4-slave run --inject-fault`; none in simulated
    /// sessions).
    fault: Option<crate::fault::ArmFault>,
    /// Tests only: run planes through the generic kernel (to compare the two).
    #[cfg(test)]
    generic_kernel: bool,
}

impl SimArm {
    /// Injects `plan` (`h4-slave run --inject-fault`): from then on the arm's readings and
    /// commands fail as [`crate::fault`] says, in the plan's window; a saturated sensor reads
    /// `saturation_n` (its full range, N).
    pub fn inject_fault(&mut self, plan: crate::fault::FaultPlan, saturation_n: f64) {
        self.fault = Some(crate::fault::ArmFault::new(plan, saturation_n));
    }

    /// The injected fault, and whether it is on now.
    pub fn fault(&self) -> Option<(crate::fault::FaultPlan, bool)> {
        self.fault
            .as_ref()
            .map(|f| (f.plan, f.active(self.time_ns)))
    }

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
        if !(cfg.command_latency_s.is_finite() && (0.0..=0.1).contains(&cfg.command_latency_s)) {
            return Err(SimError::BadParameter("command_latency_s"));
        }
        let rest_load = sensor_load(
            &Vector4::zeros(),
            initial_pose[3],
            cfg.payload_mass_kg,
            cfg.payload_com_mm,
            cfg.gravity_mm_per_s2,
        );
        let substep_ns = (1e9 / cfg.servo_rate_hz).round() as u64;
        let substep_s = substep_ns as f64 * 1e-9;
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
        let mut arm = SimArm {
            params,
            cfg,
            surface,
            time_ns: 0,
            substep_ns,
            substep_s,
            remainder_ns: 0,
            substeps_per_linearisation: ((1_000_000 / substep_ns).max(1)) as u32,
            substep_counter: 0,
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
            load_sum_n: [0.0; 3],
            load_periods: 0,
            contact_damping: 0.0,
            penetration_mm: 0.0,
            sensor: ForceSensor::new(sensor_cfg, seed, &rest_load),
            vel_at_sample: [0.0; 3],
            pending: [(0, [0.0; 4]); PENDING_MAX],
            pending_len: 0,
            latency_ns: (cfg.command_latency_s * 1e9).round() as u64,
            kinematics_faults: 0,
            cut: None,
            fault: None,
            #[cfg(test)]
            generic_kernel: false,
        };
        arm.update_contact_damping();
        arm.settle_under_gravity();
        Ok(arm)
    }

    /// With gravity on, the platform starts sagged under its weight: the plant runs
    /// [`SETTLE_NS`] with the initial command held (the servos take the weight), then the
    /// clock, the sensor's filters and its acceleration reference restart from that rest.
    fn settle_under_gravity(&mut self) {
        if self.cfg.gravity_mm_per_s2.iter().all(|g| *g == 0.0) {
            return;
        }
        self.advance_physics(SETTLE_NS);
        self.time_ns = 0;
        self.remainder_ns = 0;
        self.substep_counter = 0;
        self.vel_at_sample = [self.vel[0], self.vel[1], self.vel[2]];
        self.load_sum_n = [0.0; 3];
        self.load_periods = 0;
        let load = sensor_load(
            &self.contact_wrench,
            self.pose[3],
            self.cfg.payload_mass_kg,
            self.cfg.payload_com_mm,
            self.cfg.gravity_mm_per_s2,
        );
        self.sensor.restart(&load);
    }

    fn update_contact_damping(&mut self) {
        let m = self.cfg.tool_mass_kg * 1e-3;
        let mat = self.surface.material;
        self.contact_damping =
            2.0 * mat.damping_ratio * (mat.stiffness_n_per_mm.max(0.0) * m).sqrt();
    }

    /// The same arm carrying a spindle over the workpiece `cfg` (the stock in the base
    /// frame; the surface's material gives the rubbing contact): from now on the tool cuts.
    pub fn with_cutting(mut self, cfg: &cutting::CuttingConfig) -> Result<Self, SimError> {
        let tip = [self.pose[0], self.pose[1], self.pose[2]];
        let cut = cutting::CutState::new(cfg, tip).ok_or(SimError::BadParameter("cutting"))?;
        self.cut = Some(Box::new(cut));
        Ok(self)
    }

    /// The cut in progress, if the arm cuts.
    pub fn cut(&self) -> Option<&cutting::CutState> {
        self.cut.as_deref()
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

    /// Steps the servo, structure, contact and sensor physics by `dt_ns` of simulated time;
    /// the commands written take effect as their latency runs out.
    pub fn advance(&mut self, dt_ns: u64) {
        let mut left = dt_ns;
        while self.pending_len > 0 {
            let now = self.time_ns + self.remainder_ns;
            let due = self.pending[0].0;
            if due > now + left {
                break;
            }
            let seg = due.saturating_sub(now);
            self.advance_physics(seg);
            left -= seg;
            self.command = self.pending[0].1;
            self.pending.copy_within(1..self.pending_len, 0);
            self.pending_len -= 1;
        }
        self.advance_physics(left);
    }

    /// The load on the sensor now (the platform's acceleration since the last sample).
    fn sensor_load_now(&mut self) -> Vector4<f64> {
        let period_s = self.sensor.period_ns as f64 * 1e-9;
        let mut g_minus_a = self.cfg.gravity_mm_per_s2;
        for (a, g) in g_minus_a.iter_mut().enumerate() {
            *g -= (self.vel[a] - self.vel_at_sample[a]) / period_s;
            self.vel_at_sample[a] = self.vel[a];
        }
        // An integrating A/D reads the contact's load over the sample period, as the
        // acceleration above: an instant's sample of a milling cutter's tooth pulses
        // aliases their harmonics at multiples of the sample rate into the mean (measured:
        // the feed force read 21 % low in resin).
        let period_mean = self.sensor.cfg.adc_aperture == AdcAperture::Period;
        let contact = if period_mean && self.load_periods > 0 {
            let n = f64::from(self.load_periods);
            Vector4::new(
                self.load_sum_n[0] / n,
                self.load_sum_n[1] / n,
                self.load_sum_n[2] / n,
                self.contact_wrench[3],
            )
        } else {
            self.contact_wrench
        };
        self.load_sum_n = [0.0; 3];
        self.load_periods = 0;
        sensor_load(
            &contact,
            self.pose[3],
            self.cfg.payload_mass_kg,
            self.cfg.payload_com_mm,
            g_minus_a,
        )
    }

    /// Books `n` servo periods whose contact forces sum to `sum_n` for the sensor's mean.
    #[inline(always)]
    pub(in crate::plant) fn book_load(&mut self, sum_n: [f64; 3], n: u32) {
        for (a, s) in self.load_sum_n.iter_mut().zip(sum_n) {
            *a += s;
        }
        self.load_periods += n;
    }

    fn advance_physics(&mut self, dt_ns: u64) {
        let total = self.remainder_ns + dt_ns;
        let mut steps = total / self.substep_ns;
        self.remainder_ns = total % self.substep_ns;
        while steps > 0 {
            if self.substep_counter == 0 {
                self.relinearise();
                if let Some(cut) = self.cut.as_deref_mut() {
                    cut.update([self.pose[0], self.pose[1], self.pose[2]]);
                }
            }
            // Run substeps up to the next re-linearisation or sensor sample, whichever
            // comes first, in a kernel that keeps the state in registers.
            let to_lin = u64::from(self.substeps_per_linearisation - self.substep_counter);
            let to_sensor = self
                .sensor
                .next_sample_ns
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
            if self.time_ns >= self.sensor.next_sample_ns {
                let load = self.sensor_load_now();
                self.sensor.sample(&load);
                self.sensor.next_sample_ns += self.sensor.period_ns;
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
}

impl ArmDriver for SimArm {
    fn advance(&mut self, dt_ns: u64) {
        SimArm::advance(self, dt_ns);
    }
    fn read(&mut self) -> ArmReading {
        let res = self.cfg.encoder_resolution_mm;
        let mut act = self.q;
        if res > 0.0 {
            for a in act.iter_mut() {
                *a = quantize(*a, res);
            }
        }
        let r = ArmReading {
            time_ns: self.time_ns,
            actuators_mm: act,
            wrench: self.sensor.filtered,
        };
        match self.fault.as_mut() {
            Some(f) => f.apply(r),
            None => r,
        }
    }

    fn command(&mut self, actuators_mm: &[f64; 4]) {
        if !actuators_mm.iter().all(|a| a.is_finite()) {
            return;
        }
        if self
            .fault
            .as_ref()
            .is_some_and(|f| !f.takes_commands(self.time_ns))
        {
            return;
        }
        if self.latency_ns == 0 {
            self.command = *actuators_mm;
            return;
        }
        if self.pending_len == PENDING_MAX {
            self.command = self.pending[0].1;
            self.pending.copy_within(1..PENDING_MAX, 0);
            self.pending_len -= 1;
        }
        let due = self.time_ns + self.remainder_ns + self.latency_ns;
        self.pending[self.pending_len] = (due, *actuators_mm);
        self.pending_len += 1;
    }

    fn turntable_rad(&self) -> Option<f64> {
        Some(self.cut.as_deref()?.turntable()?.measured_rad())
    }

    fn command_turntable(&mut self, angle_rad: f64) {
        if let Some(cut) = self.cut.as_deref_mut() {
            cut.command_turntable(angle_rad);
        }
    }

    fn spindle_stalled(&self) -> bool {
        self.cut.as_deref().is_some_and(|c| c.report().stalled)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

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

    /// The prototype at rest at (0, 0, −250 mm), 100 N/mm actuators, default plant, a quiet
    /// sensor, touching `surface`.
    fn test_arm(surface: Surface) -> SimArm {
        SimArm::new(
            H4Params::PROTOTYPE,
            [100.0; 4],
            PlantConfig::default(),
            SensorConfig::quiet(),
            surface,
            Pose::new(0.0, 0.0, -250.0, 0.0),
            1,
        )
        .unwrap()
    }

    /// Pressing into a plane: the static force equals (Λ + 1/k_env)⁻¹ × the commanded
    /// depth, i.e. the platform deflects as the compliance matrix predicts.
    #[test]
    fn static_deflection_matches_compliance_matrix() {
        let params = H4Params::PROTOTYPE;
        let k_env = 200.0;
        let mut arm = test_arm(plane(-250.0, k_env));
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
        let mu = 0.3;
        let mut surface = plane(-250.0, 1000.0);
        surface.material.friction_coefficient = mu;
        let mut arm = test_arm(surface);
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
            let mut arm = test_arm(surface);
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

    /// The sensor carries the payload: at rest, tilted by θ, it reads the payload's weight
    /// in its own (turned) frame and the weight's moment about it, plus its bias; and the
    /// platform sags under the weight (gravity is in the dynamics too).
    #[test]
    fn sensor_reads_the_payload_weight_in_its_frame() {
        let theta: f64 = 0.3;
        let cfg = PlantConfig {
            payload_mass_kg: 0.5,
            payload_com_mm: [10.0, 0.0, -40.0],
            gravity_mm_per_s2: [0.0, 0.0, -9810.0],
            ..PlantConfig::default()
        };
        let start = Pose::new(0.0, 0.0, -250.0, theta);
        let mut arm = SimArm::new(
            H4Params::PROTOTYPE,
            [100.0; 4],
            cfg,
            SensorConfig::quiet(),
            plane(-400.0, 200.0),
            start,
            1,
        )
        .unwrap();
        arm.advance(200_000_000);
        let r = arm.read().wrench;
        let w = 0.5 * 9.81;
        let (s, c) = theta.sin_cos();
        // Gravity (0, 0, −w) in the sensor's frame: (s·w, 0, −c·w).
        let (px, pz) = (s * w, -c * w);
        assert!(
            (r[0] - px).abs() < 0.07 && (r[2] - pz).abs() < 0.07,
            "{r:?}"
        );
        let my = -40.0 * px - 10.0 * pz;
        assert!((r[3] - my).abs() < 1.5, "{r:?} vs My {my}");
        assert!(
            arm.true_pose()[2] < -250.0 + 1e-4,
            "no sag: {:?}",
            arm.true_pose()
        );
    }

    /// A command takes effect `command_latency_s` after it is written: with one period, the
    /// carriages have not moved at the end of the period it was written in, and have after
    /// the next one.
    #[test]
    fn commands_act_one_latency_later() {
        let cfg = PlantConfig {
            command_latency_s: 0.001,
            ..PlantConfig::default()
        };
        let params = H4Params::PROTOTYPE;
        let start = Pose::new(0.0, 0.0, -250.0, 0.0);
        let mut arm = SimArm::new(
            params,
            [100.0; 4],
            cfg,
            SensorConfig::quiet(),
            plane(-400.0, 200.0),
            start,
            1,
        )
        .unwrap();
        let l0 = arm.read().actuators_mm;
        let l = params
            .ik_checked(&Pose::new(0.0, 0.0, -249.9, 0.0))
            .unwrap();
        arm.command(&[l[0], l[1], l[2], l[3]]);
        arm.advance(1_000_000);
        let after_one = arm.read().actuators_mm;
        arm.advance(1_000_000);
        let after_two = arm.read().actuators_mm;
        assert!(
            (after_one[0] - l0[0]).abs() < 1e-3,
            "moved early: {after_one:?}"
        );
        assert!(
            (after_two[0] - l0[0]).abs() > 5e-3,
            "never moved: {after_two:?}"
        );
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
