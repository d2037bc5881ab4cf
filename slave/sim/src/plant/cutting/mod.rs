//! Cutting: a workpiece that is really cut.
//!
//! * `stock`: the block as a height field, lowered where the tool's swept volume goes below
//!   it ([`Stock::sweep`], at each removal update, along the tool tip's path since the last);
//! * `tool`: ball-end and flat end mills;
//! * `mechanics`: the mechanistic cutting force on the tool's envelope elements that touch
//!   the stock, rippling as the teeth pass;
//! * `turntable`: the rotary table the workpiece turns on, with its own servo; the stock
//!   lives in the workpiece frame, which turns with the table's true angle.
//!
//! [`CutState`] ties them to the simulated arm: at each removal update (every millisecond
//! while rubbing or not engaged, every quarter cell of travel while cutting) it sweeps the
//! stock along the tip's path, measures the removal rate and the spindle's torque (a cut
//! that needs more than the spindle has stalls it), and gathers the engagement the next
//! servo periods cut with. With the spindle turning, the stock resists the tool only through
//! the cutting force (the tool goes where the chips let it); stopped or stalled, the tool
//! rubs on the stock with the surface's contact stiffness, damping and friction.
//! Every model and its sources: `docs/cutting.md`.

pub mod export;
pub mod judge;
mod kernel;
mod mechanics;
mod stock;
mod tool;
mod turntable;

pub use mechanics::{CuttingCoefficients, Engagement};
pub use stock::Stock;
pub use tool::{Tool, ToolKind};
pub use turntable::{Turntable, TurntableConfig};

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

use super::MaterialPreset;

/// A stalled spindle restarts once the tool's lower surface is this far clear of the stock,
/// mm (a drive that has tripped is restarted with the tool retracted, not in the cut).
const RESTART_CLEARANCE_MM: f64 = 0.5;
/// While the tool cuts, the removal update runs once the tip has moved this many cells
/// relative to the stock since the last one (a ball's scallop between two such positions is
/// under a micrometre).
const REMOVAL_UPDATE_TRAVEL_CELLS: f64 = 0.25;
/// While the cut takes more than this fraction of the spindle's torque the removal update
/// runs every millisecond (a stall is met at the millisecond).
const NEAR_STALL_TORQUE_FRACTION: f64 = 0.5;
/// ... and at least this often while cutting, s.
const REMOVAL_UPDATE_MAX_S: f64 = 0.05;

/// The workpiece and the tool (`cutting.*` in a slave world or a session file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CuttingConfig {
    /// The centre of the block's top face, workpiece frame, mm.
    pub stock_centre_top_mm: [f64; 3],
    /// The block's size along x and y, mm (10 to 1000).
    pub stock_size_mm: [f64; 2],
    /// The block's thickness, mm.
    pub stock_thickness_mm: f64,
    /// Height-field cell edge, mm (0.05 to 2).
    pub cell_mm: f64,
    /// The work material's cutting coefficients (the contact stiffness, damping and friction
    /// of rubbing are the surface's).
    pub material: MaterialPreset,
    /// Overrides the material's cutting coefficients.
    pub coefficients: Option<CuttingCoefficients>,
    /// The end mill.
    pub tool: Tool,
    /// The turntable the workpiece turns on (none: the workpiece frame is the base frame).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub turntable: Option<TurntableConfig>,
}

impl Default for CuttingConfig {
    fn default() -> Self {
        CuttingConfig {
            stock_centre_top_mm: [0.0, 0.0, -250.0],
            stock_size_mm: [150.0, 150.0],
            stock_thickness_mm: 30.0,
            cell_mm: 0.25,
            material: MaterialPreset::Resin,
            coefficients: None,
            tool: Tool::default(),
            turntable: None,
        }
    }
}

