"""A frame's meta.json: the one writer (`write_meta`) and reader (`read_meta`), through FrameMeta.

    write_meta(frame_dir, FrameMeta(rig=rig.to_dict(), topdown={"grid": grid.to_dict()}, ...))
    meta = read_meta(frame_dir)      # FrameMeta; DatasetError naming the file and field if bad
    meta.camera_rig(), meta.grid(), meta.ego_box, meta.weather_preset

The file's keys are FrameMeta's fields in declaration order (fields left None are not written);
`rig` and `topdown` (with its `grid`) are required, every other field is optional.
"""

from __future__ import annotations

import json
from dataclasses import MISSING, dataclass, field, fields
from functools import lru_cache
from pathlib import Path

from common.files import read_json, write_json_atomic

from .layout import DatasetError, FrameFiles


def _opt(kind):
    return field(default=None, metadata={"kind": kind})


def _req(kind):
    return field(default=MISSING, metadata={"kind": kind})


@dataclass(frozen=True, kw_only=True)
class FrameMeta:
    """The metadata of one rendered frame (blender_scripts.worker writes every field)."""

    scene: str | None = _opt(str)
    frame: int | None = _opt(int)
    split: str | None = _opt(str)
    family: str | None = _opt(str)
    time_s: float | None = _opt(float)
    ego_pose: dict | None = _opt(dict)  # x, y, yaw, ego_to_world (4 x 4)
    actors: list | None = _opt(list)
    instances: dict | None = _opt(dict)  # instance id (string) -> name, class
    weather: dict | None = _opt(dict)  # the resolved weather; 'preset' names it
    sun: dict | None = _opt(dict)
    seeds: dict | None = _opt(dict)
    rig: dict = _req(dict)  # this frame's calibration (geometry Rig.to_dict; jittered when the recipe asks)
    rig_nominal: dict | None = _opt(dict)  # the rig before the scene's jitter
    ego: dict | None = _opt(dict)  # the ego body: box [x_min, x_max, y_min, y_max] (ego frame, m), kind, instance
    camera_method: str | None = _opt(str)
    fit_errors_px: dict | None = _opt(dict)
    topdown: dict = _req(dict)  # grid (BevGrid.to_dict), height_m, supersample, marking_share
    render: dict | None = _opt(dict)
    sensor: dict | None = _opt(dict)  # per camera: the camera effects drawn for this frame (generation.sensor)
    recipe: dict | None = _opt(dict)
    timings: dict | None = _opt(dict)
    path: Path | None = field(default=None, compare=False, repr=False, metadata={"kind": None})  # where it was read

    def __post_init__(self):
        where = self.path or "meta.json"
        for f in fields(self):
            kind, v = f.metadata["kind"], getattr(self, f.name)
            if kind is None or (v is None and f.default is None):
                continue
            if v is None:
                raise DatasetError(f"{where}: missing field '{f.name}'")
            ok = isinstance(v, kind) and not isinstance(v, bool) or (kind is float and isinstance(v, int) and not isinstance(v, bool))
            if not ok:
                raise DatasetError(f"{where}: field '{f.name}' must be {_KIND_NAMES[kind]}, got {type(v).__name__}")
        for key in ("rig", "rig_nominal"):
            r = getattr(self, key)
            if r is not None and not isinstance(r.get("cameras"), dict):
                raise DatasetError(f"{where}: field '{key}' must have a 'cameras' mapping (the rig calibration)")
        if not isinstance(self.topdown.get("grid"), dict):
            raise DatasetError(f"{where}: field 'topdown.grid' missing or not a mapping")
        box = (self.ego or {}).get("box")
        if box is not None and not (isinstance(box, list) and len(box) == 4
                                    and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in box)):
            raise DatasetError(f"{where}: field 'ego.box' must be [x_min, x_max, y_min, y_max]")

    @classmethod
    def from_dict(cls, d: dict, path=None) -> "FrameMeta":
        known = [f.name for f in fields(cls) if f.name != "path"]
        for k in d:
            if k not in known:
                raise DatasetError(f"{path or 'meta.json'}: unknown field '{k}' (known: {', '.join(known)})")
        for f in fields(cls):
            if f.default is MISSING and f.name not in d:
                raise DatasetError(f"{path or 'meta.json'}: missing field '{f.name}'")
        return cls(**d, path=Path(path) if path is not None else None)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "path" and getattr(self, f.name) is not None}

    @property
    def nominal_rig(self) -> dict:
        """The rig before the scene's jitter (older frames without `rig_nominal`: their `rig`)."""
        return self.rig_nominal if self.rig_nominal is not None else self.rig

    @property
    def weather_preset(self) -> str:
        return str((self.weather or {}).get("preset", ""))

    @property
    def ego_box(self) -> tuple | None:
        """(x_min, x_max, y_min, y_max) of the rendered ego body, None when the frame has none."""
        box = (self.ego or {}).get("box")
        return tuple(float(v) for v in box) if box is not None else None

    def camera_rig(self):
        """The rig this frame was rendered with (geometry Rig; cached by calibration)."""
        from geometry.rig import RigError

        try:
            return _rig_from_json(json.dumps(self.rig, sort_keys=True), f"{self.path or 'meta.json'}: rig")
        except RigError as exc:
            raise DatasetError(str(exc)) from None

    def grid(self):
        """The frame's label grid (geometry BevGrid), from topdown.grid."""
        from geometry.bev import BevGrid

        try:
            return BevGrid.from_dict(self.topdown["grid"])
        except (TypeError, ValueError, KeyError) as exc:
            raise DatasetError(f"{self.path or 'meta.json'}: topdown.grid: {exc}") from None


_KIND_NAMES = {str: "a string", int: "a whole number", float: "a number", dict: "a mapping", list: "a list"}


@lru_cache(maxsize=32)
def _rig_from_json(text: str, source: str):
    """rig_from_dict, cached by the calibration (building a camera checks its model, ~0.2 s)."""
    from geometry.rig import rig_from_dict

    return rig_from_dict(json.loads(text), source)


def read_meta(frame_dir) -> FrameMeta:
    """A frame's meta.json; a missing, unreadable or badly shaped file is one DatasetError line."""
    path = FrameFiles(frame_dir).meta
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    d = read_json(path, DatasetError)
    if not isinstance(d, dict):
        raise DatasetError(f"{path}: must be a JSON object")
    return FrameMeta.from_dict(d, path)


def decode_meta(data: bytes, source) -> FrameMeta:
    """read_meta of a meta.json held in memory (a shard member); `source` names it in errors."""
    try:
        d = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{source}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(d, dict):
        raise DatasetError(f"{source}: must be a JSON object")
    return FrameMeta.from_dict(d, source)


def write_meta(frame_dir, meta: FrameMeta) -> Path:
    """meta.json of a frame, atomically (keys in FrameMeta's order, one-space indent)."""
    path = FrameFiles(frame_dir).meta
    write_json_atomic(path, meta.to_dict())
    return path
