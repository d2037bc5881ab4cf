//! H-4 family kinematics, statics and compliance, in the corrected forms of
//! `KINEMATICS.md` (see `docs/kinematics.md` in this repository).
//!
//! Units: mm, rad, N, N·mm. A pose is `[x, y, z, theta]` (theta about y); actuator
//! positions are `[l1, l2, l3, l4]`, signed coordinates along the rails with the same
//! origin as x. `J[i][j] = d l_i / d P_j`. A wrench is `[Fx, Fy, Fz, My]` (N, N, N, N·mm)
//! and `delta = compliance · wrench` is `[dx, dy, dz, dtheta]` (mm, mm, mm, rad).
//!
//! Everything here is fixed-size, allocation-free and panic-free: every function returns
//! a `Result` whose error is `Copy` and names the limit that was hit and by how much.

use nalgebra::{Matrix4, Vector4};
use serde::{Deserialize, Serialize};

/// Platform pose `[x_mm, y_mm, z_mm, theta_rad]`.
pub type Pose = Vector4<f64>;
/// Actuator positions `[l1, l2, l3, l4]` in mm.
pub type Actuators = Vector4<f64>;
/// Wrench at the platform `[Fx_n, Fy_n, Fz_n, My_n_mm]`.
pub type Wrench = Vector4<f64>;

/// Why a pose or a set of actuator positions was rejected.
///
/// The first six variants carry the reason codes of `KINEMATICS.md`
/// ([`KinError::reason_code`]); the rest are the configurable workspace limits.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum KinError {
    /// An input coordinate is NaN or infinite.
    #[error("input {index} is not a finite number")]
    NonFinite {
        /// Index of the offending component.
        index: u8,
    },
    /// `R² − y_i² − z_i² < 0`: the pose is out of reach of leg pair `pair`.
    #[error("leg pair {pair} cannot reach: R^2 - y^2 - z^2 = {radicand_mm2:.6} mm^2 < 0")]
    SqrtNegative {
        /// Leg pair, 1 (actuators 1, 2) or 2 (actuators 3, 4).
        pair: u8,
        /// The negative radicand, mm².
        radicand_mm2: f64,
    },
    /// `e z + h y ≥ 0`: the pose belongs to the other assembly mode (or lies on the
    /// direct singularity); the forward kinematics would return its mirror image.
    #[error(
        "pose is in the wrong assembly mode: signed distance from the singular line is {distance_mm:.6} mm (must be > 0)"
    )]
    WrongAssemblyMode {
        /// Signed distance from the singular line `e z + h y = 0`, mm; positive in the working mode.
        distance_mm: f64,
    },
    /// |theta| exceeds the limit (π/2 mathematically, or the configured workspace limit).
    #[error("|theta| = {theta_rad:.6} rad exceeds the limit {limit_rad:.6} rad by {:.6} rad", .theta_rad.abs() - .limit_rad)]
    ThetaOutOfRange {
        /// The requested or computed theta, rad.
        theta_rad: f64,
        /// The limit that was exceeded, rad.
        limit_rad: f64,
    },
    /// `|r1 − r2| ≥ 2c`: no platform rotation matches the actuator positions.
    #[error("|r1 - r2| = {r1_minus_r2_mm:.6} mm reaches 2c = {two_c_mm:.6} mm")]
    R1MinusR2ExceedsTwoC {
        /// `r1 − r2`, mm.
        r1_minus_r2_mm: f64,
        /// `2c`, mm.
        two_c_mm: f64,
    },
    /// The forward kinematics quadratic has no real root: the actuator positions are incompatible.
    #[error("forward kinematics discriminant B^2 - 4AC = {discriminant:.6e} < 0")]
    DiscriminantNegative {
        /// The negative discriminant, mm⁴ scale.
        discriminant: f64,
    },
    /// `l1 < l2` or `l3 < l4`, contradicting the + root of the inverse kinematics.
    #[error("l{} < l{} for leg pair {pair}: slider spread {d_mm:.6} mm is negative", 2 * .pair - 1, 2 * .pair)]
    NegativeD {
        /// Leg pair, 1 or 2.
        pair: u8,
        /// `l1 − l2` or `l3 − l4`, mm.
        d_mm: f64,
    },
    /// The pose is closer to the direct singularity than the workspace allows.
    #[error(
        "distance from the singular line {distance_mm:.3} mm is below the minimum {min_mm:.3} mm by {:.3} mm", .min_mm - .distance_mm
    )]
    NearDirectSingularity {
        /// Distance from the singular line, mm.
        distance_mm: f64,
        /// Configured minimum, mm.
        min_mm: f64,
    },
    /// A leg pair is closer to perpendicular to its rail than the workspace allows
    /// (`s_i = sqrt(R² − y_i² − z_i²)` too small: the IK singularity at the lens edge).
    #[error(
        "leg pair {pair}: rail clearance {clearance_mm:.3} mm is below the minimum {min_mm:.3} mm by {:.3} mm", .min_mm - .clearance_mm
    )]
    NearBoundary {
        /// Leg pair, 1 or 2.
        pair: u8,
        /// `s_i`, mm.
        clearance_mm: f64,
        /// Configured minimum, mm.
        min_mm: f64,
    },
    /// An actuator would leave its stroke.
    #[error(
        "actuator l{actuator} = {position_mm:.3} mm is outside its stroke [{min_mm:.3}, {max_mm:.3}] mm by {:.3} mm",
        outside_by(*.position_mm, *.min_mm, *.max_mm)
    )]
    StrokeLimit {
        /// Actuator number, 1 to 4.
        actuator: u8,
        /// The position that was asked for, mm.
        position_mm: f64,
        /// Stroke minimum, mm.
        min_mm: f64,
        /// Stroke maximum, mm.
        max_mm: f64,
    },
    /// A parameter set that describes no mechanism.
    #[error("invalid kinematic parameter {name}: {value} ({requirement})")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f64,
        /// What it must satisfy.
        requirement: &'static str,
    },
}

