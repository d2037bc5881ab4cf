//! Virtual fixtures (the operator's "human assist"): limits on the commanded tool point that
//! hold whatever the master asks and whatever the force loop wants. The controller applies
//! them to every pose it commits (before the deflection compensation, so they bound where
//! the tool point is meant to be):
//!
//! * a **depth floor**: the tool point is never commanded below `z_mm`;
//! * a **corridor** around a planned path (a polyline in x, y): the tool point is never
//!   commanded further than `half_width_mm` from it (the nearest point of the path).
//!
//! Each is a section of `fixtures` in a slave world or a session file; `docs/cutting.md`.

use h4_shared::config::{ConfigError, Section, check_range};
use h4_shared::kinematics::Pose;
use serde::{Deserialize, Serialize};

/// Most points of a corridor's path.
pub const CORRIDOR_POINTS_MAX: usize = 64;

/// A floor the tool point is never commanded below (`fixtures.depth_floor`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthFloor {
    /// The floor's height, base (workpiece) frame, mm.
    pub z_mm: f64,
}

/// A corridor around a planned path in x, y (`fixtures.corridor`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorridorConfig {
    /// The path's points `[x_mm, y_mm]`, base (workpiece) frame (2 to 64).
    pub path_mm: Vec<[f64; 2]>,
    /// The largest distance of the tool point from the path, mm.
    pub half_width_mm: f64,
}

/// The fixtures (`fixtures.*`); none by default.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FixturesConfig {
    /// The depth floor.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_floor: Option<DepthFloor>,
    /// The corridor.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub corridor: Option<CorridorConfig>,
}

impl FixturesConfig {
    /// No fixture configured.
    pub fn is_empty(&self) -> bool {
        self.depth_floor.is_none() && self.corridor.is_none()
    }
}

impl Section for FixturesConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        if let Some(f) = &self.depth_floor {
            check_range(
                &format!("{prefix}depth_floor.z_mm"),
                f.z_mm,
                -1e4,
                1e4,
                "mm",
            )?;
        }
        if let Some(c) = &self.corridor {
            let n = c.path_mm.len();
            if !(2..=CORRIDOR_POINTS_MAX).contains(&n) {
                return Err(ConfigError::OutOfRange {
                    field: format!("{prefix}corridor.path_mm"),
                    value: format!("{n} points"),
                    allowed: format!("2 to {CORRIDOR_POINTS_MAX} points"),
                });
            }
            for (i, p) in c.path_mm.iter().enumerate() {
                for (a, v) in p.iter().enumerate() {
                    let f = format!("{prefix}corridor.path_mm[{i}][{a}]");
                    check_range(&f, *v, -1e4, 1e4, "mm")?;
                }
            }
            check_range(
                &format!("{prefix}corridor.half_width_mm"),
                c.half_width_mm,
                0.0,
                1e3,
                "mm",
            )?;
        }
        Ok(())
    }
}

/// The fixtures as the controller holds them (fixed size: nothing allocated per cycle).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fixtures {
    floor_z_mm: Option<f64>,
    path: [[f64; 2]; CORRIDOR_POINTS_MAX],
    path_len: usize,
    half_width_mm: f64,
    /// The last committed pose was moved by a fixture.
    pub(crate) active: bool,
    /// Cycles a fixture moved the committed pose.
    pub(crate) active_cycles: u64,
}

impl Default for Fixtures {
    fn default() -> Self {
        Fixtures {
            floor_z_mm: None,
            path: [[0.0; 2]; CORRIDOR_POINTS_MAX],
            path_len: 0,
            half_width_mm: 0.0,
            active: false,
            active_cycles: 0,
        }
    }
}

impl Fixtures {
    /// The fixtures of a (validated) configuration; a corridor's path beyond
    /// [`CORRIDOR_POINTS_MAX`] points is cut there.
    pub fn new(cfg: &FixturesConfig) -> Self {
        let mut f = Fixtures {
            floor_z_mm: cfg.depth_floor.map(|d| d.z_mm),
            ..Fixtures::default()
        };
        if let Some(c) = &cfg.corridor {
            for (dst, src) in f.path.iter_mut().zip(&c.path_mm) {
                *dst = *src;
            }
            f.path_len = c.path_mm.len().min(CORRIDOR_POINTS_MAX);
            f.half_width_mm = c.half_width_mm;
        }
        f
    }

