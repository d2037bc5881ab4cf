//! The workpiece as a height field: one top height per square cell, lowered only where the
//! tool's swept volume goes below it.

use super::tool::{Tool, ToolKind};

/// Most samples along one update's swept segment (a longer move is sampled more coarsely).
const SWEEP_SAMPLES_MAX: usize = 64;

/// A block of stock on a regular grid of square cells: each cell holds the height of its top,
/// mm, in the workpiece frame (z up). Memory is allocated once, at construction.
#[derive(Clone, Debug)]
pub struct Stock {
    /// The workpiece-frame x, y of the corner of cell (0, 0), mm.
    corner_mm: [f64; 2],
    /// Cell edge, mm.
    cell_mm: f64,
    nx: usize,
    ny: usize,
    /// The uncut top, mm.
    top_mm: f64,
    /// The bottom of the block, mm (the tool cuts nothing below it: the fixture).
    bottom_mm: f64,
    /// Top height of each cell, row-major (`iy * nx + ix`), mm.
    height_mm: Vec<f32>,
    /// Total volume removed, mm³.
    removed_mm3: f64,
}

impl Stock {
    /// A block whose top face is centred at `centre_top_mm` (workpiece frame), `size_mm`
    /// along x and y, `thickness_mm` deep, in cells of `cell_mm`. `None` when a size is not
    /// positive and finite or the grid would exceed 16 M cells.
    pub fn new(
        centre_top_mm: [f64; 3],
        size_mm: [f64; 2],
        thickness_mm: f64,
        cell_mm: f64,
    ) -> Option<Self> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !(ok(size_mm[0]) && ok(size_mm[1]) && ok(thickness_mm) && ok(cell_mm)) {
            return None;
        }
        if !centre_top_mm.iter().all(|v| v.is_finite()) {
            return None;
        }
        let nx = (size_mm[0] / cell_mm).round().max(1.0) as usize;
        let ny = (size_mm[1] / cell_mm).round().max(1.0) as usize;
        if nx.checked_mul(ny)? > 16 << 20 {
            return None;
        }
        Some(Stock {
            corner_mm: [
                centre_top_mm[0] - 0.5 * nx as f64 * cell_mm,
                centre_top_mm[1] - 0.5 * ny as f64 * cell_mm,
            ],
            cell_mm,
            nx,
            ny,
            top_mm: centre_top_mm[2],
            bottom_mm: centre_top_mm[2] - thickness_mm,
            height_mm: vec![centre_top_mm[2] as f32; nx * ny],
            removed_mm3: 0.0,
        })
    }

    /// Cells along x and y.
    pub fn dims(&self) -> (usize, usize) {
        (self.nx, self.ny)
    }

    /// Cell edge, mm.
    pub fn cell_mm(&self) -> f64 {
        self.cell_mm
    }

    /// The uncut top, mm.
    pub fn top_mm(&self) -> f64 {
        self.top_mm
    }

    /// The bottom of the block, mm.
    pub fn bottom_mm(&self) -> f64 {
        self.bottom_mm
    }

    /// The workpiece-frame x, y of the centre of cell (`ix`, `iy`), mm.
    pub fn cell_centre_mm(&self, ix: usize, iy: usize) -> [f64; 2] {
        [
            self.corner_mm[0] + (ix as f64 + 0.5) * self.cell_mm,
            self.corner_mm[1] + (iy as f64 + 0.5) * self.cell_mm,
        ]
    }

    /// The top height of cell (`ix`, `iy`), mm.
    pub fn height_at(&self, ix: usize, iy: usize) -> f64 {
        f64::from(self.height_mm[iy * self.nx + ix])
    }

    /// The top height under the workpiece-frame point (`x_mm`, `y_mm`); `None` off the block.
    pub fn height_under(&self, x_mm: f64, y_mm: f64) -> Option<f64> {
        let ix = ((x_mm - self.corner_mm[0]) / self.cell_mm).floor();
        let iy = ((y_mm - self.corner_mm[1]) / self.cell_mm).floor();
        if ix < 0.0 || iy < 0.0 || ix >= self.nx as f64 || iy >= self.ny as f64 {
            return None;
        }
        Some(self.height_at(ix as usize, iy as usize))
    }

    /// Every cell's top height, row-major (`iy * nx + ix`), mm.
    pub fn heights_mm(&self) -> &[f32] {
        &self.height_mm
    }

    /// Total volume removed so far, mm³.
    pub fn removed_mm3(&self) -> f64 {
        self.removed_mm3
    }

    /// The cells whose centres lie within `reach_mm` of the workpiece-frame point (`x`, `y`),
    /// row by row: `(iy, dy, x0, x1)`, the row, its centre's offset from the point (mm) and
    /// the inclusive range of `ix` on it (the disc's chord). Allocates nothing.
    pub fn chords(
        &self,
        x: f64,
        y: f64,
        reach_mm: f64,
    ) -> impl Iterator<Item = (usize, f64, usize, usize)> + use<> {
        self.grid().chords(x, y, reach_mm)
    }

    fn grid(&self) -> Grid {
        Grid {
            corner_mm: self.corner_mm,
            cell_mm: self.cell_mm,
            nx: self.nx,
            ny: self.ny,
        }
    }

    /// The x offset of the centre of column `ix` from `x`, mm.
    #[inline]
    pub fn dx_mm(&self, ix: usize, x: f64) -> f64 {
        self.corner_mm[0] + (ix as f64 + 0.5) * self.cell_mm - x
    }

    /// The top heights of row `iy`, columns `x0..=x1`, mm.
    #[inline]
    pub fn row_mm(&self, iy: usize, x0: usize, x1: usize) -> &[f32] {
        &self.height_mm[iy * self.nx + x0..=iy * self.nx + x1]
    }

    /// Lowers every cell the tool's swept volume goes below, for the tool's tip moving in a
    /// straight line from `from_tip_mm` (swept by the previous call) to `to_tip_mm`
    /// (workpiece frame), never below the block's bottom; returns the volume removed, mm³.
    /// Samples the segment at most half a cell apart after its start (at most
    /// `SWEEP_SAMPLES_MAX` samples). Allocates nothing.
    pub fn sweep(&mut self, tool: &Tool, from_tip_mm: [f64; 3], to_tip_mm: [f64; 3]) -> f64 {
        let d = [
            to_tip_mm[0] - from_tip_mm[0],
            to_tip_mm[1] - from_tip_mm[1],
            to_tip_mm[2] - from_tip_mm[2],
        ];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if !len.is_finite() {
            return 0.0;
        }
        let steps = ((len / (0.5 * self.cell_mm)).ceil() as usize).clamp(1, SWEEP_SAMPLES_MAX);
        let mut removed_cells_mm = 0.0;
        let r = tool.radius_mm;
        let r2 = r * r;
        let ball = tool.kind == ToolKind::Ball;
        let floor = self.bottom_mm as f32;
        let grid = self.grid();
        // The segment's start is the last update's end, swept then.
        for s in 1..=steps {
            let t = s as f64 / steps as f64;
            let p = [
                from_tip_mm[0] + t * d[0],
                from_tip_mm[1] + t * d[1],
                from_tip_mm[2] + t * d[2],
            ];
            // Nothing to cut when the tool is wholly above the block's top here.
            if p[2] >= self.top_mm {
                continue;
            }
            let pz = p[2] as f32;
            for (iy, dy, x0, x1) in grid.chords(p[0], p[1], r) {
                let row = &mut self.height_mm[iy * grid.nx + x0..=iy * grid.nx + x1];
                for (j, h) in row.iter_mut().enumerate() {
                    // The tool's lower surface is nowhere below its tip.
                    if *h <= pz {
                        continue;
                    }
                    let dx = grid.dx_mm(x0 + j, p[0]);
                    let rho2 = dx * dx + dy * dy;
                    let env = if ball {
                        // Lower only where the ball's surface is below the top:
                        // √(r² − ρ²) > tip + r − h, tested without the root.
                        let q = p[2] + r - f64::from(*h);
                        let w2 = (r2 - rho2).max(0.0);
                        if q >= 0.0 && w2 <= q * q {
                            continue;
                        }
                        p[2] + (r - w2.sqrt())
                    } else {
                        p[2]
                    };
                    let env = (env as f32).max(floor);
                    if env < *h {
                        removed_cells_mm += f64::from(*h - env);
                        *h = env;
                    }
                }
            }
        }
        let v = removed_cells_mm * self.cell_mm * self.cell_mm;
        self.removed_mm3 += v;
        v
    }
}

