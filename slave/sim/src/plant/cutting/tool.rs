//! End mills: a ball end or a flat end of a given radius, flutes and spindle speed.

use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

/// The end of the mill.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum ToolKind {
    /// A hemispherical end of the tool's radius.
    Ball,
    /// A flat end (square corners).
    Flat,
}

/// An end mill turning clockwise seen from the spindle (M03). Its tip is the arm's tool
/// point; its axis is the machine's vertical z.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Tool {
    /// Ball or flat end.
    pub kind: ToolKind,
    /// Radius, mm (0.5 to 10).
    pub radius_mm: f64,
    /// Number of flutes (teeth) (1 to 8).
    pub flutes: u32,
    /// Spindle speed, rev/min (0 = stopped: the tool only rubs; up to 60 000).
    pub spindle_rpm: f64,
    /// Length of the cutting flutes above the tip, mm: stock higher than this above the tip
    /// is not engaged by the edges (the model does not simulate the shank).
    pub flute_length_mm: f64,
    /// Largest torque the spindle delivers, N·mm: a cut that needs more stalls it.
    pub max_torque_n_mm: f64,
}

impl Default for Tool {
    fn default() -> Self {
        Tool {
            kind: ToolKind::Ball,
            radius_mm: 3.0,
            flutes: 2,
            spindle_rpm: 12_000.0,
            flute_length_mm: 12.0,
            max_torque_n_mm: 300.0,
        }
    }
}

impl Tool {
    /// Height of the tool's lower surface above its tip at horizontal distance
    /// √`rho2_mm2` from its axis (inside the radius), mm.
    #[inline]
    pub fn lift_mm(&self, rho2_mm2: f64) -> f64 {
        match self.kind {
            ToolKind::Flat => 0.0,
            ToolKind::Ball => {
                let r = self.radius_mm;
                r - (r * r - rho2_mm2).max(0.0).sqrt()
            }
        }
    }

    /// Spindle speed, rev/s.
    pub fn spindle_rev_per_s(&self) -> f64 {
        self.spindle_rpm / 60.0
    }
}

impl Section for Tool {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |n: &str| format!("{prefix}{n}");
        check_range(&f("radius_mm"), self.radius_mm, 0.5, 10.0, "mm")?;
        check_range(&f("flutes"), f64::from(self.flutes), 1.0, 8.0, "")?;
        check_range(
            &f("spindle_rpm"),
            self.spindle_rpm,
            0.0,
            60_000.0,
            "rev/min",
        )?;
        check_range(
            &f("flute_length_mm"),
            self.flute_length_mm,
            self.radius_mm,
            100.0,
            "mm (at least radius_mm)",
        )?;
        check_range(
            &f("max_torque_n_mm"),
            self.max_torque_n_mm,
            1.0,
            1e5,
            "N·mm",
        )
    }
}
