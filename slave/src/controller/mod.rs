//! The slave's 1 kHz controller: a pure step, no clock reads, no I/O, no allocation, no
//! panic.
//!
//! * **Position** mode follows the commanded pose with velocity and acceleration limits
//!   (per axis), through the checked inverse kinematics of the [`Workspace`].
//! * **ForceGuided** mode is the paper's implicit force control (§3, figures 2 and 3): the
//!   contact normal comes from the measured force (with the friction component along the
//!   tracking direction removed), the tracking direction is the commanded direction of
//!   motion projected onto the tangent plane (figure 2), and the position command moves
//!   into the surface by the compliance times the force error,
//!   `Δd = c · (ΔF_r + k_p Δe + k_i e dt)`, with `c = nᵀ Λ(x) n + ĉ_env`: the arm's
//!   compliance along the normal from the kinematics (with the *assumed* actuator
//!   stiffness) plus the environment's compliance, estimated online by recursive least
//!   squares on force and position increments (as in Chiaverini–Siciliano–Villani's
//!   stiffness adaptation). `F_r` is the set-point after a critically damped second-order
//!   prefilter, fed forward. Before contact the arm approaches the commanded pose at the
//!   approach speed; on contact loss it re-approaches along the last normal, without a jump.
//! * **Hold** (or the clutch) holds the commanded pose.
//! * [`SlaveController::safe_stop`] ramps the force to zero, retracts along the contact
//!   normal and holds.
//!
//! Limits always hold: commanded set-points above the force limit, speeds above the speed
//! limit, non-finite inputs and poses outside the workspace are rejected with a
//! [`Rejection`] (the actuators then hold their last valid command); a measured force above
//! the limit makes the arm back off; the command moves no faster than the speed limit.
//!
//! One [`SlaveController::step`] is the sequence of the controller's concerns, each a module
//! with its own state:
//! 1. the inputs are checked, the encoders' forward kinematics taken; the first cycles tare
//!    the force sensor (`tare`);
//! 2. this cycle's measurements: the arm's compliance at the measured pose (`arm_model`),
//!    the filtered position and force pushed into the motion window (`window`);
//! 3. a safe stop overrides the command (`safe_stop`); the command is checked against
//!    the limits (`guards`);
//! 4. Hold holds, Position follows the trajectory (`position`), ForceGuided approaches
//!    and touches (`contact`), then in contact: the contact normal (`normal`), the
//!    tracking direction (`tracking`), the gain schedule (`gain_schedule`), the
//!    set-point prefilter and the environment-stiffness estimate (`estimator`), the
//!    deflection compensation (`deflection`), the force law (`force_law`) with the
//!    oscillation guard, the input shaping of the motion into the surface (`shaping`),
//!    the motion along the surface, the force guards, the contact loss;
//! 5. the next commanded pose is checked against the workspace and committed.

mod arm_model;
mod compensation;
pub use compensation::sensor_load;
mod contact;
mod deflection;
mod estimator;
pub mod fixtures;
mod force_law;
mod gain_schedule;
mod guards;
mod interface;
mod normal;
mod params;
mod position;
mod safe_stop;
mod shaping;
mod tare;
mod tracking;
mod window;

pub use fixtures::{Fixtures, FixturesConfig};
pub use interface::{ControllerInput, ControllerOutput, Rejection, SlaveCommand, Status};
pub use params::ControllerParams;

use h4_shared::config::ToolModel;
use h4_shared::kinematics::{ActuatorStiffness, Pose, Workspace};
use h4_shared::wire::Mode;
use nalgebra::{Vector3, Vector4};

use arm_model::{ArmModel, CycleCompliance, along_normal};
use compensation::{ToolCompensation, to_base};
use contact::ContactState;
use deflection::DeflectionComp;
use estimator::StiffnessEstimator;
use force_law::{ForceLaw, ForceLawInputs, SetpointPrefilter};
use gain_schedule::GainSchedule;
use guards::OscillationGuard;
use normal::{NormalEstimate, NormalInputs};
use position::PositionTrajectory;
use safe_stop::{SafeStop, SafeStopStep};
use shaping::InputShaper;
use tare::SensorTare;
use tracking::Tracking;
use window::MotionWindow;

