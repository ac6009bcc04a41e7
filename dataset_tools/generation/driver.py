"""The render driver behind `python -m dataset_tools.generate`.

Plans every (scene, frame) of the config, keeps this shard's share (`--shard i/N`: job k is in
shard k mod N, so shards can run anywhere), skips frames already in the manifest, and hands the
rest to Blender worker processes (`python -m blender_scripts.worker`, one per core by default),
each building its scene once. A frame is done when its line is in <out>/manifest.jsonl, written
last, by this process only, after every file of the frame (all written atomically).
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from common.errors import ConfigError
from common.files import clean_stale_temps, write_text_atomic

from ..format.layout import RECIPES_DIR, Manifest, frame_dir_name
from .config import REPO

MARK = "@@bev "


def plan(cfg: dict, shard: tuple[int, int]) -> list[tuple[dict, int]]:
    i, n = shard
    jobs = [(s, f) for s in cfg["scenes"] for f in range(s["recipe"]["frames"]["count"])]
    return [j for k, j in enumerate(jobs) if k % n == i]


def write_recipes(cfg: dict, out: Path) -> None:
    """<out>/recipes/<scene>.yaml: the checked recipe of every scene, so any scene (sampled ones
    included) can be rendered again alone (`recipe: <out>/recipes/<scene>.yaml` in a config)."""
    import yaml

    d = out / RECIPES_DIR
    d.mkdir(parents=True, exist_ok=True)
    for s in cfg["scenes"]:
        text = yaml.safe_dump(s["recipe"], sort_keys=False, default_flow_style=None, width=120)
        path = d / f"{s['name']}.yaml"
        if not path.is_file() or path.read_text() != text:
            write_text_atomic(path, text)


def _die_with_parent() -> None:
    """In the worker, before exec: get SIGKILL when the driver dies (Linux), so a killed driver
    leaves no Blender process writing into --out."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


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
    clean_stale_temps(out)
    write_recipes(cfg, out)
    manifest = Manifest(out)
    manifest.repair()
    done = manifest.done()
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
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1,
                                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
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
                                         "family": s["recipe"]["family"], "dir": frame_dir_name(msg["scene"], msg["frame"]),
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

    if todo:
        with ThreadPoolExecutor(workers) as pool:
            for f in [pool.submit(drive) for _ in range(workers)]:
                f.result()
    bar.close()
    if errors:
        for e in errors:
            print(f"generate: {e}", file=sys.stderr)
        return 1
    from ..qa.contact_sheet import make_sheets

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
