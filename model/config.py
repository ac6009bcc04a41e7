"""Training configs: defaults, validation (a wrong field -> ConfigError naming file and field).

A config file overrides any subset of DEFAULTS; `_base` names another config file (relative to
this one) to start from. Every leaf is type-checked against its default.
"""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

from dataset_tools.recipe import read_yaml

from .pooling import POOLINGS

DEFAULTS = {
    "data": {
        "root": "data/small",
        "train_split": "train",
        "val_split": "easy",
        "input_size": [192, 120],  # (W, H) fed to the encoder
        "grid": {"bound": 25.0, "res": 0.25},
        "num_workers": 1,
    },
    "augment": {
        "enabled": True,
        "color_jitter": {"brightness": 0.3, "contrast": 0.5, "saturation": 0.3, "hue": 0.05},
        "scale": [0.95, 1.05],
        "rotation_deg": 5.0,
        "crop": True,
    },
    "model": {
        "encoder": {"widths": [16, 32, 64, 128], "blocks": [1, 1, 1]},
        "stride": 8,
        "context_channels": 32,
        "depth": {"min": 1.0, "max": 37.0, "bins": 36, "spacing": "linear"},
        "z_range": [-10.0, 10.0],
        "pooling": "sum",
        "bev_encoder": {"widths": [32, 64, 128], "blocks": [1, 1]},
        "norm": "group",
        "dropout": 0.0,
    },
    "loss": {
        "class_weights": "uniform",
        "visibility_weighting": True,
        "occlusion_weight": 1.0,
        "occlusion_target": "soft",
    },
    "train": {
        "epochs": 120,
        "max_steps": 0,  # 0: no limit
        "batch_size": 4,  # global: split across DDP processes
        "lr": 1e-3,
        "weight_decay": 0.0,
        "grad_clip": 5.0,
        "seed": 0,
        "checkpoint_every": 50,  # steps
        "val_every": 0,  # steps; 0: at the end of each epoch
        "val_max_frames": 0,  # 0: the whole validation split
        "log_every": 10,
        "image_every": 200,
        "device": "auto",  # auto | cpu | cuda
        "threads": 0,  # torch threads per process; 0: leave torch's default
    },
}

CHOICES = {
    ("model", "pooling"): POOLINGS,
    ("model", "norm"): ("group", "batch"),
    ("model", "depth", "spacing"): ("linear", "log"),
    ("loss", "occlusion_target"): ("soft", "binary"),
    ("train", "device"): ("auto", "cpu", "cuda"),
}
LIST_LENGTHS = {("data", "input_size"): 2, ("augment", "scale"): 2, ("model", "z_range"): 2,
                ("model", "bev_encoder", "widths"): 3, ("model", "bev_encoder", "blocks"): 2}


class ConfigError(ValueError):
    pass


def _check(value, default, path: tuple, source: str):
    name = ".".join(path)
    if path == ("loss", "class_weights"):
        if isinstance(value, str) and value in ("uniform", "paper"):
            return value
        if isinstance(value, list) and len(value) == 4 and all(isinstance(v, (int, float)) and v >= 0 for v in value):
            return [float(v) for v in value]
        raise ConfigError(f"{source}: {name}: must be 'uniform', 'paper' or a list of 4 non-negative weights")
    if path == ("data", "grid"):
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: {name}: must be a mapping")
        from geometry.bev import BevGrid

        try:
            BevGrid.from_dict(value)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{source}: {name}: {exc}") from None
        return dict(value)
    if isinstance(default, dict):
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: {name}: must be a mapping")
        out = copy.deepcopy(default)
        for k, v in value.items():
            if k not in default:
                raise ConfigError(f"{source}: {'.'.join(path + (str(k),))}: unknown field (fields: {', '.join(default)})")
            out[k] = _check(v, default[k], path + (k,), source)
        return out
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {name}: must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(f"{source}: {name}: must be a non-negative integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{source}: {name}: must be a number, got {value!r}")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"{source}: {name}: must be a string, got {value!r}")
        if path in CHOICES and value not in CHOICES[path]:
            raise ConfigError(f"{source}: {name}: must be one of {', '.join(CHOICES[path])}, got {value!r}")
        return value
    if isinstance(default, list):
        n = LIST_LENGTHS.get(path)
        if not isinstance(value, list) or not value or (n and len(value) != n):
            raise ConfigError(f"{source}: {name}: must be a list of {n or 'one or more'} numbers")
        kind = type(default[0])
        try:
            if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
                raise TypeError
            if kind is int and any(not float(v).is_integer() or v <= 0 for v in value):
                raise TypeError
            return [kind(v) for v in value]
        except TypeError:
            raise ConfigError(f"{source}: {name}: must be a list of {'positive integers' if kind is int else 'numbers'}") from None
    raise ConfigError(f"{source}: {name}: unexpected value {value!r}")


