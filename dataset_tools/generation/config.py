"""Dataset configs (configs/dataset/*.yaml): which scenes, with which rig, at which sizes.

    cfg = load_config("configs/dataset/small.yaml")   # every scene's recipe loaded and checked

Relative paths (rig, recipes) are looked up as given (from the working directory), then beside
the config, then in the repository. The `labels:` section belongs to the label fusion
(dataset_tools.labels.fusion.FusionConfig) and is checked there.
"""

from __future__ import annotations

from pathlib import Path

from common.errors import ConfigError
from common.files import read_yaml
from common.schema import Any, Bool, List, Name, Num, Section, Str

from ..format.layout import SPLITS
from .recipe import load_recipe

REPO = Path(__file__).resolve().parents[2]
DENOISE_QUALITIES = ("high", "balanced", "fast")  # OpenImageDenoise's, as Cycles names them

SCENE = Section({
    "recipe": Str(),
    "split": Str(choices=SPLITS, default="train"),
    "name": Name(default=None, nullable=True),
    "overrides": Section({k: Any() for k in ("name", "family", "seed", "layout", "roadside", "traffic", "ego",
                                             "weather", "frames")}, partial=True, default={}),
})
SCHEMA = Section({
    "name": Name(default=None, nullable=True),
    "rig": Str(default="configs/rigs/default.yaml"),
    "fisheye_size": List(Num(8, 8192, integer=True), length=2, default=None, nullable=True),
    "topdown": Section({
        "size": Num(8, 8192, integer=True, default=400),
        "height_m": Num(above=0, hi=1000.0, default=60.0),
        "bound": Num(above=0, hi=500.0, default=25.0),
        # label passes rendered this many times finer per axis and reduced to coverage labels
        # (dataset_tools.labels.coverage); a cell is paint when paint covers marking_share of it
        "supersample": Num(1, 8, integer=True, default=2),
        "marking_share": Num(above=0, hi=1.0, default=0.25),
    }),
    "render": Section({
        "samples": Num(1, 65536, integer=True, default=4),
        "denoise": Bool(default=True),
        "denoise_quality": Str(choices=DENOISE_QUALITIES, default="balanced"),
        "max_bounces": Num(0, 128, integer=True, default=4),
        "camera_method": Str(choices=("osl", "polynomial"), default="osl"),
    }),
    "frames": Num(1, 10000, integer=True, default=None, nullable=True),  # overrides every recipe's frames.count
    "scenes": List(Any(), max_length=100_000),
    "labels": Any(default=None, nullable=True),
})


def resolve(path, base: Path) -> Path:
    """A path as given (absolute or from the working directory), else beside the config, else in the repo."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return p
    return base / p if (base / p).exists() else REPO / p


def load_config(path) -> dict:
    """The dataset config with every scene's recipe loaded and checked."""
    path = Path(path)
    d = read_yaml(path)
    cfg = SCHEMA.validate(d, str(path))
    cfg["name"] = cfg["name"] or SCHEMA.fields["name"].validate(path.stem, f"{path}: name")
    cfg["rig"] = str(resolve(cfg["rig"], path.parent))
    if not Path(cfg["rig"]).is_file():
        raise ConfigError(f"{path}: rig: no such file {cfg['rig']}")
    _check_rig(cfg["rig"], path)
    scenes, names = [], set()
    for i, s in enumerate(cfg["scenes"]):
        where = f"{path}: scenes[{i}]"
        if not isinstance(s, dict) or "recipe" not in s:
            raise ConfigError(f"{where}: must be a mapping with 'recipe'")
        s = SCENE.validate(s, where)
        overrides = s["overrides"]
        if cfg["frames"] is not None:
            frames = overrides.get("frames") or {}
            if not isinstance(frames, dict):
                raise ConfigError(f"{where}.overrides.frames: must be a mapping")
            overrides = {**overrides, "frames": {**frames, "count": cfg["frames"]}}
        recipe = load_recipe(resolve(s["recipe"], path.parent), overrides)
        name = s["name"] or recipe["name"]
        if name in names:
            raise ConfigError(f"{where}.name: scene name '{name}' used twice")
        names.add(name)
        recipe["name"] = name
        scenes.append({"name": name, "split": s["split"], "recipe": recipe})
    cfg["scenes"] = scenes
    return cfg


def _check_rig(rig_path: str, config: Path) -> None:
    from geometry.rig import RigError, load_rig

    try:
        load_rig(rig_path)
    except RigError as exc:
        raise ConfigError(f"{config}: rig: {exc}") from None
