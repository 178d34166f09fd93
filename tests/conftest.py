"""Shared test fixtures."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest
import torch


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Run a test on one torch thread: on two shared cores, small ops only contend otherwise."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def interrupt_train() -> Callable[[Any, list[tuple[str, int]]], None]:
    """``run(cfg, stops)``: ``run_train(cfg)`` (torch rasteriser, a checkpoint every 4 steps)
    once per ``(stage, step)`` in ``stops``, each killed there by a KeyboardInterrupt from
    ``on_step``: a run interrupted mid-stage, for the resume tests."""
    from pano4d.train import run_train

    def run(cfg: Any, stops: list[tuple[str, int]]) -> None:
        pending = list(stops)

        def interrupt(stage: str, step: int) -> None:
            if pending and (stage, step) == pending[0]:
                pending.pop(0)
                raise KeyboardInterrupt

        for _ in stops:
            with pytest.raises(KeyboardInterrupt):
                run_train(cfg, progress=False, render_backend="torch", checkpoint_every=4,
                          on_step=interrupt)  # fmt: skip

    return run
