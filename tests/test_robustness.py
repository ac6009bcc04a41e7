"""Every entry point survives hostile input. The corpus is tests/robust_cases.py; each
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

from dataset_tools.__main__ import COMMANDS as DATASET_COMMANDS
from robust_cases import CASES

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {name: module for name, (module, _) in DATASET_COMMANDS.items()} | {"train": "train", "eval": "eval", "predict": "predict"}
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
        "train": {"epochs": 10, "max_steps": 2, "batch_size": 2, "lr": 3e-3, "threads": 1, "checkpoint_every": 1000,
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


def mini_frames_copy(tiny_dataset: Path, out: Path, frames: int = 2) -> Path:
    """A data set at `out` of the first `frames` fused frames of the tiny render's first scene, with
    its own manifest and index."""
    from dataset_tools.format.index import build_index, write_index

    out.mkdir(parents=True)
    lines = (tiny_dataset / "manifest.jsonl").read_text().splitlines()
    first = json.loads(lines[0])["scene"]
    keep = [line for line in lines if json.loads(line)["scene"] == first][:frames]
    for line in keep:
        d = json.loads(line)["dir"]
        shutil.copytree(tiny_dataset / d, out / d)
    (out / "manifest.jsonl").write_text("\n".join(keep) + "\n")
    write_index(out, build_index(out))
    return out


@pytest.fixture(scope="session")
def mini_dataset(tiny_dataset, tmp_path_factory):
    """Two fused frames of the tiny render (one scene), with their own manifest and index."""
    return mini_frames_copy(tiny_dataset, tmp_path_factory.mktemp("mini") / "ds")


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
    (d / "stderr.txt").write_text(r.stderr)
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
    """(exit code, stderr) of the command (`python -m dataset_tools <command>`, train.py, eval.py)
    run here through run_cli."""
    return run_in_process_main(importlib.import_module(COMMANDS[command]).main, argv, command)


def run_in_process_main(main, argv: list[str], prog: str = "python -m dataset_tools") -> tuple[int, str]:
    from common.cli import run_cli

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            run_cli(main, argv, prog=prog)
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
    if case.skip:
        pytest.skip(case.skip)
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
    # the count README and docs/errors.md give is the corpus's
    assert f"{len(CASES)} hostile inputs" in " ".join((ROOT / "README.md").read_text().split())
    assert f"({len(CASES)} malformed inputs" in (ROOT / "docs/errors.md").read_text()


@pytest.mark.parametrize("argv", [["bogus"], ["--bogus"], ["contact-sheet", "somewhere", "--bogus"]])
def test_dataset_command_table_errors_are_one_line(argv):
    from dataset_tools.__main__ import main

    code, stderr = run_in_process_main(main, argv)
    assert code == 2 and len(error_lines(stderr)) == 1 and "Traceback" not in stderr, stderr
    assert "bogus" in stderr


def test_demo_option_error_is_one_line():
    r = subprocess.run([sys.executable, "demo.py", "--bogus"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--bogus" in r.stderr, r.stderr


# ------------------------------------------------------------------ faults: full disk, read-only, two writers, kills


@contextlib.contextmanager
def small_tmpfs(folder: Path, size: str = "300k"):
    """A tmpfs of `size` at `folder` (root only; skipped elsewhere)."""
    folder.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or 'not root'})")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def read_only(folder: Path):
    r = subprocess.run(["mount", "-o", "remount,ro", str(folder)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def assert_one_line(code, stderr, want_code, *needles):
    lines = error_lines(stderr)
    assert "Traceback" not in stderr and code == want_code and len(lines) == 1, f"exit {code}:\n{stderr}"
    for n in needles:
        assert n in lines[0], f"{n!r} not in {lines[0]}"


def no_temps(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if TEMP.match(p.name)]


def test_train_prints_no_warning(tiny_checkpoint):
    assert (tiny_checkpoint.parents[1] / "stderr.txt").read_text() == ""


@pytest.mark.parametrize("command", ["train", "eval", "stats"])
def test_full_disk_is_exit_1_and_one_line(command, tmp_path, mini_dataset, request):
    ctx = Ctx(tmp_path, mini_dataset, request)
    with small_tmpfs(tmp_path / "disk") as disk:
        out = disk / "out"
        out.mkdir()
        with contextlib.suppress(OSError), open(disk / "filler", "wb") as f:
            for _ in range(1000):  # fill the disk
                f.write(b"\0" * 4096)
                f.flush()
        os.truncate(disk / "filler", max(0, (disk / "filler").stat().st_size - 8192))  # room for the lock, not for the output
        argv = {"train": lambda: ["--config", str(ctx.train_config()), "--out", str(out), "--quiet"],
                "eval": lambda: ["--checkpoint", str(ctx.checkpoint), "--data", str(mini_dataset), "--out", str(out), "--pictures", "1"],
                "stats": lambda: [str(mini_dataset), "--out", str(out)]}[command]()
        code, stderr = run_in_process(command, argv)
        assert_one_line(code, stderr, 1, str(out), "No space left")
        assert not no_temps(disk)


@contextlib.contextmanager
def full_disk(folder: Path, free: int, size: str = "2m"):
    """A tmpfs at `folder` filled up to `free` bytes (page-rounded) of room."""
    with small_tmpfs(folder, size) as disk:
        with contextlib.suppress(OSError), open(disk / "filler", "wb") as f:
            while True:
                f.write(b"\0" * 65536)
                f.flush()
        os.truncate(disk / "filler", max(0, (disk / "filler").stat().st_size - free))
        yield disk


EVAL_OUTPUTS = ("metrics.json", "table.md", "confusion_train.png", "frame_train_*.png")


@pytest.mark.parametrize("free_kb", [0, 4, 64])
@pytest.mark.parametrize("command", ["train", "eval"])
def test_a_full_disk_at_any_point_fails_loudly_or_writes_everything(command, free_kb, tmp_path, mini_dataset, request):
    """However little room is left, the command either writes every output whole (exit
    0) or exits 1 with one line naming the folder; never exit 0 with an output missing, never a
    temp file left behind."""
    ctx = Ctx(tmp_path, mini_dataset, request)
    with full_disk(tmp_path / "disk", free_kb * 1024) as disk:
        out = disk / "out"
        argv = {"train": lambda: ["--config", str(ctx.train_config()), "--out", str(out), "--quiet"],
                "eval": lambda: ["--checkpoint", str(ctx.checkpoint), "--data", str(mini_dataset), "--out", str(out), "--pictures", "1"],
                }[command]()
        code, stderr = run_in_process(command, argv)
        if code == 0:
            assert error_lines(stderr) == [], stderr
            if command == "eval":
                assert all(list(out.glob(g)) for g in EVAL_OUTPUTS), sorted(p.name for p in out.iterdir())
                json.loads((out / "metrics.json").read_text())
            else:
                import torch

                assert torch.load(out / "latest.pt", map_location="cpu", weights_only=False)["step"] == 2
                assert [p for p in (out / "tb").iterdir() if p.stat().st_size > 0]
        else:
            assert_one_line(code, stderr, 1, str(disk), "No space left")
        assert not no_temps(disk)


@pytest.mark.parametrize("command", ["generate", "fuse", "train", "eval", "index"])
def test_read_only_output_is_exit_1_and_one_line(command, tmp_path, mini_dataset, request):
    ctx = Ctx(tmp_path, mini_dataset, request)
    with small_tmpfs(tmp_path / "ro", "4m") as ro:
        if command in ("fuse", "index"):
            shutil.copytree(mini_dataset, ro / "ds")
        read_only(ro)
        argv = {"generate": lambda: ["--config", str(ctx.dataset_config()), "--out", str(ro / "out"), "--no-progress"],
                "fuse": lambda: [str(ro / "ds"), "--force", "--no-progress"],
                "index": lambda: [str(ro / "ds")],
                "train": lambda: ["--config", str(ctx.train_config()), "--out", str(ro / "out"), "--quiet"],
                "eval": lambda: ["--checkpoint", str(ctx.checkpoint), "--data", str(mini_dataset), "--out", str(ro / "out")]}[command]()
        code, stderr = run_in_process(command, argv)
        assert_one_line(code, stderr, 1, str(ro), "Read-only file system")


@pytest.fixture
def lock_holder(tmp_path):
    """Another process holding the lock of tmp_path/held (common.lock), as a running writer would."""
    folder = tmp_path / "held"
    p = subprocess.Popen([sys.executable, "-c", "import sys, time\nfrom common.lock import hold_lock\nwith hold_lock(sys.argv[1]):\n"
                          "    print('held', flush=True)\n    time.sleep(60)\n", str(folder)],
                         cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    yield folder, p.pid
    p.kill()
    p.wait()


@pytest.mark.parametrize("command", ["generate", "fuse", "train"])
def test_a_second_writer_is_refused_naming_the_holder(command, lock_holder, tmp_path, mini_dataset, request):
    folder, pid = lock_holder
    ctx = Ctx(tmp_path, mini_dataset, request)
    if command == "fuse":
        shutil.copytree(mini_dataset, folder, dirs_exist_ok=True)
    before = snapshot(folder)
    argv = {"generate": lambda: ["--config", str(ctx.dataset_config()), "--out", str(folder), "--no-progress"],
            "fuse": lambda: [str(folder), "--force", "--no-progress"],
            "train": lambda: ["--config", str(ctx.train_config()), "--out", str(folder), "--quiet"]}[command]()
    code, stderr = run_in_process(command, argv)
    assert_one_line(code, stderr, 1, str(folder / ".lock"), f"pid {pid} on ")
    assert snapshot(folder) == before


def test_a_stale_lock_is_taken_over(tmp_path, mini_dataset):
    ds = tmp_path / "ds"
    shutil.copytree(mini_dataset, ds)
    (ds / ".lock").write_text("99999999 some-host\n")  # a writer that died without removing it
    vis = first_frame_dir(ds) / "labels" / "visibility.png"
    vis.write_bytes(b"")  # a zero-byte label (a kill at the worst moment) is redone, not skipped as done
    code, stderr = run_in_process("fuse", [str(ds), "--no-progress"])
    assert code == 0, stderr
    assert not (ds / ".lock").exists() and vis.stat().st_size > 0


def first_frame_dir(ds: Path) -> Path:
    return ds / json.loads((ds / "manifest.jsonl").read_text().splitlines()[0])["dir"]


def children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def alive(pid: int) -> bool:
    try:
        return "State:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False


def descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        kids = children(todo.pop())
        out += kids
        todo += kids
    return out


def survivors_of_kill_9(p: subprocess.Popen, after_s: float = 1.0) -> list[str]:
    """kill -9 of `p` alone (not its group); -> the processes it had started that are still alive
    `after_s` seconds later (pid and command line); returns as soon as none is."""
    import time

    ours = descendants(p.pid)
    assert p.poll() is None, "the command ended before it could be killed"
    t0 = time.monotonic()
    p.kill()
    p.wait()
    left = [q for q in ours if alive(q)]
    while left and time.monotonic() - t0 < after_s:  # the outcome at after_s, found sooner where all are gone
        time.sleep(0.05)
        left = [q for q in left if alive(q)]
    names = []
    for q in left:
        with contextlib.suppress(OSError):
            names.append(f"{q} {Path(f'/proc/{q}/cmdline').read_bytes()[:80]!r}")
        with contextlib.suppress(OSError):
            os.kill(q, signal.SIGKILL)  # do not leave them to the next test
    return names


def wait_until(cond, p: subprocess.Popen, timeout: float = 120, what: str = ""):
    import time

    deadline = time.time() + timeout
    while not cond():
        assert p.poll() is None, f"the command ended before {what}: {p.stderr.read()[-2000:] if p.stderr else ''}"
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_kill_9_of_generate_leaves_no_worker_writing(tmp_path, request):
    """Only the driver is killed (not its process group): its Blender worker must die with it, within
    1 s (common.lifetime). (That
    a killed run resumes to the same files is tests/test_scenes.py::test_killed_run_resumes_to_the_same_files.)"""
    import time

    ctx = Ctx(tmp_path, None, request)
    cfg = ctx.dataset_config(frames=2, scenes=[{"recipe": "scenes/parking_lot.yaml"}])
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "dataset_tools", "generate", "--config", str(cfg), "--out", str(out), "--workers", "1",
                          "--no-progress"], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while not (out / ".lock").exists() or not children(p.pid):
        assert p.poll() is None and time.time() < deadline, "generate ended before it could be killed"
        time.sleep(0.05)
    code, stderr = run_in_process("generate", ["--config", str(cfg), "--out", str(out), "--no-progress"])
    assert_one_line(code, stderr, 1, str(out / ".lock"), f"pid {p.pid} on ")
    workers = children(p.pid)
    while not list(out.glob("parking_lot/*/*")):  # kill while the worker is writing a frame
        assert time.time() < deadline
        time.sleep(0.05)
    assert workers and set(workers) <= set(descendants(p.pid))
    assert not survivors_of_kill_9(p, 1.0), "a process of generate outlived it by 1 s"
    files = snapshot(out)
    time.sleep(2)
    assert snapshot(out) == files, "files changed after the driver was killed"
    from common.lock import hold_lock

    assert (out / ".lock").read_text().split()[0] == str(p.pid)  # left behind by the kill ...
    with hold_lock(out):  # ... and taken over by the next run
        pass


def test_kill_during_checkpoint_save_leaves_no_temp_after_the_next_run(tmp_path, tiny_checkpoint, mini_dataset, request):
    import time

    import torch

    run = tmp_path / "run"
    shutil.copytree(tiny_checkpoint.parent, run)
    # a save of a big state into the run folder, killed while its temp file is being written
    saver = subprocess.Popen([sys.executable, "-c", "import sys, torch\nfrom model.checkpoint import save_checkpoint\n"
                              "save_checkpoint(sys.argv[1], {'x': torch.zeros(60_000_000)})\n", str(run / "latest.pt")],
                             cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    deadline = time.time() + 60
    while not no_temps(run):
        assert saver.poll() is None and time.time() < deadline, "the save ended before it could be killed"
        time.sleep(0.002)
    saver.kill()
    saver.wait()
    assert no_temps(run), "the kill left no temp file to clean"
    ctx = Ctx(tmp_path, mini_dataset, request)
    # resuming with a new learning rate: the optimiser takes it, not the checkpoint's
    code, stderr = run_in_process("train", ["--config", str(ctx.train_config()), "--out", str(run), "--quiet",
                                            "--set", "train.max_steps=3", "--set", "train.lr=1e-5"])
    assert code == 0, stderr
    assert not no_temps(run)
    ckpt = torch.load(run / "latest.pt", map_location="cpu", weights_only=False)
    assert ckpt["step"] == 3 and ckpt["config"]["train"]["lr"] == 1e-5
    assert {g["lr"] for g in ckpt["optimizer"]["param_groups"]} == {1e-5}


def test_kill_9_of_fuse_with_workers_leaves_no_process(tmp_path, tiny_dataset):
    """`fuse --workers 2` killed with SIGKILL: its pool processes die with it (within 1 s)."""
    ds = tmp_path / "ds"
    shutil.copytree(tiny_dataset, ds)
    p = subprocess.Popen([sys.executable, "-m", "dataset_tools", "fuse", str(ds), "--force", "--workers", "2", "--no-progress"],
                         cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), stderr=subprocess.PIPE)
    wait_until(lambda: len(descendants(p.pid)) >= 2, p, what="its pool processes started")
    assert not survivors_of_kill_9(p), "a fuse pool process outlived fuse by 1 s"


def test_kill_9_of_train_with_loader_workers_leaves_no_process(tmp_path, mini_dataset, request):
    """Train.py with data.num_workers 2 killed with SIGKILL: its loader workers die with it."""
    ctx = Ctx(tmp_path, mini_dataset, request)
    cfg = ctx.train_config(data={"num_workers": 2}, train={"max_steps": 100000, "epochs": 100000})
    p = subprocess.Popen([sys.executable, "train.py", "--config", str(cfg), "--out", str(tmp_path / "run"), "--quiet"],
                         cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1"), stderr=subprocess.PIPE)
    wait_until(lambda: len(descendants(p.pid)) >= 2, p, timeout=180, what="its loader workers started")
    assert not survivors_of_kill_9(p), "a data loader worker outlived train.py by 1 s"


@pytest.mark.parametrize("damage", ["zero-byte", "truncated", "other-size"])
def test_resume_redoes_damaged_labels_with_one_notice(damage, tmp_path, mini_dataset):
    """Fuse without --force trusts no label it skips: a zero-byte, truncated or wrongly
    sized label PNG is redone (with one notice line naming it); whole frames are left alone."""
    import cv2

    ds = tmp_path / "ds"
    shutil.copytree(mini_dataset, ds)
    frames = [ds / json.loads(line)["dir"] for line in (ds / "manifest.jsonl").read_text().splitlines()]
    bad = frames[0] / "labels" / {"zero-byte": "semantic.png", "truncated": "instance.png", "other-size": "visibility.png"}[damage]
    whole = bad.read_bytes()
    if damage == "zero-byte":
        bad.write_bytes(b"")
    elif damage == "truncated":
        bad.write_bytes(whole[: len(whole) // 2])
    else:
        a = cv2.imread(str(bad), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(bad), a[:-1])
    untouched = {p: p.stat().st_mtime_ns for p in (frames[1] / "labels").iterdir()}
    code, stderr = run_in_process("fuse", [str(ds), "--no-progress"])
    lines = error_lines(stderr)
    assert code == 0 and len(lines) == 1, stderr
    assert "redoing 1 frame" in lines[0] and str(bad) in lines[0], lines[0]
    assert bad.read_bytes() == whole
    assert {p: p.stat().st_mtime_ns for p in (frames[1] / "labels").iterdir()} == untouched
    code, stderr = run_in_process("fuse", [str(ds), "--no-progress"])  # now whole: nothing to say
    assert code == 0 and error_lines(stderr) == [], stderr
