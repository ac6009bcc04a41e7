"""The dataset card of a data set or an export (`<folder>/README.md`, written through format.card):
Hugging Face dataset-card front matter (licence, task categories, size category, splits with their
frame counts) and a Markdown body (classes and colours, cameras and rig, how the labels and the
visibility are made, the generating config and commit, known limits), ready for
`huggingface-cli upload`.

    write_dataset_card("data/demo", config="configs/dataset/demo.yaml")   # the pipeline, at its end
    write_export_card(index, "out/demo_wds", shards)                       # export-webdataset

The toolkit's own fields (config, commit, version) are kept under the front matter's `fisheye_bev`
key, so an export's card carries over what its data set's card says about how it was made.
"""

from __future__ import annotations

import hashlib
import subprocess
from importlib import metadata
from pathlib import Path

from common.errors import InputError

from .format.audit_file import read_audit
from .format.card import read_card, write_card
from .format.layout import CARD, DatasetError
from .format.reader import DatasetIndex
from .labels.classes import FINE_CLASSES, TRAIN_PALETTE

DEFAULT_LICENSE = "cc-by-4.0"
TAGS = ["synthetic", "fisheye", "bird's-eye-view", "bev-segmentation", "autonomous-driving", "surround-view", "blender"]
DOCS = "fisheye-bev docs"  # the toolkit's pages (docs/ of its repository)


def size_category(n: int) -> str:
    """Hugging Face's size_categories bucket of `n` examples."""
    for limit, name in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M"),
                        (10_000_000, "1M<n<10M")):
        if n < limit:
            return name
    return "n>1T" if n >= 10**12 else "10M<n<100M"


def toolkit_revision() -> dict:
    """{version, commit}: the installed package's version and, in a git checkout, its commit
    (with `+dirty` when files differ from it)."""
    try:
        version = metadata.version("fisheye-bev")
    except metadata.PackageNotFoundError:
        version = "unknown"
    here = Path(__file__).resolve().parent
    commit = "not a git checkout (installed package)"
    try:
        r = subprocess.run(["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if r.returncode == 0:
            commit = r.stdout.strip()
            d = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, timeout=10)
            commit += "+dirty" if d.stdout.strip() else ""
    except (OSError, subprocess.SubprocessError):
        pass
    return {"version": version, "commit": commit}


def generator_info(config=None) -> dict:
    """What made the data set: the config (path, sha256, text) and the toolkit's revision."""
    info = {"toolkit": "fisheye-bev", **toolkit_revision()}
    if config is not None:
        p = Path(config)
        try:
            text = p.read_text()
        except OSError:
            text = ""
        info["config"] = {"path": str(config), "sha256": hashlib.sha256(text.encode()).hexdigest(), "text": text}
    return info


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(v):02x}" for v in rgb)


def _front(index: DatasetIndex, name: str, license: str, generator: dict, data_files: dict | None, split_bytes: dict) -> dict:
    counts = {s: len(r) for s, r in index.splits.items() if r}
    front = {
        "license": license,
        "pretty_name": f"fisheye-bev {name}",
        "task_categories": ["image-segmentation"],
        "task_ids": ["semantic-segmentation"],
        "tags": TAGS + (["webdataset"] if data_files else []),
        "size_categories": [size_category(sum(counts.values()))],
    }
    if data_files:
        front["configs"] = [{"config_name": "default", "data_files": [{"split": s, "path": p} for s, p in data_files.items()]}]
    front["dataset_info"] = {"splits": [{"name": s, "num_examples": n, **({"num_bytes": split_bytes[s]} if s in split_bytes else {})}
                                        for s, n in counts.items()]}
    front["fisheye_bev"] = {**generator, "class_names": list(index.class_names), "cameras": list(index.rig.names)}
    return front


