//! Virtual fixtures (the operator's "human assist"): limits on the commanded tool point that
//! hold whatever the master asks and whatever the force loop wants. The controller applies
//! them to every pose it commits (before the deflection compensation, so they bound where
//! the tool point is meant to be):
//!
//! * a **depth floor**: the tool point is never commanded below `z_mm`;
//! * a **corridor** around a planned path (a polyline in x, y): the tool point is never
//!   commanded further than `half_width_mm` from it (the nearest point of the path). With a
//!   turntable the path is in the workpiece frame: the controller turns it with the table's
//!   measured angle;
//! * a **region** (a pocket's boundary): the tool point is never commanded outside an x, y
//!   rectangle (in the workpiece frame with a turntable), so an operator who guides past a
//!   pocket's edge cuts the edge where it was planned, not where the hand stopped;
//! * the **turntable-synchronous** mode: the slave turns the table at a configured speed
//!   while the tool point is held on a radial line through the table's axis; the operator
//!   guides only its radius and depth, the turning part brings the stock round;
//! * a **mesh** (a part from a CAD model, `fixtures.mesh`): a forbidden region; the tool's
//!   envelope (a sphere about the ball end's centre) is never commanded closer than
//!   `allowance_mm` to the part's surface: a command that would put it there is projected
//!   out along the part's signed-distance gradient (in the workpiece frame, turned with the
//!   table's measured angle). Queries through the part's precomputed distance grid only.
//!
//! Each is a section of `fixtures` in a slave world or a session file; `docs/cutting.md`.

use std::sync::Arc;

use h4_shared::config::{ConfigError, Section, check_range};
use h4_shared::kinematics::Pose;
use serde::{Deserialize, Serialize};

/// Most points of a corridor's path.
pub const CORRIDOR_POINTS_MAX: usize = 64;

/// A floor the tool point is never commanded below (`fixtures.depth_floor`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DepthFloor {
    /// The floor's height, base (workpiece) frame, mm.
    pub z_mm: f64,
}

/// A corridor around a planned path in x, y (`fixtures.corridor`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CorridorConfig {
    /// The path's points `[x_mm, y_mm]`, base (workpiece) frame (2 to 64).
    pub path_mm: Vec<[f64; 2]>,
    /// The largest distance of the tool point from the path, mm.
    pub half_width_mm: f64,
}

/// A rectangle in x, y the tool point is kept within (`fixtures.region`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RegionConfig {
    /// The rectangle's corner with the smallest x and y, `[x_mm, y_mm]`, base (workpiece)
    /// frame.
    pub min_mm: [f64; 2],
    /// The corner with the largest x and y (each ≥ the minimum's).
    pub max_mm: [f64; 2],
}

/// The turntable-synchronous mode (`fixtures.turntable_sync`; needs `cutting.turntable`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TurntableSync {
    /// The table's commanded speed, rad/s (−50 to 50; positive: counter-clockwise seen from
    /// above).
    pub speed_rad_per_s: f64,
    /// The commanded speed's ramp at the start and at a stop, rad/s² (0.01 to 1e4; 2).
    #[serde(default = "default_ramp")]
    pub ramp_rad_per_s2: f64,
    /// The azimuth of the radial line the tool point is held on, base frame, rad (−2π to 2π;
    /// 0: the +x side of the axis).
    #[serde(default)]
    pub azimuth_rad: f64,
    /// The radii (from the table's axis) the tool point is held between, mm (0 to 1e4;
    /// `[0, 1e4]`).
    #[serde(default = "default_radius_range")]
    pub radius_range_mm: [f64; 2],
}

/// The part's mesh as a forbidden region (`fixtures.mesh`; the part is the `cut_target` of
/// kind `mesh`, loaded and checked with the session).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MeshFixtureConfig {
    /// The finishing allowance: the closest the tool's envelope is commanded to the part's
    /// surface, mm (0 to 10; 0.3).
    #[serde(default = "default_allowance")]
    pub allowance_mm: f64,
    /// The loaded part and the tool's envelope (set when the session or world is loaded,
    /// from `cut_target` and `cutting.tool`; not a key of the file).
    #[serde(skip)]
    #[schemars(skip)]
    pub guard: Option<MeshGuard>,
}

