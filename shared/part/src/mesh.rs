//! Loading, checking and placing a part mesh.

use std::collections::HashMap;
use std::path::Path;

use crate::PartError;
use crate::geom::{cross, dot, norm, sub};
use crate::sdf::SdfGrid;

/// Options of a part's load (limits and the distance grid's resolution).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadOptions {
    /// The largest file accepted, bytes.
    pub max_file_bytes: u64,
    /// The smallest triangle area accepted, mm².
    pub min_triangle_area_mm2: f64,
    /// The distance grid's cell, mm.
    pub grid_cell_mm: f64,
    /// The distance the grid is exact to (beyond, it answers ± this: far outside or deep
    /// inside), mm; the fixture needs the tool's radius + the allowance + a margin.
    pub band_mm: f64,
    /// The most grid nodes allowed.
    pub max_grid_nodes: usize,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            max_file_bytes: 64 << 20,
            min_triangle_area_mm2: 1e-8,
            grid_cell_mm: 0.5,
            band_mm: 4.0,
            max_grid_nodes: 16_000_000,
        }
    }
}

/// Where the part lies in the workpiece frame: `p_wp = R · p_part + translation`, R the
/// rotation about x, then y, then z (fixed axes) by `rotation_deg`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Placement {
    /// The part frame's origin in the workpiece frame, mm.
    pub translation_mm: [f64; 3],
    /// Rotations about the workpiece frame's x, y and z axes, applied in that order, degrees.
    pub rotation_deg: [f64; 3],
}

