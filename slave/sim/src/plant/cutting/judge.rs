//! A cutting session's part and its judgement: the target shape (`cut_target`), the
//! per-cycle evidence of the cutting force at steady feed, the summary's cutting fields and
//! the files `--out DIR` writes (height map, STL, deviation map).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::export::{ExportError, write_deviation_png, write_height_png, write_stl};
use super::{CutReport, Stock, Tool, ToolKind};
use h4_shared::config::{ConfigError, Section, check_range};
use serde::{Deserialize, Serialize};

/// The kinds of target shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum TargetKind {
    /// A rectangular pocket: the tool's tip covers `size_mm` at `depth_mm`; its walls and
    /// their fillets are the tool's own shape.
    Pocket,
    /// A ring groove (a contour round a turning part): the tool's tip covers the circle of
    /// `radius_mm` about `centre_mm` (a band `size_mm[0]` wide across it) at `depth_mm`.
    Ring,
    /// A part from a CAD mesh (`mesh`, an STL file in millimetres), placed by
    /// `translation_mm` and `rotation_deg` in the workpiece frame; judged over the rectangle
    /// `centre_mm` ± `size_mm`/2 (the whole block when `size_mm` is 0) against the mesh's
    /// top surface (`docs/cutting.md`).
    Mesh,
}

/// The default largest mesh file accepted, bytes (16 MiB).
pub const MESH_MAX_FILE_BYTES_DEFAULT: u64 = 16 << 20;

/// A mesh target's part as loaded (not a key of the file): the checked, placed part with
/// its distance grid, and the finishing allowance it is judged with, mm.
#[derive(Clone)]
pub struct LoadedPart {
    /// The part (workpiece frame).
    pub part: Arc<h4_part::Part>,
    /// The finishing allowance, mm (`fixtures.mesh.allowance_mm`, else its default 0.3).
    pub allowance_mm: f64,
}

impl PartialEq for LoadedPart {
    fn eq(&self, o: &Self) -> bool {
        Arc::ptr_eq(&self.part, &o.part) && self.allowance_mm == o.allowance_mm
    }
}

impl std::fmt::Debug for LoadedPart {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadedPart")
            .field("volume_mm3", &self.part.volume_mm3)
            .field("allowance_mm", &self.allowance_mm)
            .finish()
    }
}

/// The shape a session should cut (`cut_target`), in the workpiece frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CutTarget {
    /// The kind of shape.
    pub kind: TargetKind,
    /// Centre of the region the tool's tip covers (a mesh: of the region judged), x and y,
    /// mm.
    #[serde(default)]
    pub centre_mm: [f64; 2],
    /// Size of that region along x and y, mm (a ring: `[band width, unused]`, default 0).
    #[serde(default)]
    pub size_mm: [f64; 2],
    /// A ring's radius (the tip's circle), mm (0 to 1e4; unused by a pocket).
    #[serde(default)]
    pub radius_mm: f64,
    /// Depth below the block's top, mm (unused by a mesh).
    #[serde(default)]
    pub depth_mm: f64,
    /// The part is judged over the pocket and this margin of the top around it, mm.
    #[serde(default = "default_margin_mm")]
    pub margin_mm: f64,
    /// A mesh target's STL file (binary or ASCII, millimetres), relative to the session
    /// (or world) file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<PathBuf>,
    /// Where the mesh's origin lies in the workpiece frame, mm (±1e4 each).
    #[serde(default)]
    pub translation_mm: [f64; 3],
    /// The mesh's rotation about the workpiece frame's x, y, then z axes, degrees (±360
    /// each).
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    /// The largest mesh file accepted, bytes (1 to 1 GiB; 16 MiB).
    #[serde(default = "default_mesh_max_file_bytes")]
    pub mesh_max_file_bytes: u64,
    /// The mesh's part once loaded ([`CutTarget::load_mesh`]).
    #[serde(skip)]
    #[schemars(skip)]
    pub part: Option<LoadedPart>,
}

fn default_mesh_max_file_bytes() -> u64 {
    MESH_MAX_FILE_BYTES_DEFAULT
}

fn default_margin_mm() -> f64 {
    3.0
}