/// The force counts as settled at its set-point within this share of it …
const SETTLED_SHARE: f64 = 0.05;
/// … or this many newtons, whichever is larger (the experiments' settling band).
const SETTLED_MIN_N: f64 = 0.5;

/// This cycle's measurements, derived once at the start of the step.
#[derive(Clone, Copy, Debug)]
struct Cycle {
    /// The step's period (at most 0.1 s), s.
    dt_s: f64,
    /// Forward kinematics of the encoders.
    pose_fk: Pose,
    /// `pose_fk` plus the deflection under the wrench (with the compliance model).
    measured_pose: Pose,
    /// The wrench with the sensor bias removed, N and N·mm.
    wrench: Vector4<f64>,
    /// Its force, N.
    f3: Vector3<f64>,
    /// The force's magnitude, N.
    f_mag: f64,
    /// The position filtered like the force, mm.
    xf: [f64; 3],
    /// The arm's compliance at `pose_fk`.
    compliance: CycleCompliance,
}

/// The slave controller. Build it once; call [`SlaveController::step`] every cycle.
#[derive(Clone, Debug)]
pub struct SlaveController {
    arm: ArmModel,
    p: ControllerParams,
    /// Steps taken with valid inputs.
    cycles: u64,
    /// The command starts from the measured pose at the first step.
    initialised: bool,
    /// The commanded pose, without the deflection compensation.
    x_cmd: Pose,
    /// The actuator commands of the commanded pose with the compensation, mm.
    l_cmd: [f64; 4],
    tare: SensorTare,
    comp: ToolCompensation,
    window: MotionWindow,
    safe: SafeStop,
    /// How far [`SlaveController::lift_stalled_tool`] has lifted the tool in this safe stop,
    /// mm.
    stall_lift_mm: f64,
    position: PositionTrajectory,
    contact: ContactState,
    normal: NormalEstimate,
    tracking: Tracking,
    setpoint: SetpointPrefilter,
    estimator: StiffnessEstimator,
    deflection: DeflectionComp,
    force_law: ForceLaw,
    oscillation: OscillationGuard,
    shaper: InputShaper,
    fixtures: Fixtures,
    last: ControllerOutput,
}

impl SlaveController {
    /// A controller for the arm `ws` whose actuators it assumes to have stiffness
    /// `assumed_stiffness`.
    pub fn new(
        ws: Workspace,
        assumed_stiffness: ActuatorStiffness,
        params: ControllerParams,
    ) -> Self {
        let estimator = StiffnessEstimator::new(&params);
        let c_env = estimator.c_env;
        SlaveController {
            arm: ArmModel::new(ws, assumed_stiffness),
            p: params,
            cycles: 0,
            initialised: false,
            x_cmd: Pose::zeros(),
            l_cmd: [0.0; 4],
            tare: SensorTare::new(),
            comp: ToolCompensation::new(ToolModel::default()),
            window: MotionWindow::new(params.sensor_filter_cutoff_hz),
            safe: SafeStop::new(),
            stall_lift_mm: 0.0,
            position: PositionTrajectory::new(),
            contact: ContactState::new(),
            normal: NormalEstimate::new(),
            tracking: Tracking::new(),
            setpoint: SetpointPrefilter::new(),
            estimator,
            deflection: DeflectionComp::new(),
            force_law: ForceLaw::new(),
            oscillation: OscillationGuard::new(),
            shaper: InputShaper::new(),
            fixtures: Fixtures::default(),
            last: ControllerOutput {
                actuators_cmd_mm: [0.0; 4],
                commanded_pose: [0.0; 4],
                measured_pose: [0.0; 4],
                contact_normal: [0.0; 3],
                tracking_direction: [0.0; 3],
                wrench_measured: [0.0; 4],
                wrench_desired: [0.0; 4],
                normal_force_n: 0.0,
                setpoint_n: 0.0,
                env_stiffness_n_per_mm: 1.0 / c_env,
                compliance_mm_per_n: c_env,
                status: Status::Taring,
                rejection: None,
            },
        }
    }

    /// The controller with the identified tool model `tool` (`arm.tool`): its weight and
    /// inertia are taken off the sensor's reading (with `gravity_compensation` on).
    pub fn with_tool(mut self, tool: ToolModel) -> Self {
        self.comp = ToolCompensation::new(tool);
        self
    }

