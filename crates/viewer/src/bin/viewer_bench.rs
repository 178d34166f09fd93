//! Frame time of the viewer's render path (the window's path without the window), with
//! the scene resident on the GPU:
//! - *still*: the camera moves, the time does not; a frame drawn into a texture;
//! - *playing*: the time advances every frame as well, with every timestamp's dynamic set
//!   kept on the GPU (copied into place on the GPU); measured interleaved with *still*,
//!   frame by frame at the same camera poses, so their ratio is taken side by side;
//! - *streamed*: playing with the dynamic sets decoded ahead on the stream's worker thread
//!   and uploaded when shown (the fallback when they do not fit the budget);
//! - *upload*: the still frame through `Renderer::forward` (whole set uploaded, float
//!   image read back: the training path);
//! - a time change alone, the GPU waited for: the GPU-side copy of a stored set, and the
//!   decode and the upload of a set that streaming does instead;
//! - *version 2*: the same Gaussians as a version-2 scene (its dynamic part one spacetime
//!   set looping over the T timestamps), played as the window plays it, with interpolation:
//!   the shown time advanced by one display frame (1/60 s at the scene's 10 fps: 1/6 of a
//!   frame, so it falls between timestamps), the set evaluated there on the GPU and drawn
//!   (*playing*), against *still* (the same pose drawn again, no evaluation), interleaved
//!   frame by frame as above; and the evaluate pass alone, the GPU waited for. Issue #38's
//!   target: playing ≤ 1.1 × still on lavapipe.
//!
//! Prints a table and writes JSON (`cases`, each with its `version_2` figures).
//!
//! `cargo run --release -p pano4d-viewer --bin viewer-bench -- [--quick] [--json PATH]
//!  [--size WxH] [--sh-degree D] [--counts N,N,...] [--frames F] [--times T]
//!  [--budget-mib M]`; `viewer-bench --adapter` prints the adapter it would use. The
//! version-2 comparison of issue #38 on lavapipe: `viewer-bench --counts 50000 --frames 21`
//! (its `v2 ratio` column; `version_2.playing_over_still` in the JSON).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use pano4d_viewer::camera::ViewCamera;
use pano4d_viewer::render::{FrameOptions, FrameRenderer};
use pano4d_viewer::residency;
use pano4d_viewer::scene::Scene;
use pano4d_viewer::stream::DynamicStream;
use pano4d_viewer::synthetic;
use pano4d_viewer::time::{TimeControl, Timeline};
use serde::Serialize;
use splat_core::camera::Camera;
use splat_core::gaussians::SceneInput;
use splat_core::ply4d;
use splat_core::raster::{GpuContext, RenderSettings, Renderer};

/// Share of the Gaussians that are dynamic (per timestamp).
const DYNAMIC_FRACTION: f64 = 0.05;
/// The display's refresh rate the version-2 playback advances the time by, per frame.
const DISPLAY_HZ: f64 = 60.0;

/// A version-2 scene of the case's Gaussians, played with interpolation.
#[derive(Serialize)]
struct Interpolated {
    /// Frames of the scene's loop (its period).
    period: usize,
    /// Scene frames one display frame advances the shown time by.
    frames_per_display_frame: f64,
    /// Bytes of the spacetime set on the GPU.
    spacetime_bytes: u64,
    /// Loading the scene and showing time 0: static set and spacetime set uploaded, one
    /// evaluation.
    load_ms: f64,
    still_ms_median: f64,
    still_ms_min: f64,
    /// The evaluate pass at the next display frame's time, then the draw.
    playing_ms_median: f64,
    playing_ms_min: f64,
    /// Median over frames of playing / still at the same pose.
    playing_over_still: f64,
    /// The evaluate pass alone, the GPU waited for.
    evaluate_ms_median: f64,
}

#[derive(Serialize)]
struct Case {
    gaussians: usize,
    static_gaussians: usize,
    dynamic_gaussians: usize,
    timestamps: usize,
    sh_degree: u32,
    width: u32,
    height: u32,
    frames: usize,
    /// How the dynamic sets reached the GPU in *playing* (`residency::Playback`).
    playback: String,
    /// Bytes of every timestamp's dynamic set on the GPU (0 when streamed).
    resident_bytes: u64,
    /// Loading the scene for playback: static set, and every dynamic set decoded and
    /// stored when they fit.
    load_ms: f64,
    still_ms_median: f64,
    still_ms_min: f64,
    playing_ms_median: f64,
    playing_ms_min: f64,
    /// Median over frames of playing / still at the same pose.
    playing_over_still: f64,
    /// A time change alone (the GPU waited for): copying a stored set on the GPU, decoding
    /// a set, uploading a decoded set.
    copy_ms_median: f64,
    decode_ms_median: f64,
    upload_set_ms_median: f64,
    streamed_ms_median: f64,
    upload_ms_median: f64,
    version_2: Interpolated,
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
    times: usize,
    budget: u64,
    json: PathBuf,
}