impl Section for CutTarget {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |n: &str| format!("{prefix}{n}");
        for i in 0..2 {
            check_range(
                &f(&format!("centre_mm[{i}]")),
                self.centre_mm[i],
                -1e4,
                1e4,
                "mm",
            )?;
            check_range(
                &f(&format!("size_mm[{i}]")),
                self.size_mm[i],
                0.0,
                1e3,
                "mm",
            )?;
        }
        check_range(&f("radius_mm"), self.radius_mm, 0.0, 1e4, "mm")?;
        check_range(&f("depth_mm"), self.depth_mm, 0.0, 100.0, "mm")?;
        check_range(&f("margin_mm"), self.margin_mm, 0.0, 100.0, "mm")?;
        for i in 0..3 {
            check_range(
                &f(&format!("translation_mm[{i}]")),
                self.translation_mm[i],
                -1e4,
                1e4,
                "mm",
            )?;
            check_range(
                &f(&format!("rotation_deg[{i}]")),
                self.rotation_deg[i],
                -360.0,
                360.0,
                "deg",
            )?;
        }
        check_range(
            &f("mesh_max_file_bytes"),
            self.mesh_max_file_bytes as f64,
            1.0,
            (1u64 << 30) as f64,
            "bytes",
        )?;
        const NEEDS: &str = "a file with kind = \"mesh\", none otherwise";
        if h4_shared::config::recording() {
            h4_shared::config::record_rule(&f("mesh"), NEEDS);
        }
        if (self.kind == TargetKind::Mesh) != self.mesh.is_some() {
            return Err(ConfigError::OutOfRange {
                field: f("mesh"),
                value: match &self.mesh {
                    Some(m) => m.display().to_string(),
                    None => "none".to_string(),
                },
                allowed: NEEDS.to_string(),
            });
        }
        Ok(())
    }
}

/// Why a mesh target could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum MeshTargetError {
    /// A mesh target without a `[cutting]` section (no stock to place it in).
    #[error(
        "cut_target.kind = \"mesh\" needs a [cutting] section (the stock the part is placed in)"
    )]
    NoStock,
    /// A mesh fixture without a mesh target.
    #[error("fixtures.mesh needs a cut_target of kind \"mesh\" (the part it guards)")]
    NoPart,
    /// The part was refused.
    #[error("cut_target.mesh {path}: {source}")]
    Part {
        /// The file.
        path: String,
        /// The reason.
        source: h4_part::PartError,
    },
}

/// Loads a session's (or world's) mesh target and hands its part to the mesh fixture:
/// the target's part is judged with the fixture's allowance (its default without the
/// fixture); the fixture's guard is the part with the envelope of `cutting`'s tool.
pub fn load_mesh_target(
    target: Option<&mut CutTarget>,
    fixtures: &mut h4_slave::controller::FixturesConfig,
    cutting: Option<&super::CuttingConfig>,
    base_dir: &Path,
) -> Result<(), MeshTargetError> {
    let allowance_mm = fixtures.mesh.as_ref().map_or(
        h4_slave::controller::fixtures::MESH_ALLOWANCE_DEFAULT_MM,
        |m| m.allowance_mm,
    );
    let part = match target {
        Some(t) => {
            t.load_mesh(base_dir, cutting, allowance_mm)?;
            t.part.as_ref().map(|p| p.part.clone())
        }
        None => None,
    };
    if let Some(m) = fixtures.mesh.as_mut() {
        let (Some(part), Some(c)) = (part, cutting) else {
            return Err(MeshTargetError::NoPart);
        };
        m.guard = Some(h4_slave::controller::fixtures::MeshGuard::new(
            part,
            c.tool.radius_mm,
            c.tool.kind == ToolKind::Ball,
        ));
    }
    Ok(())
}

impl CutTarget {
    /// Loads a mesh target's part (nothing for the other kinds): the file (relative to
    /// `base_dir`) read and checked (closed, manifold, outward, finite, non-degenerate, not
    /// over `mesh_max_file_bytes`), placed, checked to fit the stock of `cutting`, and its
    /// distance grid built wide enough for the tool's envelope and the allowance.
    pub fn load_mesh(
        &mut self,
        base_dir: &Path,
        cutting: Option<&super::CuttingConfig>,
        allowance_mm: f64,
    ) -> Result<(), MeshTargetError> {
        let Some(rel) = self.mesh.clone() else {
            return Ok(());
        };
        let path = if rel.is_relative() {
            base_dir.join(rel)
        } else {
            rel
        };
        let c = cutting.ok_or(MeshTargetError::NoStock)?;
        let stock = h4_part::StockBox {
            centre_top_mm: c.stock_centre_top_mm,
            size_mm: c.stock_size_mm,
            thickness_mm: c.stock_thickness_mm,
        };
        let reach_mm = c.tool.radius_mm * std::f64::consts::SQRT_2 + allowance_mm;
        let opts = h4_part::LoadOptions {
            max_file_bytes: self.mesh_max_file_bytes,
            band_mm: (reach_mm + 2.0).max(4.0),
            ..h4_part::LoadOptions::default()
        };
        let placement = h4_part::Placement {
            translation_mm: self.translation_mm,
            rotation_deg: self.rotation_deg,
        };
        let part =
            h4_part::Part::load(&path, placement, Some(&stock), &opts).map_err(|source| {
                MeshTargetError::Part {
                    path: path.display().to_string(),
                    source,
                }
            })?;
        self.part = Some(LoadedPart {
            part: Arc::new(part),
            allowance_mm,
        });
        // Written out (a world file for the slave process) the path holds from anywhere.
        self.mesh = Some(path);
        Ok(())
    }
}

