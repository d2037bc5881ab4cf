//! Time-domain passivity (Ryu–Hannaford observers and controllers, in the two-port form
//! for delayed links of Ryu, Artigas and Preusche), reusable on both ports.
//!
//! Each port counts the energy that enters the link at its side (`E_in`) and the energy the
//! link delivers at its side (`E_out`), from its *own* force and velocity, and sends both,
//! cumulative, with every message. The link is passive if, for each direction, the energy
//! delivered at the far end never exceeds the energy that entered at the near end:
//!
//! * master side (force rendered to the operator): `E_out_master(t) ≤ κ · E_in_slave(t − T)`;
//! * slave side (motion commanded to the arm): `E_out_slave(t) ≤ E_in_master(t − T) / κ`.
//!
//! `κ = scale.force / scale.motion` converts slave energy to master energy (motion and force
//! scaling change the power by that factor). Since the energies are cumulative and only grow,
//! the latest *received* value is always a lower bound of the true one: whatever delay,
//! jitter or loss, using it can only make the controller more conservative.
//!
//! * [`ImpedancePort`] (master): the input is the measured handle velocity, the output a
//!   force; its controller adds a damping force `−α v` that dissipates exactly the deficit.
//! * [`AdmittancePort`] (slave): the input is the measured contact force, the output a
//!   commanded motion; its controller adds a velocity `β F` (backing away from the force)
//!   that dissipates exactly the deficit, and an energy-bounded drift compensation pulls
//!   the commanded position back towards the master's when the observer has energy to spare.
//!
//! Units: N, mm/s, s; energies in J (N·mm × 1e-3).

use crate::vec3::dot3;
use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, check_range};

const J_PER_N_MM: f64 = 1e-3;

/// Passivity control settings (`passivity.*` in session files), the same on both sides.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PassivityParams {
    /// Passivity controllers on both ports (`false`: observers only).
    pub enabled: bool,
    /// Largest damping the master's controller adds, N·s/mm.
    pub max_damping_n_s_per_mm: f64,
    /// Largest backing-off speed the slave's controller commands, mm/s.
    pub max_correction_mm_per_s: f64,
    /// Drift compensation gain, 1/s.
    pub drift_gain_per_s: f64,
    /// Largest speed at which the slave closes a gap between where it is commanded and
    /// where the master is (drift compensation, and the catch-up on a first command or a
    /// re-anchoring), mm/s: the gap is a position the master's handle did not move the
    /// slave through, so the slave does not know what lies in it (a 10 mm catch-up at the
    /// 60 mm/s speed limit hit steel at 97 N).
    pub drift_speed_max_mm_per_s: f64,
    /// Share of the slave observer's surplus the drift compensation may spend per cycle.
    pub drift_energy_share: f64,
    /// Contact force below which the slave's controller does not act (sensor noise), N.
    pub force_floor_n: f64,
    /// How long the slave's controller remembers a contact force that has dropped, ms: its
    /// energy bound uses the larger of the force measured now and the recent force, decayed
    /// with this time constant. A contact that bounces (the force drops for a few cycles
    /// and returns) would otherwise let the motion of the low-force cycles into the surface
    /// unbounded, and book it against the force that returns. 0: the force measured now.
    pub force_hold_ms: f64,
    /// Time constant with which the master controller's damping is released after the
    /// deficit that needed it is gone, ms (0: released at once, bang-bang).
    pub damping_release_ms: f64,
    /// Energy the master controller keeps in reserve: it starts damping when its observer
    /// would fall below this, J (0: only below zero).
    pub energy_reserve_j: f64,
    /// Discrete-time bound of the master controller's damping: `(α + local damping) · dt ≤
    /// damping_step_fraction · m` along each principal direction of the handle's mass `m`
    /// (`dt`: the expected hold, `damping_hold_memory_ms`; more makes the
    /// light handle's velocity overshoot and flip sign every cycle). What the bounded
    /// damping cannot dissipate is not put out: the port then scales its force down
    /// (force limiting), so the observer stays ≥ 0 either way. 0: off (the handle then
    /// chatters under a large deficit); default 1.
    pub damping_step_fraction: f64,
    /// Memory of the master's damping bound for a late loop, ms: the bound uses the
    /// longest recent time a force was held (the interval between two cycles, a starved
    /// or stalled loop's included) instead of the nominal period, that excess decaying
    /// with this time constant. A damping held over 8 ms instead of 1 ms is 8 times the
    /// step it was bounded for (a host that starved the loop 8 ms in every 20 set the
    /// handle vibrating, −200 mJ, `tests/host_stalls.rs`). 0: the nominal period only.
    pub damping_hold_memory_ms: f64,
    /// The slave hands the part of its observer's surplus above this reserve back to the
    /// master (slave units), J; negative: never. Energy the operator put in that the slave
    /// has not spent then pays for the master's model updates (the plane moved out, a
    /// stiffer surface) instead of lying idle on the slave's side.
    pub return_reserve_j: f64,
    /// Rate at which the surplus above the reserve is handed back, 1/s.
    pub return_rate_per_s: f64,
}

