"""The one place that names the files of a data set and of a frame, and reads and appends the
manifest and the render's error log. Every file has one writer (and the readers go through this
package, `format.*`, where a file has a format of its own):

    <dataset>/
      manifest.jsonl            one JSON line per finished frame, appended last, by the render driver
                                only (Manifest; generation.driver.render)
      index.json                splits -> frames, class names, grid, rig (format.index; the fuse stage,
                                `python -m dataset_tools index`, format.merge_parts)
      recipes/<scene>.yaml      the checked recipe each scene was rendered from (RECIPES_DIR;
                                generation.driver.write_recipes, copied by format.merge_parts)
      worker_errors.log         Python traces of scenes that failed to build (WorkerErrorLog;
                                generation.driver.render)
      audit.json                line-of-sight audit of the labels (format.audit_file; qa.audit)
      report/                   the static HTML QA report (REPORT_DIR; qa.html_report)
      README.md                 the dataset card (CARD; format.card, the dataset pipeline's last stage)
      <scene>/contact_sheet.png one picture of the scene's first frame (CONTACT_SHEET; qa.contact_sheet)
      <scene>/<frame:06d>/      one frame (frame_dir_name), written by the Blender worker
                                (blender_scripts.worker) but for labels/ and camera_targets.npy:
        cam_<name>.exr/.png     fisheye passes (format.passes through format.exr) and 8-bit image per camera
        cam_<name>_ego.png      the camera's self-occlusion mask (255 where the ego car's body is)
        topdown.exr             top-down passes ('all.*' first hit from above, 'ground.*' occluders hidden)
        meta.json               calibration, grid, weather, ego pose, actors (format.meta)
        labels/semantic.png, instance.png, visibility.png   (format.labels; the fuse stage)
        camera_targets.npy      per-camera distance and class, derived from the EXRs for training
                                (format.camera_targets; the fuse stage, never the loader)
      .lock                     held by the one writer at a time (common.lock)

Every file is written atomically (temp file + rename) but the manifest, which is appended line
by line: a manifest line counts only when it ends with a newline, so a run killed mid-line leaves a
torn last line, which every reader ignores and the next append cuts off (the frame is then redone).
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

from common.errors import InputError
from common.files import write_bytes_atomic, write_text_atomic

MANIFEST = "manifest.jsonl"
INDEX = "index.json"
RECIPES_DIR = "recipes"
AUDIT = "audit.json"
REPORT_DIR = "report"
CARD = "README.md"
META = "meta.json"
TOPDOWN_EXR = "topdown.exr"
CONTACT_SHEET = "contact_sheet.png"
CAMERA_TARGETS = "camera_targets.npy"
WORKER_ERRORS = "worker_errors.log"
LABEL_DIR = "labels"
SEMANTIC_PNG = "semantic.png"
INSTANCE_PNG = "instance.png"
VISIBILITY_PNG = "visibility.png"
LABEL_PNGS = (SEMANTIC_PNG, INSTANCE_PNG, VISIBILITY_PNG)  # visibility last: its presence marks a frame fused
VISIBILITY_SCALE = 65535.0  # visibility.png holds round(p(o) * VISIBILITY_SCALE) as uint16
MANIFEST_FIELDS = ("scene", "frame", "split", "dir")
SPLITS = ("train", "easy", "medium", "hard", "heldout")  # heldout: sampled scenes from seeds (and
# optionally families / weather presets) the training split never used


class DatasetError(InputError):
    """A data set file that cannot be read as expected (the message names the file and field)."""


def frame_dir_name(scene: str, frame: int) -> str:
    return f"{scene}/{int(frame):06d}"


class FrameFiles:
    """The paths of one frame's files."""

    def __init__(self, frame_dir):
        self.dir = Path(frame_dir)

    meta = property(lambda self: self.dir / META)
    topdown = property(lambda self: self.dir / TOPDOWN_EXR)
    labels = property(lambda self: self.dir / LABEL_DIR)
    semantic = property(lambda self: self.dir / LABEL_DIR / SEMANTIC_PNG)
    instance = property(lambda self: self.dir / LABEL_DIR / INSTANCE_PNG)
    visibility = property(lambda self: self.dir / LABEL_DIR / VISIBILITY_PNG)

    def camera_exr(self, name: str) -> Path:
        return self.dir / f"cam_{name}.exr"

    def camera_png(self, name: str) -> Path:
        return self.dir / f"cam_{name}.png"

    def camera_ego_mask(self, name: str) -> Path:
        return self.dir / f"cam_{name}_ego.png"

    def camera_names(self) -> list[str]:
        """Camera names, from the frame's cam_<name>.png files (sorted)."""
        return sorted(p.stem[4:] for p in self.dir.glob("cam_*.png") if not p.stem.endswith("_ego"))

    def label_paths(self) -> list[Path]:
        return [self.labels / n for n in LABEL_PNGS]