impl CutTarget {
    /// Horizontal distance of (`x`, `y`) from the region the tip covers (0 inside), mm.
    fn distance_mm(&self, x: f64, y: f64) -> f64 {
        if self.kind == TargetKind::Ring {
            let rho = (x - self.centre_mm[0]).hypot(y - self.centre_mm[1]);
            return ((rho - self.radius_mm).abs() - 0.5 * self.size_mm[0]).max(0.0);
        }
        let dx = ((x - self.centre_mm[0]).abs() - 0.5 * self.size_mm[0]).max(0.0);
        let dy = ((y - self.centre_mm[1]).abs() - 0.5 * self.size_mm[1]).max(0.0);
        (dx * dx + dy * dy).sqrt()
    }

    /// The target's height at (`x`, `y`) for a block whose top is `top_mm`, cut by `tool`:
    /// the lower envelope of the tool with its tip anywhere in the region at the depth.
    pub fn height_mm(&self, x: f64, y: f64, top_mm: f64, tool: &Tool) -> f64 {
        let d = self.distance_mm(x, y);
        let r = tool.radius_mm;
        if d > r {
            return top_mm;
        }
        let floor = top_mm - self.depth_mm;
        let lift = match tool.kind {
            ToolKind::Flat => 0.0,
            ToolKind::Ball => tool.lift_mm(d * d),
        };
        (floor + lift).min(top_mm)
    }

    /// Whether the point is judged (within the pocket's edge and the margin).
    fn judged(&self, x: f64, y: f64, tool: &Tool) -> bool {
        self.distance_mm(x, y) <= tool.radius_mm + self.margin_mm
    }

    /// `[x_min, x_max, y_min, y_max]` of a box that holds every judged point, mm.
    fn judged_box_mm(&self, tool: &Tool) -> [f64; 4] {
        let reach = tool.radius_mm + self.margin_mm;
        let half = if self.kind == TargetKind::Ring {
            let r = self.radius_mm + 0.5 * self.size_mm[0] + reach;
            [r, r]
        } else {
            [0.5 * self.size_mm[0] + reach, 0.5 * self.size_mm[1] + reach]
        };
        let [cx, cy] = self.centre_mm;
        [cx - half[0], cx + half[0], cy - half[1], cy + half[1]]
    }
}

/// The summary's cutting fields (NaN is written as null and read back as NaN).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CutSummary {
    /// Volume removed from the block, mm³.
    pub removed_volume_mm3: f64,
    /// 99th percentile of |machined − target| over the judged cells, mm (NaN without a
    /// target).
    #[serde(deserialize_with = "nan_if_null")]
    pub surface_error_p99_mm: f64,
    /// Deepest cut below the fixture floor (`fixtures.depth_floor.z_mm`, else the target's
    /// floor), mm (0: none).
    pub gouge_max_mm: f64,
    /// 99th percentile of |mean cutting force along z − set-point| / set-point at steady
    /// feed, % (NaN: no steady feed).
    #[serde(deserialize_with = "nan_if_null")]
    pub cutting_force_dev_p99_pct: f64,
    /// Mean removal rate while cutting, mm³/s.
    pub removal_rate_mm3_per_s: f64,
    /// Cycles judged as steady feed.
    pub steady_feed_cycles: u64,
    /// Spindle stalls.
    pub spindle_stalls: u64,
    /// When the last spindle stall began, s from the start (NaN: none).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub spindle_last_stall_s: f64,
    /// Cycles in which a fixture limited the commanded tool point.
    pub fixture_limited_cycles: u64,
    /// Largest true contact force during the cut, N.
    pub cutting_force_max_n: f64,
    /// A mesh target: the stock left more than the allowance from the part over the judged
    /// region, mm³.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material_left_mm3: Option<f64>,
    /// A mesh target: the stock more than the allowance from the part over the judged
    /// region before the cut (what was to be removed), mm³.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material_to_remove_mm3: Option<f64>,
}

fn nan() -> f64 {
    f64::NAN
}

/// A number that JSON wrote as null (NaN, infinite) read back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// One cycle's evidence for the cutting fields.
#[derive(Clone, Copy, Debug, Default)]
pub struct CutSample {
    /// The cut's report after this cycle.
    pub report: CutReport,
    /// The tool's true position, workpiece frame, mm.
    pub tip_mm: [f64; 3],
    /// The slave is controlling the contact force.
    pub in_contact: bool,
    /// A fixture limited this cycle's command.
    pub fixture_active: bool,
    /// The slave's (prefiltered) force set-point, N.
    pub setpoint_n: f64,
}

/// The true cutting force averaged over the last spindle revolution (up to 64 cycles): the
/// force the arm's contact carries, without the tooth-passing ripple (a milling cutter's
/// force is pulses, zero between the teeth of an interrupted cut).
pub struct RevolutionMean {
    ring: [[f64; 3]; 64],
    len: usize,
    n: usize,
}

impl RevolutionMean {
    /// The mean over one revolution at `spindle_rpm` (whole cycles, 1 to 64).
    pub fn new(spindle_rpm: f64) -> Self {
        let len = if spindle_rpm > 0.0 {
            ((60_000.0 / spindle_rpm).round() as usize).clamp(1, 64)
        } else {
            1
        };
        RevolutionMean {
            ring: [[0.0; 3]; 64],
            len,
            n: 0,
        }
    }

