//! A mesh session's part in its report (issue 34): `sim --out DIR` of `cut-mesh-dome.toml`
//! writes the cut part (`part.stl`), the deviation map against the mesh (`deviation.png`)
//! and the cutting fields (`cut.json`, the mesh judge's among them); `report --part DIR`
//! puts the judge's figures in `metrics.json` and `index.html` (as `cut/<field>`, the same
//! numbers as the summary's), embeds the deviation map and links the STL. Control: a part
//! folder without `cut.json` is an error naming it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session;
use h4_slave_sim::report::{ReportOptions, report};
use h4_telemetry::recording::Recorder;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("h4-cad-report-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn the_report_shows_the_mesh_judges_figures_and_the_deviation_map() {
    let dir = tmp("dome");
    let file =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-mesh-dome.toml");
    // The first three raster lines: enough to cut the part and judge it.
    let cfg = session::load(&file, &["duration_s=12".to_string()]).unwrap();
    let rec_path = dir.join("session.mcap");
    let part = dir.join("part");
    let mut rec = Recorder::create(&rec_path).unwrap();
    let s = session::run_with_outputs(&cfg, Some(&mut rec), Some(&part)).unwrap();
    rec.finish().unwrap();
    let c = s.cutting.as_ref().expect("cutting fields");
    for f in ["part.stl", "deviation.png", "height.png", "cut.json"] {
        let len = std::fs::metadata(part.join(f)).unwrap().len();
        assert!(len > 100, "{f}: {len} bytes");
    }
    let out_dir = dir.join("report");
    let out = report(
        &rec_path,
        &ReportOptions {
            out_dir: out_dir.clone(),
            tolerance_n: 1.0,
            part_dir: Some(part.clone()),
        },
    )
    .unwrap();
    assert!(out.figures.iter().any(|f| f == "deviation.png"), "{out:?}");
    assert!(out.figures.iter().any(|f| f == "forces.png"), "{out:?}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("metrics.json")).unwrap())
            .unwrap();
    // The same numbers as the summary's (JSON's text to 1e-12 of the value).
    let m = |k: &str| metrics[format!("cut/{k}")].as_f64().unwrap_or(f64::NAN);
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
    let fields = [
        ("surface_error_p99_mm", c.surface_error_p99_mm),
        ("gouge_max_mm", c.gouge_max_mm),
        ("material_left_mm3", c.material_left_mm3.unwrap()),
        ("material_to_remove_mm3", c.material_to_remove_mm3.unwrap()),
        ("removed_volume_mm3", c.removed_volume_mm3),
    ];
    for (k, v) in fields {
        assert!(same(m(k), v), "{k}: {} against {v}; {metrics:#}", m(k));
    }
    assert!(c.removed_volume_mm3 > 10.0, "nothing cut: {c:?}");
    let html = std::fs::read_to_string(out_dir.join("index.html")).unwrap();
    assert!(html.contains("<img src=\"deviation.png\""), "{html}");
    assert!(html.contains("<a href=\"part.stl\">"), "{html}");
    assert!(html.contains("cut/surface_error_p99_mm"), "{html}");
    for f in ["deviation.png", "part.stl"] {
        assert_eq!(
            std::fs::read(out_dir.join(f)).unwrap(),
            std::fs::read(part.join(f)).unwrap(),
            "{f}"
        );
    }
    // Control: a folder with no cutting fields is refused, naming the file.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let err = report(
        &rec_path,
        &ReportOptions {
            out_dir: dir.join("report2"),
            tolerance_n: 1.0,
            part_dir: Some(empty),
        },
    )
    .unwrap_err();
    assert!(err.to_string().contains("cut.json"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
