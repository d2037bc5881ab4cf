//! The cutting force: Altintas's mechanistic model (specific cutting coefficients × chip
//! area, tangential / radial / axial) applied to each element of the tool's envelope that
//! touches the stock, with the teeth passing over the engaged arc (the ripple).
//!
//! An envelope element of area `dA` with outward normal `n̂` (from the tool into the stock)
//! at distance `r` from the axis, moving into the stock at the normal speed `u = v·n̂`,
//! removes `u dA` of material per second. Each of the `N` teeth passing it cuts a chip of
//! thickness `h = u / (N n)` (`n` rev/s) over the width it sweeps; summed, the chip area in
//! cut at any instant is `u dA / (2π r n)`, so the element's forces on the tool are
//! (Altintas, *Manufacturing Automation*, 2nd ed., 2012, eq. 2.47 with the edge terms left
//! out):
//!
//! * radial, pushing the tool out of the stock: `−K_rc u dA / (2π r n) n̂`;
//! * tangential, against the edge's motion `t̂` (clockwise spindle): `−K_tc u dA/(2π r n) t̂`
//!   (its moment is the spindle's torque `K_tc Q / (2π n)` for a removal rate `Q`);
//! * axial (side elements, the helix lifting the tool): `+K_ac u dA / (2π r n) ẑ`.
//!
//! All three are linear in the tool's velocity: per element `F = −B v` with
//! `B = κ (K_rc n̂ + K_tc t̂ − K_ac ẑ) n̂ᵀ`, `κ = dA / (2π r n)`. The elements are gathered in
//! [`BINS`] azimuthal bins (and two layers: walls and floor); at any instant a tooth at
//! azimuth ψ carries its bin's share, so the force ripples at the tooth-passing frequency
//! with the engagement's shape, and its mean over a revolution is the sum over all
//! elements. A bin acts only while the tool moves into its stock (`v·n̄ > 0`).

use serde::{Deserialize, Serialize};

use super::stock::Stock;
use super::tool::Tool;
use crate::plant::MaterialPreset;

/// Azimuthal bins of the engaged envelope.
pub const BINS: usize = 32;
/// Layers of bins: walls (`|n_z| < 0.5`) and floor.
const LAYERS: usize = 2;
/// A cell whose top is within this of the tool's lower surface touches it, mm.
const TOUCH_MM: f64 = 2e-3;
/// Smallest cutting radius an element is given (the edge's speed vanishes on the axis: the
/// tip ploughs rather than cuts), as a fraction of the tool's radius.
const R_MIN_FRACTION: f64 = 0.2;

/// Specific cutting coefficients of a work material, N/mm² (sources in `docs/cutting.md`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CuttingCoefficients {
    /// Tangential, N/mm².
    pub k_tc_n_per_mm2: f64,
    /// Radial, N/mm².
    pub k_rc_n_per_mm2: f64,
    /// Axial, N/mm².
    pub k_ac_n_per_mm2: f64,
}

impl CuttingCoefficients {
    /// The material's coefficients (values and sources in `docs/cutting.md`).
    pub fn of(material: MaterialPreset) -> Self {
        let (t, r, a) = match material {
            MaterialPreset::Resin => (120.0, 50.0, 25.0),
            MaterialPreset::Aluminium => (767.0, 169.0, 222.0),
            MaterialPreset::Steel => (2000.0, 800.0, 400.0),
        };
        CuttingCoefficients {
            k_tc_n_per_mm2: t,
            k_rc_n_per_mm2: r,
            k_ac_n_per_mm2: a,
        }
    }
}

/// One bin: the velocity-to-force matrix of its elements and their summed normal.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bin {
    /// `Σ B` (N·s/mm): the elements' force is `−b v`.
    pub b: [[f64; 3]; 3],
    /// `Σ n̂ dA`, mm².
    pub n: [f64; 3],
}

/// The engaged envelope of the tool at one position, binned.
#[derive(Clone, Debug)]
pub struct Engagement {
    /// `[layer][bin]`.
    pub bins: [[Bin; BINS]; LAYERS],
    /// Elements touching the stock.
    pub elements: u32,
    /// Deepest penetration of the tool's lower surface into the stock under it where that
    /// is the stock's shallower way out, mm; negative: its clearance (a stalled spindle
    /// restarts once it is clear); −∞ with no stock under the tool. The rubbing force uses
    /// `rub_mm` and `rub_dir`.
    pub penetration_mm: f64,
    /// Rubbing (a tool that does not cut): the deepest penetration of the stock into the
    /// tool's solid, each cell's stock column measured along its shortest way out of the
    /// tool ([`rub_cell`]), mm; 0: none.
    pub rub_mm: f64,
    /// The direction the rubbing stock pushes the tool, unit: the penetration-weighted sum
    /// of the cells' ways out (opposite walls cancel, so the push changes smoothly as the
    /// tool moves in its groove).
    pub rub_dir: [f64; 3],
    /// `Σ p n` over the penetrating cells, before it is normalised into `rub_dir`.
    rub_sum: [f64; 3],
    /// The last servo period's solve, reused while the same bins act.
    solved: Solved,
}

/// One solve of [`Engagement::solve`]: which bins acted, the matrix they make, and the
/// adjugate and determinant of `I + c M`.
#[derive(Clone, Copy, Debug, Default)]
struct Solved {
    /// The teeth's bins and which of their layers acted (0: none cached).
    key: u64,
    c: f64,
    m: [[f64; 3]; 3],
    adj: [[f64; 3]; 3],
    det: f64,
}

impl Default for Engagement {
    fn default() -> Self {
        Engagement {
            bins: [[Bin::default(); BINS]; LAYERS],
            elements: 0,
            penetration_mm: f64::NEG_INFINITY,
            rub_mm: 0.0,
            rub_dir: [0.0, 0.0, 1.0],
            rub_sum: [0.0; 3],
            solved: Solved::default(),
        }
    }
}

