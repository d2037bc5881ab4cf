//! A cutting session's part and its judgement: the target shape (`cut_target`), the
//! per-cycle evidence of the cutting force at steady feed, the summary's cutting fields and
//! the files `--out DIR` writes (height map, STL, deviation map).

use std::path::Path;

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
}

/// The shape a session should cut (`cut_target`), in the workpiece frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CutTarget {
    /// The kind of shape.
    pub kind: TargetKind,
    /// Centre of the region the tool's tip covers, x and y, mm.
    pub centre_mm: [f64; 2],
    /// Size of that region along x and y, mm (a ring: `[band width, unused]`, default 0).
    #[serde(default)]
    pub size_mm: [f64; 2],
    /// A ring's radius (the tip's circle), mm (0 to 1e4; unused by a pocket).
    #[serde(default)]
    pub radius_mm: f64,
    /// Depth below the block's top, mm.
    pub depth_mm: f64,
    /// The part is judged over the pocket and this margin of the top around it, mm.
    #[serde(default = "default_margin_mm")]
    pub margin_mm: f64,
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
        check_range(&f("margin_mm"), self.margin_mm, 0.0, 100.0, "mm")
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
        CutSummary {
            removed_volume_mm3: stock.removed_mm3(),
            surface_error_p99_mm: p99(&mut errors),
            gouge_max_mm: floor.map_or(0.0, |f| (f - lowest).max(0.0)),
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
        write_deviation_png(&dir.join("deviation.png"), stock, 0.5, |x, y| {
            t.height_mm(x, y, top, tool)
        })?;
    }
    Ok(())
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
        };
        let ring = CutTarget {
            kind: TargetKind::Ring,
            centre_mm: [-1.0, 4.0],
            size_mm: [2.0, 0.0],
            radius_mm: 25.0,
            ..pocket
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
            ..t
        };
        assert_eq!(ring.height_mm(5.0, 20.0, 0.0, &tool), -2.0);
        let h = ring.height_mm(26.0, 0.0, 0.0, &tool);
        assert!((h - (-2.0 + 3.0 - 8f64.sqrt())).abs() < 1e-12, "{h}");
        assert_eq!(ring.height_mm(5.0, 0.0, 0.0, &tool), 0.0);
    }
}
