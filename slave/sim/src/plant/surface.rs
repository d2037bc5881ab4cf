//! The bodies the tool can touch: shape (plane, cylinder, sphere) and material (contact
//! stiffness, damping, friction). The solid is on the side opposite the outward normal.

use h4_shared::config::{ConfigError, Section, check_range};
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
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

/// A body the tool can touch: shape and material. [`SimArm::set_surface`](crate::plant::SimArm::set_surface) swaps it at
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

/// Shape of a configured surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum ShapeKind {
    /// A plane, tilted about y by `tilt_deg`.
    Plane,
    /// A cylinder of `radius_mm` whose axis is `cylinder_axis`, touched on top.
    Cylinder,
    /// A sphere of `radius_mm`, touched on top.
    Sphere,
}

/// A horizontal axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// The robot's x axis.
    X,
    /// The robot's y axis.
    Y,
}

/// The surface section (`surface.*`): a body the controller does not know, placed so the
/// tool first touches it at `contact_point_mm`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SurfaceConfig {
    /// `plane`, `cylinder` or `sphere`.
    pub shape: ShapeKind,
    /// `resin`, `steel` or `aluminium`.
    pub material: MaterialPreset,
    /// Tilt of the surface normal at the contact point about the robot's y axis, degrees.
    #[serde(default)]
    pub tilt_deg: f64,
    /// Radius of a cylinder or sphere, mm.
    #[serde(default = "default_radius")]
    pub radius_mm: f64,
    /// Overrides the material's contact stiffness, N/mm.
    #[serde(default)]
    pub stiffness_n_per_mm: Option<f64>,
    /// Overrides the material's contact damping ratio.
    #[serde(default)]
    pub damping_ratio: Option<f64>,
    /// Overrides the material's friction coefficient.
    #[serde(default)]
    pub friction_coefficient: Option<f64>,
    /// Where the tool first touches the surface, mm.
    #[serde(default = "default_contact_point")]
    pub contact_point_mm: [f64; 3],
    /// Axis of a cylinder (`x` or `y`).
    #[serde(default = "default_axis")]
    pub cylinder_axis: Axis,
}

fn default_radius() -> f64 {
    200.0
}
fn default_contact_point() -> [f64; 3] {
    [0.0, 0.0, -250.0]
}
fn default_axis() -> Axis {
    Axis::Y
}

impl SurfaceConfig {
    /// A surface of `shape` and `material` first touched at `contact_point_mm`, untilted,
    /// the other fields at their defaults (radius 200 mm, cylinder axis y, the material's
    /// own values).
    pub fn new(shape: ShapeKind, material: MaterialPreset, contact_point_mm: [f64; 3]) -> Self {
        SurfaceConfig {
            shape,
            material,
            tilt_deg: 0.0,
            radius_mm: default_radius(),
            stiffness_n_per_mm: None,
            damping_ratio: None,
            friction_coefficient: None,
            contact_point_mm,
            cylinder_axis: default_axis(),
        }
    }

    /// The surface the simulation owns: shape placed so the tool first touches it at
    /// `contact_point_mm`, with the normal there tilted by `tilt_deg` about y.
    pub fn surface(&self) -> Surface {
        let s = self;
        let preset = s.material.material();
        let material = Material {
            stiffness_n_per_mm: s.stiffness_n_per_mm.unwrap_or(preset.stiffness_n_per_mm),
            damping_ratio: s.damping_ratio.unwrap_or(preset.damping_ratio),
            friction_coefficient: s
                .friction_coefficient
                .unwrap_or(preset.friction_coefficient),
        };
        let t = s.tilt_deg.to_radians();
        let n = [t.sin(), 0.0, t.cos()];
        let p = s.contact_point_mm;
        let centre = [
            p[0] - s.radius_mm * n[0],
            p[1] - s.radius_mm * n[1],
            p[2] - s.radius_mm * n[2],
        ];
        let shape = match s.shape {
            ShapeKind::Plane => SurfaceShape::Plane {
                point_mm: p,
                normal: n,
            },
            ShapeKind::Sphere => SurfaceShape::Sphere {
                centre_mm: centre,
                radius_mm: s.radius_mm,
            },
            ShapeKind::Cylinder => SurfaceShape::Cylinder {
                axis_point_mm: centre,
                axis_dir: match s.cylinder_axis {
                    Axis::X => [1.0, 0.0, 0.0],
                    Axis::Y => [0.0, 1.0, 0.0],
                },
                radius_mm: s.radius_mm,
            },
        };
        Surface { shape, material }
    }
}

impl Section for SurfaceConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        check_range(&field("tilt_deg"), self.tilt_deg, -60.0, 60.0, "deg")?;
        check_range(&field("radius_mm"), self.radius_mm, 10.0, 1e5, "mm")?;
        if let Some(k) = self.stiffness_n_per_mm {
            check_range(&field("stiffness_n_per_mm"), k, 0.1, 1e6, "N/mm")?;
        }
        if let Some(z) = self.damping_ratio {
            check_range(&field("damping_ratio"), z, 0.0, 2.0, "")?;
        }
        if let Some(mu) = self.friction_coefficient {
            check_range(&field("friction_coefficient"), mu, 0.0, 2.0, "")?;
        }
        for (i, v) in self.contact_point_mm.iter().enumerate() {
            check_range(
                &field(&format!("contact_point_mm[{i}]")),
                *v,
                -1e4,
                1e4,
                "mm",
            )?;
        }
        Ok(())
    }
}
