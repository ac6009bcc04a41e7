"""Training configs (configs/train/*.yaml): schema, defaults and validation.

A config file overrides any subset of the defaults; `_base` names another config file (relative to
this one, or a shipped preset's name such as `cpu_default`) to start from, or a list of them,
merged in order (a shared part such as recipe.yaml written once). A wrong field raises ConfigError
naming the file and the field.
"""

from __future__ import annotations

from pathlib import Path

from common.errors import ConfigError
from common.files import parse_yaml, read_yaml
from common.resources import preset
from common.schema import Bool, Field, List, Num, OneOf, Section, Str, deep_merge, is_number

from .minutes import SKIP, TIMED
from .pooling import POOLINGS


class GridField(Field):
    """A BEV grid: {bound, res} or {x_min, x_max, y_min, y_max, res} (kept as given)."""

    def check(self, value, where):
        from geometry.bev import BevGrid

        if not isinstance(value, dict) or not all(is_number(v) for v in value.values()):
            self.fail(where, f"must be a mapping of numbers such as {{bound: 25, res: 0.25}}, got {value!r}"[:200])
        try:
            BevGrid.from_dict(value)
        except (ValueError, TypeError) as exc:
            self.fail(where, str(exc))
        return dict(value)


SCHEMA = Section({
    "data": Section({
        "root": Str(default="data/small"),
        # WebDataset shards to train from instead of the folder (export-webdataset; model.shards):
        # a brace pattern of local paths or file:/pipe: URLs; "" for none
        "shards": Str(empty=True, default=""),
        "shards_index": Str(empty=True, default=""),  # shards.json; "": beside the shards
        "shuffle_buffer": Num(1, 10**6, integer=True, default=64),  # samples
        "train_split": Str(default="train"),
        "val_split": Str(empty=True, default="easy"),  # "" for none
        "input_size": List(Num(8, 4096, integer=True), length=2, default=[192, 120]),  # (W, H) fed to the encoder
        "grid": GridField(default={"bound": 25.0, "res": 0.25}),  # geometry.bev.BevGrid.from_dict
        "num_workers": Num(0, 64, integer=True, default=1),
        # decoded frames kept in memory by each loader process, up to this many MB (0: none): the
        # camera PNGs and label PNGs are decoded, and the labels pooled, once per run, not per epoch
        "cache_mb": Num(0, 10**6, integer=True, default=1024),
        # the paper's baseline: fisheye images remapped to cylindrical ones (geometry.rectify)
        "rectify": Str(choices=("none", "cylindrical"), default="none"),
        "cylinder": Section({
            "hfov_deg": Num(1.0, 359.0, default=180.0),
            "vfov_deg": Num(1.0, 179.0, default=90.0),
        }),
    }),
    "augment": Section({
        "enabled": Bool(default=True),
        "color_jitter": Section({
            "brightness": Num(0.0, 1.0, default=0.3),
            "contrast": Num(0.0, 1.0, default=0.5),
            "saturation": Num(0.0, 1.0, default=0.3),
            "hue": Num(0.0, 0.5, default=0.05),
        }),
        "scale": List(Num(above=0, hi=4.0), length=2, default=[0.95, 1.05]),
        "rotation_deg": Num(0.0, 45.0, default=5.0),
        "crop": Bool(default=True),
        # the probability that a training sample is mirrored about the ego's x axis: every image
        # flipped left-right, the labels and the lift geometry mirrored with them (model.frustum)
        "mirror": Num(0.0, 1.0, default=0.0),
        # BEV-space rotation (BEVDet's BDA, exact here): the world of a training sample turned about the ego z
        # axis by an angle drawn uniformly in [-bev_rotation_deg, +bev_rotation_deg]: the images as they are,
        # the rig's poses and the labels turned with it (geometry.rig.Rig.turned, geometry.bev.BevGrid.turned);
        # cells whose label comes from outside the grid are left out of every loss
        "bev_rotation_deg": Num(0.0, 180.0, default=0.0),
    }),
    "model": Section({
        "trunk": Str(choices=("scratch", "efficientnet_lite0"), default="scratch"),  # model.encoder / model.efficientnet
        # the pretrained trunk's first levels kept as pretrained (no gradient, BatchNorm at ImageNet's
        # statistics): 1 the stem and the blocks at stride 2, 2 through stride 4, ... (model.efficientnet); 0 none
        "trunk_frozen": Num(0, 5, integer=True, default=0),
        # the depthwise convolution weights of the pretrained trunk's trained blocks kept as loaded (the
        # pointwise convolutions, BatchNorm and head still train, gradients still flow through them): their bf16
        # weight gradients take oneDNN's slow path, about a fifth of a step at 256x160 (docs/model.md)
        "trunk_depthwise_frozen": Bool(default=False),
        "encoder": Section({
            "widths": List(Num(1, 4096, integer=True), max_length=8, default=[16, 32, 64, 128]),
            "blocks": List(Num(1, 64, integer=True), max_length=8, default=[1, 1, 1]),
        }),
        "stride": Num(2, 256, integer=True, default=8),
        "context_channels": Num(1, 4096, integer=True, default=32),
        "depth": Section({
            "min": Num(above=0, hi=1000.0, default=1.0),
            "max": Num(above=0, hi=1000.0, default=37.0),
            "bins": Num(1, 1024, integer=True, default=36),
            "spacing": Str(choices=("linear", "log"), default="linear"),
        }),
        "z_range": List(Num(-1000.0, 1000.0), length=2, default=[-10.0, 10.0]),
        "pooling": Str(choices=POOLINGS, default="sum"),
        # the ground image (model/ground.py; docs/model.md "The ground image"): each camera's input image sampled where
        # every BEV cell's ground point (ego z = 0) projects, through a 3x3 convolution of this many channels, added
        # to the pooled BEV features and to the heads' input; exact for what lies on the road (markings); 0: off
        "ground_channels": Num(0, 4096, integer=True, default=0),
        "bev_encoder": Section({
            "widths": List(Num(1, 4096, integer=True), length=3, default=[32, 64, 128]),
            "blocks": List(Num(1, 64, integer=True), length=2, default=[1, 1]),
            # depthwise-separable 3x3 convolutions in the decoder (1/2 and full resolution): a
            # fifth of the encoder's work (model.bev_encoder)
            "separable": Bool(default=False),
        }),
        "norm": Str(choices=("group", "batch"), default="group"),
        "dropout": Num(0.0, 0.95, default=0.0),
        # bf16: the trunk and the BEV encoder run under bfloat16 autocast (lift, splat, pooling and
        # losses stay float32); training and inference alike (docs/model.md). auto: bf16 where the
        # device computes it natively (AVX512-BF16, AMX, CUDA), else fp32; a run records what it chose
        "precision": Str(choices=("fp32", "bf16", "auto"), default="fp32"),
    }),
    "loss": Section({
        "class_weights": OneOf(Str(choices=("uniform", "paper")), List(Num(0.0, 1e6), length=4),
                               wanted="'uniform', 'paper' or a list of 4 non-negative weights", default="uniform"),
        "visibility_weighting": Bool(default=True),
        "occlusion_weight": Num(0.0, 1e6, default=1.0),
        "occlusion_target": Str(choices=("soft", "binary"), default="soft"),
        # camera-view supervision from the rendered passes (model.feature_targets); 0: off
        "depth_weight": Num(0.0, 1e6, default=0.0),  # cross entropy of the lift's depth bins
        "camera_seg_weight": Num(0.0, 1e6, default=0.0),  # a 1x1 head on the context features, training only
        "dice_weight": Num(0.0, 1e6, default=0.0),  # soft Dice over the BEV classes (thin classes); 0: off
    }),
    "train": Section({
        "epochs": Num(1, 10**6, integer=True, default=120),
        "max_steps": Num(0, 10**9, integer=True, default=0),  # 0: no limit
        # the whole epochs (at most train.epochs) that fit in these minutes of train.py on this machine, from
        # its own first steps, timed during the warm-up; recorded in the checkpoints (model.minutes). 0: train.epochs
        "minutes": Num(0, 10**6, default=0),
        "batch_size": Num(1, 4096, integer=True, default=4),  # global: split across DDP processes
        "accumulate": Num(1, 1024, integer=True, default=1),  # batches per optimiser step: an effective batch of batch_size x accumulate
        "lr": Num(above=0, hi=10.0, default=1e-3),
        "lr_schedule": Str(choices=("constant", "cosine"), default="constant"),  # cosine: decays to 0 at the last step
        "warmup_steps": Num(0, 10**9, integer=True, default=0),  # linear warm-up from 0; 0: none
        # adam: weight_decay as an L2 term in the gradient (torch's Adam); adamw: decoupled, every weight shrunk by
        # lr x weight_decay a step (torch's AdamW, Loshchilov & Hutter)
        "optimizer": Str(choices=("adam", "adamw"), default="adam"),
        "weight_decay": Num(0.0, 10.0, default=0.0),
        # false: the weights of one dimension (biases, BatchNorm's scale and shift) left out of weight_decay
        "decay_vectors": Bool(default=True),
        "grad_clip": Num(0.0, 1e6, default=5.0),
        # an exponential moving average of the weights, this decay per step (0: off): validation, best.pt and
        # latest.pt's `model` hold the average (what eval and predict read); latest.pt keeps the raw weights to resume
        "ema": Num(0.0, 0.99999, default=0.0),
        "seed": Num(0, 2**31 - 1, integer=True, default=0),
        "checkpoint_every": Num(0, 10**9, integer=True, default=50),  # steps; 0: latest.pt only at each epoch end (and on a stop)
        "val_every": Num(0, 10**9, integer=True, default=0),  # steps; 0: at the end of each epoch
        "val_max_frames": Num(0, 10**9, integer=True, default=0),  # 0: the whole validation split
        "log_every": Num(0, 10**9, integer=True, default=10),  # steps; 0: no per-step scalars
        "image_every": Num(0, 10**9, integer=True, default=200),
        "device": Str(choices=("auto", "cpu", "cuda"), default="auto"),
        "threads": Num(0, 1024, integer=True, default=0),  # torch threads per process; 0: on CPU, the cores shared among the processes (model.cpu.tune_cpu)
    }),
})