    /// The controller with the virtual fixtures `fixtures`: every pose it commits is
    /// limited by them ([`fixtures`]).
    pub fn with_fixtures(mut self, fixtures: &FixturesConfig) -> Self {
        self.fixtures = Fixtures::new(fixtures);
        self
    }

    /// The controller told the turntable's axis (x, y), base frame, mm (the machine's
    /// geometry): the fixtures then work in the workpiece frame through the table's
    /// measured angle ([`SlaveController::observe_turntable`]).
    pub fn with_turntable_axis(mut self, axis_mm: [f64; 2]) -> Self {
        self.fixtures.set_turntable_axis(axis_mm);
        self
    }

    /// The turntable's measured angle (its encoder) for the next [`SlaveController::step`],
    /// rad (`None`: no turntable).
    pub fn observe_turntable(&mut self, measured_rad: Option<f64>) {
        self.fixtures.observe_turntable(measured_rad);
    }

    /// The turntable's set-point for this cycle of `dt_s` seconds: the synchronous
    /// fixture's program (its speed ramped in; ramped to a stop during a safe stop); `None`
    /// without that fixture.
    pub fn turntable_command_rad(&mut self, dt_s: f64) -> Option<f64> {
        let stop = self.safe.active();
        self.fixtures.turntable_command(dt_s, stop)
    }

    /// Whether the mesh fixture (`fixtures.mesh`) moved the last committed pose.
    pub fn mesh_fixture_active(&self) -> bool {
        self.fixtures.mesh_active()
    }

    /// Whether a fixture moved the last committed pose, and in how many cycles one did.
    pub fn fixture_activity(&self) -> (bool, u64) {
        (self.fixtures.active, self.fixtures.active_cycles)
    }

    /// The arm's workspace the commands are checked against.
    pub fn workspace(&self) -> &h4_shared::kinematics::Workspace {
        &self.arm.ws
    }

    /// The parameters.
    pub fn params(&self) -> &ControllerParams {
        &self.p
    }

    /// Starts a safe stop (for a watchdog): motion stops; in contact the force set-point is
    /// held for `safe_stop_hold_s`, then ramps to zero, the arm retracts along the contact
    /// normal by `safe_stop_retract_mm`, then holds. Commands
    /// are ignored until [`SlaveController::clear_safe_stop`].
    pub fn safe_stop(&mut self) {
        self.start_safe_stop(self.p.safe_stop_hold_s);
    }

    /// A safe stop for a fault of the arm itself (a stalled spindle): no hold of the
    /// contact force (there is no link to come back), the force ramps down at once and the
    /// tool retracts.
    pub fn safe_stop_at_once(&mut self) {
        self.start_safe_stop(0.0);
    }

    /// Call each cycle while the spindle stays stalled in a safe stop: once the stop holds,
    /// the tool lifts along the machine's vertical by another `safe_stop_retract_mm`, up to
    /// `safe_stop_release_max_mm` in all, so that it comes clear of the stock and the spindle
    /// can run again (a stalled tool in a deep slot was still in it after the retract, and
    /// the stop could never be cleared). Returns whether it started a lift.
    pub fn lift_stalled_tool(&mut self) -> bool {
        if !self.safe.done() || self.stall_lift_mm >= self.p.safe_stop_release_max_mm {
            return false;
        }
        self.normal.normal = Vector3::z();
        self.safe.retract_more(self.p.safe_stop_retract_mm);
        self.stall_lift_mm += self.p.safe_stop_retract_mm;
        true
    }

    /// A safe stop for the safety monitor's trip: whatever the controller was doing (a
    /// watchdog's safe stop holding the contact force included), the force set-point goes to
    /// zero and the arm backs away along the measured force until it is below the contact
    /// threshold, retracts by `safe_stop_retract_mm` and holds.
    pub fn safety_trip(&mut self) {
        self.safe.start(false, 0.0, 0.0, 0.0);
        self.position.stop();
    }

    /// The arm did not get the last command (the safety monitor kept it): the next step
    /// starts the command again from where the encoders say the arm is, so that nothing the
    /// controller planned meanwhile reaches the arm as a jump.
    pub fn resync_to_arm(&mut self) {
        self.initialised = false;
    }

    fn start_safe_stop(&mut self, hold_s: f64) {
        if !self.safe.active() {
            self.safe.start(
                self.contact.in_contact,
                self.setpoint.value_n,
                hold_s,
                self.p.safe_stop_ramp_s,
            );
            self.position.stop();
        }
    }

