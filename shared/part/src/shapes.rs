//! The shipped parts' generators (no downloaded data): each builds a closed, manifold mesh
//! with outward normals, in millimetres, its base on z = 0 and its axis (or centre) on
//! x = y = 0. `examples/make_parts.rs` writes them to `config/parts/` as binary STL; a test
//! checks that regenerating them gives the committed bytes.
//!
//! Both are *height-field* solids (every vertical line meets the part's top once): the
//! workpiece is a height field cut from above, which cannot hold an undercut, so a part with
//! one could not be judged against what the cutter can reach.

use std::f64::consts::PI;

/// An indexed triangle mesh in f64 (mm); faces counter-clockwise seen from outside.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshBuilder {
    /// The vertices, mm.
    pub vertices: Vec<[f64; 3]>,
    /// The faces: indices into `vertices`, counter-clockwise seen from outside.
    pub faces: Vec<[usize; 3]>,
}

impl MeshBuilder {
    fn vertex(&mut self, p: [f64; 3]) -> usize {
        self.vertices.push(p);
        self.vertices.len() - 1
    }

    /// The mesh as STL triangles (f32), each with its unit normal from its winding.
    pub fn triangles(&self) -> Vec<stl_io::Triangle> {
        self.faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| self.vertices[i]);
                let n = crate::geom::normalize(crate::geom::cross(
                    crate::geom::sub(b, a),
                    crate::geom::sub(c, a),
                ));
                let v = |p: [f64; 3]| stl_io::Vertex::new(p.map(|x| x as f32));
                stl_io::Triangle {
                    normal: stl_io::Normal::new(n.map(|x| x as f32)),
                    vertices: [v(a), v(b), v(c)],
                }
            })
            .collect()
    }

    /// The mesh as binary STL bytes (stl_io's writer: a zero header, so the bytes depend only
    /// on the triangles).
    pub fn to_binary_stl(&self) -> std::io::Result<Vec<u8>> {
        let mut out = Vec::new();
        stl_io::write_stl(&mut out, self.triangles().iter())?;
        Ok(out)
    }
}

/// The dome-and-step block's size: footprint `[x, y]`, mm.
pub const DOME_BLOCK_SIZE_MM: [f64; 2] = [80.0, 60.0];
/// The dome-and-step block's lower step height, mm.
pub const DOME_BLOCK_LOW_MM: f64 = 8.0;
/// The dome-and-step block's upper platform height, mm.
pub const DOME_BLOCK_HIGH_MM: f64 = 14.0;
/// The dome's top height, mm.
pub const DOME_BLOCK_TOP_MM: f64 = 24.0;

/// The height of the dome-and-step block's top at (`x`, `y`) (within its footprint), mm: a
/// lower step (x < −10) at 8 mm, a platform at 14 mm, on it a spherical dome (radius 20 mm)
/// centred at x = 15, y = 0 rising to 24 mm.
pub fn dome_block_height_mm(x: f64, y: f64) -> f64 {
    if x < -10.0 {
        return DOME_BLOCK_LOW_MM;
    }
    let r_sphere = 20.0;
    let centre_z = DOME_BLOCK_TOP_MM - r_sphere;
    let rho2 = (x - 15.0).powi(2) + y * y;
    let dome = if rho2 < r_sphere * r_sphere {
        centre_z + (r_sphere * r_sphere - rho2).sqrt()
    } else {
        f64::NEG_INFINITY
    };
    dome.max(DOME_BLOCK_HIGH_MM)
}

/// The dome-and-step block: a height-field solid over an 80 × 60 mm footprint centred on the
/// origin, its top sampled every `cell_mm` (the step's wall is one cell wide), its four
/// sides and its bottom (a fan from the bottom's centre) closing it.
pub fn dome_block(cell_mm: f64) -> MeshBuilder {
    let [sx, sy] = DOME_BLOCK_SIZE_MM;
    let nx = (sx / cell_mm).round().max(2.0) as usize;
    let ny = (sy / cell_mm).round().max(2.0) as usize;
    let xs: Vec<f64> = (0..=nx)
        .map(|i| -0.5 * sx + sx * i as f64 / nx as f64)
        .collect();
    let ys: Vec<f64> = (0..=ny)
        .map(|j| -0.5 * sy + sy * j as f64 / ny as f64)
        .collect();
    let mut m = MeshBuilder::default();
    // The top: a grid of vertices, two triangles per cell, counter-clockwise from above.
    let mut top = vec![0usize; (nx + 1) * (ny + 1)];
    for j in 0..=ny {
        for i in 0..=nx {
            top[j * (nx + 1) + i] = m.vertex([xs[i], ys[j], dome_block_height_mm(xs[i], ys[j])]);
        }
    }
    let t = |i: usize, j: usize| top[j * (nx + 1) + i];
    for j in 0..ny {
        for i in 0..nx {
            m.faces.push([t(i, j), t(i + 1, j), t(i + 1, j + 1)]);
            m.faces.push([t(i, j), t(i + 1, j + 1), t(i, j + 1)]);
        }
    }
    // The boundary of the top, counter-clockwise from above: (i, j) pairs.
    let mut ring: Vec<(usize, usize)> = Vec::new();
    ring.extend((0..nx).map(|i| (i, 0)));
    ring.extend((0..ny).map(|j| (nx, j)));
    ring.extend((1..=nx).rev().map(|i| (i, ny)));
    ring.extend((1..=ny).rev().map(|j| (0, j)));
    let bottom: Vec<usize> = ring
        .iter()
        .map(|&(i, j)| m.vertex([xs[i], ys[j], 0.0]))
        .collect();
    let centre = m.vertex([0.0, 0.0, 0.0]);
    let n = ring.len();
    for k in 0..n {
        let (i0, j0) = ring[k];
        let (i1, j1) = ring[(k + 1) % n];
        let (b0, b1) = (bottom[k], bottom[(k + 1) % n]);
        // The side: outward is to the right of the counter-clockwise ring seen from above.
        m.faces.push([b0, b1, t(i1, j1)]);
        m.faces.push([b0, t(i1, j1), t(i0, j0)]);
        // The bottom: seen from below, so clockwise from above.
        m.faces.push([centre, b1, b0]);
    }
    m
}