def _body(index: DatasetIndex, name: str, license: str, generator: dict, files_section: str) -> str:
    rig, grid = index.rig, index.grid
    splits = "\n".join(f"| {s} | {len(r)} | {len({x.scene for x in r})} |" for s, r in index.splits.items() if r)
    classes = "\n".join(f"| {i} | {n} | `{_hex(TRAIN_PALETTE[i]) if i < len(TRAIN_PALETTE) else '-'}` |"
                        for i, n in enumerate(index.class_names))
    fine = ", ".join(f"{cid} {n} (`{_hex(c)}`)" for cid, n, _, c in FINE_CLASSES)
    cams = "\n".join(f"| {rc.name} | {rc.camera.model} | {rc.camera.width}x{rc.camera.height} | "
                     f"{', '.join(f'{v:.2f}' for v in rc.cam_to_ego[:3, 3])} |" for rc in rig)
    cfg = generator.get("config")
    config_text = (f"Generated from `{cfg['path']}` (sha256 `{cfg['sha256'][:16]}`):\n\n```yaml\n{cfg['text'].rstrip()}\n```\n"
                   if cfg else "The generating config was not recorded (the card was written outside the dataset pipeline).\n")
    own = sum(r.own_rig for r in index.all_frames())
    audit = None
    try:
        audit = read_audit(index.root, missing_ok=True)
    except (DatasetError, InputError):
        pass
    audit_line = (f"The line-of-sight audit of the visibility labels (`audit.json`, metric `{audit.get('metric')}`) "
                  f"{'passed' if audit.get('passed') else 'did not pass'} its threshold {audit.get('threshold')}.\n" if audit else "")
    return f"""# fisheye-bev {name}

Synthetic surround-view fisheye images of road scenes with bird's-eye-view (BEV) segmentation labels,
rendered by headless Blender (Cycles) from seeded scene recipes with the fisheye-bev toolkit. Each frame
holds {len(rig)} fisheye camera images ({', '.join(rig.names)}), per-camera passes for camera-view
supervision, occlusion-aware BEV labels (semantic, vehicle instances, visibility p(o)) and its metadata
(calibration, ego pose, actors with 3D boxes, weather).

## Splits

| split | frames | scenes |
|---|---|---|
{splits}

`train` is for training; `easy`, `medium`, `hard` are the DaF-BEVSeg paper's test splits (training layouts
under new weather and traffic; unseen highways; unseen urban junctions), `heldout` sampled scenes from
seeds training never used.

## Files

{files_section}

## Classes

BEV labels (`semantic.png`, uint8) hold the training class id of each cell of a {grid.shape[0]}x{grid.shape[1]}
grid of {grid.res} m over x {grid.x_min}..{grid.x_max} m (forward, up the image), y {grid.y_min}..{grid.y_max} m
(left); colours are the toolkit's pictures':

| id | class | colour |
|---|---|---|
{classes}

`invalid` cells (the ego car's footprint, nothing rendered) are not scored. The camera passes
(`camera_targets.npy`, the EXRs) hold fine classes: {fine}.

## Cameras and rig

Rig `{rig.name}`; positions in the ego frame (ISO 8855: x forward, y left, z up, origin on the ground
below the rear axle), metres. Every frame's `meta.json` holds its own calibration (`rig`){f'; {own} frames have their own, jittered rig' if own else ''}.

| camera | model | size | position x, y, z |
|---|---|---|---|
{cams}

Camera models are those of the toolkit (`geometry.cameras`: opencv_fisheye, kb_theta, radial_poly,
double_sphere, eucm, ucm, mei, ...), rendered exactly by an OSL camera shader in Cycles.

## How the labels and the visibility are made

Labels are not drawn by hand: every material carries its fine class and every object an instance id,
so Cycles' index passes are exact. Two top-down orthographic passes (first hit from above, and with
overhead occluders such as tree crowns and bridge decks hidden) are fused into BEV labels
(`dataset_tools.labels.fusion`); thin markings are coverage labels from a finer render. Visibility
p(o) of a cell is the share of it the fisheye cameras see, from their distance passes, spread without
crossing occlusions ({DOCS}: labels.md, label-fidelity.md).
{audit_line}
## How it was generated

{config_text}
Toolkit: fisheye-bev {generator.get('version')}, commit `{generator.get('commit')}`. Render settings, the scene recipe and the
random seeds of every frame are in its `meta.json`; sampled scenes' recipes in `recipes/` of the data set.

## Licence

Renders, labels and metadata: `{license}`. Assets: every model, material and texture is procedural,
made by the toolkit's code (numpy geometry, Cycles shader nodes) from the seeded recipes; no
third-party models, textures or HDRIs are used, so the renders carry no asset licence of their own.

## Known limits

- Synthetic, procedural scenes: a domain gap to real cameras remains ({DOCS}: rendering.md).
- Few frames per scene; scenes of one family share their generator, so split by scene, as here.
- Visibility p(o) is estimated from the rendered distances, not observed; lane markings are thin at {grid.res} m
  cells and the hardest class.
- Pedestrians are rendered (fine class 18) but are `background` in the training classes.
"""


