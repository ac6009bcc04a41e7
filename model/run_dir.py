"""The files of a run folder and of an evaluation folder, named once.

    runs/<name>/            RunDir: what train.py, eval.py, the ablation and demo.py read and write
        latest.pt           the last whole step (resume point; what eval and the ablation score)
        best.pt             the best validation mIoU
        tb/                 TensorBoard logs
        budget.json         the ablation's training time so far (a killed row resumes from it)
        result.json         the ablation's scores of a finished row (never retrained)
        eval/               EvalDir: eval.py's default output folder
            metrics.json, table.md, confusion_<split>.png, frame_<split>_<scene>_<frame>.png,
            predictions/<scene>_<frame>.npz
        compare_<other>/    EvalDir: eval.py --compare against the run folder <other>
            comparison.json, comparison.md, a/ and b/ (each checkpoint's confusion_<split>.png)

Checkpoints themselves are written and read by `model.checkpoint` (one reader for resume, eval
and the ablation).
"""

from __future__ import annotations

from pathlib import Path


class RunDir:
    """A training run's folder."""

    def __init__(self, root):
        self.root = Path(root)

    @classmethod
    def of_checkpoint(cls, checkpoint) -> RunDir:
        """The run folder a checkpoint lies in."""
        return cls(Path(checkpoint).parent)

    @property
    def latest(self) -> Path:
        return self.root / "latest.pt"

    @property
    def best(self) -> Path:
        return self.root / "best.pt"

    @property
    def tb(self) -> Path:
        return self.root / "tb"

    @property
    def budget(self) -> Path:
        return self.root / "budget.json"

    @property
    def result(self) -> Path:
        return self.root / "result.json"

    @property
    def eval(self) -> EvalDir:
        return EvalDir(self.root / "eval")

    def comparison(self, other: str) -> EvalDir:
        """eval.py --compare's default output folder: this run against the run folder `other`."""
        return EvalDir(self.root / f"compare_{other}")


class EvalDir:
    """An evaluation's output folder (eval.py's --out; the ablation's `<run>/eval`)."""

    CONFUSION_GLOB, FRAME_GLOB = "confusion_*.png", "frame_*.png"

    def __init__(self, root):
        self.root = Path(root)

    def __str__(self) -> str:
        return str(self.root)

    @property
    def metrics(self) -> Path:
        return self.root / "metrics.json"

    @property
    def table(self) -> Path:
        return self.root / "table.md"

    def confusion(self, split: str) -> Path:
        return self.root / f"confusion_{split}.png"

    def frame(self, split: str, name: str) -> Path:
        return self.root / f"frame_{split}_{name}.png"

    @property
    def predictions(self) -> Path:
        return self.root / "predictions"

    def prediction(self, name: str) -> Path:
        return self.predictions / f"{name}.npz"

    @property
    def comparison(self) -> Path:
        """eval.py --compare: both checkpoints' scores and their paired difference per split."""
        return self.root / "comparison.json"

    @property
    def comparison_table(self) -> Path:
        return self.root / "comparison.md"

    def side(self, label: str) -> EvalDir:
        """eval.py --compare: one checkpoint's confusion pictures (label a or b)."""
        return EvalDir(self.root / label)


def checkpoint_path(path) -> Path:
    """A checkpoint file as given, or a run folder's latest.pt."""
    path = Path(path)
    return RunDir(path).latest if path.is_dir() else path


def frame_name(ref) -> str:
    """`<scene>_<frame>`: how a frame is named among a split's pictures and predictions."""
    return f"{ref.scene}_{ref.frame:06d}"