impl KinError {
    /// The machine-readable reason code (the codes of `KINEMATICS.md` where one applies).
    pub fn reason_code(&self) -> &'static str {
        match self {
            KinError::NonFinite { .. } => "non_finite",
            KinError::SqrtNegative { .. } => "sqrt_negative",
            KinError::WrongAssemblyMode { .. } => "wrong_assembly_mode",
            KinError::ThetaOutOfRange { .. } => "theta_out_of_range",
            KinError::R1MinusR2ExceedsTwoC { .. } => "r1_minus_r2_exceeds_2c",
            KinError::DiscriminantNegative { .. } => "discriminant_negative",
            KinError::NegativeD { .. } => "negative_d",
            KinError::NearDirectSingularity { .. } => "near_direct_singularity",
            KinError::NearBoundary { .. } => "near_workspace_boundary",
            KinError::StrokeLimit { .. } => "stroke_limit",
            KinError::InvalidParameter { .. } => "invalid_parameter",
        }
    }
}

/// Geometry of one H-4 family arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct H4Params {
    /// Leg length R, mm.
    pub leg_length_mm: f64,
    /// Footprint minus platform size, e = a − b, mm (must not be 0).
    pub e_mm: f64,
    /// Platform size c, mm (half the B12–B34 separation in the xz plane).
    pub c_mm: f64,
    /// Platform size d, mm.
    pub d_mm: f64,
}

impl H4Params {
    /// The paper's prototype: R 400 mm, a − b 143 mm, c = d = 20 mm.
    pub const PROTOTYPE: H4Params = H4Params {
        leg_length_mm: 400.0,
        e_mm: 143.0,
        c_mm: 20.0,
        d_mm: 20.0,
    };

    /// The second parameter set of the reference vectors: R 300, e 100, c 15, d 25 mm.
    pub const ALT: H4Params = H4Params {
        leg_length_mm: 300.0,
        e_mm: 100.0,
        c_mm: 15.0,
        d_mm: 25.0,
    };

