import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.chdir(ROOT)


def _run(*args):
    r = subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, f"{' '.join(args)} failed:\n{r.stderr[-3000:]}"
    return r


@pytest.fixture(scope="session")
def tiny_rendered(tmp_path_factory):
    """The `tiny` preset rendered by real Blender once per test session, with its contact sheets:
    the pipeline's first two stages (read-only: copy to change)."""
    out = tmp_path_factory.mktemp("tiny_rendered") / "ds"
    r = _run("dataset_tools", "generate", "--config", "configs/dataset/tiny.yaml", "--out", str(out), "--no-progress")
    (out.parent / "generate.stdout").write_text(r.stdout)  # what a user saw (tests/test_scenes.py)
    _run("dataset_tools", "contact_sheet", str(out))
    return out


@pytest.fixture(scope="session")
def tiny_dataset(tiny_rendered, tmp_path_factory):
    """The tiny render with fused labels and index.json (read-only: copy to change)."""
    out = tmp_path_factory.mktemp("tiny_dataset") / "ds"
    shutil.copytree(tiny_rendered, out)
    _run("dataset_tools", "fuse", str(out), "--config", "configs/dataset/tiny.yaml")
    return out
