"""When a lifting optimisation has converged: the rule that lets a dynamic set's iterations
follow the change between frames instead of a fixed count.

An optimisation records its loss every ``LOSS_EVERY`` steps (``diagnosis.TrainLog``), each
record the loss of that step's one view, drawn at random, and which view that was. Views
differ in how hard they are far more than a converging fit changes between two records, so
the rule never compares records of different views: each record is set against the last
record of the same view.

- **Converged**: over the last ``window`` steps, the median of the same-view pairs' relative
  fall per step, times the window, is under ``tolerance`` — the loss would fall by less than
  that share of itself in another window — at two checks half a window apart.
- **At its level** (the warm-started timestamps): over the last window, the median excess of
  each record over the same view's last record in the earlier timestamps (``reference``:
  where their fits ended) is under ``tolerance``: this frame is fitted as well as the
  earlier ones were, so a frame that barely changed costs a window, and one that changed a
  lot runs until its loss stops falling.

Everything is relative (a share of the loss; a window that is a share of the preset's count),
so the rule means the same on every scene and preset. A median needs ``MIN_PAIRS`` pairs;
with fewer the rule waits. It never stops before ``floor`` steps and always at ``ceiling``
(the preset's count). The decision reads only recorded losses, which are part of every
checkpoint, so a resumed run stops where the uninterrupted one would have.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from statistics import median

WINDOW_SHARE = 0.2  # a window is this share of the preset's step count…
MIN_WINDOW = 20  # …and at least this many steps (two loss records)
TOLERANCE = 0.02  # a share of the loss: under it per window, the loss has stopped falling
MIN_PAIRS = 2  # same-view pairs a median needs

Record = dict[str, float]  # {"step", "view", "total", other terms…}


@dataclass(frozen=True)
class StopRule:
    """When to stop an optimisation of at most ``ceiling`` steps."""

    ceiling: int
    window: int  # steps per window
    tolerance: float
    floor: int  # steps always taken
    reference: dict[int, float] | None = None  # view → where the earlier timestamps ended

    @classmethod
    def fixed(cls, count: int) -> StopRule:
        """Exactly ``count`` steps (the static set: its count is its preset's)."""
        return cls(count, count, 0.0, count)

    @classmethod
    def for_count(
        cls, preset_count: int, ceiling: int, earlier: Iterable[Sequence[Record]] = ()
    ) -> StopRule:
        """The rule for an optimisation whose preset count is ``preset_count``, of at most
        ``ceiling`` steps, after the optimisations whose records are ``earlier`` (oldest
        first: the earlier timestamps of the same set)."""
        window = max(MIN_WINDOW, round(WINDOW_SHARE * preset_count))
        reference = {int(r["view"]): r["total"] for records in earlier for r in records
                     if "view" in r and "total" in r}  # fmt: skip
        return cls(ceiling, window, TOLERANCE, min(ceiling, window), reference or None)

    def check(self, losses: Sequence[Record], step: int) -> Stop | None:
        """The stop at ``step`` given the records so far, or None to go on."""
        if step >= self.ceiling:
            return Stop(step, "count", None)
        if step < self.floor:
            return None
        level = self._excess(losses, step)
        if level is not None and level < self.tolerance:
            return Stop(step, "level", level)
        falls = [self._fall(losses, end) for end in (step - self.window // 2, step)]
        if all(f is not None and f < self.tolerance for f in falls):
            return Stop(step, "converged", falls[-1])
        return None

    def _in_window(self, losses: Sequence[Record], end: float) -> list[Record]:
        return [r for r in losses if end - self.window < r["step"] <= end and "view" in r]

    def _fall(self, losses: Sequence[Record], end: float) -> float | None:
        """The median same-view relative fall per step over the window ending at ``end``,
        times the window; None with fewer than MIN_PAIRS pairs."""
        rates = []
        for r in self._in_window(losses, end):
            earlier = [q for q in losses if q["step"] < r["step"] and q.get("view") == r["view"]]
            if earlier and earlier[-1]["total"] > 0:
                q = earlier[-1]
                rates.append((q["total"] - r["total"]) / q["total"] / (r["step"] - q["step"]))
        return median(rates) * self.window if len(rates) >= MIN_PAIRS else None

    def _excess(self, losses: Sequence[Record], end: float) -> float | None:
        """The median relative excess of the window's records over the same views' ends in
        the earlier timestamps; None without a reference or with fewer than MIN_PAIRS."""
        if self.reference is None:
            return None
        excess = [(r["total"] - self.reference[int(r["view"])]) / self.reference[int(r["view"])]
                  for r in self._in_window(losses, end)
                  if self.reference.get(int(r["view"]), 0.0) > 0]  # fmt: skip
        return median(excess) if len(excess) >= MIN_PAIRS else None


@dataclass(frozen=True)
class Stop:
    """Where and why an optimisation stopped."""

    step: int
    # "count": the preset's count; "converged": the loss stopped falling; "level": it is
    # where the earlier timestamps ended
    reason: str
    measure: float | None  # the fall per window or the excess that stopped it

    def to_dict(self) -> dict[str, float | int | str | None]:
        return {"step": self.step, "reason": self.reason, "measure": self.measure}