    /// A checked parameter set.
    pub fn new(leg_length_mm: f64, e_mm: f64, c_mm: f64, d_mm: f64) -> Result<Self, KinError> {
        let p = H4Params {
            leg_length_mm,
            e_mm,
            c_mm,
            d_mm,
        };
        p.validate()?;
        Ok(p)
    }

    /// What [`H4Params::validate`] requires of each parameter: its symbol, its field and the
    /// requirement in words, in the order they are checked.
    pub const RULES: [(&'static str, &'static str, &'static str); 4] = [
        ("R", "leg_length_mm", "must be finite and > 0"),
        ("e", "e_mm", "must be finite, non-zero and |e| < R"),
        ("c", "c_mm", "must be finite and > 0"),
        ("d", "d_mm", "must be finite and >= 0"),
    ];

    /// Checks that the parameters describe a mechanism the formulas can handle.
    pub fn validate(&self) -> Result<(), KinError> {
        let values = [self.leg_length_mm, self.e_mm, self.c_mm, self.d_mm];
        let oks = [
            self.leg_length_mm > 0.0,
            self.e_mm != 0.0 && self.e_mm.abs() < self.leg_length_mm,
            self.c_mm > 0.0,
            self.d_mm >= 0.0,
        ];
        for (((name, _, requirement), value), ok) in Self::RULES.into_iter().zip(values).zip(oks) {
            if !value.is_finite() || !ok {
                return Err(KinError::InvalidParameter {
                    name,
                    value,
                    requirement,
                });
            }
        }
        Ok(())
    }

    fn aux(&self, pose: &Pose) -> Result<Aux, KinError> {
        check_finite(pose)?;
        let (x, y, z, th) = (pose[0], pose[1], pose[2], pose[3]);
        let (r, e, c, d) = (self.leg_length_mm, self.e_mm, self.c_mm, self.d_mm);
        let (sin_th, cos_th) = th.sin_cos();
        let y1 = y - e;
        let z1 = z + c * cos_th - d;
        let y2 = y + e;
        let z2 = z - c * cos_th + d;
        let q1 = r * r - y1 * y1 - z1 * z1;
        let q2 = r * r - y2 * y2 - z2 * z2;
        if q1 < 0.0 {
            return Err(KinError::SqrtNegative {
                pair: 1,
                radicand_mm2: q1,
            });
        }
        if q2 < 0.0 {
            return Err(KinError::SqrtNegative {
                pair: 2,
                radicand_mm2: q2,
            });
        }
        Ok(Aux {
            x1: x + c * sin_th,
            y1,
            z1,
            x2: x - c * sin_th,
            y2,
            z2,
            s1: q1.sqrt(),
            s2: q2.sqrt(),
            sin_th,
            cos_th,
        })
    }

    /// `h = c cos(theta) − d`, mm.
    fn h_mm(&self, cos_th: f64) -> f64 {
        self.c_mm * cos_th - self.d_mm
    }

    /// Signed distance of a pose from the direct singular line `e z + h y = 0`, mm;
    /// positive in the working assembly mode.
    pub fn singular_distance_mm(&self, pose: &Pose) -> f64 {
        let h = self.h_mm(pose[3].cos());
        -(self.e_mm * pose[2] + h * pose[1]) / (self.e_mm * self.e_mm + h * h).sqrt()
    }

    /// Inverse kinematics, eqs. 1–4 exactly: rejects only non-finite input and poses no
    /// leg can reach (`sqrt_negative`). Use [`H4Params::ik_checked`] or a [`Workspace`]
    /// for commands.
    pub fn ik_raw(&self, pose: &Pose) -> Result<Actuators, KinError> {
        let a = self.aux(pose)?;
        Ok(Vector4::new(
            a.x1 + a.s1,
            a.x1 - a.s1,
            a.x2 + a.s2,
            a.x2 - a.s2,
        ))
    }

    /// Inverse kinematics of a pose the forward kinematics maps back to itself: rejects
    /// `sqrt_negative`, `theta_out_of_range` (|theta| ≥ π/2) and `wrong_assembly_mode`
    /// (`e z + h y ≥ 0`).
    pub fn ik_checked(&self, pose: &Pose) -> Result<Actuators, KinError> {
        let l = self.ik_raw(pose)?;
        let theta = pose[3];
        if theta.abs() >= core::f64::consts::FRAC_PI_2 {
            return Err(KinError::ThetaOutOfRange {
                theta_rad: theta,
                limit_rad: core::f64::consts::FRAC_PI_2,
            });
        }
        let distance_mm = self.singular_distance_mm(pose);
        if distance_mm <= 0.0 {
            return Err(KinError::WrongAssemblyMode { distance_mm });
        }
        Ok(l)
    }

    /// Closed-form forward kinematics with the corrected branch choices: theta from
    /// `r1 − r2`, the minus root for z in its numerically stable form. Rejects
    /// `negative_d`, `r1_minus_r2_exceeds_2c` and `discriminant_negative`.
    pub fn fk(&self, l: &Actuators) -> Result<Pose, KinError> {
        check_finite(l)?;
        let (r, e, c, d) = (self.leg_length_mm, self.e_mm, self.c_mm, self.d_mm);
        let r1 = 0.5 * (l[0] + l[1]);
        let r2 = 0.5 * (l[2] + l[3]);
        let d1 = l[0] - l[1];
        let d2 = l[2] - l[3];
        if d1 < 0.0 {
            return Err(KinError::NegativeD { pair: 1, d_mm: d1 });
        }
        if d2 < 0.0 {
            return Err(KinError::NegativeD { pair: 2, d_mm: d2 });
        }
        let w = r1 - r2;
        let rad = 4.0 * c * c - w * w;
        if rad <= 0.0 {
            return Err(KinError::R1MinusR2ExceedsTwoC {
                r1_minus_r2_mm: w,
                two_c_mm: 2.0 * c,
            });
        }
        let sq = rad.sqrt(); // 2 c cos(theta)
        let theta = w.atan2(sq);
        let x = 0.5 * (r1 + r2);
        let s = sq - 2.0 * d; // 2h
        let dd = d1 * d1 - d2 * d2;
        let e2 = e * e;
        let a = s * s / (2.0 * e2) + 2.0;
        let b = dd * s / (8.0 * e2);
        let cc = (d1 * d1 + d2 * d2) / 4.0 - 2.0 * r * r
            + 2.0 * e2
            + s * s / 2.0
            + dd * dd / (128.0 * e2);
        let disc = b * b - 4.0 * a * cc;
        if disc < 0.0 {
            return Err(KinError::DiscriminantNegative { discriminant: disc });
        }
        let sd = disc.sqrt();
        let z = if b >= 0.0 {
            (-b - sd) / (2.0 * a)
        } else {
            (2.0 * cc) / (-b + sd)
        };
        let y = (dd + 8.0 * z * s) / (16.0 * e);
        let pose = Vector4::new(x, y, z, theta);
        check_finite(&pose)?;
        Ok(pose)
    }

    /// Analytic Jacobian `J[i][j] = d l_i / d P_j` (theta column in mm/rad). Fails where a
    /// leg pair is perpendicular to its rail (`s_i = 0`), where J is unbounded.
    pub fn jacobian(&self, pose: &Pose) -> Result<Matrix4<f64>, KinError> {
        let a = self.aux(pose)?;
        for (pair, s) in [(1u8, a.s1), (2u8, a.s2)] {
            if s <= 0.0 {
                return Err(KinError::NearBoundary {
                    pair,
                    clearance_mm: s,
                    min_mm: 0.0,
                });
            }
        }
        let c = self.c_mm;
        let (ct, st) = (a.cos_th, a.sin_th);
        let (u1, v1) = (a.y1 / a.s1, a.z1 / a.s1);
        let (u2, v2) = (a.y2 / a.s2, a.z2 / a.s2);
        Ok(Matrix4::new(
            1.0,
            -u1,
            -v1,
            c * ct + c * st * v1,
            1.0,
            u1,
            v1,
            c * ct - c * st * v1,
            1.0,
            -u2,
            -v2,
            -c * ct - c * st * v2,
            1.0,
            u2,
            v2,
            -c * ct + c * st * v2,
        ))
    }

    /// Closed-form `J⁻¹ = dP/dl` (rows x, y, z, theta), finite even where `s_i = 0`.
    /// Fails on the direct singularity and where `cos(theta) ≤ 0`.
    pub fn jacobian_inverse(&self, pose: &Pose) -> Result<Matrix4<f64>, KinError> {
        let a = self.aux(pose)?;
        if a.cos_th <= 0.0 {
            return Err(KinError::ThetaOutOfRange {
                theta_rad: pose[3],
                limit_rad: core::f64::consts::FRAC_PI_2,
            });
        }
        let delta = a.y1 * a.z2 - a.y2 * a.z1; // = -2 (e z + h y)
        if delta == 0.0 || !delta.is_finite() {
            return Err(KinError::WrongAssemblyMode {
                distance_mm: self.singular_distance_mm(pose),
            });
        }
        let t = a.sin_th / a.cos_th;
        let (y1, z1, y2, z2, s1, s2) = (a.y1, a.z1, a.y2, a.z2, a.s1, a.s2);
        let g = y1 * z2 + y2 * z1;
        let zz = z1 * z2 * t;
        let k = 1.0 / (4.0 * self.c_mm * a.cos_th);
        let inv = Matrix4::new(
            0.25,
            0.25,
            0.25,
            0.25,
            (-z2 * s1 + zz) / (2.0 * delta),
            (z2 * s1 + zz) / (2.0 * delta),
            (z1 * s2 - zz) / (2.0 * delta),
            (-z1 * s2 - zz) / (2.0 * delta),
            (y2 * s1 / 2.0 - g * t / 4.0) / delta,
            (-y2 * s1 / 2.0 - g * t / 4.0) / delta,
            (-y1 * s2 / 2.0 + g * t / 4.0) / delta,
            (y1 * s2 / 2.0 + g * t / 4.0) / delta,
            k,
            k,
            -k,
            -k,
        );
        Ok(inv)
    }

    /// Cartesian stiffness `K = Jᵀ k J` (eq. 10) for per-actuator stiffness `k`.
    pub fn stiffness(&self, pose: &Pose, k: &ActuatorStiffness) -> Result<Matrix4<f64>, KinError> {
        let j = self.jacobian(pose)?;
        let kj = Matrix4::from_diagonal(&k.n_per_mm) * j;
        Ok(j.transpose() * kj)
    }

    /// Compliance `Λ = J⁻¹ k⁻¹ J⁻ᵀ` (eq. 11 with the corrected τ = J⁻¹): `delta = Λ F`.
    pub fn compliance(&self, pose: &Pose, k: &ActuatorStiffness) -> Result<Matrix4<f64>, KinError> {
        let inv = self.jacobian_inverse(pose)?;
        Ok(compliance_from_inverse(&inv, k))
    }
}

/// `Λ = J⁻¹ diag(1/k) J⁻ᵀ` from an already computed `J⁻¹`.
pub fn compliance_from_inverse(
    jacobian_inverse: &Matrix4<f64>,
    k: &ActuatorStiffness,
) -> Matrix4<f64> {
    let scaled = jacobian_inverse * Matrix4::from_diagonal(&k.compliance_mm_per_n());
    scaled * jacobian_inverse.transpose()
}

/// Axial stiffness of each actuator and its drive train, N/mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActuatorStiffness {
    /// Stiffness of actuators 1–4, N/mm; each must be finite and > 0.
    pub n_per_mm: Vector4<f64>,
}