/// The mesh fixture's default finishing allowance, mm.
pub const MESH_ALLOWANCE_DEFAULT_MM: f64 = 0.3;

fn default_allowance() -> f64 {
    MESH_ALLOWANCE_DEFAULT_MM
}

/// The part the mesh fixture guards and the tool's envelope, as loaded.
#[derive(Clone)]
pub struct MeshGuard {
    /// The checked, placed part with its distance grid (workpiece frame).
    pub part: Arc<h4_part::Part>,
    /// The envelope sphere's centre above the tool's tip, mm (a ball end: its radius).
    pub centre_above_tip_mm: f64,
    /// The envelope sphere's radius, mm (a ball end: its radius; a flat end: √2 × its
    /// radius, the sphere about the same centre that holds the end's corners).
    pub radius_mm: f64,
}

impl MeshGuard {
    /// The guard for a tool of `radius_mm`, a ball end (`ball`) or a flat end.
    pub fn new(part: Arc<h4_part::Part>, radius_mm: f64, ball: bool) -> Self {
        MeshGuard {
            part,
            centre_above_tip_mm: radius_mm,
            radius_mm: if ball {
                radius_mm
            } else {
                radius_mm * std::f64::consts::SQRT_2
            },
        }
    }
}

impl PartialEq for MeshGuard {
    fn eq(&self, o: &Self) -> bool {
        Arc::ptr_eq(&self.part, &o.part)
            && self.centre_above_tip_mm == o.centre_above_tip_mm
            && self.radius_mm == o.radius_mm
    }
}

impl std::fmt::Debug for MeshGuard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshGuard")
            .field("part_volume_mm3", &self.part.volume_mm3)
            .field("centre_above_tip_mm", &self.centre_above_tip_mm)
            .field("radius_mm", &self.radius_mm)
            .finish()
    }
}

fn default_ramp() -> f64 {
    2.0
}

fn default_radius_range() -> [f64; 2] {
    [0.0, 1e4]
}

/// The fixtures (`fixtures.*`); none by default.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct FixturesConfig {
    /// The depth floor.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_floor: Option<DepthFloor>,
    /// The corridor.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub corridor: Option<CorridorConfig>,
    /// The region.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub region: Option<RegionConfig>,
    /// The turntable-synchronous mode.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub turntable_sync: Option<TurntableSync>,
    /// The part's mesh as a forbidden region (needs a `cut_target` of kind `mesh`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<MeshFixtureConfig>,
}

impl FixturesConfig {
    /// No fixture configured.
    pub fn is_empty(&self) -> bool {
        self.depth_floor.is_none()
            && self.corridor.is_none()
            && self.region.is_none()
            && self.turntable_sync.is_none()
            && self.mesh.is_none()
    }

    /// The turntable-synchronous mode needs a turntable (`has_turntable`): the error names
    /// `{prefix}turntable_sync`.
    pub fn check_turntable(&self, prefix: &str, has_turntable: bool) -> Result<(), ConfigError> {
        const NEEDS: &str = "only with a [cutting.turntable] section";
        if h4_shared::config::recording() {
            h4_shared::config::record_rule(&format!("{prefix}turntable_sync"), NEEDS);
        }
        if self.turntable_sync.is_some() && !has_turntable {
            return Err(ConfigError::OutOfRange {
                field: format!("{prefix}turntable_sync"),
                value: "set without a turntable".to_string(),
                allowed: NEEDS.to_string(),
            });
        }
        Ok(())
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
            if h4_shared::config::recording() {
                h4_shared::config::record_rule(
                    &format!("{prefix}corridor.path_mm"),
                    &format!("2 to {CORRIDOR_POINTS_MAX} points"),
                );
            }
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
        if let Some(r) = &self.region {
            for a in 0..2 {
                let lo = format!("{prefix}region.min_mm[{a}]");
                check_range(&lo, r.min_mm[a], -1e4, 1e4, "mm")?;
                let hi = format!("{prefix}region.max_mm[{a}]");
                check_range(&hi, r.max_mm[a], r.min_mm[a], 1e4, "mm (≥ the minimum)")?;
            }
        }
        if let Some(m) = &self.mesh {
            check_range(
                &format!("{prefix}mesh.allowance_mm"),
                m.allowance_mm,
                0.0,
                10.0,
                "mm",
            )?;
        }
        if let Some(t) = &self.turntable_sync {
            let f = |n: &str| format!("{prefix}turntable_sync.{n}");
            check_range(
                &f("speed_rad_per_s"),
                t.speed_rad_per_s,
                -50.0,
                50.0,
                "rad/s",
            )?;
            check_range(
                &f("ramp_rad_per_s2"),
                t.ramp_rad_per_s2,
                0.01,
                1e4,
                "rad/s²",
            )?;
            let tau = 2.0 * std::f64::consts::PI;
            check_range(&f("azimuth_rad"), t.azimuth_rad, -tau, tau, "rad")?;
            let [r0, r1] = t.radius_range_mm;
            check_range(&f("radius_range_mm[0]"), r0, 0.0, 1e4, "mm")?;
            check_range(&f("radius_range_mm[1]"), r1, r0, 1e4, "mm (≥ the minimum)")?;
        }
        Ok(())
    }
}

