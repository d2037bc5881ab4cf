//! Refusals (each against the intact mesh as its control) and distance queries against
//! analytic shapes (a cube, a sphere mesh), and the query's allocation count.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_part::shapes::{MeshBuilder, revolve};
use h4_part::{LoadOptions, Part, PartError, Placement, StockBox};

#[global_allocator]
static GLOBAL: h4_shared::alloc_count::CountingAllocator =
    h4_shared::alloc_count::CountingAllocator;

/// A cube of side `s` mm with a corner at the origin, 12 outward triangles.
fn cube(s: f32) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let v: Vec<[f32; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 != 0 { s } else { 0.0 },
                if i & 2 != 0 { s } else { 0.0 },
                if i & 4 != 0 { s } else { 0.0 },
            ]
        })
        .collect();
    let f = vec![
        [0, 2, 3],
        [0, 3, 1], // z = 0, facing −z
        [4, 5, 7],
        [4, 7, 6], // z = s
        [0, 1, 5],
        [0, 5, 4], // y = 0
        [2, 6, 7],
        [2, 7, 3], // y = s
        [0, 4, 6],
        [0, 6, 2], // x = 0
        [1, 3, 7],
        [1, 7, 5], // x = s
    ];
    (v, f)
}

fn load(v: &[[f32; 3]], f: &[[usize; 3]]) -> Result<Part, PartError> {
    Part::from_mesh(v, f, Placement::default(), None, &LoadOptions::default())
}

#[test]
fn the_intact_cube_loads_with_its_volume() {
    let (v, f) = cube(20.0);
    let part = load(&v, &f).expect("a closed outward cube");
    assert!((part.volume_mm3 - 8000.0).abs() < 1e-6);
}

#[test]
fn an_open_mesh_is_refused() {
    let (v, mut f) = cube(20.0);
    f.pop();
    let err = load(&v, &f).expect_err("a cube without a face");
    assert!(matches!(err, PartError::Open { count: 3, .. }), "{err}");
    assert!(err.to_string().contains("not closed"));
}