def _semantic_checks(cfg: dict, source: str):
    """What the schema cannot say: fields that must agree with each other (its bounds hold already)."""
    m = cfg["model"]
    if len(m["encoder"]["blocks"]) != len(m["encoder"]["widths"]) - 1:
        raise ConfigError(f"{source}: model.encoder.blocks: needs one entry per stage ({len(m['encoder']['widths']) - 1})")
    s = m["stride"]
    if s & (s - 1) or s > 2 ** len(m["encoder"]["widths"]):
        raise ConfigError(f"{source}: model.stride: must be a power of 2 up to {2 ** len(m['encoder']['widths'])}")
    if m["trunk_frozen"] and m["trunk"] != "efficientnet_lite0":
        raise ConfigError(f"{source}: model.trunk_frozen: only the pretrained trunk (model.trunk: efficientnet_lite0) is kept frozen")
    if m["trunk_depthwise_frozen"] and m["trunk"] != "efficientnet_lite0":
        raise ConfigError(f"{source}: model.trunk_depthwise_frozen: only the pretrained trunk (model.trunk: efficientnet_lite0) has "
                          "loaded depthwise weights to keep")
    if m["trunk_frozen"] >= (m["stride"].bit_length() - 1 if m["trunk"] == "efficientnet_lite0" else 99):
        raise ConfigError(f"{source}: model.trunk_frozen: {m['trunk_frozen']} levels would freeze the features at the stride "
                          f"{m['stride']} the lift reads; at most {m['stride'].bit_length() - 2}")
    d = m["depth"]
    if not d["min"] < d["max"]:
        raise ConfigError(f"{source}: model.depth: need min < max")
    if m["z_range"][0] >= m["z_range"][1]:
        raise ConfigError(f"{source}: model.z_range: must be [low, high] with low < high")
    t = cfg["train"]
    if t["minutes"] and t["lr_schedule"] == "cosine" and t["warmup_steps"] < SKIP + TIMED:
        raise ConfigError(f"{source}: train.minutes: needs train.warmup_steps >= {SKIP + TIMED} with the cosine schedule (the "
                          f"steps are timed during the warm-up, whose learning rate does not depend on the total; have "
                          f"{t['warmup_steps']})")
    a = cfg["augment"]["scale"]
    if not a[0] <= a[1]:
        raise ConfigError(f"{source}: augment.scale: must be [low, high] with 0 < low <= high")
    if cfg["augment"]["mirror"] > 0:
        if m["pooling"] not in ("sum", "max"):
            raise ConfigError(f"{source}: augment.mirror: needs a pooling that treats every camera alike (sum, max); "
                              f"{m['pooling']} learns weights per camera, which a mirrored rig would swap")
        if m["ground_channels"]:
            raise ConfigError(f"{source}: augment.mirror: the ground image (model.ground_channels) learns weights per camera, "
                              "which a mirrored rig would swap")
        if cfg["data"]["input_size"][0] % s:
            raise ConfigError(f"{source}: augment.mirror: the input width {cfg['data']['input_size'][0]} must be a multiple "
                              f"of model.stride {s} (the feature columns are mirrored)")
        from geometry.bev import BevGrid

        g = BevGrid.from_dict(cfg["data"]["grid"])
        if g.y_min != -g.y_max:
            raise ConfigError(f"{source}: augment.mirror: data.grid's y range [{g.y_min:g}, {g.y_max:g}] must be symmetric about 0")