/// What one gather needs of the tool and the cut, computed once.
struct Geometry {
    r: f64,
    r2: f64,
    inv_r: f64,
    cell: f64,
    cell2: f64,
    ball: bool,
    /// The rim's height above the tip, mm.
    rim_lift: f64,
    /// The flutes' length above the tip, mm.
    flute_mm: f64,
    /// Stock below this touches nothing, mm.
    below_tip: f64,
    /// `1 / 2πn`, s (0 with the spindle stopped).
    per_rev: f64,
    k: CuttingCoefficients,
}

impl Geometry {
    fn new(
        stock: &Stock,
        tool: &Tool,
        k: &CuttingCoefficients,
        tip_mm: [f64; 3],
        rev_per_s: f64,
    ) -> Self {
        let r = tool.radius_mm;
        let cell = stock.cell_mm();
        Geometry {
            r,
            r2: r * r,
            inv_r: 1.0 / r,
            cell,
            cell2: cell * cell,
            ball: tool.kind == super::ToolKind::Ball,
            rim_lift: tool.lift_mm(r * r),
            flute_mm: tool.flute_length_mm,
            below_tip: tip_mm[2] - TOUCH_MM,
            per_rev: if rev_per_s > 0.0 {
                1.0 / (2.0 * std::f64::consts::PI * rev_per_s)
            } else {
                0.0
            },
            k: *k,
        }
    }
}

impl Engagement {
    /// Gathers the envelope elements of `tool`, tip at `tip_mm` (workpiece frame), that
    /// touch `stock`, for cutting coefficients `k` at spindle speed `rev_per_s` (> 0 for any
    /// force; 0 still measures the penetration). Allocates nothing.
    ///
    /// One pass over the cells within the tool's radius and one cell: a cell below the
    /// tool's lower surface (cut deeper by an earlier position) is told apart without a
    /// square root (`√(r² − ρ²) < tip + r − h − touch` squared); only touching elements
    /// pay for their geometry. The clearance of those cells is measured in a second pass
    /// only when nothing touches (it cannot raise the penetration otherwise).
    pub fn gather(
        &mut self,
        stock: &Stock,
        tool: &Tool,
        k: &CuttingCoefficients,
        tip_mm: [f64; 3],
        rev_per_s: f64,
    ) {
        self.bins = [[Bin::default(); BINS]; LAYERS];
        self.elements = 0;
        self.penetration_mm = f64::NEG_INFINITY;
        self.rub_mm = 0.0;
        self.rub_sum = [0.0; 3];
        self.solved.key = 0;
        let g = Geometry::new(stock, tool, k, tip_mm, rev_per_s);
        let mut below_surface = false;
        for (iy, dy, x0, x1) in stock.chords(tip_mm[0], tip_mm[1], g.r + g.cell) {
            for (j, &h32) in stock.row_mm(iy, x0, x1).iter().enumerate() {
                let h = f64::from(h32);
                let dx = stock.dx_mm(x0 + j, tip_mm[0]);
                let rho2 = dx * dx + dy * dy;
                let inside = rho2 <= g.r2;
                // Stock below the tip touches nothing (the lower surface is nowhere lower).
                if h < g.below_tip {
                    if inside {
                        self.penetration_mm = self.penetration_mm.max(h - tip_mm[2]);
                    }
                    continue;
                }
                if inside {
                    let w2 = (g.r2 - rho2).max(0.0);
                    if g.ball {
                        // Below the lower surface by more than the touch: h − env < −touch,
                        // env = tip + r − √(r² − ρ²).
                        let q = tip_mm[2] + g.r - TOUCH_MM - h;
                        if q > 0.0 && w2 < q * q {
                            below_surface = true;
                            continue;
                        }
                    }
                    self.inside_cell(&g, tip_mm[2], h, dx, dy, rho2, w2);
                } else {
                    self.wall_cell(&g, tip_mm[2], h, dx, dy, rho2);
                }
            }
        }
        if below_surface && self.penetration_mm < -TOUCH_MM {
            self.clearance_below_surface(stock, &g, tip_mm);
        }
        self.finish_rub();
    }

    /// Books one cell's rubbing penetration ([`rub_cell`]).
    #[inline]
    fn book_rub(&mut self, p_n: Option<(f64, [f64; 3])>) {
        if let Some((p, n)) = p_n {
            self.rub_mm = self.rub_mm.max(p);
            for (s, nc) in self.rub_sum.iter_mut().zip(n) {
                *s += p * nc;
            }
        }
    }

    /// The rubbing push's direction from the cells' sum; none when they cancel.
    fn finish_rub(&mut self) {
        let [x, y, z] = self.rub_sum;
        let norm = (x * x + y * y + z * z).sqrt();
        if self.rub_mm > 0.0 && norm > 1e-12 * self.rub_mm {
            self.rub_dir = [x / norm, y / norm, z / norm];
        } else {
            self.rub_mm = 0.0;
            self.rub_dir = [0.0, 0.0, 1.0];
        }
    }

    /// Whether the tool with its tip at `tip_mm` is clear of the whole block: its lower
    /// surface more than the touch above the block's top, which no cell rises above (the
    /// stock is only ever lowered), so a [`Engagement::gather`] there would engage nothing.
    #[inline]
    pub fn clear_of_block(stock: &Stock, tip_mm: [f64; 3]) -> bool {
        tip_mm[2] - TOUCH_MM > stock.top_mm()
    }