impl Placement {
    /// The rotation matrix (rows).
    pub fn matrix(&self) -> [[f64; 3]; 3] {
        let [ax, ay, az] = self.rotation_deg.map(f64::to_radians);
        let (sx, cx) = ax.sin_cos();
        let (sy, cy) = ay.sin_cos();
        let (sz, cz) = az.sin_cos();
        // Rz · Ry · Rx.
        [
            [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
            [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
            [-sy, cy * sx, cy * cx],
        ]
    }
}

/// The stock block the part must fit in, workpiece frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StockBox {
    /// The block's top face's centre, mm.
    pub centre_top_mm: [f64; 3],
    /// Its size along x and y, mm.
    pub size_mm: [f64; 2],
    /// Its thickness, mm.
    pub thickness_mm: f64,
}

impl StockBox {
    /// `(min, max)` corners, mm.
    pub fn corners_mm(&self) -> ([f64; 3], [f64; 3]) {
        let [cx, cy, top] = self.centre_top_mm;
        let [sx, sy] = self.size_mm;
        (
            [cx - 0.5 * sx, cy - 0.5 * sy, top - self.thickness_mm],
            [cx + 0.5 * sx, cy + 0.5 * sy, top],
        )
    }
}

/// A checked, placed part with its distance grid.
#[derive(Clone, Debug)]
pub struct Part {
    /// The vertices in the part's own frame, mm.
    pub vertices: Vec<[f64; 3]>,
    /// The triangles (outward winding).
    pub faces: Vec<[usize; 3]>,
    /// The placement in the workpiece frame.
    pub placement: Placement,
    rot: [[f64; 3]; 3],
    /// The signed-distance grid, in the part's own frame.
    pub grid: SdfGrid,
    /// The enclosed volume, mm³.
    pub volume_mm3: f64,
}

fn read_mesh(path: &Path, opts: &LoadOptions) -> Result<stl_io::IndexedMesh, PartError> {
    let name = path.display().to_string();
    let io = |source| PartError::Io {
        path: name.clone(),
        source,
    };
    let bytes = std::fs::metadata(path).map_err(io)?.len();
    if bytes > opts.max_file_bytes {
        return Err(PartError::TooLarge {
            path: name,
            bytes,
            limit: opts.max_file_bytes,
        });
    }
    let mut file = std::fs::File::open(path).map_err(io)?;
    stl_io::read_stl(&mut file).map_err(|e| PartError::NotStl {
        path: name,
        reason: e.to_string(),
    })
}

/// Checks a mesh (finite, non-degenerate, closed, manifold, consistently and outwards
/// wound) and returns its vertices in f64 and its enclosed volume, mm³.
pub fn check_mesh(
    vertices: &[[f32; 3]],
    faces: &[[usize; 3]],
    min_area_mm2: f64,
) -> Result<(Vec<[f64; 3]>, f64), PartError> {
    if faces.is_empty() {
        return Err(PartError::Empty);
    }
    for (index, v) in vertices.iter().enumerate() {
        if v.iter().any(|c| !c.is_finite()) {
            return Err(PartError::NonFinite { index, vertex: *v });
        }
    }
    let vs: Vec<[f64; 3]> = vertices.iter().map(|v| v.map(f64::from)).collect();
    let mut volume6 = 0.0;
    for (index, f) in faces.iter().enumerate() {
        let [a, b, c] = f.map(|i| vs[i]);
        let area_mm2 = 0.5 * norm(cross(sub(b, a), sub(c, a)));
        if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] || area_mm2 < min_area_mm2 {
            return Err(PartError::Degenerate {
                index,
                area_mm2,
                min_mm2: min_area_mm2,
            });
        }
        volume6 += dot(a, cross(b, c));
    }
    // Each undirected edge: uses in one direction and in the other.
    let mut edges: HashMap<[usize; 2], [u32; 2]> = HashMap::with_capacity(faces.len() * 2);
    for f in faces {
        for k in 0..3 {
            let (u, v) = (f[k], f[(k + 1) % 3]);
            let (key, dir) = if u < v { ([u, v], 0) } else { ([v, u], 1) };
            edges.entry(key).or_insert([0, 0])[dir] += 1;
        }
    }
    let mut sorted: Vec<(&[usize; 2], &[u32; 2])> = edges.iter().collect();
    sorted.sort_unstable();
    let count = |pred: &dyn Fn(&[u32; 2]) -> bool| {
        let hits: Vec<&[usize; 2]> = sorted
            .iter()
            .filter(|(_, n)| pred(n))
            .map(|(k, _)| *k)
            .collect();
        (hits.len(), hits.first().map(|k| **k))
    };
    if let (n, Some(first)) = count(&|u| u[0] + u[1] == 1) {
        return Err(PartError::Open { count: n, first });
    }
    if let (n, Some(first)) = count(&|u| u[0] + u[1] > 2) {
        return Err(PartError::NonManifold { count: n, first });
    }
    if let (n, Some(first)) = count(&|u| u[0] != 1 || u[1] != 1) {
        return Err(PartError::Inconsistent { count: n, first });
    }
    let volume_mm3 = volume6 / 6.0;
    if volume_mm3 < 0.0 {
        return Err(PartError::Inverted { volume_mm3 });
    }
    Ok((vs, volume_mm3))
}

