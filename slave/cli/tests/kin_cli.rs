//! `h4-slave kin` as a process: answers every line in order, never crashes, and reports
//! the reason codes of KINEMATICS.md.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::Write;
use std::process::{Command, Stdio};

fn run_kin(args: &[&str], input: &str) -> (Vec<serde_json::Value>, bool) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_h4-slave"))
        .arg("kin")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn h4-slave");
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(input.as_bytes())
        .expect("write");
    let out = child.wait_with_output().expect("wait");
    let lines = String::from_utf8(out.stdout)
        .expect("utf8")
        .lines()
        .map(|l| serde_json::from_str(l).expect("every answer is JSON"))
        .collect();
    (lines, out.status.success())
}

#[test]
fn answers_every_line_in_order() {
    let input = concat!(
        "{\"pose\":[0,0,-300,0]}\n",
        "{\"l\":[222.6005390829052,-222.6005390829052,222.6005390829052,-222.6005390829052]}\n",
        "this is not json\n",
        "{\"pose\":[0,0,-380,0]}\n",
        "{\"pose\":[0,0,100,0]}\n",
        "{\"pose\":[0,0,-300,2.0]}\n",
        "{\"l\":[100,-100,0,-200]}\n",
        "{\"l\":[395,-395,395,-395]}\n",
        "{\"l\":[-293.77064244578264,301.7174156775851,241.89278691160945,-249.83956014341192]}\n",
        "{\"pose\":[1,2,3]}\n",
        "\n",
        "{\"pose\":[0,0,-300,0],\"l\":[1,2,3,4]}\n",
    );
    let (lines, ok) = run_kin(&["--stiffness", "2"], input);
    assert!(ok);
    assert_eq!(lines.len(), 12);
    let first = &lines[0];
    let keys: Vec<&str> = first
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(keys, ["pose", "l", "J", "J_inv", "compliance", "stiffness"]);
    // Λ_11 = 1/(4k) and K_11 = 4k with k = 2 N/mm.
    assert!((first["compliance"][0][0].as_f64().unwrap() - 0.125).abs() < 1e-12);
    assert!((first["stiffness"][0][0].as_f64().unwrap() - 8.0).abs() < 1e-12);
    let z = lines[1]["pose"][2].as_f64().unwrap();
    assert!((z + 300.0).abs() < 1e-9, "{}", lines[1]);
    let reasons: Vec<&str> = lines[2..]
        .iter()
        .map(|l| l["error"].as_str().unwrap_or("-"))
        .collect();
    assert_eq!(
        reasons,
        [
            "invalid_json",
            "sqrt_negative",
            "wrong_assembly_mode",
            "theta_out_of_range",
            "r1_minus_r2_exceeds_2c",
            "discriminant_negative",
            "negative_d",
            "invalid_input",
            "invalid_json",
            "invalid_input",
        ]
    );
    assert!(lines[3]["detail"].as_str().unwrap().contains("leg pair"));
}

/// The workspace is checked (the controller would refuse these poses); the bare kinematics
/// answer them with `--no-workspace-check`.
#[test]
fn poses_outside_the_workspace_are_refused_unless_asked() {
    let input = concat!(
        "{\"pose\":[2000,0,-250,0]}\n",
        "{\"pose\":[0,0,-250,1.5]}\n",
        "{\"pose\":[10,50,-250,0.349]}\n",
    );
    let (lines, ok) = run_kin(&[], input);
    assert!(ok);
    let reasons: Vec<&str> = lines
        .iter()
        .map(|l| l["error"].as_str().unwrap_or("-"))
        .collect();
    assert_eq!(
        reasons,
        ["stroke_limit", "theta_out_of_range", "-"],
        "{lines:?}"
    );
    let (bare, ok) = run_kin(&["--no-workspace-check"], input);
    assert!(ok);
    assert!(bare.iter().all(|l| l["l"].is_array()), "{bare:?}");
    // An FK answer outside the workspace is refused the same way.
    let l = bare[0]["l"].to_string();
    let (fk, _) = run_kin(&[], &format!("{{\"l\":{l}}}\n"));
    assert_eq!(fk[0]["error"], "stroke_limit", "{fk:?}");
}

#[test]
fn custom_parameters_and_bad_flags() {
    let (lines, ok) = run_kin(
        &["--params", "300,100,15,25"],
        "{\"pose\":[0,0,-300,0]}\n{\"pose\":[0,0,-200,0]}\n",
    );
    assert!(ok);
    assert_eq!(lines[0]["error"], "sqrt_negative");
    assert!(lines[1]["l"].is_array());
    let out = Command::new(env!("CARGO_BIN_EXE_h4-slave"))
        .args(["kin", "--params", "400,0,20,20"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("parameter e"));
}
