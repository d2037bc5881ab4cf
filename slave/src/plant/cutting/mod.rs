//! Cutting: a workpiece that is really cut.
//!
//! * [`stock`]: the block as a height field, lowered where the tool's swept volume goes below
//!   it ([`Stock::sweep`], once per 1 ms update, along the tool tip's path since the last);
//! * [`tool`]: ball-end and flat end mills;
//! * [`mechanics`]: the mechanistic cutting force on the tool's envelope elements that touch
//!   the stock, rippling as the teeth pass.
//!
//! [`CutState`] ties them to the simulated arm: every millisecond it sweeps the stock along
//! the tip's path, measures the removal rate and the spindle's torque (a cut that needs
//! more than the spindle has stalls it), and gathers the engagement the next millisecond's
//! servo periods cut with. With the spindle turning, the stock resists the tool only through
//! the cutting force (the tool goes where the chips let it); stopped or stalled, the tool
//! rubs on the stock with the surface's contact stiffness, damping and friction.
//! Every model and its sources: `docs/cutting.md`.

mod kernel;
mod mechanics;
mod stock;
mod tool;

pub use mechanics::{CuttingCoefficients, Engagement};
pub use stock::Stock;
pub use tool::{Tool, ToolKind};

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

use super::MaterialPreset;

/// The workpiece and the tool (`cutting.*` in a slave world or a session file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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
        self.tool.validate_at(&f("tool."))
    }
}

/// What the cut did, for evaluation and recording.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct CutReport {
    /// Total volume removed, mm³.
    pub removed_mm3: f64,
    /// Removal rate over the last update, mm³/s.
    pub removal_rate_mm3_per_s: f64,
    /// The spindle's torque over the last update, N·mm.
    pub spindle_torque_n_mm: f64,
    /// The spindle has stalled (the tool rubs until it is pulled clear).
    pub stalled: bool,
    /// Updates in which the spindle stalled.
    pub stalls: u64,
}

/// The cut in progress: the stock, the tool, and the engagement the servo periods use.
#[derive(Clone, Debug)]
pub struct CutState {
    stock: Stock,
    tool: Tool,
    coeff: CuttingCoefficients,
    engagement: Engagement,
    /// The tip at the last update, workpiece frame, mm.
    last_tip_mm: [f64; 3],
    /// The first tooth's azimuth at the last update, revolutions.
    phase_rev: f64,
    /// Time since the last update, s (advanced by the servo periods).
    since_update_s: f64,
    /// The tip's z at the last update (the reference of the rubbing penetration), mm.
    rub_z0_mm: f64,
    report: CutReport,
}

impl CutState {
    /// The cut from its configuration, the tip starting at `tip_mm`; `None` if the grid
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
            rub_z0_mm: tip_mm[2],
            report: CutReport::default(),
        })
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

    /// The 1 ms update: sweeps the stock along the tip's path since the last update (the
    /// spindle turning), measures the removal rate and the spindle's torque, stalls the
    /// spindle if the cut needs more than it has (it restarts once the tool is clear of the
    /// stock), and gathers the engagement at `tip_mm`. Allocates nothing.
    pub fn update(&mut self, tip_mm: [f64; 3]) {
        let dt = self.since_update_s;
        let n = self.rev_per_s();
        let removed = if n > 0.0 {
            self.stock.sweep(&self.tool, self.last_tip_mm, tip_mm)
        } else {
            0.0
        };
        self.phase_rev = (self.phase_rev - n * dt).rem_euclid(1.0);
        self.since_update_s = 0.0;
        if dt > 0.0 {
            let rate = removed / dt;
            self.report.removal_rate_mm3_per_s = rate;
            self.report.spindle_torque_n_mm = if n > 0.0 {
                self.coeff.k_tc_n_per_mm2 * rate / (2.0 * std::f64::consts::PI * n)
            } else {
                0.0
            };
        }
        self.report.removed_mm3 = self.stock.removed_mm3();
        if self.report.spindle_torque_n_mm > self.tool.max_torque_n_mm && !self.report.stalled {
            self.report.stalled = true;
            self.report.stalls += 1;
        }
        self.last_tip_mm = tip_mm;
        self.rub_z0_mm = tip_mm[2];
        self.engagement.gather(
            &self.stock,
            &self.tool,
            &self.coeff,
            tip_mm,
            self.rev_per_s(),
        );
        if self.report.stalled && self.engagement.penetration_mm <= 0.0 {
            let clear = self.engagement.elements == 0;
            if clear {
                self.report.stalled = false;
                self.report.spindle_torque_n_mm = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_names_its_fields() {
        assert!(CuttingConfig::default().validate_at("cutting.").is_ok());
        let mut c = CuttingConfig::default();
        c.tool.radius_mm = 0.0;
        let e = c.validate_at("cutting.").unwrap_err().to_string();
        assert!(e.contains("cutting.tool.radius_mm"), "{e}");
        let mut c = CuttingConfig::default();
        c.cell_mm = 0.05;
        c.stock_size_mm = [1000.0, 1000.0];
        let e = c.validate_at("cutting.").unwrap_err().to_string();
        assert!(e.contains("cutting.cell_mm") && e.contains("16 M"), "{e}");
    }
}