    /// `pose` moved into the fixtures: onto the floor if below it, into the corridor if
    /// outside it (towards the path's nearest point). Records whether it moved.
    pub fn limit(&mut self, pose: Pose) -> Pose {
        let mut p = pose;
        if let Some(z) = self.floor_z_mm
            && p[2] < z
        {
            p[2] = z;
        }
        if self.path_len >= 2 {
            let (near, d) = self.nearest_on_path([p[0], p[1]]);
            if d > self.half_width_mm && d > 0.0 {
                let s = self.half_width_mm / d;
                p[0] = near[0] + (p[0] - near[0]) * s;
                p[1] = near[1] + (p[1] - near[1]) * s;
            }
        }
        self.active = p != pose;
        if self.active {
            self.active_cycles += 1;
        }
        p
    }

    /// The path's point nearest `q` and its distance, mm.
    fn nearest_on_path(&self, q: [f64; 2]) -> ([f64; 2], f64) {
        let mut best = (self.path[0], f64::INFINITY);
        for w in self.path[..self.path_len].windows(2) {
            let (a, b) = (w[0], w[1]);
            let ab = [b[0] - a[0], b[1] - a[1]];
            let len2 = ab[0] * ab[0] + ab[1] * ab[1];
            let t = if len2 > 0.0 {
                (((q[0] - a[0]) * ab[0] + (q[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let c = [a[0] + t * ab[0], a[1] + t * ab[1]];
            let d = ((q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2)).sqrt();
            if d < best.1 {
                best = (c, d);
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corridor() -> FixturesConfig {
        FixturesConfig {
            depth_floor: Some(DepthFloor { z_mm: -252.0 }),
            corridor: Some(CorridorConfig {
                path_mm: vec![[0.0, 0.0], [20.0, 0.0], [20.0, 10.0]],
                half_width_mm: 1.0,
            }),
        }
    }

    #[test]
    fn the_floor_holds_the_tool_point_above_it() {
        let mut f = Fixtures::new(&FixturesConfig {
            depth_floor: Some(DepthFloor { z_mm: -252.0 }),
            corridor: None,
        });
        let p = f.limit(Pose::new(3.0, 4.0, -253.5, 0.1));
        assert_eq!(p, Pose::new(3.0, 4.0, -252.0, 0.1));
        assert!(f.active);
        let q = Pose::new(3.0, 4.0, -251.0, 0.1);
        assert_eq!(f.limit(q), q);
        assert!(!f.active && f.active_cycles == 1);
    }

    #[test]
    fn the_corridor_pulls_the_tool_point_back_to_its_edge() {
        let mut f = Fixtures::new(&corridor());
        // Beside the first leg, 3 mm off: back to 1 mm off.
        let p = f.limit(Pose::new(10.0, 3.0, -251.0, 0.0));
        assert!(
            (p[0] - 10.0).abs() < 1e-12 && (p[1] - 1.0).abs() < 1e-12,
            "{p:?}"
        );
        // Past the corner, diagonally: onto the unit circle round the corner point.
        let p = f.limit(Pose::new(23.0, -4.0, -251.0, 0.0));
        let d = ((p[0] - 20.0).powi(2) + p[1].powi(2)).sqrt();
        assert!((d - 1.0).abs() < 1e-12, "{p:?}");
        // Inside: untouched.
        let q = Pose::new(20.5, 5.0, -251.0, 0.0);
        assert_eq!(f.limit(q), q);
        assert!(!f.active);
    }

    #[test]
    fn fixtures_name_their_fields() {
        let mut c = corridor();
        assert!(c.validate_at("fixtures.").is_ok());
        c.corridor.as_mut().unwrap().path_mm.truncate(1);
        let e = c.validate_at("fixtures.").unwrap_err().to_string();
        assert!(e.contains("fixtures.corridor.path_mm"), "{e}");
        let mut c = corridor();
        c.corridor.as_mut().unwrap().half_width_mm = -1.0;
        let e = c.validate_at("fixtures.").unwrap_err().to_string();
        assert!(e.contains("fixtures.corridor.half_width_mm"), "{e}");
    }
}
