"""Dataset configs (configs/dataset/*.yaml): which scenes, with which rig, at which sizes.

    cfg = load_config("configs/dataset/small.yaml")   # every scene's recipe loaded and checked

A scene entry names a recipe (`- {recipe: scenes/x.yaml, split: train}`) or asks for sampled
scenes (`- {sample: {count: 200, seed: 1}, split: train}`, generation.sampler). `hold_out:
{families: [...], weather: [...]}` keeps those families / weather presets out of the training
split (sampled training blocks do not draw them; a named training recipe using one is refused).
Sampled scenes of a test split must come from seeds no training scene uses: a sample block's seed
may not be reused by another block, and no recipe or traffic seed is shared between a sampled
scene and a scene of the other side (train vs. the test splits); both are refused at load time.
A test block with `training_layouts: true` takes its layouts from the training scenes (the
paper's "easy" split): its scenes share their layout seed with training on purpose, never their
traffic seed.

Relative paths (rig, recipes) are looked up as given (from the working directory), then beside
the config, then among the toolkit's shipped files (common.resources: the checkout, or the
installed package's data); `--config tiny` names a preset (configs/dataset/tiny.yaml). The
`labels:` section is the label fusion's settings: it is checked at load by
dataset_tools.labels.label_fusion.FusionConfig (`cfg["labels"]` is one), so a mistake there stops a
data set before anything renders; `load_labels` reads only that section (what `fuse --config` and
`audit --config` take).
"""

from __future__ import annotations

from pathlib import Path

from common.errors import ConfigError
from common.files import read_yaml
from common.resources import presets, resolve_input
from common.schema import Any, Bool, List, Name, Num, Section, Str, deep_merge

from ..format.layout import CARD, LABEL_DIR, RECIPES_DIR, REPORT_DIR, SPLITS
from ..labels.label_fusion import FusionConfig
from .recipe import FAMILIES, WEATHER_PRESETS, load_recipe
from .sampler import SAMPLE, relit_recipes, sample_recipes
from .sensor import EFFECTS, OFF as SENSOR_OFF, SENSOR

DENOISE_QUALITIES = ("high", "balanced", "fast")  # OpenImageDenoise's, as Cycles names them

# render quality presets: the defaults of the render section. draft: fast and clean (tests, the
# demo); photo: denoised path tracing and the camera's effects (data sets people train on)
QUALITY = {
    "draft": {"samples": 1, "denoise": False, "max_bounces": 1, "sensor": SENSOR_OFF},
    "photo": {"samples": 2, "denoise": True, "max_bounces": 3,
              "sensor": {e: e != "jpeg" for e in EFFECTS},
              # a night street is lit by dozens of small lamps: at 2 samples the denoiser smears
              # it into clay (docs/rendering.md, "Kept: night scenes at 4 samples")
              "night": {"samples": 4, "denoise_quality": "high"}},
}

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
        # what the other render fields default to (QUALITY); fields given explicitly win
        "quality": Str(choices=tuple(QUALITY), default="photo"),
        "samples": Num(1, 65536, integer=True, default=4),
        "denoise": Bool(default=True),
        "denoise_quality": Str(choices=DENOISE_QUALITIES, default="balanced"),
        "max_bounces": Num(0, 128, integer=True, default=4),
        "camera_method": Str(choices=("osl", "polynomial"), default="osl"),
        # the ego car's body around the rig (class `ego`, a self-occlusion mask per camera)
        "ego_body": Bool(default=True),
        # the camera's own effects on the image (generation.sensor), each switched on or off
        "sensor": SENSOR,
        # what night scenes (the sun below the horizon) render with at least, where given
        "night": Section({"samples": Num(1, 65536, integer=True, default=None, nullable=True),
                          "denoise_quality": Str(choices=DENOISE_QUALITIES, default=None, nullable=True)}),
    }),
    "frames": Num(1, 10000, integer=True, default=None, nullable=True),  # overrides every recipe's frames.count
    "scenes": List(Any(), max_length=100_000),
    "labels": Any(default=None, nullable=True),
    "hold_out": Section({
        "families": List(Str(choices=FAMILIES), min_length=0, default=[]),
        "weather": List(Str(choices=WEATHER_PRESETS), min_length=0, default=[]),
    }),
})
SAMPLED = Section({"sample": SAMPLE, "split": Str(choices=SPLITS, default="train")})