impl Default for PassivityParams {
    fn default() -> Self {
        PassivityParams {
            enabled: true,
            max_damping_n_s_per_mm: 2.0,
            max_correction_mm_per_s: 50.0,
            drift_gain_per_s: 10.0,
            drift_speed_max_mm_per_s: 20.0,
            drift_energy_share: 0.2,
            force_floor_n: 0.3,
            force_hold_ms: 100.0,
            damping_release_ms: 20.0,
            energy_reserve_j: 0.0,
            damping_step_fraction: 1.0,
            damping_hold_memory_ms: 100.0,
            return_reserve_j: 0.01,
            return_rate_per_s: 10.0,
        }
    }
}

impl PassivityParams {
    /// Checks every field; errors name the key with `prefix` (e.g. `"passivity."`).
    pub fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        check_range(
            &format!("{prefix}max_damping_n_s_per_mm"),
            self.max_damping_n_s_per_mm,
            0.0,
            1e3,
            "N·s/mm",
        )?;
        check_range(
            &format!("{prefix}max_correction_mm_per_s"),
            self.max_correction_mm_per_s,
            0.0,
            1e4,
            "mm/s",
        )?;
        check_range(
            &format!("{prefix}drift_speed_max_mm_per_s"),
            self.drift_speed_max_mm_per_s,
            0.0,
            1e4,
            "mm/s",
        )?;
        check_range(
            &format!("{prefix}drift_gain_per_s"),
            self.drift_gain_per_s,
            0.0,
            100.0,
            "1/s",
        )?;
        check_range(
            &format!("{prefix}drift_energy_share"),
            self.drift_energy_share,
            0.0,
            1.0,
            "",
        )?;
        check_range(
            &format!("{prefix}force_floor_n"),
            self.force_floor_n,
            0.0,
            100.0,
            "N",
        )?;
        check_range(
            &format!("{prefix}force_hold_ms"),
            self.force_hold_ms,
            0.0,
            1e4,
            "ms",
        )?;
        check_range(
            &format!("{prefix}damping_release_ms"),
            self.damping_release_ms,
            0.0,
            1e4,
            "ms",
        )?;
        check_range(
            &format!("{prefix}energy_reserve_j"),
            self.energy_reserve_j,
            0.0,
            100.0,
            "J",
        )?;
        check_range(
            &format!("{prefix}damping_step_fraction"),
            self.damping_step_fraction,
            0.0,
            2.0,
            "",
        )?;
        check_range(
            &format!("{prefix}damping_hold_memory_ms"),
            self.damping_hold_memory_ms,
            0.0,
            1e4,
            "ms",
        )?;
        check_range(
            &format!("{prefix}return_reserve_j"),
            self.return_reserve_j,
            -1.0,
            100.0,
            "J",
        )?;
        check_range(
            &format!("{prefix}return_rate_per_s"),
            self.return_rate_per_s,
            0.0,
            1e3,
            "1/s",
        )
    }
}

/// Cumulative energy flows at one port, J.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PortEnergy {
    /// Energy that has entered the link at this port.
    pub in_j: f64,
    /// Energy the link has delivered at this port.
    pub out_j: f64,
    /// Energy the passivity controller dissipated at this port.
    pub dissipated_j: f64,
}

impl PortEnergy {
    fn add_power(&mut self, power_out_n_mm_per_s: f64, dt_s: f64) {
        let e = power_out_n_mm_per_s * dt_s * J_PER_N_MM;
        if e >= 0.0 {
            self.out_j += e;
        } else {
            self.in_j -= e;
        }
    }
}

/// The master's port: observer and (force-side) passivity controller.
#[derive(Clone, Copy, Debug, Default)]
pub struct ImpedancePort {
    /// Cumulative flows at this port.
    pub energy: PortEnergy,
    remote_in_j: f64,
    /// Largest damping the controller may add, N·s/mm (bounds the force of one cycle).
    pub max_damping_n_s_per_mm: f64,
    /// Release time constant of the damping, ms (0: bang-bang).
    pub damping_release_ms: f64,
    /// Reserve below which the controller starts damping, J.
    pub energy_reserve_j: f64,
    /// This cycle's discrete-time bound of the damping, N·s/mm (`None`: only
    /// `max_damping_n_s_per_mm`); the caller sets it from the device's effective mass.
    pub damping_step_limit_n_s_per_mm: Option<f64>,
    /// Cycles in which the controller limited the force (bounded damping was not enough).
    pub limited_cycles: u64,
    /// The handle's (smallest effective) mass as the caller knows it, kg (`None`: the
    /// force limit counts only `F · v · dt`). A force held over a cycle also accelerates
    /// the handle: it does up to `|F|² dt² / 2m` more work than `F · v · dt`, which the
    /// limit then counts too.
    pub mass_estimate_kg: Option<f64>,
    /// Pairings this port has had (1 + the times [`ImpedancePort::new_pairing`] was called).
    pub pairings: u64,
    alpha: f64,
}

/// What the master's port did this cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ImpedanceStep {
    /// The force to render after the controller, N.
    pub force_n: [f64; 3],
    /// Damping the controller added, N·s/mm.
    pub damping_n_s_per_mm: f64,
    /// Observer after this cycle: `κ E_in_remote − E_out_local`, J.
    pub observed_j: f64,
}