def _counts_bytes(shards: dict | None) -> dict:
    if not shards:
        return {}
    return {s: sum(x["bytes"] for x in v["shards"]) for s, v in shards["splits"].items()}


def write_dataset_card(root, config=None, license: str = DEFAULT_LICENSE) -> Path:
    """`<root>/README.md` for a fused data set (the dataset pipeline's last step)."""
    index = DatasetIndex(root)
    gen = generator_info(config)
    files = (f"A folder per frame, `<scene>/<frame:06d>/`: `cam_<camera>.png` (8-bit sRGB), `cam_<camera>.exr` (linear RGB,\n"
             f"distance, semantic, instance, position, ego), `cam_<camera>_ego.png`, `topdown.exr`, `labels/semantic.png`,\n"
             f"`labels/instance.png`, `labels/visibility.png` (uint16, p(o) x 65535), `meta.json`; `index.json` lists the splits\n"
             f"({DOCS}: data-format.md). `python -m dataset_tools export-webdataset` makes WebDataset shards of it.")
    return write_card(root, _front(index, Path(root).resolve().name, license, gen, None, {}), _body(index, Path(root).resolve().name, license, gen, files))


def write_export_card(index: DatasetIndex, out, shards: dict, license: str | None = None) -> Path:
    """`<out>/README.md` for a WebDataset export of `index`; the data set's own card (when it has
    one) gives the generating config and commit and the licence."""
    gen, lic = None, license
    card = index.root / CARD
    if card.is_file():
        try:
            front, _ = read_card(card)
            gen = front.get("fisheye_bev") if isinstance(front.get("fisheye_bev"), dict) else None
            lic = lic or front.get("license")
        except DatasetError:
            pass
    gen = {k: v for k, v in (gen or generator_info()).items() if k not in ("class_names", "cameras")}
    lic = lic or DEFAULT_LICENSE
    name = index.root.resolve().name
    patterns = {s: v["pattern"] for s, v in shards["splits"].items()}
    files = ("WebDataset tar shards, one per split and up to "
             f"{shards['shard_size']} frames: " + ", ".join(f"`{p}`" for p in patterns.values()) + "; `shards.json` lists them with their\n"
             "frame counts and holds the data set's index (class names, grid, rig). A sample is one frame, its key\n"
             "`<scene>/<frame:06d>`, its members: " + ", ".join(f"`{f}`" for f in shards["sample_files"]) + ".\n\n"
             "```python\nimport webdataset as wds\nds = wds.WebDataset(\"" + patterns.get("train", next(iter(patterns.values()))) + "\")  # bytes per member\n```\n\n"
             "Training streams them with `data.shards` in a fisheye-bev training config (docs/publishing.md).")
    data_files = {s: f"{s}-*.tar" for s in patterns}
    return write_card(out, _front(index, name, lic, gen, data_files, _counts_bytes(shards)), _body(index, name, lic, gen, files))