    /// True while a safe stop holds the contact force it started with (`safe_stop_hold_s`
    /// not yet over): a re-pairing now finds the contact as it was.
    pub fn safe_stop_holds_contact(&self) -> bool {
        self.safe.holding_contact()
    }

    /// True while a safe stop is in progress or holding.
    pub fn is_safe_stopped(&self) -> bool {
        self.safe.active()
    }

    /// Leaves the safe stop; the next command is followed from the current pose.
    /// Cleared within the hold of a safe stop in contact, the contact (and its force loop)
    /// carries on as it was.
    pub fn clear_safe_stop(&mut self) {
        let keep_contact = self.safe.holding_contact() && self.contact.in_contact;
        self.safe.clear();
        self.stall_lift_mm = 0.0;
        self.position.stop();
        if !keep_contact {
            self.contact.leave();
        }
    }

    /// One control cycle of `dt_s` seconds (normally 0.001).
    pub fn step(&mut self, input: &ControllerInput, dt_s: f64) -> ControllerOutput {
        if !inputs_finite(input, dt_s) {
            return self.reject(Rejection::NonFiniteInput);
        }
        let dt = dt_s.min(0.1);
        self.cycles += 1;
        let pose_fk = match self.arm.ws.params.fk(&Vector4::from(input.actuators_mm)) {
            Ok(p) => p,
            Err(e) => return self.reject(Rejection::MeasuredPose(e)),
        };
        if !self.initialised {
            self.initialise(pose_fk, input.actuators_mm);
        }
        let theta = pose_fk[3];
        let raw = self.comp.remove(
            Vector4::from(input.wrench),
            theta,
            self.contact.in_contact || input.command.mode != Mode::ForceGuided,
            &self.p,
            dt,
        );
        if self.tare.taring(self.p.tare_cycles) {
            return self.tare_step(pose_fk, raw);
        }
        // Out of force control the deflection compensation fades out (no jump).
        if !(self.contact.in_contact && input.command.mode == Mode::ForceGuided) {
            self.deflection.fade();
        }
        self.window.follow_period(dt_s);
        let cx = self.measure(pose_fk, to_base(raw - self.tare.bias, theta), dt);
        let mut cmd = input.command;
        let safe_stopping = match self.safe.step(
            &input.command,
            &self.x_cmd,
            &mut self.normal.normal,
            cx.f3,
            &self.p,
            dt,
        ) {
            SafeStopStep::Inactive => false,
            SafeStopStep::RampDown(ramped) => {
                cmd = ramped;
                true
            }
            SafeStopStep::Move { mut next, status } => {
                self.contact.in_contact = false;
                // The safe stop's moves and its hold keep the force limit: something
                // pressing into the stopped tool (a moving workpiece, a fixture, a retract
                // that meets a surface) is backed away from, as in Hold mode.
                if cx.f_mag > self.p.force_limit_n {
                    guards::back_off(&mut next, &cx, self.estimator.c_env, &self.p);
                }
                return self.commit(next, &cx, 0.0, status);
            }
        };
        let speed = match guards::check_command(&cmd, &self.p, &self.arm.ws) {
            Ok(speed) => speed,
            Err(r) => return self.reject(r),
        };
        if cmd.mode != Mode::ForceGuided {
            self.contact.leave();
        }
        if cmd.mode == Mode::Hold || cmd.clutch {
            self.hold(&cx, safe_stopping)
        } else if cmd.mode == Mode::Position {
            let (next, status) =
                self.position
                    .step(&self.x_cmd, &cmd.pose, &cx, self.estimator.c_env, &self.p);
            self.commit(next, &cx, 0.0, status)
        } else {
            self.force_guided(&cmd, speed, &cx, safe_stopping)
        }
    }

    fn reject(&mut self, r: Rejection) -> ControllerOutput {
        let mut out = self.last;
        out.status = Status::Rejected;
        out.rejection = Some(r);
        out
    }

    /// The first valid cycle: the command starts where the arm is.
    fn initialise(&mut self, pose_fk: Pose, actuators_mm: [f64; 4]) {
        self.x_cmd = pose_fk;
        self.l_cmd = actuators_mm;
        self.initialised = true;
        self.window.reset([pose_fk[0], pose_fk[1], pose_fk[2]]);
    }