impl ActuatorStiffness {
    /// The same stiffness on all four actuators.
    pub fn uniform(k_n_per_mm: f64) -> Result<Self, KinError> {
        Self::per_actuator([k_n_per_mm; 4])
    }

    /// A stiffness per actuator.
    pub fn per_actuator(k_n_per_mm: [f64; 4]) -> Result<Self, KinError> {
        for k in k_n_per_mm {
            if !(k.is_finite() && k > 0.0) {
                return Err(KinError::InvalidParameter {
                    name: "actuator stiffness",
                    value: k,
                    requirement: "must be finite and > 0 N/mm",
                });
            }
        }
        Ok(ActuatorStiffness {
            n_per_mm: Vector4::from(k_n_per_mm),
        })
    }

    /// `1/k` per actuator, mm/N.
    pub fn compliance_mm_per_n(&self) -> Vector4<f64> {
        self.n_per_mm.map(|k| 1.0 / k)
    }
}

/// The limits of the usable workspace, on top of the mathematical validity of a pose.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct WorkspaceLimits {
    /// Largest |theta| allowed, rad (must be < π/2).
    pub theta_max_rad: f64,
    /// Smallest distance from the direct singular line `e z + h y = 0`, mm.
    pub min_singular_distance_mm: f64,
    /// Smallest rail clearance `s_i = sqrt(R² − y_i² − z_i²)` of each leg pair, mm
    /// (keeps the legs away from perpendicular to the rail, where J is unbounded).
    pub min_rail_clearance_mm: f64,
    /// Lowest position of each actuator on its rail, mm.
    pub stroke_min_mm: [f64; 4],
    /// Highest position of each actuator on its rail, mm.
    pub stroke_max_mm: [f64; 4],
}