impl Section for CuttingConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |n: &str| format!("{prefix}{n}");
        for (i, v) in self.stock_centre_top_mm.iter().enumerate() {
            check_range(
                &f(&format!("stock_centre_top_mm[{i}]")),
                *v,
                -1e4,
                1e4,
                "mm",
            )?;
        }
        for (i, v) in self.stock_size_mm.iter().enumerate() {
            check_range(&f(&format!("stock_size_mm[{i}]")), *v, 10.0, 1000.0, "mm")?;
        }
        check_range(
            &f("stock_thickness_mm"),
            self.stock_thickness_mm,
            1.0,
            500.0,
            "mm",
        )?;
        check_range(&f("cell_mm"), self.cell_mm, 0.05, 2.0, "mm")?;
        let cells = (self.stock_size_mm[0] / self.cell_mm) * (self.stock_size_mm[1] / self.cell_mm);
        check_range(
            &f("cell_mm"),
            cells,
            1.0,
            16.0 * 1024.0 * 1024.0,
            "cells in the grid",
        )
        .map_err(|_| ConfigError::OutOfRange {
            field: f("cell_mm"),
            value: self.cell_mm.to_string(),
            allowed: "a grid of at most 16 M cells".to_string(),
        })?;
        if let Some(k) = self.coefficients {
            for (n, v) in [
                ("coefficients.k_tc_n_per_mm2", k.k_tc_n_per_mm2),
                ("coefficients.k_rc_n_per_mm2", k.k_rc_n_per_mm2),
                ("coefficients.k_ac_n_per_mm2", k.k_ac_n_per_mm2),
            ] {
                check_range(&f(n), v, 0.0, 1e5, "N/mm²")?;
            }
        }
        if let Some(t) = &self.turntable {
            t.validate_at(&f("turntable."))?;
        }
        self.tool.validate_at(&f("tool."))
    }
}

/// What the cut did, for evaluation and recording.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct CutReport {
    /// Total volume removed, mm³.
    pub removed_mm3: f64,
    /// Removal rate of the engaged envelope at the last millisecond's velocity, mm³/s.
    pub removal_rate_mm3_per_s: f64,
    /// The spindle's torque that removal takes, N·mm.
    pub spindle_torque_n_mm: f64,
    /// The spindle has stalled (the tool rubs until it is pulled clear).
    pub stalled: bool,
    /// Updates in which the spindle stalled.
    pub stalls: u64,
    /// The contact force on the tool (cutting or rubbing) averaged over the last update's
    /// servo periods, base (machine) frame, N (the tooth-passing ripple is in the
    /// instantaneous force, not in this mean over 1 ms).
    pub mean_force_n: [f64; 3],
}

/// The cut in progress: the stock, the tool, and the engagement the servo periods use.
#[derive(Clone, Debug)]
pub struct CutState {
    stock: Stock,
    tool: Tool,
    coeff: CuttingCoefficients,
    engagement: Engagement,
    /// The tip at the last removal update, workpiece frame, mm.
    last_tip_mm: [f64; 3],
    /// The first tooth's azimuth at the last update, revolutions.
    phase_rev: f64,
    /// Time since the last update, s (advanced by the servo periods).
    since_update_s: f64,
    /// Time since the last removal update, s.
    since_removal_s: f64,
    /// The tip at the last 1 ms update, workpiece frame, mm.
    ms_tip_mm: [f64; 3],
    /// The tip at the last removal update (the reference of the rubbing penetrations), mm.
    rub_tip0_mm: [f64; 3],
    /// The contact force summed over the servo periods since the last update, base frame,
    /// N·s.
    force_impulse_n_s: [f64; 3],
    report: CutReport,
    /// The turntable, when the workpiece turns.
    table: Option<Turntable>,
    /// The table's angle in the servo period being computed, revolutions (the teeth's
    /// azimuth in the workpiece frame lags theirs in the base frame by it).
    table_rev: f64,
}

impl CutState {
    /// The cut from its configuration, the tip starting at `tip_mm` (base frame; the
    /// turntable, if any, starts at angle 0 where the frames coincide); `None` if the grid
    /// cannot be built.
    pub fn new(cfg: &CuttingConfig, tip_mm: [f64; 3]) -> Option<Self> {
        let stock = Stock::new(
            cfg.stock_centre_top_mm,
            cfg.stock_size_mm,
            cfg.stock_thickness_mm,
            cfg.cell_mm,
        )?;
        Some(CutState {
            stock,
            tool: cfg.tool,
            coeff: cfg
                .coefficients
                .unwrap_or(CuttingCoefficients::of(cfg.material)),
            engagement: Engagement::default(),
            last_tip_mm: tip_mm,
            phase_rev: 0.0,
            since_update_s: 0.0,
            since_removal_s: 0.0,
            ms_tip_mm: tip_mm,
            rub_tip0_mm: tip_mm,
            force_impulse_n_s: [0.0; 3],
            report: CutReport::default(),
            table: cfg.turntable.map(Turntable::new),
            table_rev: 0.0,
        })
    }