    /// A cycle of the sensor's tare: the arm holds still.
    fn tare_step(&mut self, pose_fk: Pose, raw: Vector4<f64>) -> ControllerOutput {
        self.tare.add(raw);
        // The bias is not known yet (the sensor's filter still settles onto the tool's
        // weight): no contact force is reported while taring, rather than the settling
        // transient (a restarted slave would otherwise show a few newtons to its master).
        let mut out = self.output(pose_fk, Vector4::zeros(), 0.0, Status::Taring);
        self.comp
            .push_command([self.x_cmd[0], self.x_cmd[1], self.x_cmd[2]]);
        out.actuators_cmd_mm = self.l_cmd;
        self.last = out;
        out
    }

    /// This cycle's measurements from the encoders' pose and the bias-corrected wrench.
    fn measure(&mut self, pose_fk: Pose, wrench: Vector4<f64>, dt: f64) -> Cycle {
        let f3 = Vector3::new(wrench[0], wrench[1], wrench[2]);
        let compliance = self.arm.at(&pose_fk, self.p.compliance_model);
        let measured_pose = compliance.deflected(pose_fk, &wrench);
        let xf = self.window.push(&pose_fk, f3);
        Cycle {
            dt_s: dt,
            pose_fk,
            measured_pose,
            wrench,
            f3,
            f_mag: f3.norm(),
            xf,
            compliance,
        }
    }

    /// Hold mode or the clutch: the command holds (backing off above the force limit).
    fn hold(&mut self, cx: &Cycle, safe_stopping: bool) -> ControllerOutput {
        self.position.stop();
        let status = if safe_stopping {
            Status::SafeStop
        } else {
            Status::Holding
        };
        let mut next = self.x_cmd;
        if cx.f_mag > self.p.force_limit_n {
            guards::back_off(&mut next, cx, self.estimator.c_env, &self.p);
        }
        self.commit(next, cx, 0.0, status)
    }

    /// ForceGuided mode: theta follows the command, rate limited; the approach until the
    /// touch, then the force loop.
    fn force_guided(
        &mut self,
        cmd: &SlaveCommand,
        speed: f64,
        cx: &Cycle,
        safe_stopping: bool,
    ) -> ControllerOutput {
        self.position.stop();
        let dt = cx.dt_s;
        let mut next = self.x_cmd;
        let dth = (cmd.pose[3] - next[3]).clamp(
            -self.p.max_theta_rate_rad_per_s * dt,
            self.p.max_theta_rate_rad_per_s * dt,
        );
        next[3] += dth;
        if !self.contact.in_contact {
            let u = self
                .contact
                .approach_direction(&next, &cmd.pose, &self.normal.normal);
            let p = &self.p;
            // At the target (no direction left) any force counts.
            let (f_push, noise_n) = if u.norm() > 0.5 {
                (-cx.f3.dot(&u), self.tare.noise_along(&u))
            } else {
                let all = Vector3::new(1.0, 1.0, 1.0);
                (cx.f_mag, self.tare.noise_along(&all))
            };
            if self.contact.touches(
                f_push,
                p.contact_threshold_n,
                noise_n,
                p.contact_noise_sigmas,
            ) {
                self.touch(cx);
            } else {
                let status =
                    self.contact
                        .approach(&mut next, &cmd.pose, &self.normal.normal, &self.p, dt);
                self.tracking.tangent = Vector3::zeros();
                let status = if safe_stopping {
                    Status::SafeStop
                } else {
                    status
                };
                return self.commit(next, cx, 0.0, status);
            }
        }
        self.contact.count_cycle();
        let (c, status) = self.control_force(&mut next, cmd, speed, cx);
        let status = if safe_stopping {
            Status::SafeStop
        } else {
            status
        };
        self.commit(next, cx, c, status)
    }

    /// First touch (or touch again): bumpless start of the force loop along the force's
    /// direction, at the force measured.
    fn touch(&mut self, cx: &Cycle) {
        let f_along = match self.p.force_axis_unit() {
            Some(a) => {
                self.normal.normal = Vector3::from(a);
                cx.f3.dot(&self.normal.normal).max(0.0)
            }
            None => {
                self.normal.normal = cx.f3 / cx.f_mag;
                cx.f_mag
            }
        };
        self.setpoint.reset(f_along);
        self.deflection.touch();
        self.force_law.touch();
        self.oscillation.touch();
        self.shaper.clear();
        self.tracking.reset_speed();
        let c_arm = along_normal(cx.compliance.lambda.as_ref(), &self.normal.normal);
        let noise_n = self.tare.noise_along(&self.normal.normal);
        self.estimator.touch(
            &self.window,
            &self.normal.normal,
            c_arm,
            self.cycles,
            noise_n,
            &self.p,
        );
    }