impl Part {
    /// Reads, checks and places the part in `path`, checks that it fits `stock` (if given),
    /// and builds its distance grid.
    pub fn load(
        path: &Path,
        placement: Placement,
        stock: Option<&StockBox>,
        opts: &LoadOptions,
    ) -> Result<Self, PartError> {
        let mesh = read_mesh(path, opts)?;
        let vertices: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.0).collect();
        let faces: Vec<[usize; 3]> = mesh.faces.iter().map(|f| f.vertices).collect();
        Self::from_mesh(&vertices, &faces, placement, stock, opts)
    }

    /// As `load`, from vertices (f32, as STL holds them) and faces.
    pub fn from_mesh(
        vertices: &[[f32; 3]],
        faces: &[[usize; 3]],
        placement: Placement,
        stock: Option<&StockBox>,
        opts: &LoadOptions,
    ) -> Result<Self, PartError> {
        check_options(opts)?;
        if let Some(&index) = faces.iter().flatten().find(|&&i| i >= vertices.len()) {
            return Err(PartError::NotStl {
                path: String::new(),
                reason: format!("a face names vertex {index} of {}", vertices.len()),
            });
        }
        let (vs, volume_mm3) = check_mesh(vertices, faces, opts.min_triangle_area_mm2)?;
        let rot = placement.matrix();
        let mut part = Self {
            vertices: vs,
            faces: faces.to_vec(),
            placement,
            rot,
            grid: SdfGrid::empty(),
            volume_mm3,
        };
        if let Some(stock) = stock {
            let (lo, hi) = stock.corners_mm();
            let tol = 1e-6;
            for (index, v) in part.vertices.iter().enumerate() {
                let p = part.to_workpiece(*v);
                if (0..3).any(|a| p[a] < lo[a] - tol || p[a] > hi[a] + tol) {
                    return Err(PartError::DoesNotFit {
                        index,
                        vertex_mm: p,
                        min_mm: lo,
                        max_mm: hi,
                    });
                }
            }
        }
        part.grid = SdfGrid::build(&part.vertices, &part.faces, opts)?;
        Ok(part)
    }

    /// A point of the part's frame in the workpiece frame.
    pub fn to_workpiece(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rot;
        let t = self.placement.translation_mm;
        [
            dot(r[0], p) + t[0],
            dot(r[1], p) + t[1],
            dot(r[2], p) + t[2],
        ]
    }

    /// A point of the workpiece frame in the part's frame.
    pub fn to_part(&self, p: [f64; 3]) -> [f64; 3] {
        let d = sub(p, self.placement.translation_mm);
        let r = &self.rot;
        [
            r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2],
            r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2],
            r[0][2] * d[0] + r[1][2] * d[1] + r[2][2] * d[2],
        ]
    }

    /// A direction of the part's frame in the workpiece frame.
    pub fn dir_to_workpiece(&self, d: [f64; 3]) -> [f64; 3] {
        let r = &self.rot;
        [dot(r[0], d), dot(r[1], d), dot(r[2], d)]
    }

    /// Signed distance of a workpiece-frame point from the part's surface, mm (negative
    /// inside; clamped to ± the grid's band). No allocation.
    pub fn signed_distance_mm(&self, p_wp: [f64; 3]) -> f64 {
        self.grid.signed_distance_mm(self.to_part(p_wp))
    }

    /// Signed distance and the unit direction of increasing distance (the outward normal of
    /// the nearest surface), workpiece frame. No allocation.
    pub fn distance_and_normal(&self, p_wp: [f64; 3]) -> (f64, [f64; 3]) {
        let (d, n) = self.grid.distance_and_gradient(self.to_part(p_wp));
        (d, self.dir_to_workpiece(n))
    }

    /// Signed distance of a workpiece-frame point from the part's surface, mm, exact at
    /// any distance: the grid's answer within its band, else the nearest triangle's
    /// distance over every face (the sign from the grid, which holds ± the band beyond it).
    /// Its cost grows with the mesh: for judging after a run, not for the cycle.
    pub fn signed_distance_exact_mm(&self, p_wp: [f64; 3]) -> f64 {
        let d = self.signed_distance_mm(p_wp);
        if d.abs() < self.grid.band_mm() - 1e-9 || !d.is_finite() {
            return d;
        }
        let p = self.to_part(p_wp);
        let nearest = self
            .faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| self.vertices[i]);
                crate::geom::distance_point_triangle(p, a, b, c)
            })
            .fold(f64::INFINITY, f64::min);
        nearest.copysign(d)
    }

    /// Whether a workpiece-frame point is inside the part.
    pub fn contains(&self, p_wp: [f64; 3]) -> bool {
        self.signed_distance_mm(p_wp) < 0.0
    }
}

fn check_options(o: &LoadOptions) -> Result<(), PartError> {
    let bad = |field, value: f64, allowed| PartError::BadOption {
        field,
        value,
        allowed,
    };
    if !(o.grid_cell_mm >= 0.01 && o.grid_cell_mm <= 10.0) {
        return Err(bad("grid_cell_mm", o.grid_cell_mm, "0.01 to 10 mm"));
    }
    if !(o.band_mm >= 2.0 * o.grid_cell_mm && o.band_mm <= 100.0) {
        return Err(bad("band_mm", o.band_mm, "2 grid cells to 100 mm"));
    }
    if !(o.min_triangle_area_mm2 >= 0.0 && o.min_triangle_area_mm2.is_finite()) {
        return Err(bad(
            "min_triangle_area_mm2",
            o.min_triangle_area_mm2,
            "≥ 0 mm²",
        ));
    }
    Ok(())
}