def validate(user: dict | None, source: str = "config") -> dict:
    cfg = SCHEMA.validate(user or {}, source)
    _semantic_checks(cfg, source)
    return cfg


def read_config_file(path, _seen=()) -> dict:
    path = Path(path)
    data = read_yaml(path) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: must be a mapping of sections")
    base = data.pop("_base", None)
    if base is None:
        return data
    merged: dict = {}
    for b in base if isinstance(base, list) else [base]:
        if not isinstance(b, str):
            raise ConfigError(f"{path}: _base: must be a file name or a list of file names, got {b!r}")
        bpath = path.parent / b
        bpath = (bpath if bpath.exists() else preset(b, "train")).resolve()  # `_base: cpu_default` names a preset
        if bpath in _seen:
            raise ConfigError(f"{path}: _base: circular reference to {bpath}")
        merged = deep_merge(merged, read_config_file(bpath, _seen + (bpath,)))
    return deep_merge(merged, data)


def load_config(path, overrides: dict | None = None) -> dict:
    """Read, merge `_base`, apply overrides ({'train': {'lr': ..}}), validate."""
    data = read_config_file(path)
    if overrides:
        data = deep_merge(data, overrides)
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
        d[parts[-1]] = parse_yaml(val)
    except Exception:
        raise ConfigError(f"override {text!r}: value is not valid YAML") from None
    return out


def parse_overrides(texts) -> dict:
    """Several --set values merged into one overrides mapping."""
    out: dict = {}
    for t in texts:
        out = deep_merge(out, parse_override(t))
    return out