    /// One cycle of force control in contact, moving `next`; returns the compliance along
    /// the normal the loop used and the state.
    fn control_force(
        &mut self,
        next: &mut Pose,
        cmd: &SlaveCommand,
        speed: f64,
        cx: &Cycle,
    ) -> (f64, Status) {
        let dt = cx.dt_s;
        let lambda = cx.compliance.lambda.as_ref();
        // The normal, corrected for the depth change along the last one.
        let c_prev = along_normal(lambda, &self.normal.normal) + self.estimator.c_env;
        let inputs = NormalInputs {
            xf: cx.xf,
            f3: cx.f3,
            c_prev_mm_per_n: c_prev,
            c_env_mm_per_n: self.estimator.c_env,
            lambda: lambda.copied(),
            speed_mm_per_s: speed,
            contact_cycles: self.contact.contact_cycles,
        };
        match self.p.force_axis_unit() {
            Some(a) => self.normal.normal = Vector3::from(a),
            None => self.normal.update(&self.window, &inputs, &self.p, dt),
        }
        let n = self.normal.normal;
        let f_n = cx.f3.dot(&n);
        let vt_n = self.tracking.direct(&n, &cmd.velocity, speed);
        // The compliance along the normal: the arm's (model) plus the environment's
        // (estimate); the gains scheduled on it.
        let c_arm = along_normal(lambda, &n);
        let gains = GainSchedule::at(c_arm, self.estimator.c_env, &self.p);
        let d_sp = self
            .setpoint
            .step(cmd.force_setpoint_n, self.p.setpoint_time_constant_s, dt);
        let contact_cycles = self.contact.contact_cycles;
        self.estimator
            .update(&self.window, &n, cx.xf, c_arm, contact_cycles, &self.p);
        let c = c_arm + self.estimator.c_env;
        let sp = self.setpoint.value_n;
        let tau_comp = self.p.deflection_comp_time_constant_s;
        let full = cx.compliance.full.as_ref();
        self.deflection.update(full, &n, f_n, sp, tau_comp, dt);
        // The force law, its motion into the surface shaped (a force-limit back-off goes
        // out unshaped), plus the motion along the surface.
        let law_inputs = ForceLawInputs { f_n, sp, d_sp, c };
        let law = self
            .force_law
            .step(&law_inputs, &gains, &mut self.oscillation, &self.p, dt);
        let env_share = (1.0 / self.estimator.c_env.max(1e-9)) / gains.k_par_n_per_mm;
        let d_shaped = self
            .shaper
            .shape(law.d_depth_mm, gains.omega_m_rad_per_s, env_share, dt);
        let d_depth = if law.limited {
            law.d_depth_mm
        } else {
            d_shaped
        };
        let mut status = if law.limited {
            Status::ForceLimited
        } else {
            Status::Contact
        };
        let target_speed = if self.contact.lost {
            0.0
        } else {
            vt_n.min(self.p.max_speed_mm_per_s)
        };
        self.force_law.sent(d_depth);
        let mut mv = -n * d_depth;
        mv += self.tracking.advance(target_speed, &self.p, dt);
        let gain = self.p.track_position_gain_per_s;
        if gain > 0.0 && !self.contact.lost {
            // Towards the commanded point along the surface (its normal part is the force
            // loop's).
            let e = Vector3::new(
                cmd.pose[0] - next[0],
                cmd.pose[1] - next[1],
                cmd.pose[2] - next[2],
            );
            mv += (e - n * e.dot(&n)) * (gain * dt).min(1.0);
        }
        let feed = self.p.max_feed_mm_per_s * dt;
        if feed > 0.0 {
            // The motion along the surface within the cutter's feed limit.
            let along = mv - n * mv.dot(&n);
            let an = along.norm();
            if an > feed {
                mv -= along * (1.0 - feed / an);
            }
        }
        let dmax = self.p.max_speed_mm_per_s * dt;
        let mvn = mv.norm();
        if mvn > dmax {
            mv *= dmax / mvn;
        }
        for i in 0..3 {
            next[i] += mv[i];
        }
        // The limits.
        let c_measured = guards::measured_compliance(c_arm, cx, &n, &self.estimator, &self.p);
        let comp = self.deflection.comp;
        if guards::force_guard(next, cx, law.f_peak_n, &n, &comp, c_measured, &self.p) {
            status = Status::ForceLimited;
        }
        if guards::magnitude_limit(next, cx, self.estimator.c_env, &self.p) {
            status = Status::ForceLimited;
        }
        // A fixture holding the tool point suspends the force loop by design: the force it
        // cannot reach there is no sign of a lost contact.
        let expected_n = if self.fixtures.active {
            0.0
        } else {
            cmd.force_setpoint_n
        };
        self.estimator
            .settled((sp - f_n).abs() <= (SETTLED_SHARE * sp).max(SETTLED_MIN_N));
        if self.contact.loses(f_n, expected_n, &self.p) {
            self.estimator.lost();
            self.force_law.e_prev_n = 0.0;
            self.tracking.tangent = Vector3::zeros();
            status = Status::ContactLost;
        }
        (c, status)
    }