def with_quality(d, where: str):
    """The config with its render section's quality preset filled in under the fields it gives."""
    if not isinstance(d, dict) or not isinstance(d.get("render", {}), dict):
        return d  # the schema says what is wrong
    render = d.get("render", {})
    field = SCHEMA.fields["render"].fields["quality"]
    quality = field.validate(render.get("quality", field.default), f"{where}: render.quality")
    return {**d, "render": deep_merge(QUALITY[quality], render)}


def for_weather(render: dict, weather: dict) -> dict:
    """The render settings a scene gets: where the sun is below the horizon (the street lamps and
    headlights light it, not the sky), at least `render.night`'s samples and denoising quality."""
    night = render.get("night") or {}
    if weather["sun_elevation_deg"] >= 0:
        return render
    out = dict(render)
    if night.get("samples"):
        out["samples"] = max(render["samples"], night["samples"])
    if night.get("denoise_quality"):  # DENOISE_QUALITIES runs from the best down
        out["denoise_quality"] = min(render["denoise_quality"], night["denoise_quality"], key=DENOISE_QUALITIES.index)
    return out


def resolve(path, base: Path) -> Path:
    """A path as given (absolute or from the working directory), else beside the config, else the
    toolkit's shipped file (common.resources)."""
    return resolve_input(path, base)


def _existing_file(path, option: str) -> Path:
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{option}: {path}: is a folder, not a file")
    if not path.exists():
        raise ConfigError(f"{option}: {path}: missing" + ("" if path.suffix else f" (or a preset's name: {', '.join(presets('dataset'))})"))
    return path


def _labels(d, path: Path) -> FusionConfig:
    """The `labels:` section of a dataset config's YAML, checked by FusionConfig (defaults when absent)."""
    return FusionConfig.from_dict(d.get("labels") if isinstance(d, dict) else None, f"{path}: labels")


def load_labels(path, option: str = "--config") -> FusionConfig:
    """Only the `labels:` section of a dataset config (a file with only that section will do)."""
    path = _existing_file(path, option)
    return _labels(read_yaml(path), path)


def load_config(path, option: str = "--config") -> dict:
    """The dataset config with every scene's recipe loaded and checked, `labels` a FusionConfig
    (`option`: what named the file, for the message when it is missing)."""
    path = _existing_file(path, option)
    d = with_quality(read_yaml(path), str(path))
    cfg = SCHEMA.validate(d, str(path))
    cfg["labels"] = _labels(cfg, path)
    cfg["name"] = cfg["name"] or SCHEMA.fields["name"].validate(path.stem, f"{path}: name")
    cfg["rig"] = str(resolve(cfg["rig"], path.parent))
    if not Path(cfg["rig"]).is_file():
        raise ConfigError(f"{path}: rig: {cfg['rig']}: missing")
    _check_rig(cfg["rig"], path)
    hold = cfg["hold_out"]
    scenes, names, blocks = [], set(), {}
    loaded = []  # (where, split, sampled, recipes; None for a training_layouts block, drawn once training is known)
    for i, s in enumerate(cfg["scenes"]):
        where = f"{path}: scenes[{i}]"
        if not isinstance(s, dict) or ("recipe" in s) == ("sample" in s):
            raise ConfigError(f"{where}: must be a mapping with 'recipe' or 'sample' (one of them)")
        if "sample" in s:
            s = SAMPLED.validate(s, where)
            relit = s["sample"]["training_layouts"]
            if relit and s["split"] == "train":
                raise ConfigError(f"{where}.sample.training_layouts: only for a test split (a training layout under new weather and traffic)")
            recipes = None if relit else _sampled(s, hold, blocks, where)
            loaded.append((where, s, True, recipes))
        else:
            s = SCENE.validate(s, where)
            recipe = load_recipe(_recipe_file(s["recipe"], path.parent, f"{where}.recipe"), s["overrides"],
                                 f"{where}.overrides")
            recipe["name"] = s["name"] or recipe["name"]
            if s["split"] == "train" and (recipe["family"] in hold["families"] or recipe["weather"]["preset"] in hold["weather"]):
                raise ConfigError(f"{where}: a training scene uses a held-out family or weather preset "
                                  f"({recipe['family']}, {recipe['weather']['preset']})")
            loaded.append((where, s, False, [recipe]))
    training = [r for _, s, _, recipes in loaded if s["split"] == "train" and recipes for r in recipes]
    for where, s, sampled, recipes in loaded:
        relit = recipes is None
        if relit:
            recipes = _sampled(s, hold, blocks, where, bases=training)
        for recipe in recipes:
            if cfg["frames"] is not None:
                recipe["frames"]["count"] = cfg["frames"]
            name = recipe["name"]
            if name in (RECIPES_DIR, REPORT_DIR, LABEL_DIR, CARD):
                raise ConfigError(f"{where}.name: '{name}' is a reserved name of the data set (a folder or file of it)")
            if name in names:
                raise ConfigError(f"{where}.name: scene name '{name}' used twice")
            names.add(name)
            scenes.append({"name": name, "split": s["split"], "recipe": recipe, "sampled": sampled, "training_layout": relit})
    _check_disjoint(scenes, path)
    cfg["scenes"] = scenes
    return cfg


