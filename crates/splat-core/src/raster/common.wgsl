// Shared by every rasteriser kernel (the first part of each module, raster/mod.rs's
// COMMON_WGSL): the render parameters, the projected Gaussian, constants and the helpers
// of linear dispatches and tiles.

// Rust: raster/params.rs's `RenderParams` (the one declaration; the wgsl tests check this
// one against it).
struct RenderParams {
    // World-to-camera rows; w holds the translation component.
    rot_row0: vec4<f32>,
    rot_row1: vec4<f32>,
    rot_row2: vec4<f32>,
    // Camera centre in world coordinates (w unused).
    cam_pos: vec4<f32>,
    // fx, fy, cx, cy in pixels.
    intrinsics: vec4<f32>,
    // Clamp limits of x/z and y/z for the EWA Jacobian (1.3 · tan(half fov)), unused, unused.
    jacobian_limits: vec4<f32>,
    background: vec4<f32>,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    num_gaussians: u32,
    sh_coeffs: u32,
    antialiased: u32,
    // Room in the per-intersection buffers: a frame with more intersections draws nothing
    // and is recorded as overflowed (tiles.wgsl, `plan_intersections`).
    intersection_capacity: u32,
    // Length of each SoA section of the Gaussian buffer (≥ num_gaussians: a GpuScene
    // keeps room for its largest dynamic set).
    gaussian_stride: u32,
    // Added to every log-scale as it is read (the viewer's splat-scale slider; 0 in training).
    log_scale_offset: f32,
    // 1: add an overflow to the running counts the host checks now and then (a training
    // loop's frames); 0: the caller checks this frame itself (one-off renders).
    record_overflow: u32,
    // The first n_static Gaussians are the frozen static set: the backward gives them zero
    // gradients without summing any (0 outside training sessions).
    n_static: u32,
    // 1: the static set's own render of this camera is bound to the blending, which
    // copies the tiles no trained Gaussian reaches from it (blend/rasterize.wgsl).
    static_render: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

const TILE_SIZE: u32 = 16u;
const NEAR_PLANE: f32 = 0.01;
// The screen-space filter added to every 2D covariance (pixels²): the classic mode's is
// 3DGS's dilation, drawn at full opacity; the antialiased mode's is Mip-Splatting's 2D filter
// (about a one-pixel box's variance, 1/12), with the opacity scaled to keep each Gaussian's
// integral (docs/rasterizer.md, "Two modes": 0.1 against 0.3 measured there).
const LOW_PASS: f32 = 0.3;
const MIP_FILTER: f32 = 0.1;

fn screen_filter(antialiased: u32) -> f32 {
    return select(LOW_PASS, MIP_FILTER, antialiased != 0u);
}
const MIN_LOG_SCALE: f32 = -12.0;
const MAX_LOG_SCALE: f32 = 8.0;
const ALPHA_MAX: f32 = 0.999;
const ALPHA_MIN: f32 = 1.0 / 255.0;
const T_MIN: f32 = 1e-4;
// Pixels outside the 3-sigma ellipse are skipped: power = -0.5 * d^2 < -4.5.
const POWER_MIN: f32 = -4.5;

// Projected Gaussian, one per input Gaussian (culled ones have radius 0). Rust:
// raster/params.rs's `Projected`.
struct Projected {
    // mean2d.x, mean2d.y, opacity (after the antialiasing factor), camera z
    xy_opacity_z: vec4<f32>,
    // conic a, b, c (inverse 2D covariance) and the pixel radius
    conic_radius: vec4<f32>,
    // view-dependent colour, w unused
    rgb: vec4<f32>,
}

fn is_finite_f32(x: f32) -> bool {
    // Bit test: compilers may fold x != x away under fast-math assumptions.
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn all_finite3(v: vec3<f32>) -> bool {
    return all((bitcast<vec3<u32>>(v) & vec3<u32>(0x7f800000u)) != vec3<u32>(0x7f800000u));
}

fn all_finite4(v: vec4<f32>) -> bool {
    return all((bitcast<vec4<u32>>(v) & vec4<u32>(0x7f800000u)) != vec4<u32>(0x7f800000u));
}

// Linear workgroup index for dispatches split over x and y (x is at most 65535).
fn linear_workgroup(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

// (x, y, 1) workgroups for an indirect dispatch of `groups` linear workgroups, as the host's
// `dispatch_linear` splits them: x at most 65535.
fn dispatch_grid(groups: u32) -> vec3<u32> {
    if groups == 0u {
        return vec3<u32>(0u, 1u, 1u);
    }
    let x = min(groups, 65535u);
    return vec3<u32>(x, (groups + x - 1u) / x, 1u);
}

// Tile rectangle [min, max) touched by a projected Gaussian; both ends clamped to the grid.
fn tile_rect(rp: RenderParams, xy: vec2<f32>, radius: f32) -> vec4<u32> {
    let tiles = vec2<f32>(f32(rp.tiles_x), f32(rp.tiles_y));
    let lo = clamp(floor((xy - vec2<f32>(radius)) / f32(TILE_SIZE)), vec2<f32>(0.0), tiles);
    let hi = clamp(floor((xy + vec2<f32>(radius)) / f32(TILE_SIZE)) + 1.0, vec2<f32>(0.0), tiles);
    return vec4<u32>(vec2<u32>(lo), vec2<u32>(hi));
}

// The pixel one invocation of a 16x16 tile workgroup blends (rasterize and its backward).
struct TilePixel {
    tile: u32,
    inside: bool,
    // Index into per-pixel arrays (meaningful only when inside).
    index: u32,
    centre: vec2<f32>,
}

fn tile_pixel(rp: RenderParams, wid: vec3<u32>, lxy: vec3<u32>) -> TilePixel {
    let px = wid.x * TILE_SIZE + lxy.x;
    let py = wid.y * TILE_SIZE + lxy.y;
    return TilePixel(wid.y * rp.tiles_x + wid.x, px < rp.width && py < rp.height,
                     py * rp.width + px, vec2<f32>(f32(px) + 0.5, f32(py) + 0.5));
}
