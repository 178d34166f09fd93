"""The GPU a batch task renders on: wgpu does not read ``CUDA_VISIBLE_DEVICES``, through
which Ray hands a task its GPU, so the task names that GPU's PCI slot to the rasteriser
(``pin_adapter``) from what nvidia-smi lists (``pci_bus_of_gpu``)."""

from __future__ import annotations

import os
import subprocess

# The rasteriser's adapter choice (splat-core raster/context.rs); read when it first starts.
ADAPTER_ENV = "PANO4D_ADAPTER"


def pin_adapter() -> str | None:
    """Point the rasteriser at the GPU Ray gave this task (``PANO4D_ADAPTER=pci:<bus id>``).

    Ray hands a task its GPU through ``CUDA_VISIBLE_DEVICES``, which wgpu does not read: on a
    machine with several GPUs every scene would otherwise render on the first one. Returns
    the preference set, or None (no GPU assigned, one set by the user, or no nvidia-smi to
    name the GPU's slot: then wgpu picks, as ``pano4d train`` does).
    """
    import ray

    gpu_ids = ray.get_gpu_ids()
    if not gpu_ids or os.environ.get(ADAPTER_ENV):
        return os.environ.get(ADAPTER_ENV)
    try:
        listing = subprocess.run(
            ["nvidia-smi", "--query-gpu=index,pci.bus_id", "--format=csv,noheader"],
            capture_output=True, text=True, timeout=30, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    bus = pci_bus_of_gpu(listing, str(gpu_ids[0]))
    if bus is not None:
        os.environ[ADAPTER_ENV] = f"pci:{bus}"
    return os.environ.get(ADAPTER_ENV)


def pci_bus_of_gpu(listing: str, index: str) -> str | None:
    """The PCI bus id of GPU ``index`` in ``nvidia-smi --query-gpu=index,pci.bus_id
    --format=csv,noheader`` output (``0, 00000000:3B:00.0`` per line)."""
    for line in listing.splitlines():
        fields = [field.strip() for field in line.split(",")]
        if len(fields) == 2 and fields[0] == index:
            return fields[1]
    return None