impl Default for WorkspaceLimits {
    /// The nominal workspace of `KINEMATICS.md` for the prototype: |theta| ≤ 60°,
    /// ≥ 10 mm from the singular line, rail clearance ≥ 0.05 R, and a stroke that
    /// covers |x| ≤ 200 mm.
    fn default() -> Self {
        WorkspaceLimits {
            theta_max_rad: 60f64.to_radians(),
            min_singular_distance_mm: 10.0,
            min_rail_clearance_mm: 20.0,
            stroke_min_mm: [-650.0; 4],
            stroke_max_mm: [650.0; 4],
        }
    }
}

/// An arm's geometry together with its workspace limits: the check every command passes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workspace {
    /// Geometry.
    pub params: H4Params,
    /// Limits.
    pub limits: WorkspaceLimits,
}

impl Workspace {
    /// Inverse kinematics of a pose that lies inside the workspace; the error says which
    /// limit the pose violates and by how much.
    pub fn ik(&self, pose: &Pose) -> Result<Actuators, KinError> {
        let l = self.params.ik_checked(pose)?;
        self.check(pose, &l)?;
        Ok(l)
    }

    /// Checks a pose and its actuator positions against the limits.
    pub fn check(&self, pose: &Pose, l: &Actuators) -> Result<(), KinError> {
        let lim = &self.limits;
        let theta = pose[3];
        if theta.abs() > lim.theta_max_rad {
            return Err(KinError::ThetaOutOfRange {
                theta_rad: theta,
                limit_rad: lim.theta_max_rad,
            });
        }
        let distance_mm = self.params.singular_distance_mm(pose);
        if distance_mm < lim.min_singular_distance_mm {
            return Err(KinError::NearDirectSingularity {
                distance_mm,
                min_mm: lim.min_singular_distance_mm,
            });
        }
        for pair in 0..2usize {
            let clearance_mm = 0.5 * (l[2 * pair] - l[2 * pair + 1]);
            if clearance_mm < lim.min_rail_clearance_mm {
                return Err(KinError::NearBoundary {
                    pair: pair as u8 + 1,
                    clearance_mm,
                    min_mm: lim.min_rail_clearance_mm,
                });
            }
        }
        for i in 0..4usize {
            if !(lim.stroke_min_mm[i]..=lim.stroke_max_mm[i]).contains(&l[i]) {
                return Err(KinError::StrokeLimit {
                    actuator: i as u8 + 1,
                    position_mm: l[i],
                    min_mm: lim.stroke_min_mm[i],
                    max_mm: lim.stroke_max_mm[i],
                });
            }
        }
        Ok(())
    }
}