    /// Adds this cycle's mean force (N) and returns the mean over the revolution.
    pub fn push(&mut self, f_n: [f64; 3]) -> [f64; 3] {
        self.ring[self.n % self.len] = f_n;
        self.n += 1;
        let k = self.n.min(self.len);
        let mut m = [0.0; 3];
        for f in &self.ring[..k] {
            for (a, b) in m.iter_mut().zip(f) {
                *a += b / k as f64;
            }
        }
        m
    }
}

/// Ring length for the steady-feed criteria, cycles (100 ms).
const HISTORY: usize = 100;
/// The feed speed counted as feeding, mm/s.
const FEED_MIN_MM_PER_S: f64 = 2.0;

/// Collects the cutting evidence cycle by cycle (allocates only at construction).
pub struct CutEvaluator {
    deviations_pct: Vec<f64>,
    /// Mean z force of the last cycles (one spindle revolution is averaged), N.
    force_ring: [f64; HISTORY],
    tip_ring: [[f64; 2]; HISTORY],
    speed_ring: [f64; HISTORY],
    setpoint_ring: [f64; HISTORY],
    n: usize,
    rev_cycles: usize,
    cutting_cycles: u64,
    removed_while_cutting_mm3: f64,
    last_removed_mm3: f64,
    force_max_n: f64,
    stalls_seen: u64,
    last_stall_cycle: Option<usize>,
}

impl CutEvaluator {
    /// An evaluator for a run of `cycles` cycles with the spindle at `spindle_rpm`.
    pub fn new(cycles: usize, spindle_rpm: f64) -> Self {
        let rev_cycles = if spindle_rpm > 0.0 {
            ((60_000.0 / spindle_rpm).round() as usize).clamp(1, HISTORY)
        } else {
            1
        };
        CutEvaluator {
            deviations_pct: Vec::with_capacity(cycles),
            force_ring: [0.0; HISTORY],
            tip_ring: [[0.0; 2]; HISTORY],
            speed_ring: [0.0; HISTORY],
            setpoint_ring: [0.0; HISTORY],
            n: 0,
            rev_cycles,
            cutting_cycles: 0,
            removed_while_cutting_mm3: 0.0,
            last_removed_mm3: 0.0,
            force_max_n: 0.0,
            stalls_seen: 0,
            last_stall_cycle: None,
        }
    }