    /// The turntable, when the workpiece turns on one.
    pub fn turntable(&self) -> Option<&Turntable> {
        self.table.as_ref()
    }

    /// A new set-point for the turntable's servo, rad (nothing without a turntable; a
    /// non-finite one is refused).
    pub fn command_turntable(&mut self, angle_rad: f64) {
        if let Some(t) = self.table.as_mut() {
            t.command(angle_rad);
        }
    }

    /// The base-frame point `p_mm` in the workpiece frame at the table's true angle, mm
    /// (the same point without a turntable).
    #[inline]
    pub fn to_workpiece(&self, p_mm: [f64; 3]) -> [f64; 3] {
        match &self.table {
            Some(t) => t.to_workpiece(p_mm),
            None => p_mm,
        }
    }

    /// The stock.
    pub fn stock(&self) -> &Stock {
        &self.stock
    }

    /// The tool.
    pub fn tool(&self) -> &Tool {
        &self.tool
    }

    /// What the cut did so far.
    pub fn report(&self) -> CutReport {
        self.report
    }

    /// The spindle's speed now, rev/s (0 stopped or stalled).
    fn rev_per_s(&self) -> f64 {
        if self.report.stalled {
            0.0
        } else {
            self.tool.spindle_rev_per_s()
        }
    }

