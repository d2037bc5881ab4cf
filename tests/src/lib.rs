//! Helpers shared by the behaviour tests: the reference kinematics vectors.

pub mod bins;

use h4_shared::H4Params;
use serde::Deserialize;

/// `tests/data/h4_vectors.json`, copied from the project's checked kinematics
/// (`KINEMATICS.md`, computed at 50 digits by `reference_kin.py`).
#[derive(Debug, Deserialize)]
pub struct Vectors {
    /// Parameter sets by name.
    pub parameter_sets: std::collections::BTreeMap<String, ParamSet>,
    /// Valid poses with their reference values.
    pub valid: Vec<ValidPose>,
    /// Poses a checked IK must reject.
    pub invalid_poses: Vec<InvalidPose>,
    /// Actuator positions the FK must reject.
    pub invalid_fk_inputs: Vec<InvalidFk>,
}

/// One parameter set.
#[derive(Debug, Deserialize)]
pub struct ParamSet {
    /// R, mm.
    #[serde(rename = "R")]
    pub r: f64,
    /// a − b, mm.
    pub a_minus_b: f64,
    /// c, mm.
    pub c: f64,
    /// d, mm.
    pub d: f64,
}

/// A valid pose.
#[derive(Debug, Deserialize)]
pub struct ValidPose {
    /// Parameter set name.
    pub params: String,
    /// Pose.
    pub pose: [f64; 4],
    /// Actuators.
    pub l: [f64; 4],
    /// Jacobian, rows.
    #[serde(rename = "J")]
    pub j: [[f64; 4]; 4],
    /// Inverse Jacobian, rows.
    #[serde(rename = "J_inv")]
    pub j_inv: [[f64; 4]; 4],
    /// Compliance at k = 1 N/mm.
    #[serde(rename = "Lambda_k1")]
    pub lambda_k1: [[f64; 4]; 4],
    /// Stiffness at k = 1 N/mm.
    #[serde(rename = "K_k1")]
    pub k_k1: [[f64; 4]; 4],
    /// Whether this is a C > 0 case.
    #[serde(rename = "fk_C_positive_both_roots_negative")]
    pub c_positive_both_roots_negative: bool,
    /// Optional tag.
    #[serde(default)]
    pub tag: Option<String>,
}

/// A pose to reject.
#[derive(Debug, Deserialize)]
pub struct InvalidPose {
    /// Parameter set name.
    pub params: String,
    /// Pose.
    pub pose: [f64; 4],
    /// Expected reason code.
    pub reason: String,
}

/// FK input to reject.
#[derive(Debug, Deserialize)]
pub struct InvalidFk {
    /// Parameter set name.
    pub params: String,
    /// Actuators.
    pub l: [f64; 4],
    /// Expected reason code.
    pub reason: String,
}

impl Vectors {
    /// Loads the vectors shipped with the tests.
    pub fn load() -> Vectors {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/data/h4_vectors.json");
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("read {path}: {e}"));
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("parse {path}: {e}"))
    }

    /// The parameters of a named set.
    pub fn params(&self, name: &str) -> H4Params {
        let p = &self.parameter_sets[name];
        H4Params::new(p.r, p.a_minus_b, p.c, p.d).unwrap_or_else(|e| panic!("{name}: {e}"))
    }
}
