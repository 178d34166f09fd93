"""``pano4d batch``: many scenes at once, one Ray task per scene.

The driver (``run_batch``) reads every scene.yaml, skips the scenes whose ``metrics.json``
says they are finished for this very config, and hands each other scene to Ray as one task
that runs ``run_train`` on a worker. Each task declares its resources (``num_gpus`` per scene
where the cluster has GPUs, else ``num_cpus``: one scene per CPU slot, rendering through
lavapipe), so Ray's scheduler places the scenes; pano4d schedules nothing itself. Outputs go
where each scene.yaml says (on a cluster that is a shared filesystem): a rerun of the same
batch finds them, and a scene killed half-way resumes from its own checkpoints.

Workers train silently (their output goes to ``OUTPUT/batch.log``) and post their stage to
a small Ray actor, the ``StageBoard``; the driver polls it and draws the only progress
display: one bar for the batch and a line per running scene. A failed scene becomes one
line in the table and in ``batch.json`` and never stops the others.

Ray is an optional dependency (``pip install 'pano4d[cluster]'``); nothing here imports it
at module level, so the rest of pano4d works without it.
"""

from pano4d.batch.driver import BatchReport, SceneOutcome, run_batch
from pano4d.batch.scenes import BatchError, collect_scenes
from pano4d.batch.table import batch_table

__all__ = [
    "BatchError",
    "BatchReport",
    "SceneOutcome",
    "batch_table",
    "collect_scenes",
    "run_batch",
]