impl ImpedancePort {
    /// A port whose controller adds at most `max_damping_n_s_per_mm`.
    pub fn new(max_damping_n_s_per_mm: f64) -> Self {
        ImpedancePort {
            max_damping_n_s_per_mm,
            ..ImpedancePort::default()
        }
    }

    /// A port with the master-side settings of `p` (damping cap, release, reserve).
    pub fn from_params(p: &PassivityParams) -> Self {
        ImpedancePort {
            damping_release_ms: p.damping_release_ms,
            energy_reserve_j: p.energy_reserve_j,
            ..ImpedancePort::new(p.max_damping_n_s_per_mm)
        }
    }

    /// Takes the far end's cumulative input energy, already converted to this port's units
    /// (J). Older (smaller) values than one already seen in this pairing are ignored.
    pub fn receive_remote_in(&mut self, remote_in_j: f64) {
        if remote_in_j.is_finite() && remote_in_j > self.remote_in_j {
            self.remote_in_j = remote_in_j;
        }
    }

    /// A new pairing (the far end restarted, or the link was re-engaged after a safe stop):
    /// a new ledger. Both cumulative flows and the far end's input start again from zero,
    /// so neither side inherits the other's lifetime energy as budget; the damping is
    /// released. (`dissipated_j` stays cumulative: it is a statistic, not a budget.)
    pub fn new_pairing(&mut self) {
        self.energy.in_j = 0.0;
        self.energy.out_j = 0.0;
        self.remote_in_j = 0.0;
        self.alpha = 0.0;
        self.pairings += 1;
    }

    /// The observer: energy available for output at this port, J (negative: the link has
    /// generated energy).
    pub fn observed_j(&self) -> f64 {
        self.remote_in_j - self.energy.out_j
    }

    /// One cycle: `force_n` is the force the link wants rendered, `velocity_mm_per_s` the
    /// measured (estimated) handle velocity. With `control` the force is first damped
    /// (within the damping bounds), then, if that is not enough, scaled down so that this
    /// cycle's output `F · v · dt` does not exceed what the observer holds: the energy put
    /// out never exceeds the observer's, by construction (up to the difference between the
    /// estimated velocity and the displacement booked). Without `control` it is only
    /// observed.
    pub fn step(
        &mut self,
        force_n: [f64; 3],
        velocity_mm_per_s: [f64; 3],
        dt_s: f64,
        control: bool,
    ) -> ImpedanceStep {
        let p0 = dot3(&force_n, &velocity_mm_per_s);
        let v2 = dot3(&velocity_mm_per_s, &velocity_mm_per_s);
        let mut force = force_n;
        let mut alpha = 0.0;
        if control {
            // The damping the deficit needs this cycle (acting before the observer reaches
            // zero when a reserve is set) ...
            let mut need = 0.0;
            if p0 > 0.0 && v2 > 1e-12 {
                let w = self.observed_j() - self.energy_reserve_j - p0 * dt_s * J_PER_N_MM;
                if w < 0.0 {
                    need = -w / (J_PER_N_MM * dt_s * v2);
                }
            }
            // ... or, if more, the previous damping released with a first-order decay:
            // extra damping only dissipates more, so passivity holds either way.
            let decay = if self.damping_release_ms > 0.0 {
                (-dt_s * 1e3 / self.damping_release_ms).exp()
            } else {
                0.0
            };
            // With a discrete-time bound (the handle's mass per cycle) the damping never
            // exceeds it: more would make the handle's velocity flip sign every cycle, and
            // the observer, booking the velocity sampled at the cycle's start, would count
            // as dissipated what the force really feeds into the handle. What the bounded
            // damping cannot dissipate stays in the observer (it goes below zero) and is
            // dissipated in the following cycles.
            let held = self.alpha * decay;
            let cap = match self.damping_step_limit_n_s_per_mm {
                Some(l) => self.max_damping_n_s_per_mm.min(l.max(0.0)),
                None => self.max_damping_n_s_per_mm,
            };
            alpha = need.max(held).min(cap);
            self.alpha = alpha;
            if alpha > 0.0 {
                for (f, v) in force.iter_mut().zip(velocity_mm_per_s.iter()) {
                    *f -= alpha * v;
                }
                self.energy.dissipated_j += alpha * v2 * dt_s * J_PER_N_MM;
            }
            // Force limiting (energy bounding): what the bounded damping could not
            // dissipate is not put out. The force is scaled down (never reversed, so it
            // cannot make the handle chatter as more damping would) until this cycle's
            // output fits what the observer holds: the energy put out never exceeds the
            // observer's, whatever the damping bound.
            let s = self.output_share(&force, &velocity_mm_per_s, dt_s);
            if s < 1.0 {
                for f in force.iter_mut() {
                    *f *= s;
                }
                self.limited_cycles += 1;
            }
        }
        ImpedanceStep {
            force_n: force,
            damping_n_s_per_mm: alpha,
            observed_j: self.observed_j() - dot3(&force, &velocity_mm_per_s).max(0.0) * dt_s * 1e-3,
        }
    }

