//! The bodies the tool can touch: shape (plane, cylinder, sphere) and material (contact
//! stiffness, damping, friction). The solid is on the side opposite the outward normal.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// A surface's material: its contact stiffness, damping and friction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Contact stiffness along the normal, N/mm.
    pub stiffness_n_per_mm: f64,
    /// Damping ratio of the contact with the tool's mass (0 to 2).
    pub damping_ratio: f64,
    /// Coulomb friction coefficient between tool and surface.
    pub friction_coefficient: f64,
}

/// Named materials (values and sources in `docs/slave-simulation.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MaterialPreset {
    /// Cast epoxy/polyurethane tooling resin block on its fixture.
    Resin,
    /// Steel plate on its fixture.
    Steel,
    /// Aluminium plate on its fixture.
    Aluminium,
}

impl MaterialPreset {
    /// The preset's values.
    pub fn material(self) -> Material {
        match self {
            MaterialPreset::Resin => Material {
                stiffness_n_per_mm: 200.0,
                damping_ratio: 0.3,
                friction_coefficient: 0.15,
            },
            MaterialPreset::Steel => Material {
                stiffness_n_per_mm: 2000.0,
                damping_ratio: 0.05,
                friction_coefficient: 0.12,
            },
            MaterialPreset::Aluminium => Material {
                stiffness_n_per_mm: 1000.0,
                damping_ratio: 0.05,
                friction_coefficient: 0.15,
            },
        }
    }
}

/// The geometry of a rigid body's surface; the solid is on the side opposite the
/// outward normal (below a plane, inside a cylinder or a sphere).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SurfaceShape {
    /// The plane through `point_mm` with outward unit normal `normal`.
    Plane {
        /// A point of the plane, mm.
        point_mm: [f64; 3],
        /// Outward unit normal.
        normal: [f64; 3],
    },
    /// An infinite cylinder.
    Cylinder {
        /// A point of the axis, mm.
        axis_point_mm: [f64; 3],
        /// Unit direction of the axis.
        axis_dir: [f64; 3],
        /// Radius, mm.
        radius_mm: f64,
    },
    /// A sphere.
    Sphere {
        /// Centre, mm.
        centre_mm: [f64; 3],
        /// Radius, mm.
        radius_mm: f64,
    },
}

/// A body the tool can touch: shape and material. [`SimArm::set_surface`] swaps it at
/// run time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    /// Geometry.
    pub shape: SurfaceShape,
    /// Material.
    pub material: Material,
}

impl Surface {
    /// Penetration depth (> 0 inside the solid), mm, and the outward unit normal at the
    /// nearest surface point.
    #[inline]
    pub fn penetration(&self, p: &Vector3<f64>) -> (f64, Vector3<f64>) {
        match self.shape {
            SurfaceShape::Plane { point_mm, normal } => {
                let n = Vector3::from(normal);
                (-(n.dot(&(p - Vector3::from(point_mm)))), n)
            }
            SurfaceShape::Sphere {
                centre_mm,
                radius_mm,
            } => {
                let w = p - Vector3::from(centre_mm);
                let d = w.norm();
                if d > 1e-9 {
                    (radius_mm - d, w / d)
                } else {
                    (radius_mm, Vector3::z())
                }
            }
            SurfaceShape::Cylinder {
                axis_point_mm,
                axis_dir,
                radius_mm,
            } => {
                let u = Vector3::from(axis_dir);
                let w = p - Vector3::from(axis_point_mm);
                let w_perp = w - u * u.dot(&w);
                let d = w_perp.norm();
                if d > 1e-9 {
                    (radius_mm - d, w_perp / d)
                } else {
                    (radius_mm, Vector3::z())
                }
            }
        }
    }
}
