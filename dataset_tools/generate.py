"""Render a data set: `python -m dataset_tools.generate --config configs/dataset/<preset>.yaml --out DIR`.

Plans every (scene, frame) of the config, keeps this shard's share (`--shard i/N`: job k is in
shard k mod N, so shards can run anywhere), skips frames already in the manifest, and hands the
rest to Blender worker processes (`python -m blender_scripts.worker`, one per core by default),
each building its scene once. A frame is done when its line is in <out>/manifest.jsonl, written
last, after every file of the frame (all written atomically). Bad input: one line, exit 2.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import subprocess
import sys
import threading
from pathlib import Path

from .recipe import RecipeError, load_recipe, read_yaml

REPO = Path(__file__).resolve().parent.parent
MARK = "@@bev "
SPLITS = ("train", "easy", "medium", "hard")
DENOISE_QUALITIES = ("high", "balanced", "fast")  # OpenImageDenoise's, as Cycles names them
# `labels` belongs to the label fusion (dataset_tools.fuse) and is not read here
CONFIG_KEYS = {"name", "rig", "fisheye_size", "topdown", "render", "frames", "scenes", "labels"}


class ConfigError(RecipeError):
    pass


def _resolve(path, base: Path) -> Path:
    """A path as given (absolute or from the working directory), else beside the config, else in the repo."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return p
    return base / p if (base / p).exists() else REPO / p


def load_config(path) -> dict:
    """The dataset config with every scene's recipe loaded and checked."""
    path = Path(path)
    d = read_yaml(path, ConfigError)
    if not isinstance(d, dict):
        raise ConfigError(f"{path}: must be a mapping")
    for k in d:
        if k not in CONFIG_KEYS:
            raise ConfigError(f"{path}: {k}: unknown field (known: {', '.join(sorted(CONFIG_KEYS))})")
    cfg = {
        "name": d.get("name", path.stem),
        "rig": str(_resolve(d.get("rig", "configs/rigs/default.yaml"), path.parent)),
        "fisheye_size": d.get("fisheye_size"),
        "topdown": {"size": 400, "height_m": 60.0, "bound": 25.0, **(d.get("topdown") or {})},
        "render": {"samples": 4, "denoise": True, "denoise_quality": "balanced", "max_bounces": 4, "camera_method": "osl",
                   **(d.get("render") or {})},
        "frames": d.get("frames"),
    }
    fs = cfg["fisheye_size"]
    if fs is not None and not (isinstance(fs, list) and len(fs) == 2 and all(isinstance(v, int) and v > 0 for v in fs)):
        raise ConfigError(f"{path}: fisheye_size: must be [width, height] in pixels, got {fs!r}")
    if set(cfg["topdown"]) - {"size", "height_m", "bound"}:
        raise ConfigError(f"{path}: topdown: unknown field '{sorted(set(cfg['topdown']) - {'size', 'height_m', 'bound'})[0]}'")
    if not (isinstance(cfg["topdown"]["size"], int) and cfg["topdown"]["size"] > 0):
        raise ConfigError(f"{path}: topdown.size: must be a positive whole number of pixels")
    render_keys = {"samples", "denoise", "denoise_quality", "max_bounces", "camera_method"}
    if set(cfg["render"]) - render_keys:
        raise ConfigError(f"{path}: render: unknown field '{sorted(set(cfg['render']) - render_keys)[0]}'")
    if cfg["render"]["camera_method"] not in ("osl", "polynomial"):
        raise ConfigError(f"{path}: render.camera_method: must be osl or polynomial")
    if cfg["render"]["denoise_quality"] not in DENOISE_QUALITIES:
        raise ConfigError(f"{path}: render.denoise_quality: must be one of {', '.join(DENOISE_QUALITIES)}")
    if not (isinstance(cfg["render"]["samples"], int) and cfg["render"]["samples"] >= 1):
        raise ConfigError(f"{path}: render.samples: must be a whole number >= 1")
    if cfg["frames"] is not None and not (isinstance(cfg["frames"], int) and cfg["frames"] >= 1):
        raise ConfigError(f"{path}: frames: must be a whole number >= 1 (overrides every recipe's frames.count)")
    if not Path(cfg["rig"]).is_file():
        raise ConfigError(f"{path}: rig: no such file {cfg['rig']}")
    scenes = d.get("scenes")
    if not isinstance(scenes, list) or not scenes:
        raise ConfigError(f"{path}: scenes: must be a non-empty list of {{recipe, split}}")
    cfg["scenes"] = []
    names = set()
    for i, s in enumerate(scenes):
        where = f"{path}: scenes[{i}]"
        if not isinstance(s, dict) or "recipe" not in s:
            raise ConfigError(f"{where}: must be a mapping with 'recipe'")
        extra = set(s) - {"recipe", "split", "name", "overrides"}
        if extra:
            raise ConfigError(f"{where}.{sorted(extra)[0]}: unknown field (known: recipe, split, name, overrides)")
        split = s.get("split", "train")
        if split not in SPLITS:
            raise ConfigError(f"{where}.split: must be one of {', '.join(SPLITS)}, got {split!r}")
        overrides = s.get("overrides") or {}
        if cfg["frames"] is not None:
            overrides = {**overrides, "frames": {**overrides.get("frames", {}), "count": cfg["frames"]}}
        recipe = load_recipe(_resolve(s["recipe"], path.parent), overrides)
        name = s.get("name", recipe["name"])
        if name in names:
            raise ConfigError(f"{where}.name: scene name '{name}' used twice")
        names.add(name)
        recipe["name"] = name
        cfg["scenes"].append({"name": name, "split": split, "recipe": recipe})
    return cfg


