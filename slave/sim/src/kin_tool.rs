//! `h4-slave kin`: kinematics for users and scripts, one JSON line in, one JSON line out.
//!
//! Input lines are `{"pose":[x,y,z,theta]}` or `{"l":[l1,l2,l3,l4]}` (mm, rad). For a pose the
//! answer is `{"pose", "l", "J", "J_inv", "compliance", "stiffness"}` (matrices as arrays of
//! rows; compliance in mm/N, mm/(N·mm), rad/N…, stiffness the inverse); for actuator positions
//! `{"l", "pose"}`; for anything rejected `{"error": "<reason>", "detail": "<text>"}` with the
//! reason codes of KINEMATICS.md. Every line gets exactly one answer, in order.
//!
//! With workspace limits (the command's default: the prototype's nominal workspace,
//! [`WorkspaceLimits::default`]) a pose, given or computed, outside them is an error too
//! (`theta_out_of_range`, `near_direct_singularity`, `near_workspace_boundary`,
//! `stroke_limit`), as the controller would refuse it; `--no-workspace-check` gives the bare
//! kinematics.

use std::io::{BufRead, Write};

use h4_shared::{ActuatorStiffness, H4Params, KinError, Workspace, WorkspaceLimits};
use nalgebra::{Matrix4, Vector4};
use serde::Deserialize;
use serde_json::{Value, json};

/// One input line.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Input {
    pose: Option<[f64; 4]>,
    l: Option<[f64; 4]>,
}

fn matrix_rows(m: &Matrix4<f64>) -> Value {
    json!(
        (0..4)
            .map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)], m[(i, 3)]])
            .collect::<Vec<_>>()
    )
}

fn vec4(v: &Vector4<f64>) -> Value {
    json!([v[0], v[1], v[2], v[3]])
}

fn error_line(reason: &str, detail: impl Into<String>) -> Value {
    json!({ "error": reason, "detail": detail.into() })
}

fn kin_error(e: KinError) -> Value {
    error_line(e.reason_code(), e.to_string())
}

/// Answers one input line; with `limits`, poses outside the workspace are refused.
pub fn answer(
    line: &str,
    params: &H4Params,
    k: &ActuatorStiffness,
    limits: Option<&WorkspaceLimits>,
) -> Value {
    let check = |pose: &Vector4<f64>, l: &Vector4<f64>| -> Result<(), KinError> {
        match limits {
            Some(limits) => Workspace {
                params: *params,
                limits: *limits,
            }
            .check(pose, l),
            None => Ok(()),
        }
    };
    let input: Input = match serde_json::from_str(line) {
        Ok(i) => i,
        Err(e) if e.is_data() => return error_line("invalid_input", e.to_string()),
        Err(e) => return error_line("invalid_json", e.to_string()),
    };
    match (input.pose, input.l) {
        (Some(pose), None) => {
            let pose = Vector4::from(pose);
            let result = (|| -> Result<Value, KinError> {
                let l = params.ik_checked(&pose)?;
                check(&pose, &l)?;
                let j = params.jacobian(&pose)?;
                let j_inv = params.jacobian_inverse(&pose)?;
                let compliance = h4_shared::kinematics::compliance_from_inverse(&j_inv, k);
                let stiffness = params.stiffness(&pose, k)?;
                Ok(json!({
                    "pose": vec4(&pose),
                    "l": vec4(&l),
                    "J": matrix_rows(&j),
                    "J_inv": matrix_rows(&j_inv),
                    "compliance": matrix_rows(&compliance),
                    "stiffness": matrix_rows(&stiffness),
                }))
            })();
            result.unwrap_or_else(kin_error)
        }
        (None, Some(l)) => {
            let l = Vector4::from(l);
            match params
                .fk(&l)
                .and_then(|pose| check(&pose, &l).map(|()| pose))
            {
                Ok(pose) => json!({ "l": vec4(&l), "pose": vec4(&pose) }),
                Err(e) => kin_error(e),
            }
        }
        _ => error_line(
            "invalid_input",
            "expected exactly one of {\"pose\":[x,y,z,theta]} or {\"l\":[l1,l2,l3,l4]}",
        ),
    }
}

/// Reads JSON lines from `input` until end of file and writes one answer per line.
pub fn run(
    input: impl BufRead,
    mut output: impl Write,
    params: &H4Params,
    k: &ActuatorStiffness,
    limits: Option<&WorkspaceLimits>,
) -> std::io::Result<()> {
    for line in input.lines() {
        let answer = match line {
            Ok(line) => answer(&line, params, k, limits),
            Err(e) => error_line("invalid_input", e.to_string()),
        };
        writeln!(output, "{answer}")?;
        output.flush()?;
    }
    Ok(())
}

/// Parses `--params`: `prototype`, `alt`, or `R,E,C,D` in mm.
pub fn parse_params(text: &str) -> Result<H4Params, String> {
    match text {
        "prototype" => Ok(H4Params::PROTOTYPE),
        "alt" => Ok(H4Params::ALT),
        other => {
            let parts: Vec<&str> = other.split(',').map(str::trim).collect();
            if parts.len() != 4 {
                return Err(format!(
                    "expected `prototype`, `alt` or R,E,C,D in mm, got `{other}`"
                ));
            }
            let mut v = [0.0; 4];
            for (slot, part) in v.iter_mut().zip(&parts) {
                *slot = part
                    .parse::<f64>()
                    .map_err(|e| format!("`{part}` in --params: {e}"))?;
            }
            H4Params::new(v[0], v[1], v[2], v[3]).map_err(|e| e.to_string())
        }
    }
}