    /// The largest share `s ∈ [0, 1]` of `force` whose work over the cycle, `s F · v dt`
    /// plus (with a mass estimate) the acceleration's `s² |F|² dt² / 2m`, fits what the
    /// observer holds above the reserve.
    fn output_share(&self, force: &[f64; 3], v: &[f64; 3], dt_s: f64) -> f64 {
        let e = (self.observed_j() - self.energy_reserve_j).max(0.0);
        let a = dot3(force, v) * dt_s * J_PER_N_MM;
        let b = match self.mass_estimate_kg {
            // N² s² / kg = N·m = 1 J.
            Some(m) if m > 0.0 => dot3(force, force) * dt_s * dt_s / (2.0 * m),
            _ => 0.0,
        };
        if a + b <= e {
            return 1.0;
        }
        let s = if b > 1e-300 {
            (-a + (a * a + 4.0 * b * e).sqrt()) / (2.0 * b)
        } else if a > 0.0 {
            e / a
        } else {
            1.0
        };
        if s.is_finite() {
            s.clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// Books the work of the force actually rendered over one cycle (after saturation, held
    /// for the cycle) from the handle's measured displacement over that cycle: `F_k · (x_k+1 −
    /// x_k)`, the exact work of a held force. (Booking `F_k · v_k · dt` with the velocity
    /// sampled at the cycle's start gets the sign wrong whenever the velocity reverses within
    /// the cycle.) Non-finite input is ignored.
    pub fn commit_displacement(&mut self, rendered_n: [f64; 3], displacement_mm: [f64; 3]) {
        let w = dot3(&rendered_n, &displacement_mm);
        if w.is_finite() {
            self.energy.add_power(w, 1.0);
        }
    }
}

/// The slave's port: observer, (velocity-side) passivity controller and energy-bounded
/// position-drift compensation.
#[derive(Clone, Copy, Debug, Default)]
pub struct AdmittancePort {
    /// Cumulative flows at this port.
    pub energy: PortEnergy,
    remote_in_j: f64,
    /// Commanded position minus the desired one, mm (the drift the controller caused).
    pub drift_mm: [f64; 3],
    /// Drift compensation gain, 1/s (how fast the drift is closed when energy allows).
    pub drift_gain_per_s: f64,
    /// Share of the observer's surplus the drift compensation may spend per cycle (0 to 1).
    pub drift_energy_share: f64,
    /// Largest backing-off speed the controller may command, mm/s.
    pub max_correction_mm_per_s: f64,
    /// Largest speed of the drift compensation, mm/s (0: no bound; see
    /// [`PassivityParams::drift_speed_max_mm_per_s`]).
    pub drift_speed_max_mm_per_s: f64,
    /// Contact force below which the controller does not act, N.
    pub force_floor_n: f64,
    /// Time constant of the force memory the energy bound uses, ms (see
    /// [`PassivityParams::force_hold_ms`]).
    pub force_hold_ms: f64,
    /// The remembered contact force, N (decays with `force_hold_ms`).
    held_force_n: [f64; 3],
    /// Surplus above this is handed back to the master, J (negative: never).
    pub return_reserve_j: f64,
    /// Rate of the hand-back, 1/s.
    pub return_rate_per_s: f64,
    /// Energy handed back to the master so far, J (no longer this port's to spend).
    pub returned_j: f64,
    /// Pairings this port has had (the times [`AdmittancePort::new_pairing`] was called).
    pub pairings: u64,
}

/// What the slave's port did this cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct AdmittanceStep {
    /// The commanded velocity after the controller, mm/s.
    pub velocity_mm_per_s: [f64; 3],
    /// The position to command this cycle, mm.
    pub target_mm: [f64; 3],
    /// Admittance the controller added, mm/(N·s).
    pub admittance_mm_per_n_s: f64,
    /// Observer after this cycle, J.
    pub observed_j: f64,
}

impl AdmittancePort {
    /// A port with the given drift compensation and correction bound.
    pub fn new(
        drift_gain_per_s: f64,
        drift_energy_share: f64,
        max_correction_mm_per_s: f64,
    ) -> Self {
        AdmittancePort {
            drift_gain_per_s,
            drift_energy_share,
            max_correction_mm_per_s,
            force_floor_n: 0.3,
            return_reserve_j: -1.0,
            ..AdmittancePort::default()
        }
    }

    /// A port with the slave-side settings of `p`.
    pub fn from_params(p: &PassivityParams) -> Self {
        AdmittancePort {
            force_floor_n: p.force_floor_n,
            force_hold_ms: p.force_hold_ms,
            drift_speed_max_mm_per_s: p.drift_speed_max_mm_per_s,
            return_reserve_j: p.return_reserve_j,
            return_rate_per_s: p.return_rate_per_s,
            ..AdmittancePort::new(
                p.drift_gain_per_s,
                p.drift_energy_share,
                p.max_correction_mm_per_s,
            )
        }
    }

    /// Takes the far end's cumulative input energy in this port's units, J (the largest
    /// seen in this pairing).
    pub fn receive_remote_in(&mut self, remote_in_j: f64) {
        if remote_in_j.is_finite() && remote_in_j > self.remote_in_j {
            self.remote_in_j = remote_in_j;
        }
    }

