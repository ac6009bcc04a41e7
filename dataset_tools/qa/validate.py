"""Check a data set: every frame's files present, readable, right shapes and value ranges, no NaN,
manifest (and index) consistent.

    python -m dataset_tools validate <dataset> [--no-labels] [--audit-threshold 0.005]

Prints one line per problem, naming the file and what is wrong, and exits 1 when there are any.
--audit-threshold also reads <dataset>/audit.json (python -m dataset_tools audit) and fails the data
set when its overall share (of the metric the audit ran with, default 'unexplained': visible cells
with no line of sight and no camera pixel near) is above the threshold.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from common.cli import ArgumentParser

from ..format.audit_file import audit_metric, read_audit
from ..format.exr import read_exr_checked
from ..format.index import read_index
from ..format.labels import label_problems
from ..format.layout import AUDIT, INDEX, MANIFEST, DatasetError, FrameFiles, Manifest, frame_dir_name
from ..format.meta import read_meta
from ..format.passes import find_channel, read_topdown
from ..format.png import read_png
from ..labels.classes import NUM_FINE_CLASSES


def check_manifest(root: Path, problems: list) -> list[dict]:
    manifest = Manifest(root)
    path = manifest.path
    if not manifest.exists():
        problems.append(f"{path}: missing")
        return []
    entries, seen = [], set()
    for n, e, problem in manifest.lines():
        if problem:
            problems.append(f"{path}: line {n}: {problem}")
            continue
        key = (str(e["scene"]), e["frame"])
        if key in seen:
            problems.append(f"{path}: line {n}: frame {e['scene']}/{e['frame']} listed twice")
        seen.add(key)
        if e["dir"] != frame_dir_name(e["scene"], e["frame"]):
            problems.append(f"{path}: line {n}: field 'dir' is {e['dir']!r}, expected '<scene>/<frame:06d>'")
        if not (root / e["dir"]).is_dir():
            problems.append(f"{root / e['dir']}: missing (listed in {MANIFEST} line {n})")
            continue
        for f in e.get("files", []):
            if not (root / e["dir"] / f).exists():
                problems.append(f"{root / e['dir'] / f}: missing (listed in {MANIFEST} line {n})")
        entries.append(e)
    if not entries and not problems:
        problems.append(f"{path}: no frames")
    return entries


def check_index(root: Path, entries: list[dict], problems: list) -> None:
    try:
        idx = read_index(root)
    except DatasetError as exc:
        problems.append(str(exc))
        return
    path = root / INDEX
    listed = {(str(x["dir"]), s) for s, xs in idx["splits"].items() for x in xs}
    want = {(str(e["dir"]), str(e["split"])) for e in entries}
    for d, s in sorted(want - listed):
        problems.append(f"{path}: frame {d} (split {s}) is in the manifest but not in the index")
    for d, s in sorted(listed - want):
        problems.append(f"{path}: frame {d} (split {s}) is in the index but not in the manifest")


def _check_exr_camera(path: Path, shape, problems: list) -> None:
    try:
        ch = read_exr_checked(path)
        dist = find_channel(ch, path, "distance")
        sem = find_channel(ch, path, "semantic")
        ins = find_channel(ch, path, "instance")
    except DatasetError as exc:
        problems.append(str(exc))
        return
    for name, a in (("distance", dist), ("semantic", sem), ("instance", ins)):
        if a.shape != shape:
            problems.append(f"{path}: channel '{name}' is {a.shape[1]}x{a.shape[0]}, the rig camera is {shape[1]}x{shape[0]}")
            return
    if not np.all(np.isfinite(dist)):
        problems.append(f"{path}: channel 'distance' has NaN or inf")
    elif dist.min() < 0:
        problems.append(f"{path}: channel 'distance' is negative ({dist.min():.3g})")
    if sem.max() >= NUM_FINE_CLASSES:
        problems.append(f"{path}: channel 'semantic' has class {int(sem.max())}, beyond the {NUM_FINE_CLASSES} fine classes")
    for k, a in ch.items():
        if a.dtype.kind == "f" and k not in ("distance",) and not np.all(np.isfinite(a)):
            problems.append(f"{path}: channel '{k}' has NaN or inf")


def check_frame(frame_dir: Path, problems: list, labels: bool = True, n_classes: int = 5) -> None:
    files = FrameFiles(frame_dir)
    try:
        meta = read_meta(frame_dir)
        rig = meta.camera_rig()
        grid = meta.grid()
    except DatasetError as exc:
        problems.append(str(exc))
        return
    for rc in rig:
        shape = (rc.camera.height, rc.camera.width)
        png = files.camera_png(rc.name)
        try:
            img = read_png(png, np.uint8, 3)
            if img.shape[:2] != shape:
                problems.append(f"{png}: {img.shape[1]}x{img.shape[0]} pixels, the rig camera is {shape[1]}x{shape[0]}")
        except DatasetError as exc:
            problems.append(str(exc))
        _check_exr_camera(files.camera_exr(rc.name), shape, problems)
    try:
        td = read_topdown(frame_dir)
        if td["semantic"].shape != grid.shape:
            problems.append(f"{files.topdown}: {td['semantic'].shape} pixels, the label grid is {grid.shape}")
        for k in ("height", "height_all"):
            if k in td and not np.all(np.isfinite(td[k])):
                problems.append(f"{files.topdown}: channel 'height' has NaN or inf")
    except DatasetError as exc:
        problems.append(str(exc))
    if not labels:
        return
    problems += label_problems(frame_dir, grid.shape, n_classes)


def check_audit(root: Path, threshold: float, problems: list) -> None:
    """The line-of-sight audit's overall metric (the one audit.json was checked with) within `threshold`."""
    try:
        a = read_audit(root)
        metric = audit_metric(a)
        share = float(a["overall"][metric])
    except DatasetError as exc:
        problems.append(str(exc))
        return
    except (AttributeError, KeyError, TypeError, ValueError):
        problems.append(f"{root / AUDIT}: no overall share to check (rerun python -m dataset_tools audit {root})")
        return
    if share > threshold:
        problems.append(f"{root / AUDIT}: {metric} {share:.4%} of the visible cells have no line of sight to any "
                        f"camera (threshold {threshold:.4%})")