    /// A cell inside the tool's radius at or above its lower surface (less the touch):
    /// rubbing (stock inside a tool that does not cut), or an element of the envelope.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn inside_cell(
        &mut self,
        g: &Geometry,
        tip_z: f64,
        h: f64,
        dx: f64,
        dy: f64,
        rho2: f64,
        w2: f64,
    ) {
        let s = w2.sqrt();
        let env = if g.ball { tip_z + (g.r - s) } else { tip_z };
        let rho = rho2.sqrt();
        // Stock inside the tool leaves it the shallower way: up, or sideways out of the
        // radius.
        let sideways = g.r - rho;
        if h - env <= sideways || rho <= 0.0 {
            self.penetration_mm = self.penetration_mm.max(h - env);
        }
        self.book_rub(rub_cell(g.ball, g.r, tip_z, h, dx, dy, rho2));
        if (h - env).abs() > TOUCH_MM {
            // Below the surface, or stock inside the tool (a stalled spindle): rubbing, not
            // cutting.
            return;
        }
        let (n, area) = if g.ball {
            let w = s.max(R_MIN_FRACTION * g.r);
            let inv_w = 1.0 / w;
            (
                [dx * g.inv_r, dy * g.inv_r, -w * g.inv_r],
                g.cell2 * g.r * inv_w,
            )
        } else {
            ([0.0, 0.0, -1.0], g.cell2)
        };
        self.element(g, dx, dy, rho, n, area, rho);
    }

    /// A cell outside the tool's radius: the wall beside the tool, stock above the rim's
    /// lower edge.
    #[inline]
    fn wall_cell(&mut self, g: &Geometry, tip_z: f64, h: f64, dx: f64, dy: f64, rho2: f64) {
        let e = h.min(tip_z + g.flute_mm) - (tip_z + g.rim_lift);
        if e <= 0.0 || rho2 <= 0.0 {
            return;
        }
        let rho = rho2.sqrt();
        let inv_rho = 1.0 / rho;
        self.element(
            g,
            dx,
            dy,
            rho,
            [dx * inv_rho, dy * inv_rho, 0.0],
            e * g.cell,
            g.r,
        );
    }

    /// Books one envelope element: normal `n` (into the stock), area `area` (mm²), at
    /// cutting radius `r_cut`, azimuth of (`dx`, `dy`); a steep one (`|n_z| < 0.5`) in the
    /// walls' layer, with the axial force.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn element(
        &mut self,
        g: &Geometry,
        dx: f64,
        dy: f64,
        rho: f64,
        n: [f64; 3],
        area: f64,
        r_cut: f64,
    ) {
        self.elements += 1;
        let wall = n[2].abs() < 0.5;
        let kappa = area * g.per_rev / r_cut.max(R_MIN_FRACTION * g.r);
        // The edge moves clockwise seen from above: t̂ = (dy, −dx, 0)/ρ.
        let t = if rho > 0.0 {
            let inv_rho = 1.0 / rho;
            [dy * inv_rho, -dx * inv_rho]
        } else {
            [0.0; 2]
        };
        let ka = if wall { g.k.k_ac_n_per_mm2 } else { 0.0 };
        let (krc, ktc) = (g.k.k_rc_n_per_mm2, g.k.k_tc_n_per_mm2);
        let dir = [
            kappa * (krc * n[0] + ktc * t[0]),
            kappa * (krc * n[1] + ktc * t[1]),
            kappa * (krc * n[2] - ka),
        ];
        let idx = ((azimuth_rev(dx, dy) * BINS as f64) as usize).min(BINS - 1);
        let bin = &mut self.bins[usize::from(!wall)][idx];
        for (row, d) in bin.b.iter_mut().zip(dir) {
            for (c, nc) in row.iter_mut().zip(n) {
                *c += d * nc;
            }
        }
        for (s, nc) in bin.n.iter_mut().zip(n) {
            *s += area * nc;
        }
    }

    /// The clearance of the cells below the ball's lower surface, which the pass skipped
    /// (the same test): the penetration when nothing touched.
    fn clearance_below_surface(&mut self, stock: &Stock, g: &Geometry, tip_mm: [f64; 3]) {
        for (iy, dy, x0, x1) in stock.chords(tip_mm[0], tip_mm[1], g.r) {
            for (j, &h32) in stock.row_mm(iy, x0, x1).iter().enumerate() {
                let h = f64::from(h32);
                if h < g.below_tip {
                    continue;
                }
                let dx = stock.dx_mm(x0 + j, tip_mm[0]);
                let rho2 = dx * dx + dy * dy;
                let w2 = (g.r2 - rho2).max(0.0);
                let q = tip_mm[2] + g.r - TOUCH_MM - h;
                if rho2 > g.r2 || q <= 0.0 || w2 >= q * q {
                    continue;
                }
                let env = tip_mm[2] + (g.r - w2.sqrt());
                self.penetration_mm = self.penetration_mm.max(h - env);
            }
        }
    }

    /// One servo period of the cut: the velocity-to-force matrix `M` in effect (as the test
    /// reference `Engagement::matrix`) and the velocity `x` that solves `(I + c M) x = v`
    /// (backward Euler of a tool of mass `1/c·dt` against the force `−M x`; `v` unchanged when the
    /// system is singular). The teeth stay in one bin for several servo periods: while the
    /// same bins act, the matrix and the system's adjugate are reused.
    #[inline]
    pub fn solve(
        &mut self,
        phase_rev: f64,
        flutes: u32,
        v_mm_per_s: &[f64; 3],
        c: f64,
    ) -> ([[f64; 3]; 3], [f64; 3]) {
        let flutes = flutes.clamp(1, 8);
        let mut key = 1u64;
        let mut idx = [0usize; 8];
        for (j, ix) in idx.iter_mut().enumerate().take(flutes as usize) {
            let a = wrap_rev(phase_rev + j as f64 / f64::from(flutes));
            *ix = ((a * BINS as f64) as usize).min(BINS - 1);
            key = (key << 7) | *ix as u64;
            for (l, layer) in self.bins.iter().enumerate() {
                let n = &layer[*ix].n;
                let into = n[0] * v_mm_per_s[0] + n[1] * v_mm_per_s[1] + n[2] * v_mm_per_s[2];
                if into > 0.0 {
                    key |= 1 << (5 + l);
                }
            }
        }
        if key != self.solved.key || c != self.solved.c {
            let scale = BINS as f64 / f64::from(flutes);
            let mut m = [[0.0f64; 3]; 3];
            for (j, ix) in idx.iter().enumerate().take(flutes as usize) {
                let bits = key >> (7 * (flutes as usize - 1 - j));
                for (l, layer) in self.bins.iter().enumerate() {
                    if bits & (1 << (5 + l)) == 0 {
                        continue;
                    }
                    for (mr, br) in m.iter_mut().zip(&layer[*ix].b) {
                        for (mc, bc) in mr.iter_mut().zip(br) {
                            *mc += scale * bc;
                        }
                    }
                }
            }
            let (adj, det) = adjugate_damped(&m, c);
            self.solved = Solved {
                key,
                c,
                m,
                adj,
                det,
            };
        }
        let sv = &self.solved;
        if sv.det.is_nan() || sv.det.abs() <= 1e-12 {
            return (sv.m, *v_mm_per_s);
        }
        let x = [0, 1, 2].map(|i| {
            (sv.adj[i][0] * v_mm_per_s[0]
                + sv.adj[i][1] * v_mm_per_s[1]
                + sv.adj[i][2] * v_mm_per_s[2])
                / sv.det
        });
        (sv.m, x)
    }

    /// The velocity-to-force matrix in effect with the teeth at `phase_rev` (the first
    /// tooth's azimuth, revolutions) for `flutes` teeth, each bin only while `v_mm_per_s`
    /// moves into it: the force on the tool is `−B v`. The reference of
    /// [`Engagement::solve`]'s matrix.
    #[cfg(test)]
    pub fn matrix(&self, phase_rev: f64, flutes: u32, v_mm_per_s: &[f64; 3]) -> [[f64; 3]; 3] {
        let mut m = [[0.0f64; 3]; 3];
        let scale = BINS as f64 / f64::from(flutes.max(1));
        for j in 0..flutes {
            let a = wrap_rev(phase_rev + f64::from(j) / f64::from(flutes));
            let idx = ((a * BINS as f64) as usize).min(BINS - 1);
            for layer in &self.bins {
                let bin = &layer[idx];
                let into =
                    bin.n[0] * v_mm_per_s[0] + bin.n[1] * v_mm_per_s[1] + bin.n[2] * v_mm_per_s[2];
                if into <= 0.0 {
                    continue;
                }
                for (mr, br) in m.iter_mut().zip(&bin.b) {
                    for (mc, bc) in mr.iter_mut().zip(br) {
                        *mc += scale * bc;
                    }
                }
            }
        }
        m
    }

    /// The rate at which the engaged envelope moving at `v_mm_per_s` (relative to the stock)
    /// removes material, mm³/s: `Σ u dA` over the bins it moves into (the chip area's
    /// source, so the spindle's torque is `K_tc` times it over `2πn`).
    pub fn removal_rate_mm3_per_s(&self, v_mm_per_s: &[f64; 3]) -> f64 {
        let mut q = 0.0;
        for layer in &self.bins {
            for bin in layer {
                let u =
                    bin.n[0] * v_mm_per_s[0] + bin.n[1] * v_mm_per_s[1] + bin.n[2] * v_mm_per_s[2];
                q += u.max(0.0);
            }
        }
        q
    }

    /// The mean (over a revolution) velocity-to-force matrix, every bin engaged.
    pub fn mean_matrix(&self) -> [[f64; 3]; 3] {
        let mut m = [[0.0f64; 3]; 3];
        for layer in &self.bins {
            for bin in layer {
                for (mr, br) in m.iter_mut().zip(&bin.b) {
                    for (mc, bc) in mr.iter_mut().zip(br) {
                        *mc += bc;
                    }
                }
            }
        }
        m
    }
}

