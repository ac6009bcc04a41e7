"""The render driver behind `python -m dataset_tools generate`.

Plans every (scene, frame) of the config, keeps this shard's share (`--shard i/N`: job k is in
shard k mod N, so shards can run anywhere), skips frames already in the manifest, and hands the
rest to Blender worker processes (`python -m blender_scripts.worker`, one per core by default),
each building its scene once. A frame is done when its line is in <out>/manifest.jsonl, written
last, by this process only, after every file of the frame (all written atomically).
"""

from __future__ import annotations

import os
import queue
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from common.backend import WorkerLost, make_backend
from common.errors import ConfigError
from common.files import clean_stale_temps, write_text_atomic
from common.resources import CODE_DIR
from common.lifetime import DieWithParent
from common.worker_protocol import RenderTask, read_message

from ..format.layout import RECIPES_DIR, Manifest, WorkerErrorLog, frame_dir_name


def plan(cfg: dict, shard: tuple[int, int]) -> list[tuple[dict, int]]:
    i, n = shard
    jobs = [(s, f) for s in cfg["scenes"] for f in range(s["recipe"]["frames"]["count"])]
    return [j for k, j in enumerate(jobs) if k % n == i]


def recipe_text(scene: dict) -> str:
    """The text of <out>/recipes/<scene>.yaml for a scene of load_config."""
    import yaml

    return yaml.safe_dump(scene["recipe"], sort_keys=False, default_flow_style=None, width=120)


def write_recipes(cfg: dict, out: Path) -> None:
    """<out>/recipes/<scene>.yaml: the checked recipe of every scene, so any scene (sampled ones
    included) can be rendered again alone (`recipe: <out>/recipes/<scene>.yaml` in a config)."""
    d = out / RECIPES_DIR
    d.mkdir(parents=True, exist_ok=True)
    for s in cfg["scenes"]:
        text, path = recipe_text(s), d / f"{s['name']}.yaml"
        if not path.is_file() or path.read_text() != text:
            write_text_atomic(path, text)


def changed_scenes(cfg: dict, out: Path, done: set) -> list[str]:
    """The config's scenes with frames in the manifest whose recipe is not the one in
    <out>/recipes/ (the config, or the code that draws its recipes, changed since they were rendered)."""
    rendered = {scene for scene, _ in done}
    d = out / RECIPES_DIR
    return [s["name"] for s in cfg["scenes"] if s["name"] in rendered and (d / f"{s['name']}.yaml").is_file()
            and (d / f"{s['name']}.yaml").read_text() != recipe_text(s)]


def forget_scenes(out: Path, manifest: Manifest, scenes: list[str]) -> None:
    """Make these scenes unrendered: each folder moved aside (one rename), their manifest lines
    dropped, then the folders deleted; a kill at any point leaves them to be rendered again whole
    (a folder left aside is removed by the next render)."""
    aside = []
    for name in scenes:
        if (out / name).is_dir():
            aside.append(out / f".{name}.{os.getpid()}.stale")
            os.replace(out / name, aside[-1])
    manifest.drop(scenes)
    for p in aside:
        shutil.rmtree(p, ignore_errors=True)


def remove_aside(out: Path) -> None:
    """Remove the scene folders a killed forget_scenes left moved aside (`.<scene>.<pid>.stale`)."""
    for p in out.glob(".*.stale"):
        shutil.rmtree(p, ignore_errors=True)


def check_changed(cfg: dict, out: Path, manifest: Manifest, rerender_changed: bool) -> set:
    """The frames already rendered from the config's recipes: scenes rendered from another recipe
    are refused (one line), or with `rerender_changed` forgotten, to be rendered again."""
    done = manifest.done()
    changed = changed_scenes(cfg, out, done)
    named = ", ".join(changed[:3]) + (", ..." if len(changed) > 3 else "")
    if changed and not rerender_changed:
        raise ConfigError(f"{out}: {len(changed)} rendered scene(s) ({named}) "
                          f"have another recipe in the config now than in {out / RECIPES_DIR} (the config or the code changed "
                          "since they were rendered); render into a new --out, or add --rerender-changed (make dataset RERENDER=1) to render them again")
    if changed:
        print(f"generate: rendering {len(changed)} changed scene(s) again ({named})", flush=True)
        forget_scenes(out, manifest, changed)
        done = manifest.done()
    return done


class WorkerFailed(Exception):
    """The worker reported an error for its task (deterministic: that scene is given up, the others
    are finished, and the run exits 1; running it again redoes only what is missing)."""

    def __init__(self, message: str, trace: str = ""):
        super().__init__(message, trace)
        self.message, self.trace = message, trace

    def __str__(self) -> str:
        return self.message


class WorkerProcess:
    """One `python -m blender_scripts.worker` process and its stdin/stdout protocol
    (common.worker_protocol); the backend runs it here or, one per actor, on Ray. A lost worker
    raises common.backend.WorkerLost: its task's unfinished frames can be rescheduled."""

    def __init__(self):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(CODE_DIR)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
        self.proc = subprocess.Popen([sys.executable, "-m", "blender_scripts.worker"], cwd=str(CODE_DIR), env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, bufsize=1,
                                     preexec_fn=DieWithParent())  # no Blender outlives its driver

    def run(self, task: RenderTask):
        """Yield the worker's "frame" messages for `task`; WorkerFailed / WorkerLost otherwise."""
        try:
            self.proc.stdin.write(task.to_line())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            raise WorkerLost("worker exited unexpectedly") from None
        for line in self.proc.stdout:
            try:
                msg = read_message(line)
            except ValueError:
                raise WorkerLost(f"garbled worker message {line.strip()[:80]!r}") from None
            if msg is None:
                continue
            if msg["event"] == "frame":
                yield msg
            elif msg["event"] == "task_done":
                return
            elif msg["event"] == "error":
                recipe = Path(task.out) / RECIPES_DIR / f"{task.scene}.yaml"
                raise WorkerFailed(f"{task.scene} (recipe {recipe}): {msg['message']}", msg.get("trace", ""))
        raise WorkerLost("worker exited unexpectedly")

    def close(self) -> None:
        if self.proc.stdin:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        self.proc.wait()


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