def validate(root, labels: bool = True, progress: bool = True, audit_threshold: float | None = None) -> list[str]:
    from tqdm import tqdm

    root = Path(root)
    problems: list[str] = []
    if not root.is_dir():
        return [f"dataset: {root}: " + ("is a file, not a folder" if root.exists() else "missing")]
    entries = check_manifest(root, problems)
    n_classes = 5
    if labels:
        check_index(root, entries, problems)
        try:
            n_classes = len(read_index(root)["class_names"])
        except DatasetError:
            pass
    for e in tqdm(entries, desc="validate", unit="frame", disable=not progress):
        check_frame(root / e["dir"], problems, labels, n_classes)
    if audit_threshold is not None:
        check_audit(root, audit_threshold, problems)
    return problems


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools validate", description="Check every file of a data set; exit 1 on any problem.")
    ap.add_argument("dataset")
    ap.add_argument("--no-labels", action="store_true", help="renders only (before fusion)")
    ap.add_argument("--audit-threshold", type=float, metavar="SHARE",
                    help="fail when audit.json (python -m dataset_tools audit) has more than this share of "
                         "visible cells with no line of sight (its metric, default 'unexplained')")
    args = ap.parse_args(argv)
    problems = validate(args.dataset, labels=not args.no_labels, audit_threshold=args.audit_threshold)
    for p in problems:
        print(p)
    if problems:
        print(f"{len(problems)} problem(s), the first: {problems[0]}", file=sys.stderr)
        return 1
    print(f"ok: {args.dataset}")
    return 0
