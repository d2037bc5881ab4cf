//! Helpers shared by the behaviour tests: the reference kinematics vectors; the project's
//! binaries ([`bins`]); the real processes of the process tests ([`procs`]); two hosts on one
//! machine ([`netns`]), a relay that impairs the network between them ([`relay`]), the real
//! processes of the remote tests ([`remote_procs`]) and their recordings ([`record`]).

pub mod netns;
pub mod procs;
pub mod record;
pub mod relay;
pub mod remote_procs;
pub mod stalls;

pub mod bins;

/// Runs `cycles` lockstep cycles of `session` and returns the largest `metric(true pose)`
/// over the cycles whose tool tip is below `below_z_mm` (the tool in the cut); 0 if none.
pub fn max_while_cutting(
    session: &mut h4_master_sim::session::Session,
    cycles: usize,
    below_z_mm: f64,
    metric: impl Fn(&h4_shared::Pose) -> f64,
) -> f64 {
    let mut worst: f64 = 0.0;
    for _ in 0..cycles {
        if let Err(e) = session.cycle() {
            panic!("session cycle: {e}");
        }
        let p = session.slave.arm().true_pose();
        if p[2] < below_z_mm {
            worst = worst.max(metric(&p));
        }
    }
    worst
}

/// The `/slave/cut` records of an MCAP recording (`h4.CutCycle`): how many, and the last one
/// decoded (None: none).
pub fn cut_records(mcap_bytes: &[u8]) -> (usize, Option<serde_json::Value>) {
    let mut count = 0;
    let mut last = None;
    let stream = mcap::MessageStream::new(mcap_bytes).unwrap_or_else(|e| panic!("MCAP: {e}"));
    for m in stream {
        let m = m.unwrap_or_else(|e| panic!("MCAP message: {e}"));
        if m.channel.topic == "/slave/cut" {
            let schema = m.channel.schema.as_ref().map(|s| s.name.as_str());
            assert_eq!(schema, Some("h4.CutCycle"));
            count += 1;
            let record = serde_json::from_slice(&m.data);
            last = Some(record.unwrap_or_else(|e| panic!("/slave/cut record: {e}")));
        }
    }
    (count, last)
}

/// Checks the files `h4-master sim --out DIR` writes for a cutting session (`height.png`,
/// `deviation.png`: PNG; `part.stl`: a binary STL whose length matches its triangle count)
/// and removes `dir`.
pub fn check_cut_outputs(dir: &std::path::Path) {
    for f in ["height.png", "deviation.png"] {
        let b = std::fs::read(dir.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert_eq!(&b[1..4], b"PNG", "{f}");
    }
    let stl = std::fs::read(dir.join("part.stl")).unwrap_or_else(|e| panic!("part.stl: {e}"));
    assert!(stl.len() >= 84, "part.stl: {} bytes", stl.len());
    let n = u32::from_le_bytes([stl[80], stl[81], stl[82], stl[83]]) as usize;
    assert_eq!(stl.len(), 84 + 50 * n);
    std::fs::remove_dir_all(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
}

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

/// One line on stderr of a mesh session's figures (the cad_mesh tests print them).
pub fn report_mesh_cut(label: &str, s: &h4_master_sim::session::Summary) {
    let Some(c) = s.cutting.as_ref() else {
        eprintln!("{label}: not a cutting session");
        return;
    };
    eprintln!(
        "{label}: stable {} ({} bounces), true force max {:.1} N, removed {:.1} mm³, \
         gouge {:.3} mm, surface error p99 {:.3} mm, material left {:.1} of {:.1} mm³ \
         ({:.1} %), fixture-limited cycles {}",
        s.stable,
        s.bounces,
        s.max_force_n,
        c.removed_volume_mm3,
        c.gouge_max_mm,
        c.surface_error_p99_mm,
        c.material_left_mm3.unwrap_or(f64::NAN),
        c.material_to_remove_mm3.unwrap_or(f64::NAN),
        100.0 * c.material_left_mm3.unwrap_or(f64::NAN)
            / c.material_to_remove_mm3.unwrap_or(f64::NAN),
        c.fixture_limited_cycles,
    );
}