def render_tasks(cfg: dict, jobs, out: Path, workers: int, threads: int) -> list[RenderTask]:
    """The tasks for `jobs` ((scene, frame) pairs) of a config checked by load_config."""
    return [RenderTask(scene=s["name"], split=s["split"], recipe=s["recipe"], frames=frames, out=str(out.resolve()),
                       rig=cfg["rig"], fisheye_size=cfg["fisheye_size"], topdown=cfg["topdown"], render=cfg["render"],
                       threads=threads)
            for s, frames in _tasks(jobs, workers)]


MAX_LOSSES = 3  # a task whose worker is lost this many times stops the run (a frame that kills Blender)


def _drive(q: queue.Queue, new_worker, on_frame, errors: list, reschedule: bool, failed: set | None = None) -> None:
    """One pool slot: take tasks from `q` until it is empty, feeding `on_frame` each finished frame.
    A lost worker's unfinished frames go back on the queue (when `reschedule`) and a new worker
    takes the slot; frames already reported are not redone. A scene that fails (the worker reports
    an error, or is lost MAX_LOSSES times) goes into `errors` and `failed`; its other tasks are
    skipped and the slot goes on with the other scenes (one scene that cannot be built
    no longer stops the data set)."""
    failed = set() if failed is None else failed
    worker = new_worker()
    try:
        while True:
            try:
                task = q.get_nowait()
            except queue.Empty:
                break
            if task.scene in failed:
                continue
            done: set[int] = set()
            try:
                for msg in worker.run(task):
                    on_frame(task, msg)
                    done.add(msg["frame"])
            except WorkerFailed as exc:
                errors.append(exc)
                failed.add(task.scene)
                worker.close()  # it ends after reporting the error
                worker = new_worker()
            except WorkerLost as exc:
                retry = task.retry([f for f in task.frames if f not in done])
                if not reschedule or retry.losses >= MAX_LOSSES:
                    errors.append(f"{task.scene}: {exc}")
                    failed.add(task.scene)
                    worker.close()
                    worker = new_worker()
                    continue
                print(f"generate: {task.scene}: {exc}; {len(retry.frames)} frame(s) rescheduled", file=sys.stderr)
                for f in retry.frames:  # the lost worker's half-written temp files (its frames are nobody else's)
                    clean_stale_temps(Path(task.out) / frame_dir_name(task.scene, f))
                q.put(retry)
                worker.close()
                worker = new_worker()
    finally:
        worker.close()


def render(cfg: dict, out: Path, shard=(0, 1), workers: int | None = None, progress: bool = True,
           backend: str = "local", address: str | None = None, threads: int = 1, rerender_changed: bool = False) -> list[str]:
    """The render stage: this shard's missing frames of `cfg` (load_config) into `out`; the problems,
    one line each (none: every frame is rendered). backend "local": `workers` Blender processes on
    this machine (default one per core, the cores shared among them); "ray": one actor per Blender
    process on the Ray cluster at `address`, `threads` cores each (common.backend). Scenes rendered
    before from another recipe raise ConfigError, or with `rerender_changed` are rendered again."""
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    clean_stale_temps(out)
    remove_aside(out)
    manifest = Manifest(out)
    manifest.repair()
    done = check_changed(cfg, out, manifest, rerender_changed)
    write_recipes(cfg, out)
    todo = [(s, f) for s, f in plan(cfg, shard) if (s["name"], f) not in done]
    if todo:  # what each camera of the rig became (exact model or a fit, with its residual), once
        from geometry.rig import load_rig

        load_rig(cfg["rig"]).print_description(cfg["rig"])
    pool = make_backend(backend, workers, address)
    workers = max(1, min(pool.slots(threads), len(todo) or 1))
    threads = pool.threads_per_worker(workers, threads)
    q: queue.Queue = queue.Queue()
    for task in render_tasks(cfg, todo, out, workers, threads):
        q.put(task)
    bar = tqdm(total=len(todo), desc=f"{cfg['name']} shard {shard[0]}/{shard[1]}", unit="frame",
               disable=not progress)
    errors: list = []

    def on_frame(task, msg):
        manifest.append({"scene": msg["scene"], "frame": msg["frame"], "split": task.split,
                         "family": task.recipe["family"], "dir": frame_dir_name(msg["scene"], msg["frame"]),
                         "files": msg["files"]})
        bar.update(1)

    def new_worker():
        return pool.start(WorkerProcess, cpus=threads, name="Render")

    try:
        if todo:
            with ThreadPoolExecutor(workers) as threads_pool:
                failed: set = set()
                for f in [threads_pool.submit(_drive, q, new_worker, on_frame, errors, pool.retries_lost_workers, failed)
                          for _ in range(workers)]:
                    f.result()
    finally:
        bar.close()
    if not errors:
        return []
    problems = []
    for e in errors:
        if isinstance(e, WorkerFailed):
            log = WorkerErrorLog(out)
            log.append(e.trace)
            e = f"{e.message} (trace in {log.path})"
        problems.append(f"generate: {e}")
    return problems + [f"generate: {len(errors)} scene(s) failed, the others are rendered; fix them (or drop them) "
                       "and run the same command again to finish"]


def parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
        if not 0 <= i < n:
            raise ValueError
    except ValueError:
        raise ConfigError(f"--shard: must be i/N with 0 <= i < N, got {text!r}") from None
    return i, n