class WorkerErrorLog:
    """`<dataset>/worker_errors.log`: the traces of scenes that failed to build, oldest first; each
    append rewrites the file atomically (it is small: a trace per failed scene)."""

    def __init__(self, root):
        self.path = Path(root) / WORKER_ERRORS

    def append(self, trace: str) -> None:
        old = self.path.read_text() if self.path.is_file() else ""
        write_text_atomic(self.path, old + trace + "\n")


def _complete_lines(path: Path) -> list[bytes]:
    """The newline-terminated lines of a file (a torn last line is left out)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc.strerror})") from None
    end = data.rfind(b"\n")
    return data[: end + 1].splitlines() if end >= 0 else []


class Manifest:
    """`<dataset>/manifest.jsonl`: one reader (`lines`, `entries`, `done`) and one writer (`append`)."""

    def __init__(self, root):
        self.root = Path(root)
        self.path = self.root / MANIFEST
        self._lock = threading.Lock()

    def exists(self) -> bool:
        return self.path.is_file()

    def lines(self):
        """(line number, entry, problem) for every complete non-blank line: the entry (with every
        MANIFEST_FIELDS field, 'frame' an int, 'dir' a relative path inside the data set) and
        problem None, or entry None and a one-line problem."""
        for n, line in enumerate(_complete_lines(self.path), 1):
            if line.strip():
                yield n, *_parse(line)

    def entries(self) -> list[dict]:
        """Every frame's entry, sorted by (scene, frame), the last line per frame winning; the
        first bad line raises DatasetError."""
        if not self.exists():
            raise DatasetError(f"{self.path}: missing")
        out: dict[tuple, dict] = {}
        for n, e, problem in self.lines():
            if problem:
                raise DatasetError(f"{self.path}: line {n}: {problem}")
            out[(e["scene"], e["frame"])] = e
        return [out[k] for k in sorted(out)]

    def done(self) -> set[tuple[str, int]]:
        """(scene, frame) of every valid line (bad lines are skipped: those frames are redone)."""
        return {(e["scene"], e["frame"]) for _, e, problem in self.lines() if not problem}

    def drop(self, scenes) -> None:
        """Remove every line of these scenes (the file rewritten atomically; bad lines are kept)."""
        scenes = set(scenes)
        with self._lock:  # no append between the read and the rewrite
            keep = [line for line in _complete_lines(self.path) if (_parse(line)[0] or {}).get("scene") not in scenes]
            write_bytes_atomic(self.path, b"".join(line + b"\n" for line in keep))

    def repair(self) -> None:
        """Cut a torn last line (a run killed mid-write) so the next append starts a clean line."""
        if not self.path.is_file():
            return
        with open(self.path, "rb+") as f:
            data = f.read()
            if data and not data.endswith(b"\n"):
                f.truncate(data.rfind(b"\n") + 1)

    def append(self, entry: dict) -> None:
        line = json.dumps(entry, sort_keys=True) + "\n"
        with self._lock:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.repair()
            with open(self.path, "a") as f:
                f.write(line)
                f.flush()
                os.fsync(f.fileno())


def _parse(line: bytes):
    try:
        line = line.decode("utf-8")
    except UnicodeDecodeError as exc:
        return None, f"not UTF-8 text (byte {exc.start})"
    try:
        e = json.loads(line)
    except json.JSONDecodeError as exc:
        return None, f"not valid JSON ({exc.msg})"
    if not isinstance(e, dict):
        return None, "not a JSON object"
    missing = [k for k in MANIFEST_FIELDS if k not in e]
    if missing:
        return None, f"missing field '{missing[0]}'"
    if not isinstance(e["scene"], str) or not e["scene"]:
        return None, "field 'scene' must be a non-empty string"
    if isinstance(e["frame"], bool) or not isinstance(e["frame"], int) or e["frame"] < 0:
        return None, "field 'frame' must be a whole number >= 0"
    d = e["dir"]
    if not isinstance(d, str) or not d or Path(d).is_absolute() or ".." in Path(d).parts:
        return None, "field 'dir' must be a relative path inside the data set"
    if not isinstance(e["split"], str):
        return None, "field 'split' must be a string"
    if "files" in e and not _file_names(e["files"]):
        return None, "field 'files' must be a list of file names inside the frame folder"
    return e, None


def _file_names(files) -> bool:
    """A list of relative paths that stay inside the frame folder."""
    return isinstance(files, list) and all(
        isinstance(f, str) and f and not Path(f).is_absolute() and ".." not in Path(f).parts for f in files)
