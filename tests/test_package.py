"""Issue 35: a real package. The wheel installs into a fresh virtual environment and its commands
work from an empty folder (presets by name, recipes, rigs and the Blender worker from the package);
the dependency lists agree; the one resolver finds the shipped files."""

import os
import re
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _requirement_lines(text: str) -> set[str]:
    return {re.sub(r"\s+#.*$", "", line).strip() for line in text.splitlines() if line.strip() and not line.startswith("#")}


def test_requirements_are_the_dependencies_and_the_dev_extra():
    p = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = p["optional-dependencies"]
    assert set(extras["dev"]) == set(extras["test"]) | set(extras["ray"])
    assert _requirement_lines((ROOT / "requirements.txt").read_text()) == set(p["dependencies"]) | set(extras["dev"])
    runtime = " ".join(p["dependencies"])
    for dev_only in ("pytest", "selenium", "import-linter", "ray"):
        assert dev_only not in runtime


def test_resolver_finds_presets_and_user_paths(tmp_path, monkeypatch):
    from common.resources import CODE_DIR, preset, presets, resolve_input, shipped

    assert CODE_DIR == ROOT and shipped("configs/rigs/default.yaml").is_file()
    assert preset("tiny", "dataset") == ROOT / "configs/dataset/tiny.yaml"
    assert {"tiny", "demo", "medium"} <= set(presets("dataset")) and "cpu_default" in presets("train")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny").mkdir()  # a folder of the user's named like a preset: a path the user gave wins
    assert preset("tiny", "dataset") == Path("tiny")
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "roundabout.yaml").write_text("name: mine\n")
    assert resolve_input("scenes/roundabout.yaml") == Path("scenes/roundabout.yaml")  # the working folder first
    assert resolve_input("scenes/intersection.yaml") == ROOT / "scenes/intersection.yaml"  # then the shipped file
    assert resolve_input("nowhere.yaml") == Path("nowhere.yaml")  # a message names what the user wrote


def _fresh_venv(tmp_path: Path, wheel: Path, env: dict) -> Path:
    """A virtual environment with the wheel installed (--no-deps), then the project's dependencies
    (the running environment's site-packages) made visible through a .pth file."""
    venv = tmp_path / "venv"
    base = Path(sys.base_prefix) / "bin" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    subprocess.run([str(base), "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120, env=env)
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "-q", "--no-deps", "--no-index",
                        str(wheel)], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    site = next((venv / "lib").glob("python3*/site-packages"))
    assert (site / "dataset_tools" / "__init__.py").is_file() and (site / "fisheye_bev_data" / "configs" / "dataset" / "tiny.yaml").is_file()
    (site / "project_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv


@pytest.mark.slow
def test_wheel_works_outside_the_checkout(tmp_path):
    import shutil

    src, wheels = tmp_path / "src", tmp_path / "wheels"  # a copy: the build leaves build/ and *.egg-info where it runs
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", ".venv", "data", "runs", "build", "*.egg-info", "__pycache__", "out",
                                                             ".pytest_cache", ".import_linter_cache", "img"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(wheels), str(src)],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    wheel = next(wheels.glob("fisheye_bev-*.whl"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    venv = _fresh_venv(tmp_path, wheel, env)
    work = tmp_path / "empty"
    work.mkdir()
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{env['PATH']}", OMP_NUM_THREADS="1")

    def run(*cmd, timeout=600):
        r = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=timeout)
        assert r.returncode == 0, f"{' '.join(cmd)}:\n{r.stdout[-1500:]}\n{r.stderr[-3000:]}"
        return r

    where = run(str(venv / "bin" / "python"), "-c", "import dataset_tools, common.resources as r; print(dataset_tools.__file__); print(r.data_root())")
    site = str(venv / "lib")
    assert all(line.startswith(site) for line in where.stdout.split()), where.stdout  # the wheel's copy, not the checkout
    run("fisheye-bev-dataset", "dataset", "--config", "tiny", "--out", "DATA", "--no-progress")
    assert (work / "DATA" / "index.json").is_file() and (work / "DATA" / "report" / "index.html").is_file()
    card = (work / "DATA" / "README.md").read_text()
    assert card.startswith("---\n") and "name: train" in card and "num_examples: 14" in card
    run("fisheye-bev-dataset", "export-webdataset", "DATA", "WDS", "--shard-size", "7", "--no-progress")
    # a user's training config next to the data, starting from a shipped preset by name
    (work / "t.yaml").write_text("_base: cpu_default\n"
                                 "data: {root: DATA, val_split: '', input_size: [64, 40], grid: {bound: 25.0, res: 0.78125}, num_workers: 0}\n"
                                 "model: {encoder: {widths: [16, 32, 32], blocks: [1, 1]}, stride: 4, context_channels: 16,\n"
                                 "        bev_encoder: {widths: [16, 32, 32], blocks: [1, 1]}}\n"
                                 "train: {max_steps: 2, batch_size: 2, threads: 1, image_every: 0}\n")
    run("fisheye-bev-train", "--config", "t.yaml", "--out", "run", "--quiet")
    run("fisheye-bev-train", "--config", "t.yaml", "--out", "run_shards", "--quiet", "--set", 'data.shards="WDS/train-{000000..000001}.tar"')
    assert (work / "run" / "latest.pt").is_file() and (work / "run_shards" / "latest.pt").is_file()
