//! Frame time of the viewer's render path (the window's path without the window): with
//! the scene resident on the GPU, draw a frame into a texture (still), or first upload the
//! next timestamp's dynamic set, decoded ahead on the stream's worker thread (playing).
//! Prints a table and writes JSON.
//!
//! `cargo run --release -p pano4d-viewer --bin viewer-bench -- [--quick] [--json PATH]
//!  [--size WxH] [--sh-degree D] [--counts N,N,...]`

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use pano4d_viewer::camera::ViewCamera;
use pano4d_viewer::render::{FrameOptions, FrameRenderer};
use pano4d_viewer::scene::Scene;
use pano4d_viewer::stream::DynamicStream;
use pano4d_viewer::synthetic;
use serde::Serialize;
use splat_core::gaussians::SceneInput;
use splat_core::ply4d;
use splat_core::raster::{GpuContext, RenderSettings, Renderer};

/// Timestamps in each benchmark scene; playback cycles through them.
const TIMES: usize = 8;
/// Share of the Gaussians that are dynamic (per timestamp).
const DYNAMIC_FRACTION: f64 = 0.05;

#[derive(Serialize)]
struct Case {
    gaussians: usize,
    static_gaussians: usize,
    dynamic_gaussians: usize,
    sh_degree: u32,
    width: u32,
    height: u32,
    frames: usize,
    /// Camera moves, time fixed: draw into a texture with the scene resident.
    still_ms_median: f64,
    still_ms_min: f64,
    /// Time advances every frame: the dynamic set is decoded and uploaded as well.
    playing_ms_median: f64,
    playing_ms_min: f64,
    /// The same still frames through `Renderer::forward` (the training path, and the
    /// viewer's path before the scene was resident): the whole set uploaded every frame
    /// and the float image read back.
    upload_ms_median: f64,
}

#[derive(Serialize)]
struct Report {
    adapter: String,
    backend: String,
    cases: Vec<Case>,
}

struct Options {
    counts: Vec<usize>,
    width: u32,
    height: u32,
    sh_degree: u32,
    frames: usize,
    json: PathBuf,
}