/// The fixtures as the controller holds them (fixed size: nothing allocated per cycle; the
/// mesh's part is shared, built at load time).
#[derive(Clone, Debug, PartialEq)]
pub struct Fixtures {
    floor_z_mm: Option<f64>,
    path: [[f64; 2]; CORRIDOR_POINTS_MAX],
    path_len: usize,
    half_width_mm: f64,
    /// The region.
    region: Option<RegionConfig>,
    /// The turntable-synchronous mode.
    sync: Option<TurntableSync>,
    /// The mesh's guard and the allowance, mm.
    mesh: Option<(MeshGuard, f64)>,
    /// The mesh's guard moved the last committed pose.
    mesh_active: bool,
    /// The turntable's axis (x, y), base frame, mm, when the machine has one (told).
    table_axis_mm: Option<[f64; 2]>,
    /// The table's measured angle this cycle, rad.
    table_measured_rad: Option<f64>,
    /// The table's commanded angle, rad, and speed, rad/s (the synchronous program).
    table_cmd_rad: f64,
    table_cmd_speed_rad_per_s: f64,
    /// The program has started (from the measured angle).
    table_started: bool,
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
            region: None,
            sync: None,
            mesh: None,
            mesh_active: false,
            table_axis_mm: None,
            table_measured_rad: None,
            table_cmd_rad: 0.0,
            table_cmd_speed_rad_per_s: 0.0,
            table_started: false,
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
            region: cfg.region,
            sync: cfg.turntable_sync,
            mesh: cfg
                .mesh
                .as_ref()
                .and_then(|m| m.guard.clone().map(|g| (g, m.allowance_mm))),
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

    /// Tells the fixtures the turntable's axis (x, y), base frame, mm: the corridor's path
    /// is then in the workpiece frame and the synchronous mode turns about it.
    pub fn set_turntable_axis(&mut self, axis_mm: [f64; 2]) {
        self.table_axis_mm = Some(axis_mm);
    }

    /// This cycle's measured turntable angle, rad (`None`: no turntable, or no reading; a
    /// non-finite reading counts as none).
    pub fn observe_turntable(&mut self, measured_rad: Option<f64>) {
        self.table_measured_rad = measured_rad.filter(|a| a.is_finite());
    }

    /// The turntable's set-point for a cycle of `dt_s` in the synchronous mode: its speed
    /// ramps (at `ramp_rad_per_s2`) to `speed_rad_per_s`, or to a stop while `stop`; the
    /// program starts from the measured angle. `None` without the synchronous mode.
    pub fn turntable_command(&mut self, dt_s: f64, stop: bool) -> Option<f64> {
        let s = self.sync?;
        if !self.table_started {
            self.table_cmd_rad = self.table_measured_rad.unwrap_or(0.0);
            self.table_started = true;
        }
        if dt_s.is_finite() && dt_s > 0.0 {
            let target = if stop { 0.0 } else { s.speed_rad_per_s };
            let step = s.ramp_rad_per_s2 * dt_s;
            let v0 = self.table_cmd_speed_rad_per_s;
            self.table_cmd_speed_rad_per_s += (target - v0).clamp(-step, step);
            self.table_cmd_rad += 0.5 * (v0 + self.table_cmd_speed_rad_per_s) * dt_s;
        }
        Some(self.table_cmd_rad)
    }

