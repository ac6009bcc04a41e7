"""Contact sheets: per scene, one PNG with the four fisheye images and the two top-down views
(first hit, and with overhead occluders hidden) coloured by fine class.

    python -m dataset_tools contact_sheet <out dir> [--frame N]

writes <out>/<scene>/contact_sheet.png for every scene with that frame rendered (default: the
scene's first finished frame). `make_sheets` is the `contact_sheets` stage of dataset_tools.pipeline
(after the render, before the fusion); this command runs it alone.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from common.cli import ArgumentParser, print_problems

from ..format.exr import read_exr_checked
from ..format.layout import CONTACT_SHEET, DatasetError, FrameFiles, frame_dir_name
from ..format.png import read_png, write_png_atomic
from ..labels.classes import colorize


def _fit(img: np.ndarray, h: int) -> np.ndarray:
    w = max(1, round(img.shape[1] * h / img.shape[0]))
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_NEAREST)


def _label(img, text):
    img = img.copy()
    cv2.putText(img, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 0), 1, cv2.LINE_AA)
    return img


def frame_sheet(frame_dir: Path, row_h: int = 240) -> np.ndarray:
    files = FrameFiles(frame_dir)
    cams = files.camera_names()
    tiles = [_label(_fit(read_png(files.camera_png(n), np.uint8, 3), row_h), n) for n in cams]
    td = read_exr_checked(files.topdown)
    for group in ("all", "ground"):
        tiles.append(_label(_fit(colorize(td[f"{group}.semantic"]), row_h), f"top-down {group}"))
    # two rows: cameras, then the two top-down views
    n = len(cams)
    rows = [tiles[: (n + 1) // 2], tiles[(n + 1) // 2: n], tiles[n:]]
    rows = [r for r in rows if r]
    width = max(sum(t.shape[1] for t in r) for r in rows)
    out = []
    for r in rows:
        line = np.concatenate(r, axis=1)
        out.append(np.pad(line, ((0, 0), (0, width - line.shape[1]), (0, 0))))
    return np.concatenate(out, axis=0)


def make_sheets(out_dir: Path, frame: int | None = None) -> list[Path]:
    made = []
    for scene_dir in sorted(p for p in Path(out_dir).iterdir() if p.is_dir() and not p.name.startswith(".")):
        frames = sorted(d for d in scene_dir.iterdir() if d.is_dir() and FrameFiles(d).meta.exists())
        if frame is not None:
            frames = [d for d in frames if d.name == frame_dir_name("", frame)[1:]]
        if not frames:
            continue
        path = scene_dir / CONTACT_SHEET
        write_png_atomic(path, frame_sheet(frames[0]))
        made.append(path)
    return made


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools contact_sheet", description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="a generate --out directory")
    ap.add_argument("--frame", type=int, default=None)
    a = ap.parse_args(argv)
    if a.frame is not None and a.frame < 0:
        raise DatasetError(f"--frame: must be >= 0, got {a.frame}")
    if not a.out.is_dir():
        raise DatasetError(f"{a.out}: not a directory")
    made = make_sheets(a.out, a.frame)
    for p in made:
        print(p)
    return print_problems([] if made else [f"contact_sheet: {a.out}: no finished frames"])

