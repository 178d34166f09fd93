//! `pano4d-view --headless`: one view to a PNG through the window's render path, and
//! clear errors (never a panic) for bad input.

use std::path::PathBuf;
use std::process::Command;

use pano4d_viewer::synthetic;
use splat_core::ply4d;

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pano4d-view-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn view() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pano4d-view"))
}

#[test]
fn headless_render_writes_the_view_at_the_chosen_time() {
    let dir = temp_dir("render");
    let scene = dir.join("scene.ply4d");
    ply4d::write(&scene, &synthetic::scene(5_000, 500, 3, 0, 2)).unwrap();
    let render = |frame: &str, out: &str| {
        let result = view()
            .arg(&scene)
            .args(["--headless", "--size", "160x90", "--frame", frame, "--out"])
            .arg(dir.join(out))
            .args([
                "--camera",
                r#"{"position":[0,0,0],"forward":[1,0.3,0],"fov_deg":90}"#,
            ])
            .output()
            .unwrap();
        assert!(
            result.status.success(),
            "{}",
            String::from_utf8_lossy(&result.stderr)
        );
        image::open(dir.join(out)).unwrap().to_rgba8()
    };
    let first = render("0", "t0.png");
    let last = render("2", "t2.png");
    assert_eq!(first.dimensions(), (160, 90));
    assert!(first.pixels().all(|p| p.0[3] == 255));
    assert_ne!(first, last, "the ball moves between timestamps");
    let lit = first.pixels().filter(|p| p.0[..3] != [0, 0, 0]).count();
    assert!(lit > 160 * 90 * 9 / 10, "{lit} of {} pixels lit", 160 * 90);
    // No temporary files are left beside the output.
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 3, "{names:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn headless_render_of_a_version_2_scene() {
    let dir = temp_dir("render-v2");
    let scene = dir.join("scene.ply4d");
    ply4d::write_spacetime(&scene, &synthetic::spacetime_scene(2_000, 400, 4, 0, 2)).unwrap();
    let render = |option: &str, value: &str| {
        let out = dir.join(format!("{option}{value}.png"));
        let result = view()
            .arg(&scene)
            .args(["--headless", "--size", "96x64", option, value, "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr).to_string();
        (result.status.success(), stderr, out)
    };
    let image = |(ok, stderr, out): (bool, String, PathBuf)| {
        assert!(ok, "{stderr}");
        image::open(out).unwrap().to_rgba8()
    };
    let first = image(render("--frame", "0"));
    let second = image(render("--frame", "1"));
    let half_way = image(render("--frame", "2"));
    assert_ne!(first, half_way, "the ball bobs between timestamps");
    // 0.15 s at 10 fps: frame 1.5, drawn there, not at a timestamp.
    let between = image(render("--time", "0.15"));
    assert_ne!(between, second);
    assert_ne!(between, half_way);
    let (ok, stderr, _) = render("--frame", "4");
    assert!(!ok && stderr.contains("out of range"), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_input_fails_with_a_message() {
    let dir = temp_dir("bad");
    let scene = dir.join("scene.ply4d");
    ply4d::write(&scene, &synthetic::scene(100, 10, 2, 0, 2)).unwrap();
    let junk = dir.join("junk.ply4d");
    std::fs::write(&junk, b"GIF89a not a scene").unwrap();
    let out = dir.join("x.png");
    let cases: Vec<(Vec<&std::ffi::OsStr>, &str)> = vec![
        (
            vec![junk.as_os_str()],
            "neither a .ply4d scene nor a 3DGS .ply",
        ),
        (
            vec![scene.as_os_str(), "--frame".as_ref(), "9".as_ref()],
            "out of range",
        ),
        (
            vec![scene.as_os_str(), "--camera".as_ref(), "{}".as_ref()],
            "invalid camera pose",
        ),
        (
            vec![scene.as_os_str(), "--size".as_ref(), "0x5".as_ref()],
            "--size",
        ),
        (
            vec![scene.as_os_str(), "--bogus".as_ref()],
            "unknown option",
        ),
    ];
    for (args, message) in cases {
        let result = view()
            .args(&args)
            .args(["--headless", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert!(!result.status.success(), "{args:?} succeeded");
        assert!(
            matches!(result.status.code(), Some(1 | 2)),
            "{args:?}: {:?}",
            result.status
        );
        assert!(stderr.contains(message), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