#[test]
fn a_non_manifold_edge_is_refused() {
    // A second cube sharing one edge (vertices 5, 7 … of the first) through an extra pair of
    // triangles: here, a fin of two triangles on the edge 5–7, back to back.
    let (mut v, mut f) = cube(20.0);
    v.push([30.0, 0.0, 20.0]);
    let fin = v.len() - 1;
    f.push([5, 7, fin]);
    f.push([7, 5, fin]);
    let err = load(&v, &f).expect_err("a fin on an edge");
    assert!(
        matches!(err, PartError::NonManifold { count: 1, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("not manifold"));
}

#[test]
fn inverted_normals_are_refused() {
    let (v, f) = cube(20.0);
    let flipped: Vec<[usize; 3]> = f.iter().map(|t| [t[0], t[2], t[1]]).collect();
    let err = load(&v, &flipped).expect_err("all faces inwards");
    assert!(matches!(err, PartError::Inverted { .. }), "{err}");
    assert!(err.to_string().contains("inwards"));
    // One face flipped: inconsistent winding.
    let mut one = f.clone();
    one[0] = [f[0][0], f[0][2], f[0][1]];
    let err = load(&v, &one).expect_err("one face flipped");
    assert!(
        matches!(err, PartError::Inconsistent { count: 3, .. }),
        "{err}"
    );
}

#[test]
fn degenerate_triangles_and_nan_vertices_are_refused() {
    let (mut v, mut f) = cube(20.0);
    // Three collinear vertices.
    v.push([5.0, 0.0, 0.0]);
    v.push([10.0, 0.0, 0.0]);
    f.push([0, v.len() - 2, v.len() - 1]);
    let err = load(&v, &f).expect_err("a zero-area triangle");
    assert!(
        matches!(err, PartError::Degenerate { index: 12, .. }),
        "{err}"
    );

    let (mut v, f) = cube(20.0);
    v[3][1] = f32::NAN;
    let err = load(&v, &f).expect_err("a NaN vertex");
    assert!(
        matches!(err, PartError::NonFinite { index: 3, .. }),
        "{err}"
    );
    v[3][1] = f32::INFINITY;
    assert!(matches!(load(&v, &f), Err(PartError::NonFinite { .. })));
}

fn temp_path(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("h4-part-{}-{name}", std::process::id()))
}

fn cube_stl(s: f32) -> Vec<u8> {
    let (v, f) = cube(s);
    let m = MeshBuilder {
        vertices: v.iter().map(|p| p.map(f64::from)).collect(),
        faces: f,
    };
    m.to_binary_stl().expect("stl")
}

#[test]
fn a_file_over_the_size_limit_and_a_non_stl_file_are_refused() {
    let path = temp_path("cube.stl");
    let bytes = cube_stl(20.0);
    std::fs::write(&path, &bytes).expect("write");
    let ok = LoadOptions::default();
    Part::load(&path, Placement::default(), None, &ok).expect("the cube's file loads");
    let small = LoadOptions {
        max_file_bytes: bytes.len() as u64 - 1,
        ..ok
    };
    let err = Part::load(&path, Placement::default(), None, &small).expect_err("too large");
    assert!(matches!(err, PartError::TooLarge { .. }), "{err}");
    std::fs::write(&path, b"solid nothing\nthis is not stl\n").expect("write");
    let err = Part::load(&path, Placement::default(), None, &ok).expect_err("garbage");
    assert!(matches!(err, PartError::NotStl { .. }), "{err}");
    let _ = std::fs::remove_file(&path);
}

#[test]
fn an_ascii_stl_loads_like_the_binary_one() {
    let path = temp_path("cube-ascii.stl");
    let (v, f) = cube(20.0);
    let mut s = String::from("solid cube\n");
    for t in &f {
        s.push_str("facet normal 0 0 0\nouter loop\n");
        for &i in t {
            s.push_str(&format!("vertex {} {} {}\n", v[i][0], v[i][1], v[i][2]));
        }
        s.push_str("endloop\nendfacet\n");
    }
    s.push_str("endsolid cube\n");
    std::fs::write(&path, s).expect("write");
    let part =
        Part::load(&path, Placement::default(), None, &LoadOptions::default()).expect("ascii cube");
    assert!((part.volume_mm3 - 8000.0).abs() < 1e-6);
    let _ = std::fs::remove_file(&path);
}

#[test]
fn a_part_that_does_not_fit_the_stock_is_refused() {
    let (v, f) = cube(20.0);
    let stock = StockBox {
        centre_top_mm: [0.0, 0.0, 0.0],
        size_mm: [50.0, 50.0],
        thickness_mm: 30.0,
    };
    let inside = Placement {
        translation_mm: [-10.0, -10.0, -25.0],
        rotation_deg: [0.0, 0.0, 0.0],
    };
    Part::from_mesh(&v, &f, inside, Some(&stock), &LoadOptions::default()).expect("fits");
    // Turned 45° about z its corners reach 14.1 mm from its centre: still fits; moved to
    // x = 10 its far side reaches x = 30 > 25: does not.
    let turned = Placement {
        rotation_deg: [0.0, 0.0, 45.0],
        ..inside
    };
    Part::from_mesh(&v, &f, turned, Some(&stock), &LoadOptions::default()).expect("fits turned");
    let out = Placement {
        translation_mm: [10.0, -10.0, -25.0],
        ..inside
    };
    let err = Part::from_mesh(&v, &f, out, Some(&stock), &LoadOptions::default())
        .expect_err("past the stock's side");
    assert!(matches!(err, PartError::DoesNotFit { .. }), "{err}");
}

#[test]
fn cube_distances_match_the_analytic_box() {
    let (v, f) = cube(20.0);
    // Placed with its corner at (100, 0, −50), turned 30° about z.
    let placement = Placement {
        translation_mm: [100.0, 0.0, -50.0],
        rotation_deg: [0.0, 0.0, 30.0],
    };
    let part = Part::from_mesh(&v, &f, placement, None, &LoadOptions::default()).expect("cube");
    let band = part.grid.band_mm();
    let boxd = |q: [f64; 3]| {
        let d = q.map(|x| (x - 10.0).abs() - 10.0);
        let out = d.map(|x| x.max(0.0));
        let o = (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt();
        o + d[0].max(d[1]).max(d[2]).min(0.0)
    };
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for i in -4..=24 {
        for j in [-3.3, 2.0, 10.0, 17.7, 22.1] {
            for k in [-2.6, 4.9, 10.0, 19.3, 23.0] {
                let q = [i as f64 + 0.37, j, k];
                let exact = boxd(q);
                if exact.abs() >= band - 0.5 {
                    continue;
                }
                let got = part.signed_distance_mm(part.to_workpiece(q));
                // Planar faces are exact; near an edge the kink costs up to half a cell.
                let tol =
                    if exact < 0.0 || q.iter().filter(|x| !(0.0..=20.0).contains(*x)).count() > 1 {
                        0.26
                    } else {
                        1e-4
                    };
                assert!((got - exact).abs() <= tol, "at {q:?}: {got} vs {exact}");
                worst = worst.max((got - exact).abs());
                checked += 1;
            }
        }
    }
    assert!(checked > 200, "{checked} points checked");
    // Inside / outside at the centre and far away; the normal on the top face is +z.
    assert!(part.contains(part.to_workpiece([10.0, 10.0, 10.0])));
    assert!(!part.contains(part.to_workpiece([10.0, 10.0, 21.0])));
    assert_eq!(part.signed_distance_mm([1e4, 0.0, 0.0]), band);
    assert_eq!(part.signed_distance_mm([f64::NAN, 0.0, 0.0]), band);
    let (_, n) = part.distance_and_normal(part.to_workpiece([10.3, 9.1, 21.0]));
    assert!((n[2] - 1.0).abs() < 1e-9, "{n:?}");
    let (_, n) = part.distance_and_normal(part.to_workpiece([21.0, 9.1, 10.3]));
    let expected = part.dir_to_workpiece([1.0, 0.0, 0.0]);
    assert!((0..3).all(|a| (n[a] - expected[a]).abs() < 1e-9), "{n:?}");
    // Control: the query is not simply the box's distance from the origin.
    assert!(worst < 0.26);
    // The placed corner is on the surface; the centre is deeper than the band.
    assert!(part.signed_distance_mm([100.0, 0.0, -50.0]).abs() < 1e-3);
    assert_eq!(part.signed_distance_mm(part.to_workpiece([10.0; 3])), -band);
}

#[test]
fn sphere_mesh_distances_match_the_sphere_within_a_few_micrometres() {
    let r = 10.0;
    let profile: Vec<[f64; 2]> = (0..=48)
        .map(|k| {
            let a = -0.5 * std::f64::consts::PI + std::f64::consts::PI * k as f64 / 48.0;
            let rr = if k == 0 || k == 48 { 0.0 } else { r * a.cos() };
            [rr, r * a.sin()]
        })
        .collect();
    let m = revolve(&profile, 96);
    let v: Vec<[f32; 3]> = m.vertices.iter().map(|p| p.map(|x| x as f32)).collect();
    let part = load(&v, &m.faces).expect("a sphere mesh");
    let sphere_volume = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
    assert!((part.volume_mm3 - sphere_volume).abs() < 0.005 * sphere_volume);
    let mut checked = 0;
    for i in 0..40 {
        let t = i as f64 * 0.731;
        let dir = [
            t.cos() * (0.3 * t).sin(),
            t.sin() * (0.3 * t).sin(),
            (0.3 * t).cos(),
        ];
        for rho in [7.5, 9.0, 9.8, 10.2, 11.0, 12.5] {
            let p = dir.map(|x| x * rho);
            let got = part.signed_distance_mm(p);
            // Facets sag ≤ r(1 − cos(π/48)) = 0.021 mm; the grid's interpolation adds
            // ≤ h²/8r ≈ 0.003 mm.
            assert!((got - (rho - r)).abs() < 0.04, "at ρ = {rho}: {got}");
            assert_eq!(part.contains(p), rho < r, "at ρ = {rho}");
            checked += 1;
        }
    }
    assert_eq!(checked, 240);
}

#[test]
fn distance_queries_allocate_nothing() {
    let (v, f) = cube(20.0);
    let part = load(&v, &f).expect("cube");
    let mut sum = 0.0;
    let n = h4_shared::alloc_count::allocations_in(|| {
        for i in 0..10_000 {
            let p = [i as f64 * 0.003, 10.0, 20.5];
            sum += part.signed_distance_mm(p);
            sum += part.distance_and_normal(p).1[2];
        }
    });
    assert_eq!(n, 0);
    assert!(sum.is_finite());
    // Control: the counter sees an allocation.
    let m = h4_shared::alloc_count::allocations_in(|| {
        std::hint::black_box(vec![1u8; 16]);
    });
    assert!(m >= 1);
}