    /// The table's angle to turn base-frame x, y into the workpiece frame: the measured
    /// angle and the axis, when both are known.
    fn table_frame(&self) -> Option<(f64, [f64; 2])> {
        Some((self.table_measured_rad?, self.table_axis_mm?))
    }

    /// `pose` moved into the fixtures: onto the floor if below it, onto the synchronous
    /// mode's radial line (its radius kept within the range), into the corridor if outside
    /// it (towards the path's nearest point), into the region if outside it (each of x, y
    /// clamped to its range); the corridor and the region in the workpiece frame with a
    /// turntable.
    /// Records whether it moved (a radial projection of less than 1 µm does not count).
    pub fn limit(&mut self, pose: Pose) -> Pose {
        let mut p = pose;
        let mut moved = false;
        if let Some(z) = self.floor_z_mm
            && p[2] < z
        {
            p[2] = z;
            moved = true;
        }
        if let (Some(s), Some(c)) = (self.sync, self.table_axis_mm) {
            let (uy, ux) = s.azimuth_rad.sin_cos();
            let [r0, r1] = s.radius_range_mm;
            let r = ((p[0] - c[0]) * ux + (p[1] - c[1]) * uy).clamp(r0, r1);
            let q = [c[0] + r * ux, c[1] + r * uy];
            moved |= (q[0] - p[0]).hypot(q[1] - p[1]) > 1e-3;
            p[0] = q[0];
            p[1] = q[1];
        }
        if self.path_len >= 2 || self.region.is_some() {
            let frame = self.table_frame();
            let mut q = match frame {
                Some((th, c)) => turn_about(c, -th, [p[0], p[1]]),
                None => [p[0], p[1]],
            };
            let mut moved_here = false;
            if self.path_len >= 2 {
                let (near, d) = self.nearest_on_path(q);
                if d > self.half_width_mm && d > 0.0 {
                    let s = self.half_width_mm / d;
                    q = [
                        near[0] + (q[0] - near[0]) * s,
                        near[1] + (q[1] - near[1]) * s,
                    ];
                    moved_here = true;
                }
            }
            if let Some(r) = self.region {
                for (a, v) in q.iter_mut().enumerate() {
                    let c = v.clamp(r.min_mm[a], r.max_mm[a]);
                    moved_here |= c != *v;
                    *v = c;
                }
            }
            if moved_here {
                let b = match frame {
                    Some((th, c)) => turn_about(c, th, q),
                    None => q,
                };
                p[0] = b[0];
                p[1] = b[1];
                moved = true;
            }
        }
        self.mesh_active = false;
        if self.mesh.is_some() {
            let q = self.out_of_the_part(p);
            if (q[0] - p[0]).abs() + (q[1] - p[1]).abs() + (q[2] - p[2]).abs() > 1e-9 {
                p = q;
                moved = true;
                self.mesh_active = true;
            }
        }
        self.active = moved;
        if self.active {
            self.active_cycles += 1;
        }
        p
    }

    /// Whether the mesh fixture moved the last committed pose.
    pub fn mesh_active(&self) -> bool {
        self.mesh_active
    }

