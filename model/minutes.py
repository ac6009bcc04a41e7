"""train.minutes: a run trains the whole epochs that fit in a number of minutes on this machine
(at most train.epochs), decided once from its own first steps and recorded in its checkpoints.

The steps are timed during the learning rate's warm-up, whose rate does not depend on the total,
so a run that decides N epochs trains bit for bit as one given train.epochs N from the start; a
resumed run keeps the recorded decision (latest.pt's `minutes`), so its resume stays exact.

    budget = MinutesBudget(run.cfg, first_step=run.step, started=clock())
    ... after each optimiser step: record = budget.after_step(step, epoch_steps, world)
"""

from __future__ import annotations

import math
import time

import torch
import torch.distributed as dist

SKIP = 5  # this process's first steps, not timed (first reads of the frames, allocator, oneDNN's kernel choice)
TIMED = 10  # at least this many steps timed
DECIDE_BY = 50  # the step that decides, at the latest (earlier where the warm-up ends earlier)


def clock() -> float:
    return time.perf_counter()


def decision_step(t: dict) -> int:
    """The optimiser step after which the epochs are decided: the warm-up's last (at most DECIDE_BY)
    under a cosine schedule, whose rate until then does not depend on the total; else DECIDE_BY."""
    return min(t["warmup_steps"], DECIDE_BY) if t["lr_schedule"] == "cosine" else DECIDE_BY


def epochs_for_minutes(minutes: float, spent_s: float, s_per_step: float, step: int, epoch_steps: int, cap: int) -> int:
    """The whole epochs a run can train in `minutes`, `spent_s` gone at optimiser step `step`, the
    rest at `s_per_step`: at least the epoch it is in, at most `cap` (train.epochs)."""
    fit = step + max(0.0, minutes * 60.0 - spent_s) / s_per_step
    return int(min(cap, max(1, math.ceil(step / epoch_steps), fit // epoch_steps)))


class MinutesBudget:
    """Times this process's steps SKIP.. up to the decision step (at least TIMED of them), then
    decides the epochs once; the minutes count from `started` (train()'s start, set-up included)
    plus, in a run resumed before its decision, its earlier steps at the measured rate."""

    def __init__(self, cfg: dict, first_step: int, started: float):
        t = cfg["train"]
        self.minutes, self.cap = t["minutes"], t["epochs"]
        self.first, self.started = first_step, started
        self.at = max(decision_step(t), first_step + SKIP + TIMED)
        self.mark: tuple[int, float] | None = None

    def after_step(self, step: int, epoch_steps: int, world: int = 1, device=None) -> dict | None:
        """Call after optimiser step `step` (1-based count of steps done); -> the decision record
        {'minutes', 'epochs', 's_per_step', 'timed': [from, to], 'spent_s'} at the decision step,
        else None. Under DDP every process decides alike (the slowest process's rate)."""
        if step == self.first + SKIP:
            self.mark = (step, clock())
        if step < self.at or self.mark is None:
            return None
        now = clock()
        s_per_step = (now - self.mark[1]) / (step - self.mark[0])
        spent = now - self.started + self.first * s_per_step
        if world > 1:
            x = torch.tensor([s_per_step, spent], dtype=torch.float64, device=device)
            dist.all_reduce(x, op=dist.ReduceOp.MAX)
            s_per_step, spent = x.tolist()
        epochs = epochs_for_minutes(self.minutes, spent, s_per_step, step, epoch_steps, self.cap)
        return {"minutes": self.minutes, "epochs": epochs, "s_per_step": round(s_per_step, 4),
                "timed": [self.mark[0], step], "spent_s": round(spent, 1)}


def describe(record: dict, total_steps: int) -> str:
    """One line: what a run's train.minutes decided, and from what."""
    return (f"train.minutes {record['minutes']:g}: {record['epochs']} epochs ({total_steps} steps), "
            f"from {record['s_per_step']:.3f} s a step over steps {record['timed'][0]}-{record['timed'][1]} "
            f"and {record['spent_s'] / 60:.1f} min spent by then")