/// `a` wrapped into [0, 1] revolutions (`a − ⌊a⌋`; 1 only by rounding, which the bins'
/// index clamps), for the phases of the teeth (|a| well below 2⁵³), without a libm call (the
/// baseline x86-64 has no rounding instruction).
#[inline]
fn wrap_rev(a: f64) -> f64 {
    let f = a - (a as i64) as f64;
    if f < 0.0 { f + 1.0 } else { f }
}

/// The azimuth of (`x`, `y`) in revolutions, 0 to 1 (a polynomial arctangent, within
/// 1e-5 rev: the bins' edges, not their sizes, move by that much).
#[inline]
fn azimuth_rev(x: f64, y: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ax < ay { (ax, ay) } else { (ay, ax) };
    if hi == 0.0 {
        return 0.0;
    }
    let t = lo / hi;
    let t2 = t * t;
    // atan(t) on [0, 1], |error| < 1e-5 rad (Abramowitz & Stegun 4.4.49).
    let a = t
        * (0.999_866_0
            + t2 * (-0.330_299_5 + t2 * (0.180_141_0 + t2 * (-0.085_133_0 + t2 * 0.020_835_1))));
    let mut ang = if ax < ay {
        std::f64::consts::FRAC_PI_2 - a
    } else {
        a
    };
    if x < 0.0 {
        ang = std::f64::consts::PI - ang;
    }
    if y < 0.0 {
        ang = 2.0 * std::f64::consts::PI - ang;
    }
    (ang / (2.0 * std::f64::consts::PI)).min(1.0 - 1e-12)
}

/// The adjugate and the determinant of `I + c M` (`x = adj v / det` solves it).
fn adjugate_damped(m: &[[f64; 3]; 3], c: f64) -> ([[f64; 3]; 3], f64) {
    let a = [
        [1.0 + c * m[0][0], c * m[0][1], c * m[0][2]],
        [c * m[1][0], 1.0 + c * m[1][1], c * m[1][2]],
        [c * m[2][0], c * m[2][1], 1.0 + c * m[2][2]],
    ];
    let adj = [
        [
            a[1][1] * a[2][2] - a[1][2] * a[2][1],
            a[0][2] * a[2][1] - a[0][1] * a[2][2],
            a[0][1] * a[1][2] - a[0][2] * a[1][1],
        ],
        [
            a[1][2] * a[2][0] - a[1][0] * a[2][2],
            a[0][0] * a[2][2] - a[0][2] * a[2][0],
            a[0][2] * a[1][0] - a[0][0] * a[1][2],
        ],
        [
            a[1][0] * a[2][1] - a[1][1] * a[2][0],
            a[0][1] * a[2][0] - a[0][0] * a[2][1],
            a[0][0] * a[1][1] - a[0][1] * a[1][0],
        ],
    ];
    let det = a[0][0] * adj[0][0] + a[0][1] * adj[1][0] + a[0][2] * adj[2][0];
    (adj, det)
}