fn parse() -> Result<Options, String> {
    let mut options = Options {
        counts: vec![50_000, 1_000_000],
        width: 1280,
        height: 720,
        sh_degree: 3,
        frames: 5,
        json: PathBuf::from("bench/out/viewer.json"),
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{arg} needs a value"));
        match arg.as_str() {
            "--quick" => {
                options.counts = vec![20_000];
                options.frames = 3;
            }
            "--json" => options.json = PathBuf::from(value()?),
            "--frames" => {
                options.frames = value()?.parse().map_err(|e| format!("--frames: {e}"))?
            }
            "--sh-degree" => {
                options.sh_degree = value()?.parse().map_err(|e| format!("--sh-degree: {e}"))?
            }
            "--counts" => {
                options.counts = value()?
                    .split(',')
                    .map(|c| c.trim().replace('_', "").parse::<usize>())
                    .collect::<Result<_, _>>()
                    .map_err(|e| format!("--counts: {e}"))?
            }
            "--size" => {
                let text = value()?;
                let (w, h) = text.split_once('x').ok_or("--size must be WxH")?;
                options.width = w.parse().map_err(|e| format!("--size: {e}"))?;
                options.height = h.parse().map_err(|e| format!("--size: {e}"))?;
            }
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if options.sh_degree > 3 || options.frames == 0 {
        return Err("--sh-degree must be 0..=3 and --frames positive".into());
    }
    Ok(options)
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn run_case(
    renderer: &mut FrameRenderer,
    baseline: &mut Renderer,
    count: usize,
    options: &Options,
) -> Result<Case, String> {
    let dynamic = ((count as f64 * DYNAMIC_FRACTION) as usize).max(1);
    let statics = count - dynamic;
    let generated = synthetic::scene(statics, dynamic, TIMES, options.sh_degree, 42);
    let dir = std::env::temp_dir().join(format!("pano4d-viewer-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let path = dir.join(format!("scene-{count}.ply4d"));
    ply4d::write(&path, &generated).map_err(|e| e.to_string())?;
    drop(generated);
    let scene = Scene::open(&path)?;
    renderer.load_scene(&scene);
    let frame_options = FrameOptions::default();
    let mut camera = ViewCamera::panorama_viewpoint(&scene.extent);
    // Frames are drawn into a texture, as in the window (no read-back).
    let target = renderer.create_target(options.width, options.height);
    // Warm-up: pipelines, buffer growth.
    renderer.show_time(&scene, 0)?;
    renderer.draw(
        &camera.to_camera(options.width, options.height),
        &frame_options,
        &target,
    )?;

    let mut still = Vec::new();
    for _ in 0..options.frames {
        camera.drag(15.0, 0.0);
        let start = Instant::now();
        renderer.draw(
            &camera.to_camera(options.width, options.height),
            &frame_options,
            &target,
        )?;
        still.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let mut whole = scene.static_set.clone();
    whole.extend_from(&scene.dynamic_set(0)?);
    let mut upload = Vec::new();
    for _ in 0..options.frames {
        camera.drag(15.0, 0.0);
        let start = Instant::now();
        baseline
            .forward(
                &SceneInput::from(&whole),
                &camera.to_camera(options.width, options.height),
                &RenderSettings::default(),
            )
            .map_err(|e| e.to_string())?;
        upload.push(start.elapsed().as_secs_f64() * 1e3);
    }
    drop(whole);
    // Playback as the window does it: the next timestamp decodes while this one draws.
    let scene = Arc::new(scene);
    let mut stream = DynamicStream::new(Arc::clone(&scene));
    stream.prefetch(1);
    let mut playing = Vec::new();
    for frame in 0..options.frames {
        let t = (frame + 1) % TIMES;
        let start = Instant::now();
        renderer.show(&scene, t, &stream.take(t)?)?;
        stream.prefetch((t + 1) % TIMES);
        renderer.draw(
            &camera.to_camera(options.width, options.height),
            &frame_options,
            &target,
        )?;
        playing.push(start.elapsed().as_secs_f64() * 1e3);
    }
    drop(stream);
    drop(scene);
    std::fs::remove_file(&path).map_err(|e| e.to_string())?;
    let _ = std::fs::remove_dir(&dir);
    Ok(Case {
        gaussians: count,
        static_gaussians: statics,
        dynamic_gaussians: dynamic,
        sh_degree: options.sh_degree,
        width: options.width,
        height: options.height,
        frames: options.frames,
        still_ms_min: still.iter().copied().fold(f64::INFINITY, f64::min),
        still_ms_median: median(&mut still),
        playing_ms_min: playing.iter().copied().fold(f64::INFINITY, f64::min),
        playing_ms_median: median(&mut playing),
        upload_ms_median: median(&mut upload),
    })
}

fn run() -> Result<(), String> {
    let options = parse()?;
    let mut renderer = FrameRenderer::headless()?;
    let mut baseline =
        Renderer::new(GpuContext::new().map_err(|e| e.to_string())?).map_err(|e| e.to_string())?;
    let adapter = renderer.adapter().clone();
    println!(
        "viewer render path, {}x{}, SH degree {}, adapter {} ({})",
        options.width, options.height, options.sh_degree, adapter.name, adapter.backend
    );
    println!(
        "{:>10} {:>10} {:>9} | {:>10} {:>7} | {:>10} {:>7} | {:>10} {:>8}",
        "gaussians",
        "static",
        "dynamic",
        "still ms",
        "fps",
        "playing ms",
        "fps",
        "upload ms",
        "speed-up"
    );
    let mut cases = Vec::new();
    for &count in &options.counts {
        let case = run_case(&mut renderer, &mut baseline, count, &options)?;
        println!(
            "{:>10} {:>10} {:>9} | {:>10.1} {:>7.1} | {:>10.1} {:>7.1} | {:>10.1} {:>7.1}x",
            case.gaussians,
            case.static_gaussians,
            case.dynamic_gaussians,
            case.still_ms_median,
            1e3 / case.still_ms_median,
            case.playing_ms_median,
            1e3 / case.playing_ms_median,
            case.upload_ms_median,
            case.upload_ms_median / case.still_ms_median
        );
        cases.push(case);
    }
    let report = Report {
        adapter: adapter.name,
        backend: adapter.backend,
        cases,
    };
    if let Some(parent) = options.json.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .map_err(|e| format!("cannot create {}: {e}", parent.display()))?;
    }
    let json = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
    let tmp = options.json.with_extension("json.tmp");
    std::fs::write(&tmp, json)
        .and_then(|()| std::fs::rename(&tmp, &options.json))
        .map_err(|e| format!("cannot write {}: {e}", options.json.display()))?;
    println!("wrote {}", options.json.display());
    Ok(())
}

fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("viewer-bench: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
