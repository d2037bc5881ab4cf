//! A part from a CAD mesh (issue 34): read an STL file (binary or ASCII, millimetres) with
//! `stl_io`, refuse it with a reason if it is not a solid a cutter can be guarded by (not
//! closed, a non-manifold edge, faces wound inwards or inconsistently, degenerate triangles,
//! non-finite vertices, a file over the size limit, a part that does not fit the stock),
//! place it in the workpiece frame by a translation and a rotation, and precompute at load
//! time a signed-distance grid, so that the distance and inside queries in the 1 kHz cycle
//! are a trilinear interpolation: constant time, no allocation, no branch on the mesh's size.
//!
//! Why a grid and not a BVH (e.g. parry3d's `TriMesh`): a BVH query's cost grows with the
//! mesh and the query point (a few µs for a 10 000-triangle part, more far from it), and a
//! signed query needs a pseudo-normal or a ray test on top; a grid answers in ~50 ns
//! whatever the mesh, needs no further dependency, and its error (the interpolation's,
//! ≤ a fraction of the cell near curved or sharp features) is covered by the finishing
//! allowance. `docs/cad-parts.md`.
#![deny(unsafe_code)]

pub mod geom;
pub mod mesh;
pub mod sdf;
pub mod shapes;

pub use mesh::{LoadOptions, Part, Placement, StockBox};
pub use sdf::SdfGrid;

/// Why a mesh is refused.
#[derive(Debug, thiserror::Error)]
pub enum PartError {
    /// The file could not be opened or its length read.
    #[error("cannot read part mesh {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is larger than the configured limit.
    #[error("part mesh {path} is {bytes} bytes, over the limit of {limit} bytes")]
    TooLarge {
        /// The file.
        path: String,
        /// Its size, bytes.
        bytes: u64,
        /// The limit, bytes.
        limit: u64,
    },
    /// The file is not STL (binary or ASCII).
    #[error("part mesh {path} is not a readable STL file: {reason}")]
    NotStl {
        /// The file.
        path: String,
        /// stl_io's reason.
        reason: String,
    },
    /// No triangles.
    #[error("part mesh has no triangles")]
    Empty,
    /// A vertex with a NaN or infinite coordinate.
    #[error("part mesh vertex {index} is not finite: {vertex:?}")]
    NonFinite {
        /// The vertex's index.
        index: usize,
        /// Its coordinates, mm.
        vertex: [f32; 3],
    },
    /// A triangle of (near) zero area: a repeated vertex or three collinear ones.
    #[error("part mesh triangle {index} is degenerate (area {area_mm2:e} mm², under {min_mm2:e})")]
    Degenerate {
        /// The triangle's index.
        index: usize,
        /// Its area, mm².
        area_mm2: f64,
        /// The smallest area allowed, mm².
        min_mm2: f64,
    },
    /// Edges used by one triangle only: the mesh has holes.
    #[error(
        "part mesh is not closed: {count} edges belong to one triangle only (first: vertices {first:?})"
    )]
    Open {
        /// How many boundary edges.
        count: usize,
        /// The first one's vertex indices.
        first: [usize; 2],
    },
    /// Edges shared by more than two triangles.
    #[error(
        "part mesh is not manifold: {count} edges belong to more than two triangles (first: vertices {first:?})"
    )]
    NonManifold {
        /// How many such edges.
        count: usize,
        /// The first one's vertex indices.
        first: [usize; 2],
    },
    /// Two triangles run along a shared edge the same way: their windings disagree.
    #[error(
        "part mesh's triangles are wound inconsistently: {count} edges are run the same way by both their triangles (first: vertices {first:?})"
    )]
    Inconsistent {
        /// How many such edges.
        count: usize,
        /// The first one's vertex indices.
        first: [usize; 2],
    },
    /// The enclosed volume is negative: every normal points inwards.
    #[error(
        "part mesh's normals point inwards (enclosed volume {volume_mm3:.1} mm³ < 0): flip its faces"
    )]
    Inverted {
        /// The signed volume, mm³.
        volume_mm3: f64,
    },
    /// A placed vertex lies outside the stock.
    #[error(
        "part does not fit the stock: vertex {index} at {vertex_mm:?} mm (workpiece frame) is outside the block {min_mm:?} to {max_mm:?} mm"
    )]
    DoesNotFit {
        /// The vertex's index.
        index: usize,
        /// Its placed position, mm.
        vertex_mm: [f64; 3],
        /// The stock's lowest corner, mm.
        min_mm: [f64; 3],
        /// The stock's highest corner, mm.
        max_mm: [f64; 3],
    },
    /// The grid the part would need is too large.
    #[error(
        "part's distance grid would have {nodes} nodes, over the limit of {limit}: use a larger grid cell"
    )]
    GridTooLarge {
        /// Nodes needed.
        nodes: usize,
        /// The limit.
        limit: usize,
    },
    /// An option out of its range.
    #[error("{field} = {value} is out of range: allowed {allowed}")]
    BadOption {
        /// The option.
        field: &'static str,
        /// Its value.
        value: f64,
        /// The range.
        allowed: &'static str,
    },
}
