//! `pano4d-view SCENE`: opens the viewer window; `pano4d-view SCENE --headless --out x.png`
//! renders one view without a window; `pano4d-view --edit scene.yaml` opens the region
//! editor.

use std::path::PathBuf;
use std::process::ExitCode;

use eframe::egui_wgpu;
use pano4d_viewer::app::ViewerApp;
use pano4d_viewer::camera::CameraPose;
use pano4d_viewer::edit::{app::EditorApp, bridge::Python};
use pano4d_viewer::headless::{render_file, TimeSelection, ViewRequest};
use pano4d_viewer::render::save_png;

const USAGE: &str = "\
usage: pano4d-view [SCENE] [--headless --out PNG] [options]
       pano4d-view --edit scene.yaml

SCENE is a .ply4d scene, a 3DGS .ply file, or a folder of per-frame .ply files.
--edit (or a .yaml SCENE) opens the region editor: draw what moves on the panorama,
preview it, save it into scene.yaml (through the pano4d Python package: the python
beside this program, or $PANO4D_PYTHON).

options (headless):
  --headless             render one view to --out instead of opening a window
  --out PATH             the PNG to write
  --camera POSE          {\"position\":[x,y,z],\"forward\":[x,y,z],\"fov_deg\":f}
                         (default: the panorama's viewpoint, origin looking along +x)
  --time SECONDS         the scene at SECONDS, round the loop: a version-2 scene at
                         that real time, others at the timestamp holding it (the last
                         at or before it), as the window plays them (default: the first)
  --frame N              timestamp index N
  --size WxH             image size (default 1280x720)
  --background R,G,B     background colour, 0..1 each (default 0,0,0)
  --splat-scale S        multiply every Gaussian's scale by S (default 1)
";

struct Args {
    scene: Option<PathBuf>,
    edit: bool,
    headless: bool,
    out: Option<PathBuf>,
    request: ViewRequest,
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("--size must be WxH, got {text:?}"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&v| (1..=16384).contains(&v))
    };
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!(
            "--size must be WxH with sides 1..=16384, got {text:?}"
        )),
    }
}

fn parse_rgb(text: &str) -> Result<[f32; 3], String> {
    let values: Vec<f32> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("--background must be R,G,B numbers, got {text:?}"))?;
    match values[..] {
        [r, g, b] if values.iter().all(|v| (0.0..=1.0).contains(v)) => Ok([r, g, b]),
        _ => Err(format!(
            "--background must be three values in 0..1, got {text:?}"
        )),
    }
}

fn parse_args(mut args: impl Iterator<Item = String>) -> Result<Args, String> {
    let mut parsed = Args {
        scene: None,
        edit: false,
        headless: false,
        out: None,
        request: ViewRequest::default(),
    };
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "-h" | "--help" => return Err(String::new()),
            "--edit" => parsed.edit = true,
            "--headless" => parsed.headless = true,
            "--out" => parsed.out = Some(PathBuf::from(value("--out")?)),
            "--camera" => parsed.request.pose = Some(CameraPose::parse(&value("--camera")?)?),
            "--time" => {
                let text = value("--time")?;
                let seconds = text
                    .parse::<f64>()
                    .ok()
                    .filter(|s| s.is_finite())
                    .ok_or_else(|| format!("--time must be a number of seconds, got {text:?}"))?;
                parsed.request.time = TimeSelection::Seconds(seconds);
            }
            "--frame" => {
                let text = value("--frame")?;
                let index = text
                    .parse::<usize>()
                    .map_err(|_| format!("--frame must be a timestamp index, got {text:?}"))?;
                parsed.request.time = TimeSelection::Index(index);
            }
            "--size" => {
                let (w, h) = parse_size(&value("--size")?)?;
                parsed.request.width = w;
                parsed.request.height = h;
            }
            "--background" => {
                parsed.request.options.background = parse_rgb(&value("--background")?)?
            }
            "--splat-scale" => {
                let text = value("--splat-scale")?;
                parsed.request.options.splat_scale = text
                    .parse::<f32>()
                    .ok()
                    .filter(|s| s.is_finite() && *s > 0.0)
                    .ok_or_else(|| {
                        format!("--splat-scale must be a positive number, got {text:?}")
                    })?;
            }
            flag if flag.starts_with('-') => return Err(format!("unknown option {flag}")),
            path if parsed.scene.is_none() => parsed.scene = Some(PathBuf::from(path)),
            extra => return Err(format!("unexpected argument {extra:?}")),
        }
    }
    let yaml = parsed
        .scene
        .as_ref()
        .and_then(|s| s.extension())
        .is_some_and(|e| e == "yaml" || e == "yml");
    parsed.edit |= yaml && !parsed.headless;
    if parsed.edit && (parsed.headless || parsed.scene.is_none()) {
        return Err("--edit needs a scene.yaml and no --headless".into());
    }
    Ok(parsed)
}

fn run_headless(args: &Args) -> Result<(), String> {
    let scene = args.scene.as_ref().ok_or("--headless needs a SCENE")?;
    let out = args.out.as_ref().ok_or("--headless needs --out PATH")?;
    let image = render_file(scene, &args.request)?;
    save_png(&image, out)
}

fn run_window(scene: Option<PathBuf>) -> Result<(), String> {
    let setup = pano4d_viewer::full_limits(egui_wgpu::WgpuSetupCreateNew::without_display_handle());
    let options = eframe::NativeOptions {
        viewport: eframe::egui::ViewportBuilder::default()
            .with_title("pano4d-view")
            .with_inner_size([1280.0, 800.0]),
        wgpu_options: egui_wgpu::WgpuConfiguration {
            wgpu_setup: setup.into(),
            ..Default::default()
        },
        ..Default::default()
    };
    eframe::run_native(
        "pano4d-view",
        options,
        Box::new(move |cc| Ok(Box::new(ViewerApp::new(cc, scene.as_deref())))),
    )
    .map_err(|e| format!("cannot open the viewer window: {e}"))
}

fn run_editor(scene: PathBuf) -> Result<(), String> {
    let options = eframe::NativeOptions {
        viewport: eframe::egui::ViewportBuilder::default()
            .with_title(format!("pano4d-view: regions of {}", scene.display()))
            .with_inner_size([1280.0, 800.0]),
        ..Default::default()
    };
    eframe::run_native(
        "pano4d-view-edit",
        options,
        Box::new(move |_| Ok(Box::new(EditorApp::new(&scene, Python::locate())))),
    )
    .map_err(|e| format!("cannot open the editor window: {e}"))
}

fn main() -> ExitCode {
    let args = match parse_args(std::env::args().skip(1)) {
        Ok(args) => args,
        Err(e) if e.is_empty() => {
            print!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("pano4d-view: {e}\n\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    let result = if args.edit {
        run_editor(args.scene.expect("checked by parse_args"))
    } else if args.headless {
        run_headless(&args)
    } else {
        run_window(args.scene)
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pano4d-view: {e}");
            ExitCode::FAILURE
        }
    }
}
