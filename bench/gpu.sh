#!/usr/bin/env bash
# Every GPU figure in one command: the rasteriser, the viewer, the full-size Panoramic
# Denoiser, the training step and the quality presets, all JSON into one folder.
#
#   bench/gpu.sh [--smoke] [--dry-run] [OUT] [PART ...]
#
#   OUT        folder for every JSON, log and summary.json (default bench/out/gpu-DATE-TIME)
#   PART       raster viewer animate train_step quality (default all, in this order)
#   --smoke    each part at a tiny size on whatever adapter there is (lavapipe and the CPU
#              here): checks the script and the benches; its figures mean nothing
#   --dry-run  check the prerequisites and print the commands; run nothing
#
# Exit status: 0 every part passed; 1 a part failed (the summary names it; the others still
# ran); 2 a prerequisite is missing (one line each; nothing ran).
#
# What each part needs and how to bring it to a GPU machine without network: see
# bench/README.md. In short, on the GPU machine: an NVIDIA driver with its Vulkan ICD, the
# Vulkan loader (libvulkan1 libegl1 libglvnd0 ... unpacked with dpkg -x into .gl/, put on
# LD_LIBRARY_PATH here), the extension python/pano4d/_core.abi3.so and
# target/release/viewer-bench built here (abi3-py311 loads on Python 3.12), the wheels the
# machine lacks in .whl/ (installed offline here when a module is missing), torch with CUDA.
#
# Knobs (environment): PANO4D_GPU_PYTHON (interpreter; default .venv/bin/python, else
# python3), VIEWER_BENCH (default target/release/viewer-bench), PANO4D_WHEELS (default
# .whl), PANO4D_VULKAN_ROOT (default .gl), VK_DRIVER_FILES (default the NVIDIA ICD under
# /usr/local/nvidia when it exists), PART_TIMEOUT (seconds per part, default 540: under the
# 10-minute limit of one command on the lent GPU machines; 1800 with --smoke),
# SVD_WEIGHTS (where the random full-size SVD is written once and reused, default
# /tmp/pano4d-svd-full), ANIMATE_ARGS, QUALITY_ARGS, TRAIN_STEP_ARGS (replace the parts'
# default arguments).

set -uo pipefail
cd "$(dirname "$0")/.."

ALL_PARTS=(raster viewer animate train_step quality)
smoke=0
dry_run=0
out=""
parts=()
for arg in "$@"; do
    case "$arg" in
        --smoke) smoke=1 ;;
        --dry-run) dry_run=1 ;;
        -h | --help) awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "$0"; exit 0 ;;
        raster | viewer | animate | train_step | quality) parts+=("$arg") ;;
        -*) echo "gpu.sh: unknown option $arg (see bench/gpu.sh --help)" >&2; exit 2 ;;
        *)
            if [ -n "$out" ]; then
                echo "gpu.sh: unknown part $arg (parts: ${ALL_PARTS[*]})" >&2
                exit 2
            fi
            out="$arg"
            ;;
    esac
done
[ ${#parts[@]} -eq 0 ] && parts=("${ALL_PARTS[@]}")
out="${out:-bench/out/gpu-$(date +%Y%m%d-%H%M%S)}"

if [ -n "${PANO4D_GPU_PYTHON:-}" ]; then
    PY="$PANO4D_GPU_PYTHON"
elif [ -x .venv/bin/python ]; then
    PY=.venv/bin/python
else
    PY=python3
fi
VIEWER_BENCH="${VIEWER_BENCH:-target/release/viewer-bench}"
WHEELS="${PANO4D_WHEELS:-.whl}"
VULKAN_ROOT="${PANO4D_VULKAN_ROOT:-.gl}"
# Under the 10-minute limit of one command on the lent GPU machines; smoke runs on a
# loaded 2-core machine take longer (raster.py --quick's torch reference alone minutes).
PART_TIMEOUT="${PART_TIMEOUT:-$([ $smoke -eq 1 ] && echo 1800 || echo 540)}"
SVD_WEIGHTS="${SVD_WEIGHTS:-/tmp/pano4d-svd-full}"
LAKE=../shared/data/pano_lake.jpg
export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"

# The Vulkan loader unpacked beside the repository, and on a GPU the NVIDIA ICD.
for lib in "$VULKAN_ROOT/usr/lib/x86_64-linux-gnu" "$VULKAN_ROOT/lib/x86_64-linux-gnu"; do
    [ -d "$lib" ] && export LD_LIBRARY_PATH="$PWD/$lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
done
if [ $smoke -eq 0 ]; then
    export PANO4D_ADAPTER="${PANO4D_ADAPTER:-gpu}"
    nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$nvidia_icd" ]; then
        export VK_DRIVER_FILES="$nvidia_icd"
    fi
fi

has_part() {
    local p
    for p in "${parts[@]}"; do [ "$p" = "$1" ] && return 0; done
    return 1
}
python_parts=0
for p in raster animate train_step quality; do has_part "$p" && python_parts=1; done
vulkan_parts=0
for p in raster viewer train_step quality; do has_part "$p" && vulkan_parts=1; done

# --- prerequisites: one line for each that is missing ---------------------------------------
missing=()
need() { missing+=("$1"); }

# Python module -> the wheel that provides it.
wheel_of() {
    case "$1" in
        OpenImageIO) echo openimageio ;;
        pydantic_core) echo pydantic-core ;;
        annotated_types) echo annotated-types ;;
        typing_inspection) echo typing-inspection ;;
        lazy_importer) echo lazy-importer ;;
        huggingface_hub) echo huggingface-hub ;;
        yaml) echo pyyaml ;;
        *) echo "$1" ;;
    esac
}

