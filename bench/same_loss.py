"""An accuracy check of speed work: the training loss curve of this checkout against a baseline
commit's, same config, data and seed (the speed work changes float rounding only: memory format
and thread count).

    PYTHONPATH=. python -m bench.same_loss DATA_ROOT [--steps 30] [--baseline REV] [--set k=v ...]

Each side trains `steps` steps of configs/train/cpu_default.yaml on DATA_ROOT in a fresh process
(model.training.train, as train.py does) and the per-step losses are printed side by side with
their largest relative difference.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.model import BASELINE, ROOT, checkout

CHILD = """
import json, sys
from pathlib import Path
from common.schema import deep_merge
from model.config import load_config, parse_overrides
from model.training import train
over = deep_merge({{"data": {{"root": {data!r}, "val_split": ""}}, "train": {{"max_steps": {steps}, "checkpoint_every": 0, "log_every": 0, "image_every": 0}}}}, parse_overrides({sets!r}))
cfg = load_config(Path("configs/train/cpu_default.yaml"), over)
res = train(cfg, Path({out!r}), quiet=True)
print("@@" + json.dumps(res["losses"]))
"""


def losses(root: Path, data: str, steps: int, sets: list, out: Path) -> list:
    code = CHILD.format(data=data, steps=steps, sets=sets, out=str(out))
    r = subprocess.run([sys.executable, "-c", code], cwd=root, env=dict(os.environ, PYTHONPATH=str(root)),
                       capture_output=True, text=True, timeout=3600)
    if r.returncode:
        raise SystemExit(f"training at {root} failed: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
    return json.loads([ln for ln in r.stdout.splitlines() if ln.startswith("@@")][-1][2:])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--set", nargs="+", action="extend", default=[], help="config overrides key=value (repeatable)")
    a = ap.parse_args(argv)
    data = str(Path(a.data).resolve())
    with tempfile.TemporaryDirectory() as tmp:
        base = losses(checkout(a.baseline, Path(tmp) / "baseline"), data, a.steps, a.set, Path(tmp) / "run_base")
        ours = losses(ROOT, data, a.steps, a.set, Path(tmp) / "run_ours")
    print("step  baseline    ours        rel.diff")
    worst = 0.0
    for k, (b, o) in enumerate(zip(base, ours), 1):
        rel = abs(o - b) / max(abs(b), 1e-12)
        worst = max(worst, rel)
        print(f"{k:4d}  {b:.6f}  {o:.6f}  {rel:.2e}")
    print(f"largest relative difference over {len(ours)} steps: {worst:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