    /// `pose` with the tool's envelope moved out of the part grown by the allowance: the
    /// envelope's centre (workpiece frame, through the table's measured angle) stepped along
    /// the distance field's gradient by what it lacks, up to 8 times (straight up where the
    /// gradient is lost, deep inside). Unchanged without a mesh or for a non-finite pose.
    fn out_of_the_part(&self, pose: Pose) -> Pose {
        let Some((g, allowance_mm)) = &self.mesh else {
            return pose;
        };
        if !(pose[0].is_finite() && pose[1].is_finite() && pose[2].is_finite()) {
            return pose;
        }
        let frame = self.table_frame();
        let q = match frame {
            Some((th, c)) => turn_about(c, -th, [pose[0], pose[1]]),
            None => [pose[0], pose[1]],
        };
        let need = g.radius_mm + allowance_mm;
        let start = [q[0], q[1], pose[2] + g.centre_above_tip_mm];
        let mut c = start;
        for _ in 0..8 {
            let (d, n) = g.part.distance_and_normal(c);
            if !d.is_finite() || d >= need {
                break;
            }
            let n_ok =
                n.iter().all(|v| v.is_finite()) && (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) > 0.25;
            let n = if n_ok { n } else { [0.0, 0.0, 1.0] };
            // A micrometre beyond, so the interpolated field is met from outside.
            let step = need - d + 1e-3;
            for (a, v) in c.iter_mut().enumerate() {
                *v += step * n[a];
            }
        }
        if c == start {
            return pose;
        }
        let b = match frame {
            Some((th, axis)) => turn_about(axis, th, [c[0], c[1]]),
            None => [c[0], c[1]],
        };
        let mut p = pose;
        p[0] = b[0];
        p[1] = b[1];
        p[2] = c[2] - g.centre_above_tip_mm;
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

/// `q` turned by `angle_rad` about `c` (x, y), mm.
#[inline]
fn turn_about(c: [f64; 2], angle_rad: f64, q: [f64; 2]) -> [f64; 2] {
    let (s, co) = angle_rad.sin_cos();
    let (x, y) = (q[0] - c[0], q[1] - c[1]);
    [c[0] + co * x - s * y, c[1] + s * x + co * y]
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
            ..FixturesConfig::default()
        }
    }

    fn region() -> FixturesConfig {
        FixturesConfig {
            region: Some(RegionConfig {
                min_mm: [-10.0, -6.0],
                max_mm: [10.0, 6.0],
            }),
            ..FixturesConfig::default()
        }
    }

    /// The region clamps x and y each to its range (past a corner: onto the corner), leaves
    /// z, θ and the points inside alone.
    #[test]
    fn the_region_keeps_the_tool_point_inside_its_rectangle() {
        let mut f = Fixtures::new(&region());
        let p = f.limit(Pose::new(11.5, 2.0, -251.0, 0.1));
        assert_eq!(p, Pose::new(10.0, 2.0, -251.0, 0.1));
        assert!(f.active);
        let p = f.limit(Pose::new(-12.0, -7.0, -260.0, 0.0));
        assert_eq!(p, Pose::new(-10.0, -6.0, -260.0, 0.0));
        let q = Pose::new(-9.9, 5.9, -251.0, 0.0);
        assert_eq!(f.limit(q), q);
        assert!(!f.active && f.active_cycles == 2);
    }

    /// With a turntable the region is in the workpiece frame: a quarter turn of the table
    /// turns it with the part.
    #[test]
    fn the_region_turns_with_the_table() {
        let mut f = Fixtures::new(&region());
        f.set_turntable_axis([0.0, 0.0]);
        f.observe_turntable(Some(std::f64::consts::FRAC_PI_2));
        // Turned a quarter, the rectangle spans x ∈ [−6, 6], y ∈ [−10, 10] in the base frame.
        let p = f.limit(Pose::new(8.0, 9.0, -251.0, 0.0));
        assert!(
            (p[0] - 6.0).abs() < 1e-9 && (p[1] - 9.0).abs() < 1e-9,
            "{p:?}"
        );
        let q = Pose::new(5.0, -9.0, -251.0, 0.0);
        let p = f.limit(q);
        assert!(
            (p[0] - 5.0).abs() < 1e-9 && (p[1] + 9.0).abs() < 1e-9,
            "{p:?}"
        );
    }

