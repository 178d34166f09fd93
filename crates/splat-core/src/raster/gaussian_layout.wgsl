// Where each parameter of Gaussian i lies in a buffer of SoA sections `n` entries long
// (means, log-scales, quaternions, opacity logits, SH; `SceneInput::packed` in Rust):
// shared by the kernels that read Gaussians, their gradients or their Adam moments.

struct GaussianOffsets {
    means: u32,
    log_scales: u32,
    quats: u32,
    opacity: u32,
    sh: u32,
}

fn gaussian_offsets(n: u32) -> GaussianOffsets {
    return GaussianOffsets(0u, 3u * n, 6u * n, 10u * n, 11u * n);
}