/// The turned part's height, mm.
pub const PAWN_HEIGHT_MM: f64 = 22.0;
/// The turned part's base radius (its largest), mm.
pub const PAWN_BASE_RADIUS_MM: f64 = 6.0;

/// The turned part's profile: `(radius, height)` points, mm, from the base's rim (r > 0,
/// z = 0) up to the top's pole (r = 0); the radius never grows with the height. Drawn on
/// an 18 mm radius, 24 mm tall sketch, scaled to `PAWN_BASE_RADIUS_MM` and `PAWN_HEIGHT_MM`
/// (a part a 3 mm ball end roughs out on the turntable in a short session).
pub fn pawn_profile_mm() -> Vec<[f64; 2]> {
    let mut p: Vec<[f64; 2]> = vec![[18.0, 0.0], [18.0, 1.5], [18.0, 3.0]];
    // A convex quarter round from the base's rim to the collar: centre (12, 3), semi-axes 6, 4.
    for k in 1..=8 {
        let a = 0.5 * PI * k as f64 / 8.0;
        p.push([12.0 + 6.0 * a.cos(), 3.0 + 4.0 * a.sin()]);
    }
    // The collar, then a chamfer to the body.
    p.push([12.0, 8.5]);
    p.push([9.0, 9.5]);
    // The body: a concave taper from r = 9 at z = 9.5 to r = 6 at z = 18.
    for k in 1..=8 {
        let s = k as f64 / 8.0;
        p.push([6.0 + 3.0 * (1.0 - s).powi(2), 9.5 + 8.5 * s]);
    }
    // The head: a hemisphere of radius 6 centred on the axis at z = 18.
    for k in 1..=12 {
        let a = 0.5 * PI * k as f64 / 12.0;
        let r = if k == 12 { 0.0 } else { 6.0 * a.cos() };
        p.push([r, 18.0 + 6.0 * a.sin()]);
    }
    let (sr, sz) = (PAWN_BASE_RADIUS_MM / 18.0, PAWN_HEIGHT_MM / 24.0);
    p.iter().map(|&[r, z]| [r * sr, z * sz]).collect()
}

/// The turned, chess-pawn-like part: the profile (`pawn_profile_mm`) turned about the z axis
/// in `segments` steps, its bottom a fan from the axis.
pub fn pawn(segments: usize) -> MeshBuilder {
    revolve(&pawn_profile_mm(), segments)
}

/// A surface of revolution about the z axis: `profile` is `(radius, height)` points, mm,
/// from the bottom up, its last point on the axis (r = 0: a pole); a first point on the
/// axis is a pole too, else the bottom is a flat disc (a fan from the axis) at its height.
/// Turned in `segments` steps (at least 3).
pub fn revolve(profile: &[[f64; 2]], segments: usize) -> MeshBuilder {
    let segments = segments.max(3);
    let mut m = MeshBuilder::default();
    if profile.len() < 2 {
        return m;
    }
    let south_pole = profile[0][0] == 0.0;
    let first = usize::from(south_pole);
    let last = profile.len() - 1; // the north pole
    let mut ring_start = Vec::with_capacity(last);
    for &[r, z] in &profile[first..last] {
        ring_start.push(m.vertices.len());
        for s in 0..segments {
            let phi = 2.0 * PI * s as f64 / segments as f64;
            m.vertex([r * phi.cos(), r * phi.sin(), z]);
        }
    }
    let rings = ring_start.len();
    if rings == 0 {
        return MeshBuilder::default();
    }
    let pole = m.vertex([0.0, 0.0, profile[last][1]]);
    let bottom = m.vertex([0.0, 0.0, profile[0][1]]);
    let v = |ring: usize, s: usize| ring_start[ring] + s % segments;
    for s in 0..segments {
        for ring in 0..rings - 1 {
            let (a, b) = (v(ring, s), v(ring, s + 1));
            let (c, d) = (v(ring + 1, s + 1), v(ring + 1, s));
            // Outward: the angle's direction × up is the radial direction.
            m.faces.push([a, b, c]);
            m.faces.push([a, c, d]);
        }
        m.faces.push([v(rings - 1, s), v(rings - 1, s + 1), pole]);
        m.faces.push([bottom, v(0, s + 1), v(0, s)]);
    }
    m
}

/// The dome-and-step block as shipped (`config/parts/dome-block.stl`): 1 mm cells.
pub fn shipped_dome_block() -> MeshBuilder {
    dome_block(1.0)
}

/// The turned part as shipped (`config/parts/pawn.stl`): 96 segments.
pub fn shipped_pawn() -> MeshBuilder {
    pawn(96)
}