    /// The 1 ms update. Books the last millisecond's mean force; when the removal update is
    /// due, sweeps the stock along the tip's path since the last one (the spindle turning)
    /// and gathers the engagement at `tip_mm` (base frame; the cut works with it in the
    /// workpiece frame) that the servo periods cut with until the next one; then measures
    /// the removal rate of the engaged envelope at the last millisecond's velocity relative
    /// to the stock and the spindle's torque it takes, and stalls the spindle if the cut
    /// needs more than it has (it restarts once the tool is `RESTART_CLEARANCE_MM` clear of
    /// the stock). Due: every millisecond while the spindle is stopped or stalled (the tool
    /// rubs: an elastic contact), while nothing is engaged (a first touch is met within the
    /// millisecond; not while the tool is clear of the whole block, where none can be) and
    /// while the cut takes more than half the spindle's torque (a stall is met within the
    /// millisecond); otherwise, engaged and cutting, once the tip has moved a quarter of a
    /// cell relative to the stock since the last one, and at least every
    /// `REMOVAL_UPDATE_MAX_S`. The cutting force is `−B v` with the tool's present
    /// velocity: an engagement a fraction of a cell old differs from the present one only
    /// where the engaged region changes shape (in steady feed it keeps its shape relative
    /// to the tool). Allocates nothing.
    pub fn update(&mut self, tip_base_mm: [f64; 3]) {
        let tip_mm = self.to_workpiece(tip_base_mm);
        let dt = self.since_update_s;
        let n = self.rev_per_s();
        self.phase_rev = (self.phase_rev - n * dt).rem_euclid(1.0);
        self.since_update_s = 0.0;
        let mut v_mm_per_s = [0.0; 3];
        if dt > 0.0 {
            for (m, i) in self
                .report
                .mean_force_n
                .iter_mut()
                .zip(self.force_impulse_n_s)
            {
                *m = i / dt;
            }
            self.force_impulse_n_s = [0.0; 3];
            for (v, (a, b)) in v_mm_per_s.iter_mut().zip(tip_mm.iter().zip(self.ms_tip_mm)) {
                *v = (a - b) / dt;
            }
        }
        self.ms_tip_mm = tip_mm;
        self.since_removal_s += dt;
        let moved2: f64 = (0..3)
            .map(|i| (tip_mm[i] - self.last_tip_mm[i]).powi(2))
            .sum();
        let step = REMOVAL_UPDATE_TRAVEL_CELLS * self.stock.cell_mm();
        let clear = n > 0.0
            && self.engagement.elements == 0
            && Engagement::clear_of_block(&self.stock, tip_mm);
        if clear {
            // Above the whole block nothing is cut or engaged: the sweep starts here.
            self.last_tip_mm = tip_mm;
            self.since_removal_s = 0.0;
        }
        let due = !clear
            && (n <= 0.0
                || self.engagement.elements == 0
                || moved2 > step * step
                || moved2.is_nan()
                || self.since_removal_s >= REMOVAL_UPDATE_MAX_S
                || self.report.spindle_torque_n_mm
                    > NEAR_STALL_TORQUE_FRACTION * self.tool.max_torque_n_mm);
        if due {
            if n > 0.0 {
                self.stock.sweep(&self.tool, self.last_tip_mm, tip_mm);
            }
            self.since_removal_s = 0.0;
            self.last_tip_mm = tip_mm;
            self.rub_tip0_mm = tip_mm;
            self.engagement
                .gather(&self.stock, &self.tool, &self.coeff, tip_mm, n);
        }
        self.report.removed_mm3 = self.stock.removed_mm3();
        let rate = if n > 0.0 && v_mm_per_s.iter().all(|v| v.is_finite()) {
            self.engagement.removal_rate_mm3_per_s(&v_mm_per_s)
        } else {
            0.0
        };
        self.report.removal_rate_mm3_per_s = rate;
        self.report.spindle_torque_n_mm = if n > 0.0 {
            self.coeff.k_tc_n_per_mm2 * rate / (2.0 * std::f64::consts::PI * n)
        } else {
            0.0
        };
        if self.report.spindle_torque_n_mm > self.tool.max_torque_n_mm && !self.report.stalled {
            self.report.stalled = true;
            self.report.stalls += 1;
            // A stalled spindle rubs from this millisecond on, on the stock as the turning
            // tool left it: cut up to where the tip is (the removal update runs only every
            // quarter cell; the cutter itself cut continuously until it stopped).
            self.stock.sweep(&self.tool, self.last_tip_mm, tip_mm);
            self.engagement
                .gather(&self.stock, &self.tool, &self.coeff, tip_mm, 0.0);
            self.last_tip_mm = tip_mm;
            self.rub_tip0_mm = tip_mm;
        }
        if self.report.stalled
            && self.engagement.penetration_mm <= -RESTART_CLEARANCE_MM
            && self.engagement.rub_mm <= 0.0
        {
            self.report.stalled = false;
            self.report.spindle_torque_n_mm = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::{
        AdcAperture, Material, PlantConfig, SensorConfig, SimArm, Surface, SurfaceShape,
    };
    use h4_slave::arm::ArmDriver;

    use h4_shared::kinematics::{H4Params, Pose};

    /// The prototype at (0, 0, −248) above a resin block whose top is at −250, a ball end
    /// of 3 mm; the spindle at `rpm`, the material `material`.
    fn cutting_arm(material: MaterialPreset, rpm: f64, max_torque_n_mm: f64) -> SimArm {
        let mat: Material = material.material();
        let surface = Surface {
            shape: SurfaceShape::Plane {
                point_mm: [0.0, 0.0, -250.0],
                normal: [0.0, 0.0, 1.0],
            },
            material: mat,
        };
        let cfg = CuttingConfig {
            material,
            tool: Tool {
                spindle_rpm: rpm,
                max_torque_n_mm,
                ..Tool::default()
            },
            ..CuttingConfig::default()
        };
        SimArm::new(
            H4Params::PROTOTYPE,
            [100.0; 4],
            PlantConfig::default(),
            SensorConfig::quiet(),
            surface,
            Pose::new(0.0, 0.0, -248.0, 0.0),
            1,
        )
        .unwrap()
        .with_cutting(&cfg)
        .unwrap()
    }

    fn go(arm: &mut SimArm, pose: [f64; 4], ms: u32) -> f64 {
        let l = H4Params::PROTOTYPE.ik_checked(&Pose::from(pose)).unwrap();
        let mut peak: f64 = 0.0;
        for _ in 0..ms {
            arm.command(&[l[0], l[1], l[2], l[3]]);
            arm.advance(1_000_000);
            peak = peak.max(arm.true_contact_wrench().norm());
        }
        peak
    }

    /// A turning ball end commanded 1 mm into the block goes there: it cuts its way down,
    /// the force dies away once it stops (a cut holds no force at rest), and the volume
    /// removed is the ball's cap at the depth it reached, within the grid's resolution.
    #[test]
    fn a_turning_tool_cuts_down_to_its_command() {
        let mut arm = cutting_arm(MaterialPreset::Resin, 12_000.0, 1e4);
        // Down at 5 mm/s, then hold.
        let mut peak: f64 = 0.0;
        let mut lowest = f64::INFINITY;
        for k in 0..1600u32 {
            let z = (-248.0 - 5e-3 * f64::from(k)).max(-251.0);
            peak = peak.max(go(&mut arm, [0.0, 0.0, z, 0.0], 1));
            lowest = lowest.min(arm.true_pose()[2]);
        }
        assert!(lowest > -251.02, "overshot to {lowest}");
        let depth = -250.0 - arm.true_pose()[2];
        assert!((depth - 1.0).abs() < 0.01, "reached {depth} mm deep");
        assert!(peak > 1.0, "the cut never resisted: {peak} N");
        assert!(arm.true_contact_wrench().norm() < 0.05);
        let r = 3.0;
        let cap = std::f64::consts::PI * depth * depth * (3.0 * r - depth) / 3.0;
        let removed = arm.cut().unwrap().report().removed_mm3;
        // The cap's rim, one cell wide, is the grid's uncertainty.
        let rim = 2.0 * std::f64::consts::PI * (2.0 * r * depth).sqrt() * 0.25 * depth * 0.5;
        assert!(
            (removed - cap).abs() < rim,
            "removed {removed} mm³, cap {cap}"
        );
    }

    /// With the spindle stopped the tool only rubs: pressed 0.5 mm in, it holds the force
    /// the surface's contact stiffness in series with the arm gives, and removes nothing.
    #[test]
    fn a_stopped_spindle_rubs_and_removes_nothing() {
        let mut arm = cutting_arm(MaterialPreset::Resin, 0.0, 1e4);
        go(&mut arm, [0.0, 0.0, -250.5, 0.0], 1500);
        let k = h4_shared::ActuatorStiffness::uniform(100.0).unwrap();
        let lam = H4Params::PROTOTYPE
            .compliance(&arm.true_pose(), &k)
            .unwrap();
        let expected = 0.5 / (lam[(2, 2)] + 1.0 / 200.0);
        let fz = arm.true_contact_wrench()[2];
        assert!(
            (fz - expected).abs() < 0.03 * expected,
            "{fz} vs {expected}"
        );
        assert_eq!(arm.cut().unwrap().report().removed_mm3, 0.0);
        assert!((arm.read().wrench[2] - fz).abs() < 0.1);
    }

    /// Feeding sideways through the block: the force opposes the feed (and rises with the
    /// material's coefficients), the removal rate is the cut's cross-section × feed, and
    /// the force ripples at the tooth-passing frequency in the true force.
    #[test]
    fn feeding_meets_the_cutting_resistance() {
        let mut feed_force = [0.0; 2];
        for (i, m) in [MaterialPreset::Resin, MaterialPreset::Aluminium]
            .iter()
            .enumerate()
        {
            let mut arm = cutting_arm(*m, 12_000.0, 1e5);
            go(&mut arm, [0.0, 0.0, -251.0, 0.0], 800);
            let params = H4Params::PROTOTYPE;
            let speed = 10.0; // mm/s
            let mut sum_fx = 0.0;
            let mut samples = 0;
            let removed0 = arm.cut().unwrap().report().removed_mm3;
            let mut lo = f64::INFINITY;
            let mut hi = f64::NEG_INFINITY;
            for k in 0..2000u32 {
                let x = speed * f64::from(k) * 1e-3;
                let l = params.ik_checked(&Pose::new(x, 0.0, -251.0, 0.0)).unwrap();
                arm.command(&[l[0], l[1], l[2], l[3]]);
                for _ in 0..20 {
                    arm.advance(50_000);
                    if k >= 1000 {
                        let fx = arm.true_contact_wrench()[0];
                        sum_fx += fx;
                        samples += 1;
                        lo = lo.min(fx);
                        hi = hi.max(fx);
                    }
                }
            }
            let mean_fx = sum_fx / f64::from(samples);
            assert!(
                mean_fx < 0.0,
                "{m:?}: the feed force {mean_fx} N does not oppose the feed"
            );
            assert!(
                hi - lo > 0.3 * mean_fx.abs(),
                "{m:?}: no ripple ({lo}..{hi} N)"
            );
            feed_force[i] = mean_fx;
            // Ball at depth a = 1: the cut's cross-section ≈ ∫ over the chord.
            let removed = arm.cut().unwrap().report().removed_mm3 - removed0;
            let (r, a) = (3.0_f64, 1.0_f64);
            let half = ((r - a) / r).acos();
            let section = r * r * (half - half.sin() * half.cos());
            let expected = section * speed * 2.0;
            assert!(
                (removed - expected).abs() < 0.1 * expected,
                "{m:?}: removed {removed} mm³ vs {expected}"
            );
        }
        let ratio = feed_force[1] / feed_force[0];
        let k = |m| CuttingCoefficients::of(m).k_rc_n_per_mm2;
        let expected = k(MaterialPreset::Aluminium) / k(MaterialPreset::Resin);
        assert!(
            (ratio - expected).abs() < 0.25 * expected,
            "aluminium/resin feed force {ratio}, coefficients {expected}"
        );
    }

    /// The mean over 1 s of feed of what the sensor reads and of the cut's true force, N,
    /// a 3 mm ball end 1 mm deep at 10 mm/s, the sensor's A/D reading `aperture`.
    fn read_and_true_feed_force(m: MaterialPreset, aperture: AdcAperture) -> ([f64; 3], [f64; 3]) {
        let mut arm = cutting_arm(m, 12_000.0, 1e5);
        arm.sensor.cfg.adc_aperture = aperture;
        go(&mut arm, [0.0, 0.0, -251.0, 0.0], 800);
        let params = H4Params::PROTOTYPE;
        let (mut read, mut truth) = ([0.0f64; 3], [0.0f64; 3]);
        for k in 0..2000u32 {
            let x = 10.0 * f64::from(k) * 1e-3;
            let l = params.ik_checked(&Pose::new(x, 0.0, -251.0, 0.0)).unwrap();
            arm.command(&[l[0], l[1], l[2], l[3]]);
            arm.advance(1_000_000);
            if k >= 1000 {
                let w = arm.read().wrench;
                let f = arm.cut().unwrap().report().mean_force_n;
                for a in 0..3 {
                    read[a] += w[a] * 1e-3;
                    truth[a] += f[a] * 1e-3;
                }
            }
        }
        (read, truth)
    }

    /// An integrating A/D (`adc_aperture = "period"`) reads a milling cutter's force as
    /// its mean: the tooth pulses (400 Hz and their harmonics, at 2 flutes and
    /// 12 000 rev/min) reach the 1 kHz sensor averaged over each sample period, so no
    /// harmonic at a multiple of the sample rate aliases into the reading. An instant's
    /// sample (`instant`, the default) reads the resin cut's feed force more than 10 % low
    /// (measured: 21 %; the 5th harmonic of 400 Hz is twice the sample rate).
    #[test]
    fn the_sensor_reads_the_cutting_force_s_mean() {
        let (read, truth) = read_and_true_feed_force(MaterialPreset::Resin, AdcAperture::Instant);
        assert!(
            (read[0] - truth[0]).abs() > 0.1 * truth[0].abs(),
            "an instant's sample: read {} N, the cut's mean {} N",
            read[0],
            truth[0]
        );
        for m in [MaterialPreset::Resin, MaterialPreset::Aluminium] {
            let (read, truth) = read_and_true_feed_force(m, AdcAperture::Period);
            for a in [0, 2] {
                assert!(
                    (read[a] - truth[a]).abs() < 0.02 * truth[a].abs() + 0.01,
                    "{m:?}, axis {a}: the sensor read {} N, the cut's mean {} N",
                    read[a],
                    truth[a]
                );
            }
        }
    }

    /// Pushed into steel faster than the spindle's torque allows, the spindle stalls: the
    /// cut stops (nothing more is removed), the tool rubs on the stock with its contact
    /// stiffness; pulled clear, the spindle restarts.
    #[test]
    fn a_spindle_pushed_beyond_its_torque_stalls_and_restarts_clear() {
        let mut arm = cutting_arm(MaterialPreset::Steel, 12_000.0, 5.0);
        go(&mut arm, [0.0, 0.0, -253.0, 0.0], 300);
        let rep = arm.cut().unwrap().report();
        assert!(rep.stalled && rep.stalls >= 1, "{rep:?}");
        let removed = rep.removed_mm3;
        go(&mut arm, [0.0, 0.0, -253.0, 0.0], 300);
        assert_eq!(arm.cut().unwrap().report().removed_mm3, removed);
        let fz = arm.true_contact_wrench()[2];
        assert!(
            fz > 50.0,
            "a stalled tool presses with the stiffness: {fz} N"
        );
        go(&mut arm, [0.0, 0.0, -245.0, 0.0], 300);
        assert!(!arm.cut().unwrap().report().stalled);
    }

    /// The area of the groove's cross-section on the radial line at azimuth `phi` (workpiece
    /// frame, about the origin), mm², sampled every 0.005 mm from `rho0` to `rho1`; and the
    /// deepest point's radius and depth below `top`.
    fn groove_section(stock: &Stock, phi: f64, rho0: f64, rho1: f64) -> (f64, f64, f64) {
        let (mut area, mut deepest, mut at) = (0.0, 0.0, 0.0);
        let step = 0.005;
        let mut rho = rho0;
        while rho < rho1 {
            let h = stock
                .height_under(rho * phi.cos(), rho * phi.sin())
                .unwrap();
            let d = stock.top_mm() - h;
            area += d * step;
            if d > deepest {
                deepest = d;
                at = rho;
            }
            rho += step;
        }
        (area, at, deepest)
    }

    /// A constant-speed turn of the table under a stationary tool at a fixed depth cuts a
    /// circular groove: its cross-section (read from the height field on radial lines) is
    /// the same all round and is the ball's segment at the depth the tool really ran at; the
    /// removed volume is that area × the circumference at its radius (Pappus) within 3 %,
    /// the groove's radius is the tool's true radius in the workpiece frame; the force turns
    /// back into the base frame (the stock drags the stationary tool along its motion).
    #[test]
    fn a_turn_under_a_stationary_tool_cuts_a_circular_groove() {
        let (radius, depth) = (30.0, 1.0);
        let cfg = CuttingConfig {
            tool: Tool {
                spindle_rpm: 12_000.0,
                max_torque_n_mm: 1e4,
                ..Tool::default()
            },
            turntable: Some(TurntableConfig::default()),
            ..CuttingConfig::default()
        };
        let mut arm = SimArm::new(
            H4Params::PROTOTYPE,
            [100.0; 4],
            PlantConfig::default(),
            SensorConfig::quiet(),
            Surface {
                shape: SurfaceShape::Plane {
                    point_mm: [0.0, 0.0, -250.0],
                    normal: [0.0, 0.0, 1.0],
                },
                material: MaterialPreset::Resin.material(),
            },
            Pose::new(radius, 0.0, -248.0, 0.0),
            1,
        )
        .unwrap()
        .with_cutting(&cfg)
        .unwrap();
        // Plunge with the table still, then turn it 1.1 revolutions at 0.5 rad/s.
        for k in 0..1600u32 {
            let z = (-248.0 - 5e-3 * f64::from(k)).max(-250.0 - depth);
            go(&mut arm, [radius, 0.0, z, 0.0], 1);
        }
        let plunged = arm.cut().unwrap().report().removed_mm3;
        let l = H4Params::PROTOTYPE
            .ik_checked(&Pose::new(radius, 0.0, -250.0 - depth, 0.0))
            .unwrap();
        let omega = 0.5;
        let end = 1.1 * 2.0 * std::f64::consts::PI;
        let (mut sum_r, mut sum_z, mut sum_fy, mut n) = (0.0, 0.0, 0.0, 0.0);
        for k in 0..((end / omega) * 1000.0) as u32 + 500 {
            let sp = (omega * f64::from(k) * 1e-3).min(end);
            arm.command(&[l[0], l[1], l[2], l[3]]);
            arm.command_turntable(sp);
            arm.advance(1_000_000);
            if k > 500 && sp < end {
                let tp = arm.true_pose();
                let wp = arm.cut().unwrap().to_workpiece([tp[0], tp[1], tp[2]]);
                sum_r += (wp[0] * wp[0] + wp[1] * wp[1]).sqrt();
                sum_z += tp[2];
                sum_fy += arm.cut().unwrap().report().mean_force_n[1];
                n += 1.0;
            }
        }
        let table = *arm.cut().unwrap().turntable().unwrap();
        assert!(
            (table.angle_rad() - end).abs() < 1e-3,
            "{}",
            table.angle_rad()
        );
        let measured = arm.turntable_rad().unwrap();
        assert!((measured - table.angle_rad()).abs() <= 1e-5);
        go(&mut arm, [radius, 0.0, -245.0, 0.0], 500);
        let cut = arm.cut().unwrap();
        let removed = cut.report().removed_mm3;
        let (tip_r, tip_depth) = (sum_r / n, -250.0 - sum_z / n);
        assert!(
            (tip_depth - depth).abs() < 0.1,
            "the tool ran {tip_depth} mm deep"
        );
        let r = 3.0;
        let segment =
            |d: f64| r * r * ((r - d) / r).acos() - (r - d) * (2.0 * r * d - d * d).max(0.0).sqrt();
        let mut areas = Vec::new();
        for i in 0..24 {
            let phi = f64::from(i) * std::f64::consts::PI / 12.0 + 0.1;
            let (area, at, deepest) = groove_section(cut.stock(), phi, radius - 5.0, radius + 5.0);
            assert!(
                (at - tip_r).abs() < 0.2,
                "azimuth {phi}: groove at radius {at}, tool at {tip_r}"
            );
            assert!(
                (deepest - tip_depth).abs() < 0.06,
                "azimuth {phi}: groove {deepest} deep, tool {tip_depth}"
            );
            assert!(
                (area - segment(deepest)).abs() < 0.05 * segment(deepest),
                "azimuth {phi}: section {area} mm² vs the ball's {}",
                segment(deepest)
            );
            areas.push(area);
        }
        let mean_area = areas.iter().sum::<f64>() / areas.len() as f64;
        let spread = areas
            .iter()
            .fold(0.0f64, |m, a| m.max((a - mean_area).abs()));
        assert!(spread < 0.04 * mean_area, "not round: ±{spread} mm²");
        let pappus = mean_area * 2.0 * std::f64::consts::PI * tip_r;
        assert!(
            (removed - pappus).abs() < 0.03 * pappus,
            "removed {removed} mm³, section × circumference {pappus}"
        );
        assert!(plunged < 0.03 * removed, "the plunge alone cut {plunged}");
        assert!(
            sum_fy / n > 0.1,
            "the stock does not drag the tool: {}",
            sum_fy / n
        );
    }

    #[test]
    fn config_names_its_fields() {
        assert!(CuttingConfig::default().validate_at("cutting.").is_ok());
        let mut c = CuttingConfig::default();
        c.tool.radius_mm = 0.0;
        let e = c.validate_at("cutting.").unwrap_err().to_string();
        assert!(e.contains("cutting.tool.radius_mm"), "{e}");
        let c = CuttingConfig {
            cell_mm: 0.05,
            stock_size_mm: [1000.0, 1000.0],
            ..CuttingConfig::default()
        };
        let e = c.validate_at("cutting.").unwrap_err().to_string();
        assert!(e.contains("cutting.cell_mm") && e.contains("16 M"), "{e}");
    }
}