    /// A new pairing (the far end restarted, or re-engagement after a safe stop): a new
    /// ledger, see [`ImpedancePort::new_pairing`]. The drift is kept (it is where the arm
    /// is, not energy) and is closed with the new ledger's energy.
    pub fn new_pairing(&mut self) {
        self.energy.in_j = 0.0;
        self.energy.out_j = 0.0;
        self.remote_in_j = 0.0;
        self.returned_j = 0.0;
        self.pairings += 1;
    }

    /// Books the work of one cycle's motion from the forces of the same instants: the
    /// displacement commanded over the cycle against the mean of the forces measured at
    /// its start and at its end (trapezoid), `−½(F_k + F_k+1) · Δx`. Booking the force of
    /// the cycle before against this cycle's motion would lag the force by a cycle (and
    /// the sensor's filter by more), crediting a phantom input of about `k·τ·∫v²` on a
    /// stiff wall. Non-finite input is ignored.
    pub fn commit_work(
        &mut self,
        force_start_n: [f64; 3],
        force_end_n: [f64; 3],
        displacement_mm: [f64; 3],
    ) {
        let mut f = [0.0; 3];
        for i in 0..3 {
            f[i] = 0.5 * (force_start_n[i] + force_end_n[i]);
        }
        let w = -dot3(&f, &displacement_mm);
        if w.is_finite() {
            self.energy.add_power(w, 1.0);
        }
    }

    /// The observer, J.
    pub fn observed_j(&self) -> f64 {
        self.remote_in_j - self.energy.out_j - self.returned_j
    }

    /// The energy the far end may count as entered at this port, J: what entered here plus
    /// what was handed back ([`AdmittancePort::hand_back`]). Sent on the wire as the
    /// feedback's `energy_in_j`.
    pub fn available_to_remote_j(&self) -> f64 {
        self.energy.in_j + self.returned_j
    }

    /// Hands the surplus above the reserve back to the far end at the return rate: it
    /// leaves this port's observer at once and reaches the far end's with the next
    /// feedback (`available_to_remote_j`). Both sides together still never give out more
    /// than was put in: the slave can no longer spend what it handed back.
    pub fn hand_back(&mut self, dt_s: f64) {
        if self.return_reserve_j < 0.0 {
            return;
        }
        let surplus = self.observed_j() - self.return_reserve_j;
        if surplus > 0.0 {
            self.returned_j += surplus * (self.return_rate_per_s * dt_s).min(1.0);
        }
    }

    /// One cycle of a position-commanded arm. `commanded_mm` is where the arm was commanded
    /// last cycle, `desired_mm` where the link asks it to be now and `desired_mm_per_s` the
    /// link's velocity; `force_n` the measured contact force (the force the environment
    /// exerts on the tool); `max_speed_mm_per_s` the arm's speed limit.
    ///
    /// Without `control` the arm is sent to `desired_mm`. With it, the motion of this cycle
    /// starts from `commanded_mm`: the link's velocity plus a drift compensation
    /// (`drift_gain_per_s` × the remaining gap, paid for only from `drift_energy_share` of
    /// the observer's surplus), then limited so that the energy it puts into the contact
    /// does not exceed what the observer holds, then, if the observer is in deficit, backed
    /// away from the force (at most `max_correction_mm_per_s`) to dissipate the deficit.
    /// The gap to `desired_mm` that remains is [`AdmittancePort::drift_mm`].
    #[allow(clippy::too_many_arguments)]
    pub fn step_position(
        &mut self,
        commanded_mm: [f64; 3],
        desired_mm: [f64; 3],
        desired_mm_per_s: [f64; 3],
        force_n: [f64; 3],
        max_speed_mm_per_s: f64,
        dt_s: f64,
        control: bool,
    ) -> AdmittanceStep {
        if !control {
            self.drift_mm = [0.0; 3];
            let mut v = [0.0; 3];
            for i in 0..3 {
                v[i] = (desired_mm[i] - commanded_mm[i]) / dt_s;
            }
            return AdmittanceStep {
                velocity_mm_per_s: v,
                target_mm: desired_mm,
                admittance_mm_per_n_s: 0.0,
                observed_j: self.observed_j(),
            };
        }
        // The energy bound uses the bounding force (the measured force, or the larger
        // recent or expected one); the dissipation only the measured force, which is what
        // the booking of the motion will count.
        let bound_n = self.bounding_force(force_n, dt_s);
        let power = |v: &[f64; 3]| -dot3(&bound_n, v);
        let b2 = dot3(&bound_n, &bound_n);
        let f2 = dot3(&force_n, &force_n);
        let floor2 = self.force_floor_n.max(1e-6).powi(2);
        let bounded = b2 > floor2;
        let budget = self.observed_j().max(0.0) / (dt_s * J_PER_N_MM);
        // The link's motion plus the drift compensation.
        let mut v = desired_mm_per_s;
        let mut vc = [0.0; 3];
        for i in 0..3 {
            let gap = desired_mm[i] - commanded_mm[i] - desired_mm_per_s[i] * dt_s;
            vc[i] = (self.drift_gain_per_s * gap).clamp(-gap.abs() / dt_s, gap.abs() / dt_s);
        }
        let vc_speed = dot3(&vc, &vc).sqrt();
        if self.drift_speed_max_mm_per_s > 0.0 && vc_speed > self.drift_speed_max_mm_per_s {
            for c in vc.iter_mut() {
                *c *= self.drift_speed_max_mm_per_s / vc_speed;
            }
        }
        let pc = power(&vc);
        let share = if bounded && pc > 0.0 {
            let avail = self.drift_energy_share * (budget - power(&v).max(0.0)).max(0.0);
            (avail / pc).min(1.0)
        } else {
            1.0
        };
        for i in 0..3 {
            v[i] += share * vc[i];
        }
        let speed = dot3(&v, &v).sqrt();
        if speed > max_speed_mm_per_s && speed > 0.0 {
            for vi in v.iter_mut() {
                *vi *= max_speed_mm_per_s / speed;
            }
        }
        let mut beta = 0.0;
        // Below the noise floor the force's direction is noise: correcting along it would
        // steer free motion sideways.
        if bounded {
            // Limit the energy output to what the observer holds (this removes only the
            // part of the motion that pushes into the force).
            let p0 = power(&v);
            if p0 > budget {
                let b = (p0 - budget) / b2;
                for (vi, f) in v.iter_mut().zip(bound_n.iter()) {
                    *vi += b * f;
                }
                beta += b * b2.sqrt() / f2.sqrt().max(self.force_floor_n.max(1e-6));
                self.energy.dissipated_j += b * b2 * dt_s * J_PER_N_MM;
            }
        }
        if f2 > floor2 {
            // Dissipate a deficit by backing away from the measured force.
            let w = self.observed_j();
            if w < 0.0 {
                let b =
                    (-w / (J_PER_N_MM * dt_s * f2)).min(self.max_correction_mm_per_s / f2.sqrt());
                for (vi, f) in v.iter_mut().zip(force_n.iter()) {
                    *vi += b * f;
                }
                beta += b;
                self.energy.dissipated_j += b * f2 * dt_s * J_PER_N_MM;
            }
        }
        let mut target = [0.0; 3];
        for i in 0..3 {
            target[i] = commanded_mm[i] + v[i] * dt_s;
            self.drift_mm[i] = target[i] - desired_mm[i];
        }
        AdmittanceStep {
            velocity_mm_per_s: v,
            target_mm: target,
            admittance_mm_per_n_s: beta,
            observed_j: self.observed_j(),
        }
    }