    /// One cycle (1 ms).
    pub fn push(&mut self, s: &CutSample) {
        let i = self.n % HISTORY;
        self.force_ring[i] = s.report.mean_force_n[2];
        self.tip_ring[i] = [s.tip_mm[0], s.tip_mm[1]];
        self.setpoint_ring[i] = s.setpoint_n;
        if s.report.stalls > self.stalls_seen {
            self.stalls_seen = s.report.stalls;
            self.last_stall_cycle = Some(self.n);
        }
        let f = s.report.mean_force_n;
        self.force_max_n = self
            .force_max_n
            .max((f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt());
        // Feed speed over the last 20 ms.
        let n = self.n;
        let back = |k: usize| (n + HISTORY - k) % HISTORY;
        let speed = if self.n >= 20 {
            let a = self.tip_ring[back(20)];
            let b = self.tip_ring[i];
            ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt() / 0.020
        } else {
            0.0
        };
        self.speed_ring[i] = speed;
        let removed = s.report.removed_mm3 - self.last_removed_mm3;
        self.last_removed_mm3 = s.report.removed_mm3;
        // The removal rate holds over the removal update's interval (the stock is swept
        // every quarter cell of travel, not every cycle).
        let cutting = s.report.removal_rate_mm3_per_s > 0.0;
        if cutting {
            self.cutting_cycles += 1;
            self.removed_while_cutting_mm3 += removed;
        }
        self.n += 1;
        if self.n < HISTORY || !(cutting && s.in_contact && !s.fixture_active) {
            return;
        }
        let old = self.speed_ring[back(HISTORY - 1)];
        let sp_old = self.setpoint_ring[back(HISTORY - 1)];
        let steady = speed >= FEED_MIN_MM_PER_S
            && (speed - old).abs() <= 0.2 * speed
            && s.setpoint_n > 0.0
            && (s.setpoint_n - sp_old).abs() <= 0.02 * s.setpoint_n;
        if steady && self.deviations_pct.len() < self.deviations_pct.capacity() {
            let mut mean = 0.0;
            for k in 0..self.rev_cycles {
                mean += self.force_ring[back(k)];
            }
            mean /= self.rev_cycles as f64;
            self.deviations_pct
                .push(100.0 * (mean - s.setpoint_n).abs() / s.setpoint_n);
        }
    }

    /// The cutting fields from the evidence, the stock, the tool, the target and the
    /// fixture floor.
    pub fn finish(
        mut self,
        stock: &Stock,
        tool: &Tool,
        report: &CutReport,
        target: Option<&CutTarget>,
        floor_z_mm: Option<f64>,
        fixture_limited_cycles: u64,
    ) -> CutSummary {
        let top = stock.top_mm();
        let (nx, ny) = stock.dims();
        let mut errors = Vec::new();
        let mut lowest = top;
        let judged_box = target.map(|t| t.judged_box_mm(tool));
        for iy in 0..ny {
            for ix in 0..nx {
                let h = stock.height_at(ix, iy);
                lowest = lowest.min(h);
                if let (Some(t), Some(b)) = (target, judged_box) {
                    let c = stock.cell_centre_mm(ix, iy);
                    let in_box = c[0] >= b[0] && c[0] <= b[1] && c[1] >= b[2] && c[1] <= b[3];
                    if in_box && t.judged(c[0], c[1], tool) {
                        errors.push((h - t.height_mm(c[0], c[1], top, tool)).abs());
                    }
                }
            }
        }
        let floor = floor_z_mm.or(target.map(|t| top - t.depth_mm));
        let mesh = target.and_then(|t| t.part.as_ref().map(|p| judge_mesh(stock, t, p)));
        let (surface_error_p99_mm, gouge_max_mm) = match &mesh {
            Some(m) => (m.surface_error_p99_mm, m.gouge_max_mm),
            None => (
                p99(&mut errors),
                floor.map_or(0.0, |f| (f - lowest).max(0.0)),
            ),
        };
        CutSummary {
            removed_volume_mm3: stock.removed_mm3(),
            surface_error_p99_mm,
            gouge_max_mm,
            material_left_mm3: mesh.as_ref().map(|m| m.material_left_mm3),
            material_to_remove_mm3: mesh.as_ref().map(|m| m.material_to_remove_mm3),
            cutting_force_dev_p99_pct: p99(&mut self.deviations_pct),
            removal_rate_mm3_per_s: if self.cutting_cycles > 0 {
                self.removed_while_cutting_mm3 / (self.cutting_cycles as f64 * 1e-3)
            } else {
                0.0
            },
            steady_feed_cycles: self.deviations_pct.len() as u64,
            spindle_stalls: report.stalls,
            spindle_last_stall_s: self
                .last_stall_cycle
                .map_or(f64::NAN, |n| n as f64 / 1000.0),
            fixture_limited_cycles,
            cutting_force_max_n: self.force_max_n,
        }
    }
}

/// A mesh target's judgement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshJudgement {
    /// 99th percentile of |the distance from each judged cell's machined surface point to
    /// the part's surface| (point to mesh, signed: + outside, − inside; the allowance is
    /// part of it), mm.
    pub surface_error_p99_mm: f64,
    /// Deepest cut into the part (the part's top − the machined height) over every cut
    /// cell, mm (0: none).
    pub gouge_max_mm: f64,
    /// Stock left more than the allowance from the part over the judged cells, mm³.
    pub material_left_mm3: f64,
    /// Stock more than the allowance from the part over the judged cells before the cut, mm³.
    pub material_to_remove_mm3: f64,
}

/// The height of the part's top above (`x`, `y`) (workpiece frame) below `z_top_mm`: the
/// highest point of the column inside the part (sphere-traced down its distance field,
/// then bisected to 1e-5 mm), or `None` if the column above `z_bottom_mm` misses it.
pub fn part_top_mm(
    part: &h4_part::Part,
    x: f64,
    y: f64,
    z_top_mm: f64,
    z_bottom_mm: f64,
) -> Option<f64> {
    let mut above = z_top_mm + 1e-3;
    let mut z = above;
    loop {
        let d = part.signed_distance_mm([x, y, z]);
        if d <= 0.0 {
            if z >= above {
                return Some(z);
            }
            let (mut lo, mut hi) = (z, above);
            for _ in 0..32 {
                let m = 0.5 * (lo + hi);
                if part.signed_distance_mm([x, y, m]) <= 0.0 {
                    lo = m;
                } else {
                    hi = m;
                }
                if hi - lo < 1e-5 {
                    break;
                }
            }
            return Some(lo);
        }
        if z <= z_bottom_mm {
            return None;
        }
        above = z;
        z = (z - d.max(0.02)).max(z_bottom_mm);
    }
}

/// The judged rectangle of a mesh target, `[x_min, x_max, y_min, y_max]`, mm (None: the
/// whole block).
fn mesh_region_mm(t: &CutTarget) -> Option<[f64; 4]> {
    let [sx, sy] = t.size_mm;
    if sx <= 0.0 || sy <= 0.0 {
        return None;
    }
    let [cx, cy] = t.centre_mm;
    Some([cx - 0.5 * sx, cx + 0.5 * sx, cy - 0.5 * sy, cy + 0.5 * sy])
}

