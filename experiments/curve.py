"""Accuracy against training time: the validation scores train.py logged of one or more
runs (`train.val_every` steps on `data.val_split`, TensorBoard scalars `val/...`), as a table and a
picture, so that a run that has not reached its goal says how far it is and how fast it moves.

    python -m experiments.curve RUN [RUN ...] [--metrics miou iou/vehicle iou/lane_marking] [--out curve.png]

Training time is measured from the `train/loss` scalars' wall times (logged every
`train.log_every` steps), with the pauses of a stopped and resumed run taken out: a gap longer
than 10 times the run's median time between two logged steps counts as that median.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import write_bytes_atomic
from model.run_dir import RunDir

DEFAULT_METRICS = ("miou", "iou/vehicle", "iou/lane_marking")
PAUSE = 10.0  # a gap this many times the median step interval is a pause (stop and resume)


class CurveError(InputError):
    pass


def _scalars(tb: Path) -> dict[str, list[tuple[int, float, float]]]:
    """tag -> [(step, wall time, value)] over every event file of the folder, sorted by step
    (a resumed run writes a new file; the last value logged at a step wins)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, dict[int, tuple[float, float]]] = {}
    for f in sorted(tb.glob("events.out.tfevents.*")):
        ea = EventAccumulator(str(f), size_guidance={"scalars": 0})
        ea.Reload()
        for tag in ea.Tags()["scalars"]:
            for e in ea.Scalars(tag):
                out.setdefault(tag, {})[e.step] = (e.wall_time, e.value)
    return {tag: [(s, w, v) for s, (w, v) in sorted(d.items())] for tag, d in out.items()}


def training_seconds(points: list[tuple[int, float, float]]) -> dict[int, float]:
    """step -> training seconds so far, from (step, wall time, _) points, pauses taken out."""
    if not points:
        return {}
    steps = np.array([p[0] for p in points], dtype=np.float64)
    walls = np.array([p[1] for p in points], dtype=np.float64)
    dt = np.diff(walls)
    per_step = dt / np.maximum(np.diff(steps), 1)
    typical = float(np.median(per_step)) if len(per_step) else 0.0
    paused = per_step > PAUSE * typical
    per_step[paused] = typical
    seconds = np.concatenate([[steps[0] * typical], steps[0] * typical + np.cumsum(per_step * np.diff(steps))])
    return {int(s): float(t) for s, t in zip(steps, seconds)}


def read_curve(run: Path, metrics) -> dict:
    """{'run', 'steps', 'minutes', metric: [...]} of one run folder's validation scores."""
    tb = RunDir(run).tb
    if not tb.is_dir() or not any(tb.glob("events.out.tfevents.*")):
        raise CurveError(f"{run}: no TensorBoard log (expected {tb}/events.out.tfevents.*; was it trained with train.py?)")
    scalars = _scalars(tb)
    missing = [m for m in metrics if f"val/{m}" not in scalars]
    if missing:
        have = sorted(t[4:] for t in scalars if t.startswith("val/"))
        raise CurveError(f"{run}: no validation scores 'val/{missing[0]}' in {tb} "
                         f"(have: {', '.join(have) or 'none; train with data.val_split and train.val_every'})")
    clock = training_seconds(scalars.get("train/loss", []))
    steps = [s for s, _, _ in scalars[f"val/{metrics[0]}"]]
    known = sorted(clock)
    minutes = [clock[max((k for k in known if k <= s), default=known[0])] / 60 if known else float("nan") for s in steps]
    curve = {"run": str(run), "steps": steps, "minutes": minutes}
    for m in metrics:
        by_step = {s: v for s, _, v in scalars[f"val/{m}"]}
        curve[m] = [by_step.get(s, float("nan")) for s in steps]
    return curve


def table(curves: list[dict], metrics) -> str:
    lines = ["| Run | Step | Training min | " + " | ".join(metrics) + " |", "|---|---|---|" + "---|" * len(metrics)]
    for c in curves:
        for i, s in enumerate(c["steps"]):
            lines.append(f"| {c['run']} | {s} | {c['minutes'][i]:.1f} | " + " | ".join(f"{c[m][i]:.3f}" for m in metrics) + " |")
    return "\n".join(lines) + "\n"


def picture(curves: list[dict], metrics) -> bytes:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 3.4), squeeze=False)
    for ax, m in zip(axes[0], metrics):
        for c in curves:
            ax.plot(c["minutes"], c[m], marker="o", ms=3, label=Path(c["run"]).name)
        ax.set_title(m)
        ax.set_xlabel("training minutes")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def main(argv=None) -> int:
    p = ArgumentParser(prog="experiments.curve", description="Validation scores against training time of train.py runs.")
    p.add_argument("runs", nargs="+", help="run folders (train.py --out)")
    p.add_argument("--metrics", nargs="+", default=list(DEFAULT_METRICS), help="val/ scalars (default: miou iou/vehicle iou/lane_marking)")
    p.add_argument("--out", help="write the picture here (PNG)")
    a = p.parse_args(argv)
    curves = [read_curve(Path(r), a.metrics) for r in a.runs]
    print(table(curves, a.metrics), end="")
    if a.out:
        write_bytes_atomic(Path(a.out), picture(curves, a.metrics))
        print(f"written {a.out}")
    return 0


if __name__ == "__main__":
    run_cli(main)