/// How far the stock column of one cell (height `h`, at (`dx`, `dy`) from the tool's axis,
/// `rho2 = dx² + dy²`) reaches into the tool's solid (tip at `tip_z`, radius `r`; a ball
/// end, or a flat end mill's cylinder), along its shortest way out, and that way: the unit
/// direction the column pushes the tool. For a ball, the column's point nearest the ball's
/// centre (at `tip_z + r`, the column's top or the centre's height, whichever is lower)
/// gives both, so a ball displaced in a groove of its own shape is pushed back along the
/// groove's normal, smoothly, and a column above the ball's equator pushes it sideways
/// (the shank above is the same cylinder). For a flat end, the shallower of up and
/// sideways. `None` where the column does not reach into the tool.
#[inline]
fn rub_cell(
    ball: bool,
    r: f64,
    tip_z: f64,
    h: f64,
    dx: f64,
    dy: f64,
    rho2: f64,
) -> Option<(f64, [f64; 3])> {
    if rho2 > r * r {
        return None;
    }
    if ball {
        let zc = tip_z + r;
        let dz = zc - h.min(zc);
        let d2 = rho2 + dz * dz;
        if d2 >= r * r {
            return None;
        }
        let d = d2.sqrt();
        if d <= 0.0 {
            return Some((r, [0.0, 0.0, 1.0]));
        }
        return Some((r - d, [-dx / d, -dy / d, dz / d]));
    }
    let up = h - tip_z;
    if up <= 0.0 {
        return None;
    }
    let rho = rho2.sqrt();
    let side = r - rho;
    if up <= side || rho <= 0.0 {
        Some((up, [0.0, 0.0, 1.0]))
    } else {
        Some((side, [-dx / rho, -dy / rho, 0.0]))
    }
}

/// Solves `(I + c M) x = v` for `x` (backward Euler of a tool of mass `1/c·dt` against the
/// force `−M x`); `v` unchanged when the system is singular. The reference of
/// [`Engagement::solve`].
#[cfg(test)]
fn solve_damped(m: &[[f64; 3]; 3], c: f64, v: &[f64; 3]) -> [f64; 3] {
    let a = [
        [1.0 + c * m[0][0], c * m[0][1], c * m[0][2]],
        [c * m[1][0], 1.0 + c * m[1][1], c * m[1][2]],
        [c * m[2][0], c * m[2][1], 1.0 + c * m[2][2]],
    ];
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if det.is_nan() || det.abs() <= 1e-12 {
        return *v;
    }
    let col = |k: usize| -> f64 {
        let mut b = a;
        for (row, vi) in b.iter_mut().zip(v) {
            row[k] = *vi;
        }
        b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1])
            - b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0])
            + b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0])
    };
    [col(0) / det, col(1) / det, col(2) / det]
}

#[cfg(test)]
mod tests {
    use super::super::ToolKind;
    use super::*;

    fn cut_slot(kind: ToolKind, depth: f64) -> (Stock, Tool, [f64; 3]) {
        let mut s = Stock::new([0.0, 0.0, 0.0], [60.0, 40.0], 20.0, 0.1).unwrap();
        let t = Tool {
            kind,
            radius_mm: 3.0,
            flutes: 2,
            spindle_rpm: 12_000.0,
            flute_length_mm: 12.0,
            max_torque_n_mm: 300.0,
        };
        let mut x = -10.0;
        while x < 0.0 {
            s.sweep(&t, [x, 0.0, -depth], [x + 0.05, 0.0, -depth]);
            x += 0.05;
        }
        (s, t, [x, 0.0, -depth])
    }

