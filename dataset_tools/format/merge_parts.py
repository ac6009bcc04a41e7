"""Merge data set parts rendered apart (`--out` per node, Slurm array tasks with `--shard i/N`)
into one data set: `python -m dataset_tools merge OUT PART...`.

Checks first, writes nothing on a problem: every part's manifest reads, no frame is in two parts,
every file a manifest line lists is there, and (with the dataset config) the parts together hold
exactly the config's frames. Then copies each frame folder into OUT (through a temp folder and a
rename: a killed merge leaves no half frame, and a rerun finishes it), appends the manifest lines
in (scene, frame) order, copies recipes/, and writes index.json (the pipeline draws the contact sheets).
OUT may be one of the parts (its frames stay where they are).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from common.files import clean_stale_temps, read_json

from .index import build_index, write_index
from .layout import INDEX, RECIPES_DIR, DatasetError, FrameFiles, Manifest, frame_dir_name

MAX_LISTED = 10  # problems listed in full; the rest are counted


def check_parts(out: Path, parts: list[Path], expected: set | None = None) -> tuple[dict, list[str]]:
    """({(scene, frame): (part, entry)}, problems) over OUT (if it has a manifest) and the parts."""
    sources = [out] + [p for p in parts if p.resolve() != out.resolve()] if Manifest(out).exists() else parts
    frames: dict[tuple, tuple[Path, dict]] = {}
    problems: list[str] = []
    for part in sources:
        if not Manifest(part).exists():
            problems.append(f"{part}: no manifest.jsonl (not a generate --out folder)")
            continue
        for e in Manifest(part).entries():
            key = (e["scene"], e["frame"])
            if key in frames:
                problems.append(f"{e['dir']}: in both {frames[key][0]} and {part}")
                continue
            frames[key] = (part, e)
            files = e.get("files") or [FrameFiles("").meta.name]
            lost = [f for f in files if not (part / e["dir"] / f).is_file()]
            if lost:
                problems.append(f"{part / e['dir']}: missing {', '.join(lost[:3])}")
    if expected is not None:
        missing = sorted(expected - frames.keys())
        extra = sorted(frames.keys() - expected)
        problems += [f"{frame_dir_name(s, f)}: missing from every part" for s, f in missing]
        problems += [f"{frames[k][0] / frames[k][1]['dir']}: not a frame of the config" for k in extra]
    return frames, problems


def _copy_dir(src: Path, dst: Path) -> None:
    tmp = dst.parent / f".{dst.name}.merge.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp)
    if dst.exists():  # a frame folder without a manifest line (a killed render): replaced
        shutil.rmtree(dst)
    os.replace(tmp, dst)


def _class_names(parts: list[Path]):
    names = [read_json(p / INDEX, DatasetError).get("class_names") for p in parts if (p / INDEX).is_file()]
    for n in names[1:]:
        if n != names[0]:
            raise DatasetError(f"index.json: the parts' class_names differ ({names[0]} vs {n})")
    return names[0] if names else None


def merge(out, parts, expected: set | None = None, progress: bool = True) -> list[str]:
    """Merge `parts` into `out`; returns the problems (nothing is written when there are any)."""
    from tqdm import tqdm

    out, parts = Path(out), [Path(p) for p in parts]
    for p in parts:
        if not p.is_dir():
            raise DatasetError(f"{p}: not a directory")
    frames, problems = check_parts(out, parts, expected)
    if problems:
        extra = len(problems) - MAX_LISTED
        return problems[:MAX_LISTED] + ([f"... and {extra} more"] if extra > 0 else [])
    class_names = _class_names(parts)
    out.mkdir(parents=True, exist_ok=True)
    clean_stale_temps(out)
    manifest = Manifest(out)
    manifest.repair()
    have = manifest.done()
    for key in tqdm(sorted(frames), desc="merge", unit="frame", disable=not progress):
        part, e = frames[key]
        if key in have:
            continue
        if part.resolve() != out.resolve():
            (out / e["dir"]).parent.mkdir(parents=True, exist_ok=True)
            _copy_dir(part / e["dir"], out / e["dir"])
        manifest.append(e)
    for part in parts:
        for recipe in sorted((part / RECIPES_DIR).glob("*")) if part.resolve() != out.resolve() else []:
            if recipe.is_file() and not (out / RECIPES_DIR / recipe.name).exists():
                (out / RECIPES_DIR).mkdir(exist_ok=True)
                shutil.copy2(recipe, out / RECIPES_DIR / recipe.name)
    write_index(out, build_index(out, class_names))
    return []
