//! Whether every timestamp's dynamic set is kept on the GPU, so that moving the time
//! slider or playing costs what a still frame costs (a GPU-side copy of the shown set
//! after the static set, instead of a decode and an upload), or streamed as it is shown.
//! A version-2 scene has one dynamic set for every time, kept on the GPU and evaluated
//! there at the shown time ([`Playback::Evaluated`]); no budget applies to it.
//!
//! They are kept when each set fits one GPU buffer (the device's `max_buffer_size`: the
//! stored sets are only copied from, never bound, so the smaller storage-binding limit
//! does not apply to them) and all of them together fit the memory budget: 1 GiB unless
//! `PANO4D_VIEW_BUDGET_MIB` says otherwise. That holds 14 timestamps of 300k Gaussians of
//! SH degree 3 (990 MB), a 3·10⁶-Gaussian scene with 10 % of it moving; wgpu does not
//! tell how much memory a GPU has, so the budget is a stated figure rather than a share
//! of it. The static set plus the largest dynamic set must fit one storage binding
//! either way (`FrameRenderer` says so when they do not).

use splat_core::raster::GpuScene;

/// The budget for all stored dynamic sets together when `PANO4D_VIEW_BUDGET_MIB` is unset.
pub const DEFAULT_BUDGET_BYTES: u64 = 1 << 30;
pub const BUDGET_ENV: &str = "PANO4D_VIEW_BUDGET_MIB";

const MIB: u64 = 1 << 20;

/// How the dynamic sets of the loaded scene reach the GPU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Playback {
    /// Every timestamp's set is on the GPU, `bytes` in all.
    Resident { bytes: u64 },
    /// Each set is decoded and uploaded when its timestamp is shown, because of `reason`.
    Streamed { reason: String },
    /// A version-2 scene's spacetime set is on the GPU, `bytes`, and evaluated there at the
    /// shown time (splat_core::spacetime::GpuSpacetimeSet).
    Evaluated { bytes: u64 },
}

impl Playback {
    pub fn is_resident(&self) -> bool {
        matches!(self, Self::Resident { .. })
    }

    /// Whether dynamic sets are decoded on the host as they are shown (what
    /// [`crate::stream::DynamicStream`] does ahead of playback).
    pub fn streams(&self) -> bool {
        matches!(self, Self::Streamed { .. })
    }

    /// One line for the side panel.
    pub fn describe(&self) -> String {
        match self {
            Self::Resident { bytes } => {
                format!("all on the GPU ({} MiB)", bytes.div_ceil(MIB))
            }
            Self::Streamed { reason } => format!("streamed: {reason}"),
            Self::Evaluated { bytes } => {
                format!(
                    "any time, evaluated on the GPU ({} MiB)",
                    bytes.div_ceil(MIB)
                )
            }
        }
    }
}

/// The budget in bytes: `PANO4D_VIEW_BUDGET_MIB` if set (an unreadable value is an error),
/// else [`DEFAULT_BUDGET_BYTES`].
pub fn budget_from_env() -> Result<u64, String> {
    match std::env::var(BUDGET_ENV) {
        Err(_) => Ok(DEFAULT_BUDGET_BYTES),
        Ok(text) => text
            .trim()
            .parse::<u64>()
            .map(|mib| mib.saturating_mul(MIB))
            .map_err(|_| format!("{BUDGET_ENV} must be a whole number of MiB, got {text:?}")),
    }
}

/// Whether dynamic sets of `counts` Gaussians with `sh_coeffs` SH coefficients per channel
/// are kept on a device whose buffers hold at most `max_buffer_size` bytes, within `budget`
/// bytes for all of them.
pub fn plan(counts: &[usize], sh_coeffs: usize, max_buffer_size: u64, budget: u64) -> Playback {
    let sizes: Vec<u64> = counts
        .iter()
        .map(|&n| GpuScene::bytes_for(n, sh_coeffs))
        .collect();
    let total: u64 = sizes.iter().sum();
    if let Some((t, &largest)) = sizes.iter().enumerate().max_by_key(|&(_, &bytes)| bytes) {
        if largest > max_buffer_size {
            return Playback::Streamed {
                reason: format!(
                    "timestamp {t}'s dynamic set takes {} MiB, more than one GPU buffer holds \
                     ({} MiB)",
                    largest.div_ceil(MIB),
                    max_buffer_size / MIB
                ),
            };
        }
    }
    if total > budget {
        return Playback::Streamed {
            reason: format!(
                "the {} dynamic sets take {} MiB, over the {} MiB budget ({BUDGET_ENV})",
                counts.len(),
                total.div_ceil(MIB),
                budget / MIB
            ),
        };
    }
    Playback::Resident { bytes: total }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_are_kept_when_each_fits_a_buffer_and_all_fit_the_budget() {
        let one = GpuScene::bytes_for(1_000, 16);
        let counts = [600, 1_000, 900];
        let all = GpuScene::bytes_for(2_500, 16);
        assert_eq!(
            plan(&counts, 16, one, all),
            Playback::Resident { bytes: all }
        );
        let over_budget = plan(&counts, 16, one, all - 1);
        assert!(!over_budget.is_resident());
        assert!(over_budget.describe().contains("budget"), "{over_budget:?}");
        let too_big = plan(&counts, 16, one - 4, u64::MAX);
        assert!(
            too_big.describe().contains("timestamp 1's dynamic set"),
            "{too_big:?}"
        );
        // No dynamic sets (a static .ply): nothing to stream.
        assert_eq!(plan(&[0], 1, one, 0), Playback::Resident { bytes: 0 });
    }
}