    #[test]
    fn the_floor_holds_the_tool_point_above_it() {
        let mut f = Fixtures::new(&FixturesConfig {
            depth_floor: Some(DepthFloor { z_mm: -252.0 }),
            ..FixturesConfig::default()
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

    fn sync(speed: f64) -> FixturesConfig {
        FixturesConfig {
            turntable_sync: Some(TurntableSync {
                speed_rad_per_s: speed,
                ramp_rad_per_s2: 2.0,
                azimuth_rad: std::f64::consts::FRAC_PI_2,
                radius_range_mm: [5.0, 40.0],
            }),
            ..FixturesConfig::default()
        }
    }

    /// The synchronous mode holds the tool point on its radial line (here +y of the axis
    /// at (10, 0)), the radius within its range, z untouched; a tiny projection does not
    /// count as the fixture acting.
    #[test]
    fn the_synchronous_mode_holds_the_tool_on_its_radial_line() {
        let mut f = Fixtures::new(&sync(1.0));
        f.set_turntable_axis([10.0, 0.0]);
        let p = f.limit(Pose::new(13.0, 20.0, -251.0, 0.2));
        assert!(
            (p[0] - 10.0).abs() < 1e-12 && (p[1] - 20.0).abs() < 1e-12,
            "{p:?}"
        );
        assert_eq!((p[2], p[3]), (-251.0, 0.2));
        assert!(f.active);
        let p = f.limit(Pose::new(10.0, 60.0, -251.0, 0.0));
        assert!((p[1] - 40.0).abs() < 1e-12, "{p:?}");
        let p = f.limit(Pose::new(10.0, -3.0, -251.0, 0.0));
        assert!((p[1] - 5.0).abs() < 1e-12, "{p:?}");
        f.limit(Pose::new(10.0 + 1e-4, 20.0, -251.0, 0.0));
        assert!(!f.active);
    }

    /// The program ramps the commanded speed to the configured one from the measured
    /// angle, and ramps it down to a stop while stopping; without the mode there is none.
    #[test]
    fn the_synchronous_program_ramps_the_table() {
        let mut f = Fixtures::new(&sync(1.5));
        f.observe_turntable(Some(0.25));
        let mut last = 0.25;
        let mut speed = 0.0;
        for _ in 0..2000 {
            let a = f.turntable_command(1e-3, false).unwrap();
            speed = (a - last) / 1e-3;
            last = a;
        }
        assert!((speed - 1.5).abs() < 1e-9, "{speed}");
        // 0.75 s of ramp (1.5 / 2), then 1.25 s at speed: 0.5625 + 1.875 rad.
        assert!((last - 0.25 - 0.5625 - 1.875).abs() < 1e-3, "{last}");
        for _ in 0..1000 {
            let a = f.turntable_command(1e-3, true).unwrap();
            speed = (a - last) / 1e-3;
            last = a;
        }
        assert!(speed.abs() < 1e-9, "still turning at {speed}");
        assert!(
            Fixtures::new(&corridor())
                .turntable_command(1e-3, false)
                .is_none()
        );
    }

    /// With a turntable the corridor's path is in the workpiece frame: a quarter turn of
    /// the table turns it with the part.
    #[test]
    fn the_corridor_turns_with_the_table() {
        let mut f = Fixtures::new(&FixturesConfig {
            corridor: Some(CorridorConfig {
                path_mm: vec![[10.0, 0.0], [30.0, 0.0]],
                half_width_mm: 0.5,
            }),
            ..FixturesConfig::default()
        });
        f.set_turntable_axis([0.0, 0.0]);
        f.observe_turntable(Some(std::f64::consts::FRAC_PI_2));
        // The path now runs along +y in the base frame: (3, 20) comes back to (0.5, 20).
        let p = f.limit(Pose::new(3.0, 20.0, -251.0, 0.0));
        assert!(
            (p[0] - 0.5).abs() < 1e-9 && (p[1] - 20.0).abs() < 1e-9,
            "{p:?}"
        );
        f.observe_turntable(Some(0.0));
        let p = f.limit(Pose::new(20.0, 3.0, -251.0, 0.0));
        assert!((p[1] - 0.5).abs() < 1e-9, "{p:?}");
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
        let mut c = sync(1.0);
        c.turntable_sync.as_mut().unwrap().radius_range_mm = [10.0, 5.0];
        let e = c.validate_at("fixtures.").unwrap_err().to_string();
        assert!(
            e.contains("fixtures.turntable_sync.radius_range_mm[1]"),
            "{e}"
        );
        let mut c = region();
        c.region.as_mut().unwrap().max_mm[1] = -7.0;
        let e = c.validate_at("fixtures.").unwrap_err().to_string();
        assert!(e.contains("fixtures.region.max_mm[1]"), "{e}");
        let mut c = region();
        c.region.as_mut().unwrap().min_mm[0] = f64::NAN;
        let e = c.validate_at("fixtures.").unwrap_err().to_string();
        assert!(e.contains("fixtures.region.min_mm[0]"), "{e}");
        let e = sync(1.0).check_turntable("fixtures.", false).unwrap_err();
        assert!(e.to_string().contains("fixtures.turntable_sync"), "{e}");
        assert!(sync(1.0).check_turntable("fixtures.", true).is_ok());
    }

    /// The dome-and-step block (2 mm cells) on a block whose top is at z = −250, the dome's
    /// top 1 mm under it, guarded for a 3 mm ball end with a 0.3 mm allowance.
    fn mesh_fixture() -> (Fixtures, Arc<h4_part::Part>) {
        let m = h4_part::shapes::dome_block(2.0);
        let v: Vec<[f32; 3]> = m.vertices.iter().map(|p| p.map(|x| x as f32)).collect();
        let opts = h4_part::LoadOptions {
            band_mm: 7.0,
            ..h4_part::LoadOptions::default()
        };
        let placement = h4_part::Placement {
            translation_mm: [-15.0, 0.0, -275.0],
            rotation_deg: [0.0; 3],
        };
        let part =
            Arc::new(h4_part::Part::from_mesh(&v, &m.faces, placement, None, &opts).unwrap());
        let cfg = FixturesConfig {
            mesh: Some(MeshFixtureConfig {
                allowance_mm: 0.3,
                guard: Some(MeshGuard::new(part.clone(), 3.0, true)),
            }),
            ..FixturesConfig::default()
        };
        (Fixtures::new(&cfg), part)
    }

    /// Commanded anywhere over and into the dome (down to 8 mm into it), the ball's centre
    /// ends at least radius + allowance from the part (to the grid's 0.01 mm); a command clear
    /// of it is left alone. Control: without the mesh fixture the same commands stay inside.
    #[test]
    fn the_mesh_keeps_the_balls_envelope_off_the_part() {
        let (mut f, part) = mesh_fixture();
        let mut none = Fixtures::new(&FixturesConfig::default());
        let (mut held, mut inside_without) = (0, 0);
        for i in -12..=12 {
            for j in -8..=8 {
                for k in 0..12 {
                    let cmd = Pose::new(f64::from(i), f64::from(j), -250.0 - f64::from(k), 0.0);
                    let p = f.limit(cmd);
                    let d = part.signed_distance_mm([p[0], p[1], p[2] + 3.0]);
                    assert!(d >= 3.3 - 0.01, "{cmd:?} -> {p:?}: {d} mm");
                    let d_cmd = part.signed_distance_mm([cmd[0], cmd[1], cmd[2] + 3.0]);
                    if d_cmd >= 3.3 {
                        assert_eq!(p, cmd, "clear of the part: unchanged");
                        assert!(!f.mesh_active());
                    } else {
                        held += 1;
                        assert!(f.mesh_active() && f.active);
                    }
                    let q = none.limit(cmd);
                    if part.signed_distance_mm([q[0], q[1], q[2] + 3.0]) < 3.3 {
                        inside_without += 1;
                    }
                }
            }
        }
        assert!(
            held > 1000 && held == inside_without,
            "{held} held, {inside_without}"
        );
        // A NaN command is not moved (the controller's own guards refuse it).
        let p = f.limit(Pose::new(f64::NAN, 0.0, -260.0, 0.0));
        assert!(p[0].is_nan());
    }

    /// With a turntable the part turns with the table's measured angle: the dome, 15 mm off
    /// the axis, is guarded where the table has turned it.
    #[test]
    fn the_mesh_turns_with_the_table() {
        let (mut f, part) = mesh_fixture();
        f.set_turntable_axis([-15.0, 0.0]);
        // Turned by 90°, the dome's top (workpiece (0, 0)) lies at base (−15, 15).
        f.observe_turntable(Some(std::f64::consts::FRAC_PI_2));
        let p = f.limit(Pose::new(-15.0, 15.0, -254.0, 0.0));
        assert!(f.mesh_active(), "{p:?}");
        let wp = turn_about([-15.0, 0.0], -std::f64::consts::FRAC_PI_2, [p[0], p[1]]);
        let d = part.signed_distance_mm([wp[0], wp[1], p[2] + 3.0]);
        assert!(d >= 3.29, "{d}");
        // The base-frame point over the unturned dome is clear now (the dome has moved).
        let q = f.limit(Pose::new(0.0, 0.0, -254.0, 0.0));
        assert_eq!(q, Pose::new(0.0, 0.0, -254.0, 0.0));
    }
}