modules_missing() {
    "$PY" - "$@" <<'PY'
import importlib.util
import sys

for name in sys.argv[1:]:
    try:
        found = importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        print(name)
PY
}

if [ $python_parts -eq 1 ]; then
    modules=(numpy torch yaml rich pydantic pydantic_core annotated_types typing_inspection
             typing_extensions OpenImageIO)
    has_part animate && modules+=(diffusers transformers safetensors huggingface_hub
                                  importlib_metadata lazy_importer)
    has_part quality && modules+=(kornia kornia_rs)
    if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
        need "Python 3.11 or later: '$PY' does not run or is older (set PANO4D_GPU_PYTHON)"
    else
        absent=$(modules_missing "${modules[@]}")
        if [ -n "$absent" ] && [ -d "$WHEELS" ] && [ $dry_run -eq 0 ]; then
            names=()
            for m in $absent; do names+=("$(wheel_of "$m")"); done
            echo "installing from $WHEELS (offline): ${names[*]}"
            "$PY" -m pip install --quiet --no-index --find-links "$WHEELS" "${names[@]}" ||
                echo "gpu.sh: the offline install from $WHEELS failed; the lines below say what is missing"
            absent=$(modules_missing "${modules[@]}")
        fi
        for m in $absent; do
            need "Python module $m: put the $(wheel_of "$m") wheel (for this Python) in $WHEELS/, or pip install it"
        done
        if ! compgen -G "python/pano4d/_core*.so" >/dev/null; then
            need "python/pano4d/_core.abi3.so: build it with 'maturin develop --release' on a machine with Rust and bring it along"
        fi
        if [ $smoke -eq 0 ] && has_part animate && ! echo "$absent" | grep -qx torch; then
            "$PY" -c 'import sys, torch; sys.exit(not torch.cuda.is_available())' 2>/dev/null ||
                need "CUDA: torch in '$PY' sees no GPU (animate runs SVD's full UNet on one)"
        fi
    fi
fi

if has_part viewer && [ ! -x "$VIEWER_BENCH" ]; then
    need "$VIEWER_BENCH: build it with 'cargo build --release -p pano4d-viewer --bin viewer-bench' and bring it along (or set VIEWER_BENCH)"
fi

if [ $vulkan_parts -eq 1 ]; then
    loader=0
    # (grep without -q: an early exit would break ldconfig's pipe under pipefail)
    ldconfig -p 2>/dev/null | grep 'libvulkan\.so\.1 ' >/dev/null && loader=1
    IFS=: read -ra lib_dirs <<<"${LD_LIBRARY_PATH:-}"
    for d in "${lib_dirs[@]}"; do [ -e "$d/libvulkan.so.1" ] && loader=1; done
    if [ $loader -eq 0 ]; then
        need "the Vulkan loader libvulkan.so.1: apt-get install libvulkan1, or unpack its deb (dpkg -x) into $VULKAN_ROOT/"
    elif [ $smoke -eq 0 ] && [ -n "${VK_DRIVER_FILES:-}" ] && [ ! -f "$VK_DRIVER_FILES" ]; then
        need "VK_DRIVER_FILES=$VK_DRIVER_FILES does not exist: point it at the GPU's Vulkan ICD json"
    elif [ $smoke -eq 0 ]; then
        # The adapter wgpu picks with PANO4D_ADAPTER=gpu; an error names what it found.
        adapter=""
        if [ -x "$VIEWER_BENCH" ]; then
            adapter=$("$VIEWER_BENCH" --adapter 2>&1 | grep -v XDG_RUNTIME_DIR | tail -1)
        elif [ $python_parts -eq 1 ] && [ ${#missing[@]} -eq 0 ]; then
            adapter=$("$PY" -c 'from pano4d.renderer import adapter_info as a; i = a()
print("%s (%s, %s)" % (i["name"], i["backend"], i["device_type"]))' 2>&1 | tail -1)
        fi
        case "$adapter" in
            "") ;; # nothing to ask yet: the lines above say what is missing first
            *Gpu*) echo "adapter: $adapter" ;;
            *) need "a GPU Vulkan adapter: wgpu found '$adapter' (is VK_DRIVER_FILES the NVIDIA ICD json?)" ;;
        esac
    fi
fi