    fn output(
        &self,
        pose_fk: Pose,
        wrench: Vector4<f64>,
        c: f64,
        status: Status,
    ) -> ControllerOutput {
        let n = self.normal.normal;
        let t = self.tracking.tangent;
        let comp = self.deflection.comp;
        let in_contact = self.contact.in_contact;
        let sp = self.setpoint.value_n;
        ControllerOutput {
            actuators_cmd_mm: self.l_cmd,
            commanded_pose: [
                self.x_cmd[0] + comp[0],
                self.x_cmd[1] + comp[1],
                self.x_cmd[2] + comp[2],
                self.x_cmd[3] + comp[3],
            ],
            measured_pose: [pose_fk[0], pose_fk[1], pose_fk[2], pose_fk[3]],
            contact_normal: [n[0], n[1], n[2]],
            tracking_direction: [t[0], t[1], t[2]],
            wrench_measured: [wrench[0], wrench[1], wrench[2], wrench[3]],
            wrench_desired: if in_contact {
                [n[0] * sp, n[1] * sp, n[2] * sp, 0.0]
            } else {
                [0.0; 4]
            },
            normal_force_n: if in_contact {
                wrench[0] * n[0] + wrench[1] * n[1] + wrench[2] * n[2]
            } else {
                0.0
            },
            setpoint_n: if in_contact { sp } else { 0.0 },
            env_stiffness_n_per_mm: 1.0 / self.estimator.c_env,
            compliance_mm_per_n: c,
            status,
            rejection: None,
        }
    }

    /// Checks `next` against the workspace; on success it becomes the command.
    fn commit(&mut self, next: Pose, cx: &Cycle, c: f64, status: Status) -> ControllerOutput {
        let next = self.fixtures.limit(next);
        let target = next + self.deflection.comp;
        let mp = cx.measured_pose;
        let mut out = match self.arm.ws.ik(&target) {
            Ok(l) => {
                self.x_cmd = next;
                self.comp.push_command([target[0], target[1], target[2]]);
                self.l_cmd = [l[0], l[1], l[2], l[3]];
                self.output(cx.pose_fk, cx.wrench, c, status)
            }
            Err(e) => {
                self.position.stop();
                let mut out = self.output(cx.pose_fk, cx.wrench, c, Status::Rejected);
                out.rejection = Some(Rejection::Workspace(e));
                out
            }
        };
        out.measured_pose = [mp[0], mp[1], mp[2], mp[3]];
        self.last = out;
        out
    }
}

/// Whether every input is finite and the period positive.
fn inputs_finite(input: &ControllerInput, dt_s: f64) -> bool {
    let cmd = &input.command;
    input.actuators_mm.iter().all(|v| v.is_finite())
        && input.wrench.iter().all(|v| v.is_finite())
        && cmd.pose.iter().all(|v| v.is_finite())
        && cmd.velocity.iter().all(|v| v.is_finite())
        && cmd.force_setpoint_n.is_finite()
        && dt_s.is_finite()
        && dt_s > 0.0
}
