"""Issue 15: every entry point survives hostile input. The corpus is tests/robust_cases.py; each
case runs its command in-process through the CLI boundary (`common.cli.run_cli`) and must exit with
the case's code, print exactly one line on stderr (no traceback) naming the file and field, and
write nothing outside its output folder, leaving no temp file behind."""

from __future__ import annotations

import contextlib
import copy
import importlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from robust_cases import CASES

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {
    "generate": "dataset_tools.generate", "fuse": "dataset_tools.fuse", "index": "dataset_tools.index",
    "validate": "dataset_tools.qa.validate", "inspect": "dataset_tools.qa.inspect", "consistency": "dataset_tools.qa.consistency",
    "stats": "dataset_tools.qa.stats", "contact_sheet": "dataset_tools.qa.contact_sheet", "train": "train", "eval": "eval",
}
WRITES_DATASET = {"fuse", "index", "stats", "inspect", "contact_sheet"}  # may write into the data set they are given
TEMP = re.compile(r"^\..+\.tmp(\.[A-Za-z0-9]+)?$")
PROGRESS = re.compile(r"\d+%\||\d+/\d+ \[")  # a tqdm bar line
TINY_MODEL = {
    "encoder": {"widths": [16, 32, 32], "blocks": [1, 1]}, "stride": 4, "context_channels": 16,
    "depth": {"min": 1.0, "max": 37.0, "bins": 24}, "bev_encoder": {"widths": [16, 32, 32], "blocks": [1, 1]},
}


def tiny_train_config(root) -> dict:
    from dataset_tools.format.reader import DatasetIndex

    g = DatasetIndex(root).grid
    grid = {"x_min": g.x_min, "x_max": g.x_max, "y_min": g.y_min, "y_max": g.y_max, "res": g.res}
    return {
        "_base": str(ROOT / "configs/train/cpu_default.yaml"),
        "data": {"root": str(root), "val_split": "", "input_size": [64, 40], "grid": grid, "num_workers": 0},
        "model": copy.deepcopy(TINY_MODEL),
        "train": {"epochs": 1, "max_steps": 2, "batch_size": 2, "lr": 3e-3, "threads": 1, "checkpoint_every": 1000,
                  "image_every": 0, "log_every": 5},
    }


def merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if v is None:
            out.pop(k, None)
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


@pytest.fixture(scope="session")
def mini_dataset(tiny_dataset, tmp_path_factory):
    """Two fused frames of the tiny render (one scene), with their own manifest and index."""
    from dataset_tools.format.index import build_index, write_index

    out = tmp_path_factory.mktemp("mini") / "ds"
    out.mkdir()
    lines = (tiny_dataset / "manifest.jsonl").read_text().splitlines()
    first = json.loads(lines[0])["scene"]
    keep = [line for line in lines if json.loads(line)["scene"] == first][:2]
    for line in keep:
        d = json.loads(line)["dir"]
        shutil.copytree(tiny_dataset / d, out / d)
    (out / "manifest.jsonl").write_text("\n".join(keep) + "\n")
    write_index(out, build_index(out))
    return out


@pytest.fixture(scope="session")
def tiny_checkpoint(mini_dataset, tmp_path_factory):
    """latest.pt of a 2-step training run on the mini data set."""
    d = tmp_path_factory.mktemp("ckpt")
    cfg = d / "t.yaml"
    cfg.write_text(yaml.safe_dump(tiny_train_config(mini_dataset)))
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "train.py", "--config", str(cfg), "--out", str(d / "run"), "--quiet"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return d / "run" / "latest.pt"


class Ctx:
    def __init__(self, ws: Path, mini: Path, request):
        self.ws, self.mini, self._request = ws, mini, request
        self.out = ws / "a" / "b" / "c" / "out"
        self._ds = None
        self._ckpt = None

    def write(self, rel, content) -> Path:
        p = self.ws / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(content if isinstance(content, bytes) else content.encode())
        return p

    def out_is_a_file(self):
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.out.write_text("a file\n")

    def dataset_config(self, **over) -> Path:
        base = {"name": "case", "rig": str(ROOT / "configs/rigs/default.yaml"), "fisheye_size": [64, 40],
                "topdown": {"size": 64, "height_m": 60.0, "bound": 25.0}, "render": {"samples": 1, "denoise": False, "max_bounces": 1},
                "frames": 1, "scenes": [{"recipe": "scenes/highway_straight.yaml", "split": "train"}]}
        return self.write("cfg/ds.yaml", yaml.safe_dump(merge(base, over)))

    def recipe(self, **over) -> Path:
        base = yaml.safe_load((ROOT / "scenes/highway_straight.yaml").read_text())
        return self.write("cfg/r.yaml", yaml.safe_dump(merge(base, over)))

    def ds(self, edit=None) -> Path:
        if self._ds is None:
            self._ds = self.ws / "ds"
            shutil.copytree(self.mini, self._ds)
        if edit:
            edit(self, self._ds)
        return self._ds

    def train_config(self, **sections) -> Path:
        return self.write("cfg/t.yaml", yaml.safe_dump(merge(tiny_train_config(self.mini), sections)))

    @property
    def checkpoint(self) -> Path:
        if self._ckpt is None:
            self._ckpt = self._request.getfixturevalue("tiny_checkpoint")
        return self._ckpt

    def checkpoint_dict(self) -> dict:
        import torch

        return torch.load(self.checkpoint, map_location="cpu", weights_only=False)


def snapshot(folder: Path) -> dict:
    return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*") if p.is_file()}


def run_in_process(command: str, argv: list[str]) -> tuple[int, str]:
    """(exit code, stderr) of `python -m <command> argv` run here through run_cli."""
    from common.cli import run_cli

    main = importlib.import_module(COMMANDS[command]).main
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            run_cli(main, argv, prog=command)
        code = 0
    except SystemExit as exc:
        code = exc.code
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
    return code, err.getvalue()


def error_lines(stderr: str) -> list[str]:
    lines = [line.rsplit("\r", 1)[-1].strip() for line in stderr.split("\n")]
    return [line for line in lines if line and not PROGRESS.search(line)]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_hostile_input(case, tmp_path, mini_dataset, request):
    ctx = Ctx(tmp_path, mini_dataset, request)
    argv = case.build(ctx)
    before = snapshot(tmp_path)
    code, stderr = run_in_process(case.command, argv)
    lines = error_lines(stderr)
    assert "Traceback" not in stderr, stderr
    assert code == case.code and len(lines) == 1, f"exit {code}, stderr:\n{stderr}"
    for needle in case.needles:
        assert needle in lines[0], f"{needle!r} not named in: {lines[0]}"
    allowed = [ctx.out] + ([ctx.ws / "ds"] if case.command in WRITES_DATASET else [])
    after = snapshot(tmp_path)
    changed = [p for p, st in after.items() if before.get(p) != st]
    outside = [p for p in changed if not any(p.is_relative_to(a) for a in allowed)]
    assert not outside, f"written outside the output folder: {outside}"
    temps = [p for p in after if TEMP.match(p.name)]
    assert not temps, f"temp files left: {temps}"


def test_corpus_covers_every_entry_point():
    assert len(CASES) >= 100
    assert {c.command for c in CASES} == set(COMMANDS)