if has_part quality && ! command -v ffmpeg >/dev/null; then
    # The imageio-ffmpeg wheel carries a static ffmpeg: link it where PATH finds it.
    exe=$("$PY" -c 'import imageio_ffmpeg; print(imageio_ffmpeg.get_ffmpeg_exe())' 2>/dev/null)
    if [ -n "$exe" ] && [ $dry_run -eq 0 ]; then
        mkdir -p "$out/.bin" && ln -sf "$exe" "$out/.bin/ffmpeg"
        export PATH="$PWD/$out/.bin:$PATH"
    elif [ -z "$exe" ]; then
        need "ffmpeg on PATH (quality: training writes preview.mp4): install it, or put the imageio-ffmpeg wheel in $WHEELS/"
    fi
fi

if [ ${#missing[@]} -gt 0 ]; then
    for line in "${missing[@]}"; do echo "gpu.sh: missing: $line" >&2; done
    exit 2
fi

# --- the parts ------------------------------------------------------------------------------
panorama="$LAKE"
[ -f "$LAKE" ] || panorama=synthetic
if [ $smoke -eq 1 ]; then
    raster_cmd=("$PY" bench/raster.py --quick --repeats 1)
    viewer_cmd=("$VIEWER_BENCH" --quick --counts 5000 --frames 2 --size 320x180
                --json "$out/viewer.json")
    animate_args="${ANIMATE_ARGS:---frames 2 --steps 1 --worth 1 --decode-widths 512}"
    quality_args="${QUALITY_ARGS:---presets draft --width 512 --frames 2}"
    train_step_args="${TRAIN_STEP_ARGS:---sizes draft --steps 1 --width 512}"
else
    raster_cmd=("$PY" bench/raster.py --repeats 5)
    viewer_cmd=("$VIEWER_BENCH" --size 1920x1080 --sh-degree 3 --counts 100000,1000000,3000000
                --times 14 --frames 30 --json "$out/viewer.json")
    # Per-step figures need few steps; all 25 take longer than one 10-minute call.
    animate_args="${ANIMATE_ARGS:---full --steps 5 --weights $SVD_WEIGHTS}"
    quality_args="${QUALITY_ARGS:---presets draft balanced --frames 2}"
    # #12's GPU targets: the resident step against the old path and gsplat + torch Adam.
    train_step_args="${TRAIN_STEP_ARGS:---sizes draft balanced max --steps 5 --gsplat}"
fi
read -ra animate_extra <<<"$animate_args"
read -ra quality_extra <<<"$quality_args"
read -ra train_step_extra <<<"$train_step_args"
animate_cmd=("$PY" bench/animate.py "${animate_extra[@]}" --panorama "$panorama"
             --json "$out/animate.json")
quality_cmd=("$PY" bench/quality.py "${quality_extra[@]}" --json "$out/quality.json")
train_step_cmd=("$PY" bench/train_step.py "${train_step_extra[@]}" --json "$out/train_step.json")

command_of() {
    local name="${1}_cmd[@]"
    printf '%q ' "${!name}"
}

if [ $dry_run -eq 1 ]; then
    echo "prerequisites: all present ($([ $smoke -eq 1 ] && echo smoke || echo GPU) mode)"
    [ "$panorama" = synthetic ] && has_part animate &&
        echo "note: $LAKE is not here; animate uses a synthetic panorama"
    for part in "${parts[@]}"; do
        echo "$part: $(command_of "$part")"
    done
    exit 0
fi

mkdir -p "$out"
marker="$out/.started"
touch "$marker"
declare -A status seconds
failed=()
for part in "${parts[@]}"; do
    name="${part}_cmd[@]"
    echo "== $part: $(command_of "$part")"
    start=$(date +%s)
    timeout --kill-after=30 "$PART_TIMEOUT" "${!name}" 2>&1 | tee "$out/$part.log"
    code=${PIPESTATUS[0]}
    seconds[$part]=$(($(date +%s) - start))
    # Benches without an output option write bench/out/<part>*.json: collect this run's.
    for json in bench/out/"$part"*.json; do
        [ -f "$json" ] && [ "$json" -nt "$marker" ] && cp "$json" "$out/"
    done
    if [ "$code" -eq 0 ]; then
        status[$part]=passed
    else
        [ "$code" -eq 124 ] && echo "== $part: stopped after PART_TIMEOUT=${PART_TIMEOUT}s"
        status[$part]="failed (exit $code)"
        failed+=("$part")
    fi
done

{
    echo "{"
    echo "  \"mode\": \"$([ $smoke -eq 1 ] && echo smoke || echo gpu)\","
    echo "  \"date\": \"$(date -u +%Y-%m-%dT%H:%M:%SZ)\","
    echo "  \"host\": \"$(uname -n)\","
    echo "  \"parts\": {"
    sep=""
    for part in "${parts[@]}"; do
        printf '%s    "%s": {"status": "%s", "seconds": %s}' "$sep" "$part" "${status[$part]}" "${seconds[$part]}"
        sep=$',\n'
    done
    printf '\n  }\n}\n'
} >"$out/summary.json"

echo "== summary ($out)"
for part in "${parts[@]}"; do printf '%-11s %s (%ss)\n' "$part" "${status[$part]}" "${seconds[$part]}"; done
if [ ${#failed[@]} -gt 0 ]; then
    echo "failed: ${failed[*]} (logs in $out)"
    exit 1
fi