fn parse() -> Result<Options, String> {
    let mut options = Options {
        counts: vec![50_000, 1_000_000],
        width: 1280,
        height: 720,
        sh_degree: 3,
        frames: 5,
        times: 8,
        budget: residency::budget_from_env()?,
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
            "--times" => options.times = value()?.parse().map_err(|e| format!("--times: {e}"))?,
            "--budget-mib" => {
                let mib: u64 = value()?.parse().map_err(|e| format!("--budget-mib: {e}"))?;
                options.budget = mib << 20;
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
    if options.sh_degree > 3 || options.frames == 0 || options.times < 2 {
        return Err("--sh-degree must be 0..=3, --frames positive and --times at least 2".into());
    }
    Ok(options)
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn min(values: &[f64]) -> f64 {
    values.iter().copied().fold(f64::INFINITY, f64::min)
}

/// Milliseconds `f` takes.
fn timed(f: impl FnOnce() -> Result<(), String>) -> Result<f64, String> {
    let start = Instant::now();
    f()?;
    Ok(start.elapsed().as_secs_f64() * 1e3)
}

fn run_case(
    resident: &mut FrameRenderer,
    streamed: &mut FrameRenderer,
    baseline: &mut Renderer,
    count: usize,
    options: &Options,
) -> Result<Case, String> {
    let (width, height, times) = (options.width, options.height, options.times);
    let dynamic = ((count as f64 * DYNAMIC_FRACTION) as usize).max(1);
    let statics = count - dynamic;
    let generated = synthetic::scene(statics, dynamic, times, options.sh_degree, 42);
    let dir = std::env::temp_dir().join(format!("pano4d-viewer-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let path = dir.join(format!("scene-{count}.ply4d"));
    ply4d::write(&path, &generated).map_err(|e| e.to_string())?;
    drop(generated);
    let scene = Arc::new(Scene::open(&path)?);
    let mut playback = None;
    let load_ms = timed(|| {
        playback = Some(resident.load_scene_resident(&scene, options.budget).clone());
        resident.show_time(&scene, 0.0)
    })?;
    let playback = playback.expect("set by the load");
    streamed.load_scene(&scene);
    let frame_options = FrameOptions::default();
    // Frames are drawn into a texture, as in the window (no read-back).
    let target = resident.create_target(width, height);
    let streamed_target = streamed.create_target(width, height);
    let (start, poses) = poses(&scene, options);
    // Warm-up: pipelines, buffer growth.
    resident.draw(&start, &frame_options, &target)?;

    // Playing and still, interleaved at the same poses: playing shows the next timestamp
    // and draws; still draws the same pose again at that timestamp.
    let (mut still, mut playing, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for (frame, camera) in poses.iter().enumerate() {
        let t = (frame + 1) % times;
        let play = timed(|| {
            resident.show_time(&scene, t as f64)?;
            resident.draw(camera, &frame_options, &target)
        })?;
        let draw = timed(|| resident.draw(camera, &frame_options, &target))?;
        playing.push(play);
        still.push(draw);
        ratios.push(play / draw);
    }

    // A time change by itself, the GPU waited for: the GPU-side copy of a stored set (the
    // resident path), and the decode and the upload of a set (the streamed path).
    let (mut copy, mut decode, mut upload_set) = (Vec::new(), Vec::new(), Vec::new());
    streamed.show_time(&scene, 0.0)?;
    for frame in 0..options.frames {
        let t = (frame + 1) % times;
        copy.push(timed(|| {
            resident.show_time(&scene, t as f64)?;
            resident.wait()
        })?);
        let mut set = None;
        decode.push(timed(|| {
            set = Some(scene.dynamic_set(t)?);
            Ok(())
        })?);
        let set = set.expect("decoded above");
        upload_set.push(timed(|| {
            streamed.show(&scene, t, &set)?;
            streamed.wait()
        })?);
    }

    // Streaming as the window does it when the sets do not fit: the next timestamp
    // decodes while this one draws.
    let mut stream = DynamicStream::new(Arc::clone(&scene));
    streamed.show_time(&scene, 0.0)?;
    streamed.draw(&poses[0], &frame_options, &streamed_target)?;
    stream.prefetch(1);
    let mut streaming = Vec::new();
    for (frame, camera) in poses.iter().enumerate() {
        let t = (frame + 1) % times;
        streaming.push(timed(|| {
            streamed.show(&scene, t, &stream.take(t)?)?;
            stream.prefetch((t + 1) % times);
            streamed.draw(camera, &frame_options, &streamed_target)
        })?);
    }
    drop(stream);

    let mut whole = scene.static_set.clone();
    whole.extend_from(&scene.dynamic_set(0)?);
    let mut upload = Vec::new();
    for camera in &poses {
        upload.push(timed(|| {
            baseline
                .forward(
                    &SceneInput::from(&whole),
                    camera,
                    &RenderSettings::default(),
                )
                .map(|_| ())
                .map_err(|e| e.to_string())
        })?);
    }
    drop(whole);
    drop(scene);
    std::fs::remove_file(&path).map_err(|e| e.to_string())?;
    let version_2 = run_version_2(resident, statics, dynamic, options, &dir)?;
    let _ = std::fs::remove_dir(&dir);
    Ok(Case {
        gaussians: count,
        static_gaussians: statics,
        dynamic_gaussians: dynamic,
        timestamps: times,
        sh_degree: options.sh_degree,
        width,
        height,
        frames: options.frames,
        resident_bytes: match &playback {
            residency::Playback::Resident { bytes } => *bytes,
            // A version-1 scene is never evaluated.
            residency::Playback::Streamed { .. } | residency::Playback::Evaluated { .. } => 0,
        },
        playback: playback.describe(),
        load_ms,
        still_ms_min: min(&still),
        still_ms_median: median(&mut still),
        playing_ms_min: min(&playing),
        playing_ms_median: median(&mut playing),
        playing_over_still: median(&mut ratios),
        copy_ms_median: median(&mut copy),
        decode_ms_median: median(&mut decode),
        upload_set_ms_median: median(&mut upload_set),
        streamed_ms_median: median(&mut streaming),
        upload_ms_median: median(&mut upload),
        version_2,
    })
}

/// The camera the frames start from, and one pose per frame turning right from it.
fn poses(scene: &Scene, options: &Options) -> (Camera, Vec<Camera>) {
    let (width, height) = (options.width, options.height);
    let start = ViewCamera::panorama_viewpoint(&scene.extent);
    let poses = (0..options.frames)
        .scan(start, |camera, _| {
            camera.drag(15.0, 0.0);
            Some(camera.to_camera(width, height))
        })
        .collect();
    (start.to_camera(width, height), poses)
}

/// The case's Gaussians as a version-2 scene (`statics` static, `dynamic` in the spacetime
/// set, looping over `options.times` frames), played with interpolation on `renderer` as
/// the window plays it, against still frames at the same poses.
fn run_version_2(
    renderer: &mut FrameRenderer,
    statics: usize,
    dynamic: usize,
    options: &Options,
    dir: &Path,
) -> Result<Interpolated, String> {
    let generated = synthetic::spacetime_scene(
        statics,
        dynamic,
        options.times as u32,
        options.sh_degree,
        42,
    );
    let path = dir.join(format!("scene-{}-v2.ply4d", statics + dynamic));
    ply4d::write_spacetime(&path, &generated).map_err(|e| e.to_string())?;
    drop(generated);
    let scene = Scene::open(&path)?;
    let mut time = TimeControl::new(&scene.timestamps, Timeline::Continuous);
    let mut playback = None;
    let load_ms = timed(|| {
        playback = Some(renderer.load_scene_resident(&scene, options.budget).clone());
        renderer.show_time(&scene, time.frame())
    })?;
    let spacetime_bytes = match playback {
        Some(residency::Playback::Evaluated { bytes }) => bytes,
        other => return Err(format!("the version-2 scene was loaded as {other:?}")),
    };
    let frame_options = FrameOptions::default();
    let target = renderer.create_target(options.width, options.height);
    let (start, poses) = poses(&scene, options);
    // Warm-up: pipelines, buffer growth.
    renderer.draw(&start, &frame_options, &target)?;

    // Playing and still, interleaved at the same poses: playing advances the time by one
    // display frame, evaluates the set there and draws; still draws the same pose again.
    time.toggle_play();
    let (mut still, mut playing, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for camera in &poses {
        time.advance(1.0 / DISPLAY_HZ);
        let play = timed(|| {
            renderer.show_time(&scene, time.frame())?;
            renderer.draw(camera, &frame_options, &target)
        })?;
        let draw = timed(|| renderer.draw(camera, &frame_options, &target))?;
        playing.push(play);
        still.push(draw);
        ratios.push(play / draw);
    }
    // The evaluate pass by itself, the GPU waited for.
    let mut evaluate = Vec::new();
    for _ in 0..options.frames {
        time.advance(1.0 / DISPLAY_HZ);
        evaluate.push(timed(|| {
            renderer.show_time(&scene, time.frame())?;
            renderer.wait()
        })?);
    }
    let period = scene.num_times();
    drop(scene);
    std::fs::remove_file(&path).map_err(|e| e.to_string())?;
    Ok(Interpolated {
        period,
        frames_per_display_frame: synthetic::FPS / DISPLAY_HZ,
        spacetime_bytes,
        load_ms,
        still_ms_min: min(&still),
        still_ms_median: median(&mut still),
        playing_ms_min: min(&playing),
        playing_ms_median: median(&mut playing),
        playing_over_still: median(&mut ratios),
        evaluate_ms_median: median(&mut evaluate),
    })
}

fn run() -> Result<(), String> {
    if std::env::args().nth(1).as_deref() == Some("--adapter") {
        // What bench/gpu.sh checks before a GPU run: the adapter PANO4D_ADAPTER picks.
        let adapter = FrameRenderer::headless()?.adapter().clone();
        println!(
            "{} ({}, {})",
            adapter.name, adapter.backend, adapter.device_type
        );
        return Ok(());
    }
    let options = parse()?;
    let mut resident = FrameRenderer::headless()?;
    let mut streamed = FrameRenderer::headless()?;
    let mut baseline =
        Renderer::new(GpuContext::new().map_err(|e| e.to_string())?).map_err(|e| e.to_string())?;
    let adapter = resident.adapter().clone();
    println!(
        "viewer render path, {}x{}, SH degree {}, {} timestamps, adapter {} ({})",
        options.width,
        options.height,
        options.sh_degree,
        options.times,
        adapter.name,
        adapter.backend
    );
    println!(
        "{:>10} {:>9} | {:>9} {:>7} | {:>10} {:>7} {:>6} | {:>11} | {:>9} | {:>8} {:>9}",
        "gaussians",
        "dynamic",
        "still ms",
        "fps",
        "playing ms",
        "fps",
        "ratio",
        "streamed ms",
        "upload ms",
        "load ms",
        "resident"
    );
    let mut cases = Vec::new();
    for &count in &options.counts {
        let case = run_case(&mut resident, &mut streamed, &mut baseline, count, &options)?;
        println!(
            "{:>10} {:>9} | {:>9.1} {:>7.1} | {:>10.1} {:>7.1} {:>5.3}x | {:>11.1} | {:>9.1} | \
             {:>8.0} {:>8}M",
            case.gaussians,
            case.dynamic_gaussians,
            case.still_ms_median,
            1e3 / case.still_ms_median,
            case.playing_ms_median,
            1e3 / case.playing_ms_median,
            case.playing_over_still,
            case.streamed_ms_median,
            case.upload_ms_median,
            case.load_ms,
            case.resident_bytes.div_ceil(1 << 20),
        );
        println!(
            "{:>10} time change alone: copy {:.2} ms (resident) | decode {:.1} ms + upload \
             {:.2} ms (streamed); playback {}",
            "",
            case.copy_ms_median,
            case.decode_ms_median,
            case.upload_set_ms_median,
            case.playback
        );
        let v2 = &case.version_2;
        println!(
            "{:>10} version 2, interpolated ({:.3} frame a display frame): still {:.1} ms | \
             playing {:.1} ms | v2 ratio {:.3}x | evaluate alone {:.2} ms | load {:.0} ms",
            "",
            v2.frames_per_display_frame,
            v2.still_ms_median,
            v2.playing_ms_median,
            v2.playing_over_still,
            v2.evaluate_ms_median,
            v2.load_ms
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