fn outside_by(value: f64, min: f64, max: f64) -> f64 {
    if value < min {
        min - value
    } else {
        value - max
    }
}

struct Aux {
    x1: f64,
    y1: f64,
    z1: f64,
    x2: f64,
    y2: f64,
    z2: f64,
    s1: f64,
    s2: f64,
    sin_th: f64,
    cos_th: f64,
}

fn check_finite(v: &Vector4<f64>) -> Result<(), KinError> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(KinError::NonFinite { index: index as u8 }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn home_pose_round_trips() {
        let p = H4Params::PROTOTYPE;
        let pose = Vector4::new(0.0, 0.0, -300.0, 0.0);
        let l = p.ik_checked(&pose).unwrap();
        let back = p.fk(&l).unwrap();
        assert!((back - pose).norm() < 1e-9, "{back:?}");
    }

    #[test]
    fn x_is_decoupled_in_compliance() {
        let p = H4Params::PROTOTYPE;
        let pose = Vector4::new(10.0, 50.0, -250.0, 20f64.to_radians());
        let lam = p
            .compliance(&pose, &ActuatorStiffness::uniform(2.0).unwrap())
            .unwrap();
        assert!((lam[(0, 0)] - 1.0 / 8.0).abs() < 1e-12);
        for j in 1..4 {
            assert!(lam[(0, j)].abs() < 1e-12);
        }
        // KINEMATICS.md: Lambda_24 = +8.45e-3 for k = 1 (the paper's sign is wrong).
        let lam1 = p
            .compliance(&pose, &ActuatorStiffness::uniform(1.0).unwrap())
            .unwrap();
        assert!((lam1[(1, 3)] - 8.45e-3).abs() < 1e-5, "{}", lam1[(1, 3)]);
        assert!((lam1[(2, 3)] - 1.71e-3).abs() < 1e-5, "{}", lam1[(2, 3)]);
    }

    #[test]
    fn nan_is_rejected_not_propagated() {
        let p = H4Params::PROTOTYPE;
        let pose = Vector4::new(0.0, f64::NAN, -300.0, 0.0);
        assert_eq!(p.ik_raw(&pose), Err(KinError::NonFinite { index: 1 }));
        assert!(p.fk(&Vector4::new(f64::INFINITY, 0.0, 0.0, 0.0)).is_err());
        assert!(
            p.compliance(&pose, &ActuatorStiffness::uniform(1.0).unwrap())
                .is_err()
        );
    }

    #[test]
    fn workspace_errors_say_by_how_much() {
        let ws = Workspace {
            params: H4Params::PROTOTYPE,
            limits: WorkspaceLimits::default(),
        };
        let err = ws.ik(&Vector4::new(0.0, 0.0, -300.0, 1.2)).unwrap_err();
        assert_eq!(err.reason_code(), "theta_out_of_range");
        let text = err.to_string();
        assert!(text.contains("by 0.152"), "{text}");
        let err = ws.ik(&Vector4::new(0.0, 0.0, -5.0, 0.0)).unwrap_err();
        assert_eq!(err.reason_code(), "near_direct_singularity");
        assert!(err.to_string().contains("by 5.000"), "{err}");
    }

    #[test]
    fn bad_parameters_are_named() {
        let err = H4Params::new(400.0, 0.0, 20.0, 20.0).unwrap_err();
        assert!(err.to_string().contains("parameter e"), "{err}");
        assert!(H4Params::new(f64::NAN, 143.0, 20.0, 20.0).is_err());
    }
}