    /// Books the motion the arm was actually commanded this cycle (`velocity_mm_per_s`,
    /// after the controller's own limits) against the measured contact force: the observer
    /// counts what really left the link, not what was asked for.
    pub fn commit(&mut self, force_n: [f64; 3], velocity_mm_per_s: [f64; 3], dt_s: f64) {
        if force_n
            .iter()
            .chain(velocity_mm_per_s.iter())
            .all(|x| x.is_finite())
        {
            self.energy
                .add_power(-dot3(&force_n, &velocity_mm_per_s), dt_s);
        }
    }

    /// The force the energy bound uses: the force measured now or, when the remembered
    /// force (decayed with `force_hold_ms`) is larger, the remembered one. A motion chosen
    /// against the larger force puts out no more than the bound allows when the force
    /// returns within the memory's time (a bounce).
    fn bounding_force(&mut self, force_n: [f64; 3], dt_s: f64) -> [f64; 3] {
        if !force_n.iter().all(|f| f.is_finite()) {
            return self.held_force_n;
        }
        let decay = if self.force_hold_ms > 0.0 {
            (-dt_s * 1e3 / self.force_hold_ms).exp()
        } else {
            0.0
        };
        for h in self.held_force_n.iter_mut() {
            *h *= decay;
        }
        if dot3(&force_n, &force_n) >= dot3(&self.held_force_n, &self.held_force_n) {
            self.held_force_n = force_n;
        }
        self.held_force_n
    }

    /// Sets the drift (a re-anchoring that turns a gap into drift to be closed passively).
    pub fn set_drift(&mut self, drift_mm: [f64; 3]) {
        if drift_mm.iter().all(|d| d.is_finite()) {
            self.drift_mm = drift_mm;
        }
    }