/// Judges the block against a mesh target, in the workpiece frame the height field is kept
/// in (through the table's angle): per judged cell, the signed distance of its machined
/// surface point (the cell's centre at the machined height) from the part's surface, point
/// to mesh (the vertical height difference would exaggerate the error on a slope by
/// 1/cos(slope)); the gouge, the part's top less the machined height over every cut cell;
/// the material more than the allowance from the part integrated up each judged column in
/// 0.02 mm steps.
pub fn judge_mesh(stock: &Stock, t: &CutTarget, p: &LoadedPart) -> MeshJudgement {
    let part = &*p.part;
    let top = stock.top_mm();
    let bottom = stock.bottom_mm();
    let (nx, ny) = stock.dims();
    let cell = stock.cell_mm();
    let region = mesh_region_mm(t);
    let mut errors = Vec::new();
    let mut gouge: f64 = 0.0;
    let (mut left, mut to_remove) = (0.0, 0.0);
    let dz = 0.02;
    for iy in 0..ny {
        for ix in 0..nx {
            let h = stock.height_at(ix, iy);
            let c = stock.cell_centre_mm(ix, iy);
            let judged =
                region.is_none_or(|b| c[0] >= b[0] && c[0] <= b[1] && c[1] >= b[2] && c[1] <= b[3]);
            let cut = h < top - 1e-9;
            if !judged && !cut {
                continue;
            }
            let pt = part_top_mm(part, c[0], c[1], top, bottom);
            if let Some(z) = pt {
                gouge = gouge.max(z - h);
            }
            if !judged {
                continue;
            }
            let base = pt.unwrap_or(bottom);
            errors.push(part.signed_distance_exact_mm([c[0], c[1], h]).abs());
            let mut z = base + 0.5 * dz;
            while z < top {
                if part.signed_distance_mm([c[0], c[1], z]) > p.allowance_mm {
                    let len = dz.min(top - (z - 0.5 * dz));
                    to_remove += len * cell * cell;
                    if z < h {
                        left += dz.min(h - (z - 0.5 * dz)).min(len) * cell * cell;
                    }
                }
                z += dz;
            }
        }
    }
    MeshJudgement {
        surface_error_p99_mm: p99(&mut errors),
        gouge_max_mm: gouge.max(0.0),
        material_left_mm3: left,
        material_to_remove_mm3: to_remove,
    }
}

