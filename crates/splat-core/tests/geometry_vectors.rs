//! The Rust geometry against `tests/vectors/geometry.json`, written by the Python side,
//! so that the two implementations of docs/design.md's conventions cannot drift.

use glam::{DVec2, DVec3};
use serde_json::Value;
use splat_core::camera::{dir_to_equirect, equirect_to_dir, Camera};

fn vectors() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/vectors/geometry.json"
    );
    let text = std::fs::read_to_string(path).expect("geometry.json is committed");
    serde_json::from_str(&text).expect("geometry.json parses")
}

fn f(v: &Value) -> f64 {
    v.as_f64().expect("number")
}

fn vec3(v: &Value) -> DVec3 {
    DVec3::new(f(&v[0]), f(&v[1]), f(&v[2]))
}

fn vec2(v: &Value) -> DVec2 {
    DVec2::new(f(&v[0]), f(&v[1]))
}

fn u32_of(v: &Value) -> u32 {
    v.as_u64().expect("integer") as u32
}

/// Distance between two u coordinates on the circle of circumference `width`.
fn seam_distance(a: f64, b: f64, width: f64) -> f64 {
    let d = (a - b).rem_euclid(width);
    d.min(width - d)
}

#[test]
fn equirect_to_dir_matches_python() {
    let v = vectors();
    let tol = f(&v["tolerance"]);
    for case in v["equirect_to_dir"].as_array().unwrap() {
        let d = equirect_to_dir(
            f(&case["u"]),
            f(&case["v"]),
            u32_of(&case["width"]),
            u32_of(&case["height"]),
        );
        let want = vec3(&case["dir"]);
        assert!((d - want).length() < tol, "{case}: got {d}");
        assert!((d.length() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn dir_to_equirect_matches_python_including_seam_and_poles() {
    let v = vectors();
    for case in v["dir_to_equirect"].as_array().unwrap() {
        let (w, h) = (u32_of(&case["width"]), u32_of(&case["height"]));
        let uv = dir_to_equirect(vec3(&case["dir"]), w, h);
        assert!(uv.x >= 0.0 && uv.x < w as f64, "u out of [0, W): {}", uv.x);
        // At the seam u = 0 and u = W - ε are the same place: compare on the circle.
        assert!(
            seam_distance(uv.x, f(&case["u"]), w as f64) < 1e-6,
            "{case}: got {uv}"
        );
        assert!((uv.y - f(&case["v"])).abs() < 1e-6, "{case}: got {uv}");
    }
}

#[test]
fn cameras_match_python() {
    let v = vectors();
    for case in v["cameras"].as_array().unwrap() {
        let cam = Camera::from_fov(
            f(&case["fov_deg"]),
            u32_of(&case["width"]),
            u32_of(&case["height"]),
            vec3(&case["position"]),
            vec3(&case["forward"]),
            vec3(&case["up"]),
        );
        let k = &case["K"];
        assert!((cam.fx - f(&k[0][0])).abs() < 1e-9);
        assert!((cam.fy - f(&k[1][1])).abs() < 1e-9);
        assert!((cam.cx - f(&k[0][2])).abs() < 1e-12);
        assert!((cam.cy - f(&k[1][2])).abs() < 1e-12);
        let w2c = &case["world_to_cam"];
        for r in 0..3 {
            let row = cam.rotation.row(r);
            for c in 0..3 {
                assert!(
                    (row[c] - f(&w2c[r][c])).abs() < 1e-12,
                    "R[{r}][{c}] in {case}"
                );
            }
            assert!((cam.translation[r] - f(&w2c[r][3])).abs() < 1e-9);
        }
        assert!((cam.position() - vec3(&case["position"])).length() < 1e-9);
        for p in case["project"].as_array().unwrap() {
            let (uv, z) = cam.project(vec3(&p["point"]));
            assert!((z - f(&p["z"])).abs() < 1e-9);
            let want = vec2(&p["uv"]);
            assert!(
                (uv - want).length() < 1e-6 * want.length().max(1.0),
                "{p}: got {uv}"
            );
        }
        for p in case["unproject_z"].as_array().unwrap() {
            let got = cam.unproject_z(vec2(&p["uv"]), f(&p["z"]));
            assert!((got - vec3(&p["point"])).length() < 1e-9 * f(&p["z"]).max(1.0));
        }
        for p in case["unproject_ray"].as_array().unwrap() {
            let got = cam.unproject_ray(vec2(&p["uv"]), f(&p["ray_length"]));
            let want = vec3(&p["point"]);
            assert!((got - want).length() < 1e-9 * f(&p["ray_length"]).max(1.0));
            assert!(
                ((got - cam.position()).length() - f(&p["ray_length"])).abs()
                    < 1e-9 * f(&p["ray_length"]).max(1.0)
            );
        }
        // Reconstruct from the matrices as views.json stores them: the same camera.
        let k3: [[f64; 3]; 3] =
            std::array::from_fn(|r| std::array::from_fn(|c| f(&case["K"][r][c])));
        let m: [[f64; 4]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| f(&w2c[r][c])));
        let again = Camera::from_matrices(k3, m, cam.width, cam.height);
        assert!((again.position() - cam.position()).length() < 1e-9);
    }
}

#[test]
fn known_point_projects_to_expected_pixel() {
    // A point 10 m ahead of a 90° camera, 1 m to the viewer's right (−y) and 1 m up,
    // lands at (cx + fx/10, cy − fy/10).
    let cam = Camera::from_fov(90.0, 200, 100, DVec3::ZERO, DVec3::X, DVec3::Z);
    let (uv, z) = cam.project(DVec3::new(10.0, -1.0, 1.0));
    assert!((z - 10.0).abs() < 1e-12);
    assert!(
        (uv - DVec2::new(100.0 + 10.0, 50.0 - 10.0)).length() < 1e-9,
        "{uv}"
    );
}
