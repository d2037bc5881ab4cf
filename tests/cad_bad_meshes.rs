//! A cutting session's part from a CAD mesh is read and checked before the run (issue 34):
//! `h4-master sim FILE` refuses a mesh that is open, wound inwards, has a degenerate
//! triangle or a NaN vertex, is over `cut_target.mesh_max_file_bytes`, or does not fit the
//! stock, with the reason and exit code 2, and runs nothing; the good mesh is accepted.
//! The STL files are written by the test into a temporary directory.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use h4_tests::bins::{binaries, workspace};

/// A 10 mm cube's 12 triangles, counter-clockwise seen from outside (its corner at 0).
fn cube() -> Vec<[[f32; 3]; 3]> {
    let c = |i: u8| {
        [
            f32::from(i & 1) * 10.0,
            f32::from((i >> 1) & 1) * 10.0,
            f32::from((i >> 2) & 1) * 10.0,
        ]
    };
    // Corner index: x + 2y + 4z. Each face as two triangles, outward winding.
    let quads: [[u8; 4]; 6] = [
        [0, 2, 3, 1], // bottom (z = 0), normal −z
        [4, 5, 7, 6], // top, +z
        [0, 1, 5, 4], // y = 0, −y
        [2, 6, 7, 3], // y = 10, +y
        [0, 4, 6, 2], // x = 0, −x
        [1, 3, 7, 5], // x = 10, +x
    ];
    let mut t = Vec::new();
    for q in quads {
        t.push([c(q[0]), c(q[1]), c(q[2])]);
        t.push([c(q[0]), c(q[2]), c(q[3])]);
    }
    t
}

/// Binary STL bytes of `tris` (normals written as zero: readers use the winding).
fn stl(tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        for _ in 0..3 {
            b.extend_from_slice(&0f32.to_le_bytes());
        }
        for v in t {
            for x in v {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        b.extend_from_slice(&0u16.to_le_bytes());
    }
    b
}

/// A scratch directory with the session file (`cut-mesh-dome.toml` with its part replaced
/// by `part.stl`, placed in the stock) and `part.stl` holding `tris`.
fn scratch(name: &str, tris: &[[[f32; 3]; 3]]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h4-cad-bad-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let shipped =
        std::fs::read_to_string(workspace().join("config/sessions/cut-mesh-dome.toml")).unwrap();
    let session = shipped
        .replace("mesh = \"../parts/dome-block.stl\"", "mesh = \"part.stl\"")
        .replace(
            "translation_mm = [-15.0, 0.0, -274.5]",
            "translation_mm = [-5.0, -5.0, -275.0]",
        );
    assert!(session.contains("mesh = \"part.stl\"") && session.contains("[-5.0, -5.0, -275.0]"));
    std::fs::write(dir.join("session.toml"), session).unwrap();
    std::fs::write(dir.join("part.stl"), stl(tris)).unwrap();
    dir
}

/// `h4-master sim DIR/session.toml --set EXTRA…`: exit code, stdout, stderr.
fn sim(dir: &Path, extra: &[&str]) -> (i32, String, String) {
    let (master, _) = binaries();
    let mut cmd = Command::new(master);
    cmd.arg("sim").arg(dir.join("session.toml"));
    for s in extra {
        cmd.args(["--set", s]);
    }
    let out = cmd
        .env("H4_PROGRESS", "off")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn refused(name: &str, tris: &[[[f32; 3]; 3]], extra: &[&str], reason: &str) {
    let dir = scratch(name, tris);
    let (code, out, err) = sim(&dir, extra);
    assert_eq!(code, 2, "{name}: exit {code}, stderr {err}");
    assert!(
        out.trim().is_empty(),
        "{name}: nothing run, no summary: {out}"
    );
    assert!(err.contains("cut_target.mesh"), "{name}: {err}");
    assert!(err.contains(reason), "{name}: {err:?} lacks {reason:?}");
    eprintln!("{name}: {}", err.trim());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_meshes_are_refused_with_their_reason_and_exit_2() {
    let good = cube();
    // Open: one triangle missing.
    refused("open", &good[1..], &[], "is not closed");
    // Inverted normals: every triangle wound the other way.
    let inverted: Vec<_> = good.iter().map(|t| [t[0], t[2], t[1]]).collect();
    refused("inverted", &inverted, &[], "normals point inwards");
    // A degenerate triangle: two of its corners the same point.
    let mut degenerate = good.clone();
    degenerate[3][1] = degenerate[3][0];
    refused("degenerate", &degenerate, &[], "is degenerate");
    // A NaN vertex.
    let mut nan = good.clone();
    nan[5][2][1] = f32::NAN;
    refused("nan", &nan, &[], "is not finite");
    // The good cube's 684 bytes over a 600-byte limit.
    refused(
        "too-large",
        &good,
        &["cut_target.mesh_max_file_bytes=600"],
        "over the limit of 600 bytes",
    );
    // Placed half out of the block's top (the block's top is at z = −250 mm).
    refused(
        "does-not-fit",
        &good,
        &["cut_target.translation_mm=[-5.0,-5.0,-255.0]"],
        "does not fit the stock",
    );
}

/// The control: the good cube in the same session runs (a short run: exit 0 or 1, a
/// summary with the mesh target's fields).
#[test]
fn the_good_mesh_is_accepted_and_judged() {
    let dir = scratch("good", &cube());
    let (code, out, err) = sim(&dir, &["duration_s=0.2"]);
    assert!(code == 0 || code == 1, "exit {code}: {err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).expect("a JSON summary");
    for k in [
        "surface_error_p99_mm",
        "gouge_max_mm",
        "material_left_mm3",
        "material_to_remove_mm3",
    ] {
        assert!(v.get(k).is_some(), "{k} missing from {out}");
    }
    // Nothing cut yet in 0.2 s: what is to be removed is all left.
    let left = v["material_left_mm3"].as_f64().unwrap();
    let to_remove = v["material_to_remove_mm3"].as_f64().unwrap();
    assert!(
        to_remove > 0.0 && (left - to_remove).abs() < 1e-6 * to_remove,
        "{left} / {to_remove}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