/// The 99th percentile (nearest rank); NaN when empty.
fn p99(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let k = ((0.99 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[k]
}

/// Writes the part into `dir`: `height.png`, `part.stl` and, with a target,
/// `deviation.png` (±0.5 mm full scale).
pub fn write_outputs(
    dir: &Path,
    stock: &Stock,
    tool: &Tool,
    target: Option<&CutTarget>,
) -> Result<(), ExportError> {
    std::fs::create_dir_all(dir).map_err(|e| ExportError {
        path: dir.display().to_string(),
        message: e.to_string(),
    })?;
    write_height_png(&dir.join("height.png"), stock)?;
    write_stl(&dir.join("part.stl"), stock)?;
    if let Some(t) = target {
        let top = stock.top_mm();
        if let Some(p) = &t.part {
            // A mesh: the signed distance of the machined surface from the part's surface,
            // as the judge measures it (its allowance shows as + allowance); the grid's
            // answer, which saturates at its band, far beyond the map's full scale.
            let bottom = stock.bottom_mm();
            write_deviation_png(&dir.join("deviation.png"), stock, 0.5, |x, y| {
                let h = stock.height_under(x, y).unwrap_or(bottom);
                h - p.part.signed_distance_mm([x, y, h])
            })?;
        } else {
            write_deviation_png(&dir.join("deviation.png"), stock, 0.5, |x, y| {
                t.height_mm(x, y, top, tool)
            })?;
        }
    }
    Ok(())
}

/// The file `--out DIR` holds the summary's cutting fields in (`h4-master report --part DIR`
/// reads it).
pub const CUT_JSON: &str = "cut.json";

/// Writes the summary's cutting fields into `dir` as `cut.json` (pretty JSON).
pub fn write_cut_json(dir: &Path, summary: &CutSummary) -> Result<(), ExportError> {
    let path = dir.join(CUT_JSON);
    let text = serde_json::to_string_pretty(summary).map_err(|e| ExportError {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    std::fs::write(&path, text + "\n").map_err(|e| ExportError {
        path: path.display().to_string(),
        message: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The box the judge scans holds every judged point, for a pocket and a ring (points on
    /// a 0.05 mm grid around each, the box's edges included).
    #[test]
    fn the_judged_box_holds_every_judged_point() {
        let tool = Tool::default();
        let pocket = CutTarget {
            kind: TargetKind::Pocket,
            centre_mm: [3.0, -2.0],
            size_mm: [20.0, 12.0],
            radius_mm: 0.0,
            depth_mm: 2.0,
            margin_mm: 3.0,
            mesh: None,
            translation_mm: [0.0; 3],
            rotation_deg: [0.0; 3],
            mesh_max_file_bytes: MESH_MAX_FILE_BYTES_DEFAULT,
            part: None,
        };
        let ring = CutTarget {
            kind: TargetKind::Ring,
            centre_mm: [-1.0, 4.0],
            size_mm: [2.0, 0.0],
            radius_mm: 25.0,
            ..pocket.clone()
        };
        for t in [pocket, ring] {
            let b = t.judged_box_mm(&tool);
            let (mut judged, mut outside) = (0u32, 0u32);
            for i in -800..=800 {
                for j in -800..=800 {
                    let (x, y) = (
                        t.centre_mm[0] + 0.05 * f64::from(i),
                        t.centre_mm[1] + 0.05 * f64::from(j),
                    );
                    if t.judged(x, y, &tool) {
                        judged += 1;
                        assert!(
                            x >= b[0] && x <= b[1] && y >= b[2] && y <= b[3],
                            "{t:?}: ({x}, {y}) outside {b:?}"
                        );
                    } else {
                        outside += 1;
                    }
                }
            }
            assert!(
                judged > 1000 && outside > 1000,
                "{judged} judged, {outside} not"
            );
        }
    }

    /// The target is the ball's envelope over the pocket: the floor inside, the fillet of
    /// the tool's radius at the edge, the top beyond.
    #[test]
    fn pocket_target_is_the_tools_envelope() {
        let t = CutTarget {
            kind: TargetKind::Pocket,
            centre_mm: [0.0, 0.0],
            size_mm: [20.0, 10.0],
            radius_mm: 0.0,
            depth_mm: 2.0,
            margin_mm: 3.0,
            mesh: None,
            translation_mm: [0.0; 3],
            rotation_deg: [0.0; 3],
            mesh_max_file_bytes: MESH_MAX_FILE_BYTES_DEFAULT,
            part: None,
        };
        let tool = Tool::default(); // ball, 3 mm
        assert_eq!(t.height_mm(0.0, 0.0, 0.0, &tool), -2.0);
        assert_eq!(t.height_mm(9.9, 4.9, 0.0, &tool), -2.0);
        let h = t.height_mm(11.0, 0.0, 0.0, &tool);
        assert!((h - (-2.0 + 3.0 - 8f64.sqrt())).abs() < 1e-12, "{h}");
        assert_eq!(t.height_mm(13.5, 0.0, 0.0, &tool), 0.0);
        assert!(t.judged(15.9, 0.0, &tool) && !t.judged(16.1, 0.0, &tool));
        let mut v = vec![3.0, 1.0, 2.0];
        assert_eq!(p99(&mut v), 3.0);
        assert!(p99(&mut []).is_nan());
        // A ring of 20 mm about (5, 0): its floor on the circle, the fillet beside it.
        let ring = CutTarget {
            kind: TargetKind::Ring,
            radius_mm: 20.0,
            size_mm: [0.0, 0.0],
            centre_mm: [5.0, 0.0],
            ..t.clone()
        };
        assert_eq!(ring.height_mm(5.0, 20.0, 0.0, &tool), -2.0);
        let h = ring.height_mm(26.0, 0.0, 0.0, &tool);
        assert!((h - (-2.0 + 3.0 - 8f64.sqrt())).abs() < 1e-12, "{h}");
        assert_eq!(ring.height_mm(5.0, 0.0, 0.0, &tool), 0.0);
    }

    /// A 10 × 10 mm box whose top is 3 mm under a 20 × 20 mm block's top, as a loaded part
    /// with a 0.3 mm allowance.
    fn box_part() -> LoadedPart {
        box_part_placed(h4_part::Placement::default())
    }

    /// The box of `box_part`, placed by `placement`.
    fn box_part_placed(placement: h4_part::Placement) -> LoadedPart {
        let c = |i: usize| {
            [
                if i & 1 == 1 { 5.0 } else { -5.0 },
                if i & 2 == 2 { 5.0 } else { -5.0 },
                if i & 4 == 4 { -3.0 } else { -8.0 },
            ]
        };
        let vertices: Vec<[f32; 3]> = (0..8).map(|i| c(i).map(|x| x as f32)).collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let mut faces = Vec::new();
        for q in quads {
            faces.push([q[0], q[1], q[2]]);
            faces.push([q[0], q[2], q[3]]);
        }
        let part = h4_part::Part::from_mesh(
            &vertices,
            &faces,
            placement,
            None,
            &h4_part::LoadOptions::default(),
        )
        .unwrap();
        LoadedPart {
            part: Arc::new(part),
            allowance_mm: 0.3,
        }
    }

    fn mesh_target(size_mm: [f64; 2]) -> CutTarget {
        CutTarget {
            kind: TargetKind::Mesh,
            centre_mm: [0.0, 0.0],
            size_mm,
            radius_mm: 0.0,
            depth_mm: 0.0,
            margin_mm: 3.0,
            mesh: Some(PathBuf::from("box.stl")),
            translation_mm: [0.0; 3],
            rotation_deg: [0.0; 3],
            mesh_max_file_bytes: MESH_MAX_FILE_BYTES_DEFAULT,
            part: Some(box_part()),
        }
    }

    /// The mesh judge: the part's top found down each column; an uncut block over the box
    /// has everything above the allowance to remove and all of it left; a flat end sweeping
    /// the box's top at the allowance leaves almost nothing and cuts nothing of the part,
    /// 0.5 mm deeper it gouges 0.5 mm.
    #[test]
    fn the_mesh_judge_measures_what_is_left_and_what_is_gouged() {
        let p = box_part();
        let top = part_top_mm(&p.part, 1.0, 2.0, 0.0, -10.0).unwrap();
        assert!((top + 3.0).abs() < 1e-3, "{top}");
        assert!(part_top_mm(&p.part, 7.0, 0.0, 0.0, -10.0).is_none());
        let t = mesh_target([8.0, 8.0]);
        let fresh = Stock::new([0.0, 0.0, 0.0], [20.0, 20.0], 10.0, 0.25).unwrap();
        let j = judge_mesh(&fresh, &t, &p);
        // 8 × 8 mm judged, 2.7 mm of each column more than 0.3 mm above the box.
        let want = 64.0 * 2.7;
        assert!(
            (j.material_to_remove_mm3 - want).abs() < 0.02 * want,
            "{j:?}"
        );
        assert_eq!(j.material_left_mm3, j.material_to_remove_mm3);
        assert!((j.surface_error_p99_mm - 3.0).abs() < 1e-3, "{j:?}");
        assert_eq!(j.gouge_max_mm, 0.0);
        let tool = Tool {
            kind: ToolKind::Flat,
            radius_mm: 2.0,
            ..Tool::default()
        };
        let raster = |stock: &mut Stock, z: f64| {
            for k in 0..=12 {
                let y = -6.0 + f64::from(k);
                stock.sweep(&tool, [-7.0, y, z], [7.0, y, z]);
            }
        };
        let mut cut = fresh.clone();
        raster(&mut cut, -2.7);
        let j = judge_mesh(&cut, &t, &p);
        assert!(j.material_left_mm3 < 0.01 * want, "{j:?}");
        assert!((j.surface_error_p99_mm - 0.3).abs() < 0.01, "{j:?}");
        assert!(j.gouge_max_mm < 1e-3, "{j:?}");
        let mut deep = fresh.clone();
        raster(&mut deep, -3.5);
        let j = judge_mesh(&deep, &t, &p);
        assert!((j.gouge_max_mm - 0.5).abs() < 0.01, "{j:?}");
        assert!((j.surface_error_p99_mm - 0.5).abs() < 0.01, "{j:?}");
        assert!(j.material_left_mm3 < 1e-9, "{j:?}");
    }

    /// The surface error is the machined point's distance to the part's surface, not the
    /// vertical height difference: over the box tilted 30° about x, the uncut block's top
    /// (2.5 to 3.5 mm from the tilted face over the judged cells) is judged cos 30° of the
    /// vertical difference; the distance is exact beyond the grid's band too (the fallback
    /// over every face).
    #[test]
    fn the_mesh_judge_measures_the_distance_to_the_surface_not_the_height() {
        let placement = h4_part::Placement {
            translation_mm: [0.0; 3],
            rotation_deg: [30.0, 0.0, 0.0],
        };
        let p = box_part_placed(placement);
        let t = CutTarget {
            centre_mm: [0.0, 1.0],
            part: Some(p.clone()),
            ..mesh_target([4.0, 4.0])
        };
        let fresh = Stock::new([0.0, 0.0, 0.0], [20.0, 20.0], 10.0, 0.25).unwrap();
        let j = judge_mesh(&fresh, &t, &p);
        let mut vertical = Vec::new();
        let (nx, ny) = fresh.dims();
        for iy in 0..ny {
            for ix in 0..nx {
                let c = fresh.cell_centre_mm(ix, iy);
                if c[0].abs() <= 2.0 && (c[1] - 1.0).abs() <= 2.0 {
                    let z = part_top_mm(&p.part, c[0], c[1], 0.0, -10.0).unwrap();
                    vertical.push(-z);
                }
            }
        }
        let v = p99(&mut vertical);
        let cos = 30f64.to_radians().cos();
        assert!(
            (j.surface_error_p99_mm - cos * v).abs() < 0.01,
            "{j:?}, vertical p99 {v} mm"
        );
        // The plane's distance from (x, y, 0): 3 − y/2 mm; the lowest judged cell centre
        // is at y = −0.875 (0.25 mm cells, the region from y = −1).
        assert!((j.surface_error_p99_mm - 3.4375).abs() < 0.01, "{j:?}");
        // Control: the vertical difference is larger by 1/cos 30°.
        assert!(v > j.surface_error_p99_mm + 0.4, "{v} mm");
        // Beyond the grid's band (4 mm), the exact distance: 3 − 1/2 + 4 cos 30° mm.
        let far = [0.0, 1.0, 4.0];
        assert_eq!(p.part.signed_distance_mm(far), 4.0);
        let d = p.part.signed_distance_exact_mm(far);
        assert!((d - (2.5 + 4.0 * cos)).abs() < 1e-6, "{d}");
    }
}