def plan(cfg: dict, shard: tuple[int, int]) -> list[tuple[dict, int]]:
    i, n = shard
    jobs = [(s, f) for s in cfg["scenes"] for f in range(s["recipe"]["frames"]["count"])]
    return [j for k, j in enumerate(jobs) if k % n == i]


def read_manifest(path: Path) -> set[tuple[str, int]]:
    done = set()
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                e = json.loads(line)
                done.add((e["scene"], int(e["frame"])))
            except (json.JSONDecodeError, KeyError, TypeError, ValueError):
                continue  # a line cut short by a kill: that frame is redone
    return done


class Manifest:
    def __init__(self, path: Path):
        self.path = path
        self.lock = threading.Lock()

    def append(self, entry: dict) -> None:
        line = json.dumps(entry, sort_keys=True) + "\n"
        with self.lock, open(self.path, "a") as f:
            if f.tell() > 0:  # a previous run killed mid-line leaves no newline: start afresh
                with open(self.path, "rb") as r:
                    r.seek(-1, os.SEEK_END)
                    if r.read(1) != b"\n":
                        f.write("\n")
            f.write(line)
            f.flush()
            os.fsync(f.fileno())


def _tasks(jobs, workers: int) -> list[tuple[dict, list[int]]]:
    """Group frames by scene; split a scene among workers only when scenes are fewer."""
    by_scene: dict[str, tuple[dict, list[int]]] = {}
    for s, f in jobs:
        by_scene.setdefault(s["name"], (s, []))[1].append(f)
    groups = list(by_scene.values())
    parts = max(1, -(-workers // max(1, len(groups))))
    tasks = []
    for s, frames in groups:
        k = min(parts, len(frames))
        for j in range(k):
            tasks.append((s, frames[j::k]))
    return tasks


def run(cfg: dict, out: Path, shard=(0, 1), workers: int | None = None, progress: bool = True) -> int:
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    manifest = Manifest(out / "manifest.jsonl")
    done = read_manifest(manifest.path)
    todo = [(s, f) for s, f in plan(cfg, shard) if (s["name"], f) not in done]
    cores = os.cpu_count() or 1
    workers = max(1, min(workers or cores, len(todo) or 1))
    threads = max(1, cores // workers)
    q: queue.Queue = queue.Queue()
    for s, frames in _tasks(todo, workers):
        q.put({"scene": s["name"], "split": s["split"], "recipe": s["recipe"], "frames": frames,
               "out": str(out), "rig": cfg["rig"], "fisheye_size": cfg["fisheye_size"],
               "topdown": cfg["topdown"], "render": cfg["render"], "threads": threads})
    bar = tqdm(total=len(todo), desc=f"{cfg['name']} shard {shard[0]}/{shard[1]}", unit="frame",
               disable=not progress)
    errors: list[str] = []
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))

    def drive():
        proc = subprocess.Popen([sys.executable, "-m", "blender_scripts.worker"], cwd=str(REPO), env=env,
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
        try:
            while not errors:
                try:
                    task = q.get_nowait()
                except queue.Empty:
                    break
                proc.stdin.write(json.dumps(task) + "\n")
                proc.stdin.flush()
                for line in proc.stdout:
                    if not line.startswith(MARK):
                        continue
                    try:
                        msg = json.loads(line[len(MARK):])
                    except json.JSONDecodeError:
                        errors.append(f"{task['scene']}: garbled worker message {line.strip()[:80]!r}")
                        break
                    if msg["event"] == "frame":
                        s = task
                        manifest.append({"scene": msg["scene"], "frame": msg["frame"], "split": s["split"],
                                         "family": s["recipe"]["family"], "dir": f"{msg['scene']}/{msg['frame']:06d}",
                                         "files": msg["files"]})
                        bar.update(1)
                    elif msg["event"] == "task_done":
                        break
                    elif msg["event"] == "error":
                        with open(out / "worker_errors.log", "a") as log:
                            log.write(msg.get("trace", "") + "\n")
                        errors.append(f"{task['scene']}: {msg['message']} (trace in {out / 'worker_errors.log'})")
                        break
                else:
                    errors.append(f"{task['scene']}: worker exited unexpectedly")
        finally:
            if proc.stdin:
                proc.stdin.close()
            proc.wait()

    pool = [threading.Thread(target=drive, daemon=True) for _ in range(workers if todo else 0)]
    for t in pool:
        t.start()
    for t in pool:
        t.join()
    bar.close()
    if errors:
        for e in errors:
            print(f"generate: {e}", file=sys.stderr)
        return 1
    from .contact_sheet import make_sheets

    make_sheets(out)
    return 0


def parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
        if not 0 <= i < n:
            raise ValueError
    except ValueError:
        raise ConfigError(f"--shard: must be i/N with 0 <= i < N, got {text!r}") from None
    return i, n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Render procedural road scenes through the fisheye rig.")
    ap.add_argument("--config", required=True, type=Path, help="configs/dataset/<preset>.yaml")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--shard", default="0/1", help="i/N: render every N-th job starting at i")
    ap.add_argument("--workers", type=int, default=None, help="Blender processes (default: one per core)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    try:
        shard = parse_shard(a.shard)
        if a.workers is not None and a.workers < 1:
            raise ConfigError(f"--workers: must be >= 1, got {a.workers}")
        cfg = load_config(a.config)
    except RecipeError as exc:
        print(f"generate: {exc}", file=sys.stderr)
        return 2
    return run(cfg, a.out, shard, a.workers, progress=not a.no_progress)


if __name__ == "__main__":
    sys.exit(main())