def _recipe_file(name: str, base: Path, where: str) -> Path:
    """The recipe a scene entry names; a missing one is named with the field that points there."""
    p = resolve(name, base)
    if p.is_dir():
        raise ConfigError(f"{where}: {p}: is a folder, not a file")
    if not p.is_file():
        raise ConfigError(f"{where}: {p}: missing")
    return p


def _sampled(s: dict, hold: dict, blocks: dict, where: str, bases: list[dict] | None = None) -> list[dict]:
    spec, split = s["sample"], s["split"]
    if spec["seed"] in blocks:
        raise ConfigError(f"{where}.sample.seed: {spec['seed']} is already the seed of {blocks[spec['seed']]} "
                          f"(every sample block needs its own seed)")
    blocks[spec["seed"]] = where.split(": ", 1)[1]
    families = [f for f in FAMILIES if f not in hold["families"]]
    weather = [w for w in WEATHER_PRESETS if w not in hold["weather"]]
    if split == "train":
        for key, allowed in (("families", families), ("weather", weather)):
            bad = [v for v in spec[key] or () if v not in allowed]
            if bad:
                raise ConfigError(f"{where}.sample.{key}: {bad[0]} is held out (hold_out.{key})")
        if not families or not weather:
            raise ConfigError(f"{where}.sample: hold_out leaves no family or weather preset to train on")
    if spec["training_layouts"]:
        return relit_recipes(spec, bases, f"{where}.sample")
    return sample_recipes(spec, f"{where}.sample", families if split == "train" else None,
                          weather if split == "train" else None)


def _check_disjoint(scenes: list[dict], path: Path) -> None:
    """No recipe or traffic seed shared between a sampled scene and a scene on the other side of the
    train / test divide (named test scenes and `training_layouts` blocks reuse a training layout on
    purpose, as `easy` does: the traffic seed of a `training_layouts` scene must still be new)."""
    seeds = lambda s: ({s["recipe"]["traffic"]["seed"]} if s.get("training_layout")  # noqa: E731
                       else {s["recipe"]["seed"], s["recipe"]["traffic"]["seed"]})
    by_seed: dict[int, list] = {}
    for a in scenes:
        if a["split"] == "train":
            for x in seeds(a):
                by_seed.setdefault(x, []).append(a)
    for b in scenes:
        if b["split"] == "train":
            continue
        for a in (a for x in seeds(b) for a in by_seed.get(x, ())):
            if a["sampled"] or b["sampled"]:
                raise ConfigError(f"{path}: scenes: '{b['name']}' ({b['split']}) shares a seed with training "
                                  f"scene '{a['name']}': draw the test scenes from another sample seed")


def _check_rig(rig_path: str, config: Path) -> None:
    from geometry.rig import RigError, load_rig

    try:
        load_rig(rig_path)
    except RigError as exc:
        raise ConfigError(f"{config}: rig: {exc}") from None