    /// A flat end mill feeding along x in a full slot: the mean forces are Altintas's
    /// closed-form slot averages (feed force N a c K_rc / 4, cross-feed N a c K_tc / 4,
    /// axial N a c K_ac / π; c the feed per tooth) to within the grid's resolution.
    #[test]
    fn slot_forces_match_the_closed_form_averages() {
        let depth = 2.0;
        let (s, t, tip) = cut_slot(ToolKind::Flat, depth);
        let k = CuttingCoefficients::of(MaterialPreset::Aluminium);
        let mut e = Engagement::default();
        let n = t.spindle_rev_per_s();
        e.gather(&s, &t, &k, tip, n);
        let v = [10.0, 0.0, 0.0];
        let m = e.mean_matrix();
        let f: Vec<f64> = (0..3)
            .map(|i| -(m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]))
            .collect();
        let c = v[0] / (2.0 * n); // feed per tooth, mm
        let nac = 2.0 * depth * c;
        let feed = -nac * k.k_rc_n_per_mm2 / 4.0;
        let cross = nac * k.k_tc_n_per_mm2 / 4.0;
        let axial = nac * k.k_ac_n_per_mm2 / std::f64::consts::PI;
        // Altintas's y (cross-feed) is −y here (his tool turns the other way round his
        // frame): compare magnitudes with signs stated: feed against motion, axial up.
        assert!(
            (f[0] - feed).abs() < 0.06 * feed.abs(),
            "feed {} vs {feed}",
            f[0]
        );
        assert!(
            (f[1].abs() - cross).abs() < 0.06 * cross,
            "cross {} vs {cross}",
            f[1]
        );
        assert!(
            (f[2] - axial).abs() < 0.06 * axial,
            "axial {} vs {axial}",
            f[2]
        );
        // Moving up, out of the slot's floor and away from nothing: no force.
        let up = e.matrix(0.3, 2, &[0.0, 0.0, 5.0]);
        assert!(up.iter().flatten().all(|x| x.abs() < 1e-12), "{up:?}");
    }

    /// The teeth make the force ripple at N × spindle speed, and its mean over a revolution
    /// is the mean matrix.
    #[test]
    fn the_force_ripples_at_tooth_passing_and_averages_to_the_mean() {
        let (s, t, tip) = cut_slot(ToolKind::Ball, 1.5);
        let k = CuttingCoefficients::of(MaterialPreset::Resin);
        let mut e = Engagement::default();
        e.gather(&s, &t, &k, tip, t.spindle_rev_per_s());
        let v = [10.0, 0.0, 0.0];
        let steps = 3200;
        let (mut sum, mut lo, mut hi) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
        let mut series = Vec::new();
        for i in 0..steps {
            let m = e.matrix(i as f64 / steps as f64, 2, &v);
            let fx = -(m[0][0] * v[0]);
            sum += fx;
            lo = lo.min(fx);
            hi = hi.max(fx);
            series.push(fx);
        }
        let mean = sum / steps as f64;
        // The mean matrix counts every bin; the instant one only the bins the motion
        // enters (the slot's side walls' edge cells face slightly backwards).
        let m = e.mean_matrix();
        assert!(
            (mean + m[0][0] * v[0]).abs() < 1e-3 * mean.abs(),
            "{mean} vs {}",
            -m[0][0] * v[0]
        );
        assert!(hi - lo > 0.5 * mean.abs(), "no ripple: {lo}..{hi}");
        // Two teeth: the pattern repeats every half revolution.
        for i in 0..steps / 2 {
            assert!((series[i] - series[i + steps / 2]).abs() < 1e-9);
        }
    }

    /// A stopped tool pushed 0.5 mm sideways into the slot's wall, 2 mm below the top: the
    /// stock leaves it sideways (0.5 mm, pushing back along −x), not up by the wall's 2 mm.
    #[test]
    fn a_stopped_tool_in_a_wall_is_pushed_back_sideways() {
        let (s, t, tip) = cut_slot(ToolKind::Flat, 2.0);
        let k = CuttingCoefficients::of(MaterialPreset::Steel);
        let mut e = Engagement::default();
        e.gather(&s, &t, &k, [tip[0] + 0.5, tip[1], tip[2]], 0.0);
        assert!((e.rub_mm - 0.5).abs() < 0.15, "{}", e.rub_mm);
        assert!(e.rub_dir[0] < -0.9, "{:?}", e.rub_dir);
        assert!(
            e.penetration_mm <= 1e-3,
            "pushed up by {}",
            e.penetration_mm
        );
    }

    /// A stopped ball end displaced sideways in the groove it cut, 2 mm deep: the groove's
    /// wall pushes it back and up along the wall's normal (not sideways from one cell, not
    /// flipping), the push grows smoothly with the displacement, and a mirrored displacement
    /// gives the mirrored push; centred in its groove it is not pushed at all.
    #[test]
    fn a_stopped_ball_in_its_groove_is_pushed_back_along_the_wall() {
        let (s, t, tip) = cut_slot(ToolKind::Ball, 2.0);
        let k = CuttingCoefficients::of(MaterialPreset::Aluminium);
        // Back along the slot, away from its end face.
        let at = |dy: f64| {
            let mut e = Engagement::default();
            e.gather(&s, &t, &k, [tip[0] - 3.0, tip[1] + dy, tip[2]], 0.0);
            (e.rub_mm, e.rub_dir)
        };
        let (p0, _) = at(0.0);
        assert!(p0 < 0.01, "centred, pushed by {p0} mm");
        let mut last = 0.0;
        for dy in [0.025, 0.05, 0.1, 0.2] {
            let (p, d) = at(dy);
            let (pm, dm) = at(-dy);
            // The wall 2 mm deep on a 3 mm ball is inclined (its normal 48° from the
            // vertical at the rim): the push has a lifting part, the depth is a fraction of
            // the displacement.
            assert!(p > 0.3 * dy && p < 1.1 * dy, "{dy}: {p}");
            assert!(d[1] < -0.5 && d[2] > 0.2 && d[0].abs() < 0.2, "{dy}: {d:?}");
            assert!((pm - p).abs() < 0.1 * p + 0.01, "{dy}: {pm} vs {p}");
            assert!(
                dm[1] > 0.5 && (dm[2] - d[2]).abs() < 0.1,
                "{dy}: {dm:?} vs {d:?}"
            );
            assert!(p > last, "{dy}: {p} after {last}");
            last = p;
        }
    }

    /// A stopped flat or ball end mill pressed into the uncut top is pushed straight up by
    /// the depth, as the plane contact pushes it.
    #[test]
    fn a_stopped_tool_pressed_into_the_top_is_pushed_up() {
        let s = Stock::new([0.0, 0.0, 0.0], [60.0, 40.0], 20.0, 0.1).unwrap();
        let k = CuttingCoefficients::of(MaterialPreset::Steel);
        for kind in [ToolKind::Flat, ToolKind::Ball] {
            let t = Tool {
                kind,
                ..Tool::default()
            };
            let mut e = Engagement::default();
            e.gather(&s, &t, &k, [1.03, -2.01, -0.3], 0.0);
            // The ball's deepest cell is within half a cell of its axis: ρ²/2r ≤ 0.001 mm.
            assert!((e.rub_mm - 0.3).abs() < 1e-3, "{kind:?}: {}", e.rub_mm);
            assert!(e.rub_dir[2] > 0.999, "{kind:?}: {:?}", e.rub_dir);
        }
    }

    /// The cells within `reach` of (`x`, `y`), the way the first gather walked them.
    fn for_cells_near<F: FnMut(usize, usize, f64, f64)>(
        stock: &Stock,
        x: f64,
        y: f64,
        reach: f64,
        mut f: F,
    ) {
        let (nx, ny) = stock.dims();
        let c0 = stock.cell_centre_mm(0, 0);
        let cell = stock.cell_mm();
        let range = |c: f64, c0: f64, n: usize| {
            let lo = (((c - reach - c0) / cell).floor() - 1.0).max(0.0) as usize;
            let hi = ((((c + reach - c0) / cell).ceil() + 1.0).max(0.0) as usize).min(n - 1);
            lo..=hi
        };
        for iy in range(y, c0[1], ny) {
            for ix in range(x, c0[0], nx) {
                let c = stock.cell_centre_mm(ix, iy);
                let (dx, dy) = (c[0] - x, c[1] - y);
                if dx * dx + dy * dy <= reach * reach {
                    f(ix, iy, dx, dy);
                }
            }
        }
    }

    /// The first gather, kept as the reference the one-pass gather is checked against.
    impl Engagement {
        fn gather_reference(
            &mut self,
            stock: &Stock,
            tool: &Tool,
            k: &CuttingCoefficients,
            tip_mm: [f64; 3],
            rev_per_s: f64,
        ) {
            self.bins = [[Bin::default(); BINS]; LAYERS];
            self.elements = 0;
            self.penetration_mm = f64::NEG_INFINITY;
            self.rub_mm = 0.0;
            self.rub_sum = [0.0; 3];
            let r = tool.radius_mm;
            let cell = stock.cell_mm();
            let rim_lift = tool.lift_mm(r * r);
            let top = tip_mm[2] + tool.flute_length_mm;
            let per_rev = if rev_per_s > 0.0 {
                1.0 / (2.0 * std::f64::consts::PI * rev_per_s)
            } else {
                0.0
            };
            for_cells_near(stock, tip_mm[0], tip_mm[1], r + cell, |ix, iy, dx, dy| {
                let h = stock.height_at(ix, iy);
                let rho2 = dx * dx + dy * dy;
                let inside = rho2 <= r * r;
                // Stock below the tip touches nothing (the lower surface is nowhere lower).
                if h < tip_mm[2] - TOUCH_MM {
                    if inside {
                        self.penetration_mm = self.penetration_mm.max(h - tip_mm[2]);
                    }
                    return;
                }
                let rho = rho2.sqrt();
                let (n, area, r_cut) = if inside {
                    let env = tip_mm[2] + tool.lift_mm(rho2);
                    // Stock inside the tool leaves it the shallower way: up, or sideways out of
                    // the radius.
                    let sideways = r - rho;
                    if h - env <= sideways || rho <= 0.0 {
                        self.penetration_mm = self.penetration_mm.max(h - env);
                    }
                    let ball = tool.kind == ToolKind::Ball;
                    self.book_rub(rub_cell(ball, r, tip_mm[2], h, dx, dy, rho2));
                    if (h - env).abs() > TOUCH_MM && h < env {
                        return;
                    }
                    if h - env > TOUCH_MM {
                        // Stock inside the tool (a stalled spindle): rubbing, not cutting.
                        return;
                    }
                    match tool.kind {
                        ToolKind::Flat => ([0.0, 0.0, -1.0], cell * cell, rho),
                        ToolKind::Ball => {
                            let w = (r * r - rho2).max(0.0).sqrt().max(0.2 * r);
                            ([dx / r, dy / r, -w / r], cell * cell * r / w, rho)
                        }
                    }
                } else {
                    // The wall beside the tool: stock above the rim's lower edge.
                    let e = h.min(top) - (tip_mm[2] + rim_lift);
                    if e <= 0.0 || rho <= 0.0 {
                        return;
                    }
                    ([dx / rho, dy / rho, 0.0], e * cell, r)
                };
                self.elements += 1;
                let kappa = area * per_rev / r_cut.max(R_MIN_FRACTION * r);
                // The edge moves clockwise seen from above: t̂ = (dy, −dx, 0)/ρ.
                let t = if rho > 0.0 {
                    [dy / rho, -dx / rho, 0.0]
                } else {
                    [0.0; 3]
                };
                let wall = n[2].abs() < 0.5;
                let ka = if wall { k.k_ac_n_per_mm2 } else { 0.0 };
                let dir = [
                    k.k_rc_n_per_mm2 * n[0] + k.k_tc_n_per_mm2 * t[0],
                    k.k_rc_n_per_mm2 * n[1] + k.k_tc_n_per_mm2 * t[1],
                    k.k_rc_n_per_mm2 * n[2] - ka,
                ];
                let idx = ((azimuth_rev(dx, dy) * BINS as f64) as usize).min(BINS - 1);
                let bin = &mut self.bins[usize::from(!wall)][idx];
                for (row, d) in bin.b.iter_mut().zip(dir) {
                    for (c, nc) in row.iter_mut().zip(n) {
                        *c += kappa * d * nc;
                    }
                }
                for (s, nc) in bin.n.iter_mut().zip(n) {
                    *s += area * nc;
                }
            });
            self.finish_rub();
        }
    }

    /// A tool clear of the block by `clear_of_block` engages nothing anywhere over a cut
    /// stock, and one just under the block's top over uncut stock engages something.
    #[test]
    fn a_tool_clear_of_the_block_engages_nothing() {
        let mut rng = h4_shared::rng::Rng::new(11);
        for kind in [ToolKind::Ball, ToolKind::Flat] {
            let (mut s, t, _) = cut_slot(kind, 1.5);
            s.sweep(&t, [-5.0, 6.0, 0.5], [5.0, 6.0, -1.5]);
            let k = CuttingCoefficients::of(MaterialPreset::Aluminium);
            let n = t.spindle_rev_per_s();
            let mut e = Engagement::default();
            let mut clear = 0;
            for _ in 0..300 {
                let p = [
                    -14.0 + 24.0 * rng.uniform(),
                    -12.0 + 24.0 * rng.uniform(),
                    s.top_mm() + 0.01 * rng.uniform() - 0.003,
                ];
                e.gather(&s, &t, &k, p, n);
                if Engagement::clear_of_block(&s, p) {
                    clear += 1;
                    assert_eq!(e.elements, 0, "{kind:?} at {p:?}");
                }
            }
            assert!(clear > 100, "{clear} positions clear");
            let p = [20.0, -10.0, s.top_mm() - 0.001];
            assert!(!Engagement::clear_of_block(&s, p));
            e.gather(&s, &t, &k, p, n);
            assert!(e.elements > 0, "{kind:?} touching uncut stock engages");
        }
    }

    /// The one-pass gather books the same elements, bins, penetration and sideways contact
    /// as the reference on cut slots, ramps, plunges and dwell positions of both tools, the
    /// spindle turning or stopped, tool clear above the cut, touching, inside the stock.
    #[test]
    fn the_one_pass_gather_matches_the_reference() {
        let mut rng = h4_shared::rng::Rng::new(7);
        let mut checked = 0;
        for kind in [ToolKind::Ball, ToolKind::Flat] {
            for depth in [0.5, 1.5, 3.5] {
                let (mut s, t, tip) = cut_slot(kind, depth);
                // A ramp and a plunge beside the slot, so the stock has slopes and holes.
                s.sweep(&t, [-5.0, 6.0, 0.5], [5.0, 6.0, -depth]);
                s.sweep(&t, [3.0, -7.0, 0.5], [3.0, -7.0, -depth]);
                let k = CuttingCoefficients::of(MaterialPreset::Aluminium);
                for i in 0..400 {
                    let p = if i == 0 {
                        tip
                    } else {
                        [
                            -12.0 + 20.0 * rng.uniform(),
                            -10.0 + 20.0 * rng.uniform(),
                            -depth - 0.3 + (depth + 1.0) * rng.uniform(),
                        ]
                    };
                    let n = if i % 5 == 0 {
                        0.0
                    } else {
                        t.spindle_rev_per_s()
                    };
                    let (mut a, mut b) = (Engagement::default(), Engagement::default());
                    a.gather(&s, &t, &k, p, n);
                    b.gather_reference(&s, &t, &k, p, n);
                    assert_eq!(a.elements, b.elements, "{kind:?} at {p:?}");
                    let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * (1.0 + y.abs());
                    assert!(
                        close(a.penetration_mm, b.penetration_mm)
                            || a.penetration_mm == b.penetration_mm,
                        "{kind:?} at {p:?}: {} vs {}",
                        a.penetration_mm,
                        b.penetration_mm
                    );
                    assert!(close(a.rub_mm, b.rub_mm), "{kind:?} at {p:?}");
                    for (x, y) in a.rub_dir.iter().zip(&b.rub_dir) {
                        assert!((x - y).abs() <= 1e-9, "{kind:?} at {p:?}");
                    }
                    for (la, lb) in a.bins.iter().zip(&b.bins) {
                        for (ba, bb) in la.iter().zip(lb) {
                            for (ra, rb) in ba.b.iter().zip(&bb.b) {
                                for (x, y) in ra.iter().zip(rb) {
                                    assert!(close(*x, *y), "{kind:?} at {p:?}: {x} vs {y}");
                                }
                            }
                            for (x, y) in ba.n.iter().zip(&bb.n) {
                                assert!(close(*x, *y), "{kind:?} at {p:?}: {x} vs {y}");
                            }
                        }
                    }
                    checked += usize::from(b.elements > 0);
                }
            }
        }
        assert!(checked > 300, "only {checked} positions touched the stock");
    }

    #[test]
    fn wrap_rev_is_rem_euclid() {
        for k in -4000..4000 {
            let a = f64::from(k) * 0.00731 + 1e-9;
            assert!((wrap_rev(a) - a.rem_euclid(1.0)).abs() < 1e-12, "{a}");
        }
        assert!(wrap_rev(f64::NAN).is_nan());
    }

    #[test]
    fn azimuth_matches_atan2() {
        for k in 0..3600 {
            let a = f64::from(k) * std::f64::consts::PI / 1800.0 + 1e-3;
            let (x, y) = (2.0 * a.cos(), 2.0 * a.sin());
            let want =
                y.atan2(x).rem_euclid(2.0 * std::f64::consts::PI) / (2.0 * std::f64::consts::PI);
            let got = azimuth_rev(x, y);
            let d = (got - want).abs().min(1.0 - (got - want).abs());
            assert!(d < 2e-5, "{a}: {got} vs {want}");
        }
    }

    /// The cached solve gives the matrix and the velocity of `matrix` + `solve_damped`
    /// through a revolution of the teeth, the velocity turning, for 1 to 4 flutes.
    #[test]
    fn the_cached_solve_matches_matrix_and_solve_damped() {
        let (s, t, tip) = cut_slot(ToolKind::Ball, 1.5);
        let k = CuttingCoefficients::of(MaterialPreset::Aluminium);
        let mut e = Engagement::default();
        e.gather(&s, &t, &k, tip, t.spindle_rev_per_s());
        let mut hits = 0;
        for flutes in 1..=4 {
            for i in 0..2000 {
                let a = i as f64 * 0.003;
                let v = [10.0 * a.cos(), 10.0 * a.sin(), -2.0 + 4.0 * (0.7 * a).sin()];
                let phase = i as f64 / 613.0;
                let key_before = e.solved.key;
                let (m, x) = e.solve(phase, flutes, &v, 0.02);
                hits += usize::from(e.solved.key == key_before);
                let m_ref = e.matrix(phase, flutes, &v);
                let x_ref = solve_damped(&m_ref, 0.02, &v);
                for r in 0..3 {
                    assert!((x[r] - x_ref[r]).abs() < 1e-9 * (1.0 + x_ref[r].abs()));
                    for c in 0..3 {
                        assert!((m[r][c] - m_ref[r][c]).abs() < 1e-12 * (1.0 + m_ref[r][c].abs()));
                    }
                }
            }
        }
        assert!(hits > 1000, "the cache was reused {hits} times");
    }

    #[test]
    fn damped_solve_inverts() {
        let m = [[3.0, 1.0, 0.0], [0.5, 2.0, 0.2], [0.0, 0.1, 4.0]];
        let v = [1.0, -2.0, 0.5];
        let x = solve_damped(&m, 0.7, &v);
        for i in 0..3 {
            let lhs = x[i] + 0.7 * (m[i][0] * x[0] + m[i][1] * x[1] + m[i][2] * x[2]);
            assert!((lhs - v[i]).abs() < 1e-12);
        }
    }
}