    /// Forgets the drift (after a re-anchoring that absorbs it).
    pub fn clear_drift(&mut self) {
        self.drift_mm = [0.0; 3];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A link that returns more energy than it received is caught and corrected: the
    /// master's output never exceeds what the slave put in.
    #[test]
    fn impedance_port_never_outputs_more_than_received() {
        let mut port = ImpedancePort::new(1e9);
        port.receive_remote_in(0.001);
        let dt = 0.001;
        for _ in 0..1000 {
            let s = port.step([10.0, 0.0, 0.0], [5.0, 0.0, 0.0], dt, true);
            port.commit_displacement(s.force_n, [5.0 * dt, 0.0, 0.0]);
        }
        assert!(port.observed_j() >= -1e-12, "{}", port.observed_j());
        assert!(port.energy.dissipated_j > 0.0);
        // Without control the same input drives the observer far below zero.
        let mut off = ImpedancePort::new(1e9);
        off.receive_remote_in(0.001);
        for _ in 0..1000 {
            let s = off.step([10.0, 0.0, 0.0], [5.0, 0.0, 0.0], dt, false);
            off.commit_displacement(s.force_n, [5.0 * dt, 0.0, 0.0]);
        }
        assert!(off.observed_j() < -0.04, "{}", off.observed_j());
    }

    /// With a release time the damping decays after the deficit instead of switching off:
    /// it stays on for a while, dissipates at least as much as bang-bang, and the observer
    /// stays ≥ 0 either way.
    #[test]
    fn impedance_port_damping_release_decays_and_stays_passive() {
        let dt = 0.001;
        let run = |release_ms: f64| {
            let mut port = ImpedancePort::from_params(&PassivityParams {
                damping_release_ms: release_ms,
                ..PassivityParams::default()
            });
            port.receive_remote_in(0.0005);
            let mut after = Vec::new();
            for k in 0..200 {
                // A 20-cycle burst that needs damping, then a small force with the handle
                // moving (no deficit any more once energy arrives).
                let (f, v) = if k < 20 { (10.0, 5.0) } else { (0.0, 5.0) };
                if k == 20 {
                    port.receive_remote_in(1.0);
                }
                let s = port.step([f, 0.0, 0.0], [v, 0.0, 0.0], dt, true);
                port.commit_displacement(s.force_n, [v * dt, 0.0, 0.0]);
                assert!(port.observed_j() >= -1e-12, "{}", port.observed_j());
                if k >= 20 {
                    after.push(s.damping_n_s_per_mm);
                }
            }
            (after, port.energy.dissipated_j)
        };
        let (bang, e_bang) = run(0.0);
        let (smooth, e_smooth) = run(20.0);
        assert!(bang.iter().all(|&a| a == 0.0), "{bang:?}");
        assert!(smooth[0] > 0.0 && smooth[0] > smooth[30] && smooth[30] > smooth[150]);
        assert!(smooth[150] < 0.01 * smooth[0], "{smooth:?}");
        assert!(e_smooth > e_bang);
    }

    /// A discrete-time bound holds all of the damping; what it cannot dissipate the port
    /// does not put out (force limiting): the observer never goes below zero.
    #[test]
    fn impedance_port_step_limit_bounds_the_damping_and_limits_the_force() {
        let dt = 0.001;
        let mut port = ImpedancePort::from_params(&PassivityParams::default());
        port.damping_step_limit_n_s_per_mm = Some(0.1);
        port.receive_remote_in(0.0005);
        let mut lowest = 0.0_f64;
        for k in 0..200 {
            let f = if k < 20 { 10.0 } else { 0.0 };
            if k == 20 {
                port.receive_remote_in(1.0);
            }
            let s = port.step([f, 0.0, 0.0], [5.0, 0.0, 0.0], dt, true);
            port.commit_displacement(s.force_n, [5.0 * dt, 0.0, 0.0]);
            assert!(s.damping_n_s_per_mm <= 0.1 + 1e-12, "{k}: {s:?}");
            assert!(s.force_n[0] <= f + 1e-12, "{k}: {s:?}");
            lowest = lowest.min(port.observed_j());
        }
        assert!(lowest >= -1e-12, "{lowest}");
        assert!(port.limited_cycles > 0);
        assert!(port.observed_j() > 0.0, "{}", port.observed_j());
        // The same deficit with force limiting off (observer only) goes below zero: the
        // limit is what holds it.
        let mut off = ImpedancePort::from_params(&PassivityParams::default());
        off.receive_remote_in(0.0005);
        for _ in 0..20 {
            let s = off.step([10.0, 0.0, 0.0], [5.0, 0.0, 0.0], dt, false);
            off.commit_displacement(s.force_n, [5.0 * dt, 0.0, 0.0]);
        }
        assert!(off.observed_j() < -1e-4, "{}", off.observed_j());
    }

    /// A new pairing starts a new ledger on both ports: nothing of the old pairing's
    /// energy is budget any more, and the far end's new (small) cumulative values count.
    #[test]
    fn new_pairing_starts_a_new_ledger_on_both_ports() {
        let dt = 0.001;
        let mut m = ImpedancePort::from_params(&PassivityParams::default());
        m.receive_remote_in(5.0);
        m.commit_displacement([10.0, 0.0, 0.0], [-1.0, 0.0, 0.0]);
        assert!(m.observed_j() > 4.0);
        m.new_pairing();
        assert_eq!(m.observed_j(), 0.0);
        assert_eq!((m.energy.in_j, m.energy.out_j), (0.0, 0.0));
        m.receive_remote_in(0.001);
        assert!((m.observed_j() - 0.001).abs() < 1e-15);
        // With no budget the port puts nothing out.
        let s = m.step([10.0, 0.0, 0.0], [100.0, 0.0, 0.0], dt, true);
        assert!(dot3(&s.force_n, &[100.0, 0.0, 0.0]) * dt * 1e-3 <= 0.001 + 1e-12);
        let mut sl = AdmittancePort::from_params(&PassivityParams::default());
        sl.receive_remote_in(5.0);
        sl.hand_back(dt);
        sl.new_pairing();
        assert_eq!(sl.observed_j(), 0.0);
        assert_eq!(sl.available_to_remote_j(), 0.0);
        assert_eq!(sl.pairings, 1);
    }

    /// The slave books the displacement against the forces of the same instants: moving
    /// into a force that rises from 0 to 20 N over the cycle is 10 N times the
    /// displacement of output, not 0 (the force of the cycle before).
    #[test]
    fn admittance_port_books_force_and_motion_of_the_same_instant() {
        let mut port = AdmittancePort::from_params(&PassivityParams::default());
        port.commit_work([0.0, 0.0, 0.0], [0.0, 0.0, 20.0], [0.0, 0.0, -0.1]);
        assert!(
            (port.energy.out_j - 1e-3).abs() < 1e-15,
            "{:?}",
            port.energy
        );
        port.commit_work([0.0, 0.0, 20.0], [0.0, 0.0, 10.0], [0.0, 0.0, 0.1]);
        assert!(
            (port.energy.in_j - 1.5e-3).abs() < 1e-15,
            "{:?}",
            port.energy
        );
        port.commit_work([f64::NAN, 0.0, 0.0], [0.0; 3], [0.0, 0.0, 1.0]);
        assert!((port.energy.in_j - 1.5e-3).abs() < 1e-15);
    }

    /// Booked from the displacement, a force whose handle reverses within the cycle is
    /// counted as the work it really did; the start-of-cycle velocity would have the sign
    /// wrong.
    #[test]
    fn impedance_port_books_the_work_of_the_displacement() {
        let mut port = ImpedancePort::new(0.0);
        // 10 N along x; the handle moved −0.01 mm over the cycle (into the force): input.
        port.commit_displacement([10.0, 0.0, 0.0], [-0.01, 0.0, 0.0]);
        assert!((port.energy.in_j - 1e-4).abs() < 1e-15, "{:?}", port.energy);
        assert_eq!(port.energy.out_j, 0.0);
        // Then +0.02 mm (out along the force): output, whatever the sampled velocity was.
        port.commit_displacement([10.0, 0.0, 0.0], [0.02, 0.0, 0.0]);
        assert!(
            (port.energy.out_j - 2e-4).abs() < 1e-15,
            "{:?}",
            port.energy
        );
        port.commit_displacement([f64::NAN, 0.0, 0.0], [0.02, 0.0, 0.0]);
        assert!((port.energy.out_j - 2e-4).abs() < 1e-15);
    }

    /// The slave hands its surplus above the reserve back: its own observer falls to the
    /// reserve, what the far end may count grows by the same amount, and the sum of what
    /// both sides may still give out is unchanged.
    #[test]
    fn admittance_port_hands_back_the_surplus_above_the_reserve() {
        let mut port = AdmittancePort::from_params(&PassivityParams {
            return_reserve_j: 0.002,
            return_rate_per_s: 10.0,
            ..PassivityParams::default()
        });
        port.receive_remote_in(0.010);
        let before = port.observed_j() + port.available_to_remote_j();
        for _ in 0..2000 {
            port.hand_back(0.001);
        }
        assert!(
            (port.observed_j() - 0.002).abs() < 1e-9,
            "{}",
            port.observed_j()
        );
        assert!((port.available_to_remote_j() - 0.008).abs() < 1e-9);
        assert!((port.observed_j() + port.available_to_remote_j() - before).abs() < 1e-12);
        // A negative reserve never hands anything back.
        let mut never = AdmittancePort::new(2.0, 0.5, 1e6);
        never.receive_remote_in(0.010);
        never.hand_back(0.001);
        assert_eq!(never.returned_j, 0.0);
    }

    #[test]
    fn admittance_port_stops_at_the_budget_and_compensates_drift_when_energy_arrives() {
        let mut port = AdmittancePort::new(2.0, 0.5, 1e6);
        let dt = 0.001;
        let f = [0.0, 0.0, 20.0];
        // The link asks to push into a 20 N force at 5 mm/s with no energy received: the
        // arm does not advance, the observer stays >= 0, the gap becomes drift.
        let mut x = [0.0; 3];
        for k in 1..=100 {
            let desired = [0.0, 0.0, -0.005 * k as f64];
            let s = port.step_position(x, desired, [0.0, 0.0, -5.0], f, 100.0, dt, true);
            port.commit(f, s.velocity_mm_per_s, dt);
            x = s.target_mm;
        }
        assert!(port.observed_j() >= -1e-12, "{}", port.observed_j());
        assert!(x[2].abs() < 1e-9, "{x:?}");
        assert!((port.drift_mm[2] - 0.5).abs() < 1e-9, "{:?}", port.drift_mm);
        // Energy arrives: the drift closes, and the observer never goes negative.
        port.receive_remote_in(10.0);
        let desired = [0.0, 0.0, -0.5];
        for _ in 0..3000 {
            let s = port.step_position(x, desired, [0.0; 3], f, 100.0, dt, true);
            port.commit(f, s.velocity_mm_per_s, dt);
            x = s.target_mm;
            assert!(port.observed_j() >= -1e-12);
        }
        assert!(port.drift_mm[2].abs() < 0.01, "{:?}", port.drift_mm);
        // Without control the arm is simply sent where the link asks.
        let mut off = AdmittancePort::new(2.0, 0.5, 1e6);
        let s = off.step_position([0.0; 3], [0.0, 0.0, -1.0], [0.0; 3], f, 100.0, dt, false);
        assert_eq!(s.target_mm, [0.0, 0.0, -1.0]);
    }
}