/// The grid's geometry (a copy, so a sweep can walk it while it lowers the heights).
#[derive(Clone, Copy, Debug)]
struct Grid {
    corner_mm: [f64; 2],
    cell_mm: f64,
    nx: usize,
    ny: usize,
}

impl Grid {
    /// The range of cell indices (inclusive) whose centres lie within `reach_mm` of `c` on
    /// one axis; `None` when it misses the block.
    fn span(&self, c: f64, corner: f64, n: usize, reach_mm: f64) -> Option<(usize, usize)> {
        let lo = ((c - reach_mm - corner) / self.cell_mm - 0.5)
            .ceil()
            .max(0.0);
        let hi = ((c + reach_mm - corner) / self.cell_mm - 0.5)
            .floor()
            .min(n as f64 - 1.0);
        (lo <= hi && hi >= 0.0).then_some((lo as usize, hi as usize))
    }

    #[inline]
    fn dx_mm(&self, ix: usize, x: f64) -> f64 {
        self.corner_mm[0] + (ix as f64 + 0.5) * self.cell_mm - x
    }

    fn chords(
        self,
        x: f64,
        y: f64,
        reach_mm: f64,
    ) -> impl Iterator<Item = (usize, f64, usize, usize)> {
        let rows = if reach_mm.is_finite() && x.is_finite() && y.is_finite() {
            self.span(y, self.corner_mm[1], self.ny, reach_mm)
        } else {
            None
        };
        let (y0, y1) = rows.map_or((1, 0), |r| r);
        let r2 = reach_mm * reach_mm;
        (y0..=y1).filter_map(move |iy| {
            let dy = self.corner_mm[1] + (iy as f64 + 0.5) * self.cell_mm - y;
            let half = r2 - dy * dy;
            if half < 0.0 {
                return None;
            }
            let (x0, x1) = self.span(x, self.corner_mm[0], self.nx, half.sqrt())?;
            Some((iy, dy, x0, x1))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::tool::{Tool, ToolKind};
    use super::*;

    fn tool(kind: ToolKind, r: f64) -> Tool {
        Tool {
            kind,
            radius_mm: r,
            flutes: 2,
            spindle_rpm: 10_000.0,
            flute_length_mm: 15.0,
            max_torque_n_mm: 500.0,
        }
    }

    /// A straight pass of a flat end mill removes width × depth × length (plus the two
    /// half-discs at its ends) to within the grid's resolution, and leaves the floor flat at
    /// the pass's depth across its width.
    #[test]
    fn flat_pass_removes_width_times_depth_times_length() {
        let mut s = Stock::new([0.0, 0.0, 0.0], [60.0, 40.0], 20.0, 0.25).unwrap();
        let t = tool(ToolKind::Flat, 3.0);
        let (depth, len) = (1.5, 30.0);
        let mut v = 0.0;
        // In 1 ms steps at 20 mm/s: 0.02 mm per step.
        let n = (len / 0.02) as usize;
        for k in 0..n {
            let a = -15.0 + len * k as f64 / n as f64;
            let b = -15.0 + len * (k + 1) as f64 / n as f64;
            v += s.sweep(&t, [a, 0.0, -depth], [b, 0.0, -depth]);
        }
        let exact = (2.0 * 3.0 * len + std::f64::consts::PI * 9.0) * depth;
        // One cell's worth of width along both long edges and around the ends.
        let tol = (2.0 * len + 2.0 * std::f64::consts::PI * 3.0) * 0.25 * depth;
        assert!((v - exact).abs() < tol, "removed {v} mm³, exact {exact}");
        assert!((s.removed_mm3() - v).abs() < 1e-9);
        for y in [-2.8, -1.0, 0.0, 2.0, 2.8] {
            let h = s.height_under(0.0, y).unwrap();
            assert!((h + depth).abs() < 1e-5, "floor at y={y}: {h}");
        }
        assert!(
            (s.height_under(0.0, 3.4).unwrap()).abs() < 1e-9,
            "cut outside the tool"
        );
        assert!((s.height_under(-15.0 - 3.4, 0.0).unwrap()).abs() < 1e-9);
    }

    /// A ball end leaves its circular profile across the pass: the height at lateral
    /// offset y is the tip depth plus R − √(R² − y²); two passes `step` apart leave a
    /// scallop of height R − √(R² − (step/2)²) between them.
    #[test]
    fn ball_end_leaves_the_scallop_profile() {
        let r = 4.0;
        let mut s = Stock::new([0.0, 0.0, 0.0], [40.0, 40.0], 20.0, 0.1).unwrap();
        let t = tool(ToolKind::Ball, r);
        let depth = 2.0;
        let step = 3.0;
        for y in [0.0, step] {
            for k in 0..200 {
                let a = -10.0 + 0.1 * k as f64;
                s.sweep(&t, [a, y, -depth], [a + 0.1, y, -depth]);
            }
        }
        // Across the first pass, away from the second.
        for y in [-2.5_f64, -1.5, -0.5, 0.0] {
            let yc = (y / 0.1).floor() * 0.1 + 0.05; // the sampled cell's centre
            let expected = -depth + r - (r * r - yc * yc).sqrt();
            let h = s.height_under(0.0, y).unwrap();
            assert!((h - expected).abs() < 1e-4, "y={y}: {h} vs {expected}");
        }
        let cusp = s.height_under(0.0, step / 2.0 - 1e-6).unwrap();
        // The cell's centre, 1.45 mm from the first pass and 1.55 mm from the second: the
        // nearer pass cut it.
        let yc = ((step / 2.0 - 1e-6) / 0.1).floor() * 0.1 + 0.05;
        let from_pass = |d: f64| -depth + r - (r * r - d * d).sqrt();
        let expected = from_pass(yc).min(from_pass(step - yc));
        assert!((cusp - expected).abs() < 1e-4, "{cusp} vs {expected}");
        let scallop = r - (r * r - (step / 2.0_f64).powi(2)).sqrt();
        assert!(
            (cusp + depth - scallop).abs() < 0.02,
            "scallop {}",
            cusp + depth
        );
    }

    /// Above the block, the tool cuts nothing; below its bottom, the cut stops at the bottom.
    #[test]
    fn cuts_nothing_above_and_nothing_below_the_block() {
        let mut s = Stock::new([0.0, 0.0, 0.0], [20.0, 20.0], 5.0, 0.25).unwrap();
        let t = tool(ToolKind::Flat, 2.0);
        assert_eq!(s.sweep(&t, [0.0, 0.0, 0.1], [3.0, 0.0, 0.1]), 0.0);
        s.sweep(&t, [0.0, 0.0, -9.0], [0.0, 0.0, -9.0]);
        assert!((s.height_under(0.0, 0.0).unwrap() + 5.0).abs() < 1e-6);
        assert_eq!(s.sweep(&t, [f64::NAN, 0.0, -1.0], [0.0, 0.0, -1.0]), 0.0);
        assert!(Stock::new([0.0; 3], [0.0, 1.0], 1.0, 0.25).is_none());
        assert!(Stock::new([0.0; 3], [1e6, 1e6], 1.0, 0.01).is_none());
    }

    /// The cell range of the first sweep.
    fn span(s: &Stock, c: f64, corner: f64, n: usize, reach_mm: f64) -> Option<(usize, usize)> {
        s.grid().span(c, corner, n, reach_mm)
    }

    /// The first sweep, kept as the reference the chord-wise one is checked against.
    impl Stock {
        fn sweep_reference(
            &mut self,
            tool: &Tool,
            from_tip_mm: [f64; 3],
            to_tip_mm: [f64; 3],
        ) -> f64 {
            let d = [
                to_tip_mm[0] - from_tip_mm[0],
                to_tip_mm[1] - from_tip_mm[1],
                to_tip_mm[2] - from_tip_mm[2],
            ];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if !len.is_finite() {
                return 0.0;
            }
            let steps = ((len / (0.5 * self.cell_mm)).ceil() as usize).clamp(1, SWEEP_SAMPLES_MAX);
            let mut removed_cells_mm = 0.0;
            let r = tool.radius_mm;
            let floor = self.bottom_mm as f32;
            // The segment's start is the last update's end, swept then.
            for s in 1..=steps {
                let t = s as f64 / steps as f64;
                let p = [
                    from_tip_mm[0] + t * d[0],
                    from_tip_mm[1] + t * d[1],
                    from_tip_mm[2] + t * d[2],
                ];
                // Nothing to cut when the tool is wholly above the block's top here.
                if p[2] >= self.top_mm {
                    continue;
                }
                let nx = self.nx;
                let (x0, x1, y0, y1) = match (
                    span(self, p[0], self.corner_mm[0], self.nx, r),
                    span(self, p[1], self.corner_mm[1], self.ny, r),
                ) {
                    (Some((x0, x1)), Some((y0, y1))) => (x0, x1, y0, y1),
                    _ => continue,
                };
                for iy in y0..=y1 {
                    let dy = self.corner_mm[1] + (iy as f64 + 0.5) * self.cell_mm - p[1];
                    let row = &mut self.height_mm[iy * nx..(iy + 1) * nx];
                    for (ix, h) in row.iter_mut().enumerate().take(x1 + 1).skip(x0) {
                        let dx = self.corner_mm[0] + (ix as f64 + 0.5) * self.cell_mm - p[0];
                        let rho2 = dx * dx + dy * dy;
                        // The tool's lower surface is nowhere below its tip.
                        if rho2 > r * r || f64::from(*h) <= p[2] {
                            continue;
                        }
                        let env = ((p[2] + tool.lift_mm(rho2)) as f32).max(floor);
                        if env < *h {
                            removed_cells_mm += f64::from(*h - env);
                            *h = env;
                        }
                    }
                }
            }
            let v = removed_cells_mm * self.cell_mm * self.cell_mm;
            self.removed_mm3 += v;
            v
        }
    }

    /// The chord-wise sweep without square roots for the cells it leaves leaves the same
    /// heights and removes the same volume as the reference, for both tools along random
    /// segments (plunges, ramps, long moves, moves above the block).
    #[test]
    fn the_chordwise_sweep_matches_the_reference() {
        let mut rng = h4_shared::rng::Rng::new(11);
        for kind in [ToolKind::Ball, ToolKind::Flat] {
            let t = tool(kind, 2.5);
            let mut a = Stock::new([0.0, 0.0, 0.0], [40.0, 30.0], 10.0, 0.25).unwrap();
            let mut b = a.clone();
            let mut from = [0.0, 0.0, 1.0];
            let mut removed = 0.0;
            for i in 0..600 {
                let to = if i % 7 == 0 {
                    [
                        rng.uniform_in(-22.0, 22.0),
                        rng.uniform_in(-17.0, 17.0),
                        0.5,
                    ]
                } else {
                    [
                        from[0] + rng.uniform_in(-1.5, 1.5),
                        from[1] + rng.uniform_in(-1.5, 1.5),
                        rng.uniform_in(-4.0, 0.2),
                    ]
                };
                let va = a.sweep(&t, from, to);
                let vb = b.sweep_reference(&t, from, to);
                assert!(
                    (va - vb).abs() <= 1e-6 * (1.0 + vb.abs()),
                    "{kind:?} {i}: {va} vs {vb}"
                );
                removed += vb;
                from = to;
            }
            assert!(removed > 100.0, "{kind:?}: only {removed} mm³ cut");
            for (ha, hb) in a.heights_mm().iter().zip(b.heights_mm()) {
                assert!((ha - hb).abs() <= 1e-5, "{kind:?}: {ha} vs {hb}");
            }
        }
    }
}