def _semantic_checks(cfg: dict, source: str):
    m, t = cfg["model"], cfg["train"]
    if len(m["encoder"]["blocks"]) != len(m["encoder"]["widths"]) - 1:
        raise ConfigError(f"{source}: model.encoder.blocks: needs one entry per stage ({len(m['encoder']['widths']) - 1})")
    s = m["stride"]
    if s < 2 or s & (s - 1) or s > 2 ** len(m["encoder"]["widths"]):
        raise ConfigError(f"{source}: model.stride: must be a power of 2 up to {2 ** len(m['encoder']['widths'])}")
    if m["context_channels"] < 1:
        raise ConfigError(f"{source}: model.context_channels: must be >= 1")
    d = m["depth"]
    if not 0 < d["min"] < d["max"] or d["bins"] < 1:
        raise ConfigError(f"{source}: model.depth: need 0 < min < max and bins >= 1")
    if m["z_range"][0] >= m["z_range"][1]:
        raise ConfigError(f"{source}: model.z_range: must be [low, high] with low < high")
    if t["batch_size"] < 1 or t["epochs"] < 1:
        raise ConfigError(f"{source}: train: batch_size and epochs must be >= 1")
    for k in ("checkpoint_every", "log_every"):
        if t[k] < 1:
            raise ConfigError(f"{source}: train.{k}: must be >= 1 (steps)")
    if not t["lr"] > 0:
        raise ConfigError(f"{source}: train.lr: must be positive")
    if any(v <= 0 for v in cfg["data"]["input_size"]):
        raise ConfigError(f"{source}: data.input_size: must be positive")
    a = cfg["augment"]["scale"]
    if not 0 < a[0] <= a[1]:
        raise ConfigError(f"{source}: augment.scale: must be [low, high] with 0 < low <= high")


def validate(user: dict | None, source: str = "config") -> dict:
    cfg = _check(user or {}, DEFAULTS, (), source)
    _semantic_checks(cfg, source)
    return cfg


def _deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) and k != "grid" else v
    return out


def read_config_file(path, _seen=()) -> dict:
    path = Path(path)
    data = read_yaml(path, ConfigError) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: must be a mapping of sections")
    base = data.pop("_base", None)
    if base is not None:
        bpath = (path.parent / str(base)).resolve()
        if bpath in _seen:
            raise ConfigError(f"{path}: _base: circular reference to {bpath}")
        data = _deep_merge(read_config_file(bpath, _seen + (bpath,)), data)
    return data


def load_config(path, overrides: dict | None = None) -> dict:
    """Read, merge `_base`, apply overrides ({'train': {'lr': ..}}), validate."""
    data = read_config_file(path)
    if overrides:
        data = _deep_merge(data, overrides)
    return validate(data, str(path))


def parse_override(text: str) -> dict:
    """'train.lr=1e-4' -> {'train': {'lr': 0.0001}} (value parsed as YAML)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected section.field=value")
    key, val = text.split("=", 1)
    parts = key.strip().split(".")
    out: dict = {}
    d = out
    for p in parts[:-1]:
        d = d.setdefault(p, {})
    try:
        d[parts[-1]] = yaml.safe_load(val)
    except yaml.YAMLError:
        raise ConfigError(f"override {text!r}: value is not valid YAML") from None
    return out
