"""The hostile-input corpus: one row per case, run by tests/test_robustness.py.

A case is (id, command, build, code, needles): `build(ctx)` writes the bad input into the case's
own folder and returns the command's argv; the command must exit with `code` (2 bad input, 1
environment or problems found), print exactly one line on stderr with no traceback, name every needle in it (the file
and the field) and write nothing outside its output folder. `ctx` (tests/test_robustness.py Ctx)
gives a scratch folder, a copy of a two-frame fused data set and a tiny trained checkpoint.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Callable

import numpy as np

BILLION_LAUGHS = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi"))
DEEP = "x: " + "[" * 3000 + "]" * 3000 + "\n"
NON_UTF8 = b"name: caf\xe9\nscenes: []\n"


@dataclass
class Case:
    id: str
    command: str  # a `python -m dataset_tools` command (dataset_tools/__main__.py), train, eval or predict
    build: Callable
    code: int = 2
    needles: tuple = ()
    skip: str = ""  # a reason to skip on this machine ("" to run)


CASES: list[Case] = []


def _register(c: "Case") -> None:
    if any(x.id == c.id for x in CASES):  # a second case of the same id would shadow the first
        raise ValueError(f"robust_cases: case id '{c.id}' is used twice")
    CASES.append(c)


def case(id, command, code=2, needles=()):
    def deco(fn):
        _register(Case(id, command, fn, code, tuple(needles)))
        return fn
    return deco


def add(id, command, build, code=2, needles=()):
    _register(Case(id, command, build, code, tuple(needles)))


# ------------------------------------------------------------------ generate: dataset configs

def gen(**over):
    """generate on a one-scene dataset config with `over` merged in (None deletes a key)."""
    def build(ctx):
        return ["--config", str(ctx.dataset_config(**over)), "--out", str(ctx.out), "--no-progress"]
    return build


def gen_raw(text):
    def build(ctx):
        return ["--config", str(ctx.write("cfg/ds.yaml", text)), "--out", str(ctx.out), "--no-progress"]
    return build


def gen_recipe(**over):
    def build(ctx):
        cfg = ctx.dataset_config(scenes=[{"recipe": str(ctx.recipe(**over))}], frames=None if "frames" in over else 1)
        return ["--config", str(cfg), "--out", str(ctx.out), "--no-progress"]
    return build


def gen_rig(rig_text, name="rig.yaml"):
    def build(ctx):
        return ["--config", str(ctx.dataset_config(rig=str(ctx.write(f"cfg/{name}", rig_text)))), "--out", str(ctx.out), "--no-progress"]
    return build


add("gen-recipe-name-escapes", "generate", gen_recipe(name="../../escaped"), needles=("r.yaml", "name"))
add("gen-recipe-name-absolute", "generate", gen_recipe(name="/tmp/abs"), needles=("r.yaml", "name"))
add("gen-recipe-name-slash", "generate", gen_recipe(name="a/b"), needles=("r.yaml", "name"))
add("gen-scene-name-dotdot", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "name": "../x"}]),
    needles=("ds.yaml", "scenes[0].name"))
add("gen-scene-name-dotdot-only", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "name": ".."}]),
    needles=("ds.yaml", "scenes[0].name"))
add("gen-override-name-escapes", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"name": "../../e"}}]),
    needles=("ds.yaml", "scenes[0].overrides.name"))
add("gen-config-name-escapes", "generate", gen(name="../up"), needles=("ds.yaml", "name"))
add("gen-non-utf8", "generate", gen_raw(NON_UTF8), needles=("ds.yaml", "UTF-8"))
add("gen-billion-laughs", "generate", gen_raw(BILLION_LAUGHS), needles=("ds.yaml", "aliases"))
add("gen-deep-nesting", "generate", gen_raw(DEEP), needles=("ds.yaml", "nested"))
add("gen-yaml-syntax", "generate", gen_raw("scenes: [\n"), needles=("ds.yaml", "not valid YAML"))
add("gen-top-level-list", "generate", gen_raw("- 1\n- 2\n"), needles=("ds.yaml", "mapping"))
add("gen-empty-file", "generate", gen_raw(""), needles=("ds.yaml", "mapping"))
add("gen-oversized", "generate", gen_raw("# " + "x" * (5 * 1024 * 1024) + "\n"), needles=("ds.yaml", "bytes"))
add("gen-overrides-list", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": [1, 2]}]),
    needles=("ds.yaml", "scenes[0].overrides"))
add("gen-overrides-scalar", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": 5}]),
    needles=("ds.yaml", "scenes[0].overrides"))
add("gen-overrides-section-scalar", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"layout": 3}}]),
    needles=("ds.yaml", "scenes[0].overrides.layout", "mapping"))
# an override is blamed where it was written (the dataset config), not on the recipe it overrides
add("gen-overrides-frames-scalar", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"frames": 5}}]),
    needles=("ds.yaml", "scenes[0].overrides.frames", "mapping"))
add("gen-overrides-frames-count-zero", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"frames": {"count": 0}}}]),
    needles=("ds.yaml", "scenes[0].overrides.frames.count"))
add("gen-overrides-layout-unknown", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"layout": {"lanes": 2}}}]),
    needles=("ds.yaml", "scenes[0].overrides.layout.lanes"))
add("gen-overrides-family-typo", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"family": "motorway"}}]),
    needles=("ds.yaml", "scenes[0].overrides.family"))
add("gen-overrides-unknown", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "overrides": {"colour": 3}}]),
    needles=("ds.yaml", "overrides.colour"))
add("gen-recipe-int", "generate", gen(scenes=[{"recipe": 7}]), needles=("ds.yaml", "scenes[0].recipe"))
add("gen-recipe-missing-file", "generate", gen(scenes=[{"recipe": "scenes/nope.yaml"}]),
    needles=("ds.yaml", "scenes[0].recipe", "nope.yaml", "missing"))
add("gen-recipe-missing-file-4th", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "name": f"s{i}"} for i in range(3)]
                                                   + [{"recipe": "scenes/nope.yaml"}]),
    needles=("ds.yaml", "scenes[3].recipe", "nope.yaml", "missing"))
add("gen-recipe-folder", "generate", gen(scenes=[{"recipe": "scenes"}]), needles=("ds.yaml", "scenes[0].recipe", "folder"))
add("gen-scene-not-mapping", "generate", gen(scenes=["scenes/highway_straight.yaml"]), needles=("ds.yaml", "scenes[0]"))
add("gen-scenes-empty", "generate", gen(scenes=[]), needles=("ds.yaml", "scenes"))
add("gen-scenes-mapping", "generate", gen(scenes={"a": 1}), needles=("ds.yaml", "scenes"))
add("gen-split-typo", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml", "split": "eassy"}]),
    needles=("ds.yaml", "scenes[0].split"))
add("gen-duplicate-scene", "generate", gen(scenes=[{"recipe": "scenes/highway_straight.yaml"}, {"recipe": "scenes/highway_straight.yaml"}]),
    needles=("ds.yaml", "scenes[1].name"))
add("gen-max-bounces-negative", "generate", gen(render={"max_bounces": -1}), needles=("ds.yaml", "render.max_bounces"))
add("gen-samples-zero", "generate", gen(render={"samples": 0}), needles=("ds.yaml", "render.samples"))
add("gen-denoise-string", "generate", gen(render={"denoise": "yes"}), needles=("ds.yaml", "render.denoise"))
add("gen-denoise-quality", "generate", gen(render={"denoise_quality": "ultra"}), needles=("ds.yaml", "render.denoise_quality"))
add("gen-topdown-bound-zero", "generate", gen(topdown={"bound": 0}), needles=("ds.yaml", "topdown.bound"))
add("gen-topdown-height-negative", "generate", gen(topdown={"height_m": -5}), needles=("ds.yaml", "topdown.height_m"))
add("gen-topdown-size-nan", "generate", gen(topdown={"size": float("nan")}), needles=("ds.yaml", "topdown.size"))
add("gen-fisheye-size-bool", "generate", gen(fisheye_size=[True, 3]), needles=("ds.yaml", "fisheye_size[0]"))
add("gen-fisheye-size-huge", "generate", gen(fisheye_size=[100000, 100000]), needles=("ds.yaml", "fisheye_size[0]"))
add("gen-fisheye-size-one", "generate", gen(fisheye_size=[64]), needles=("ds.yaml", "fisheye_size"))
add("gen-frames-zero", "generate", gen(frames=0), needles=("ds.yaml", "frames"))
add("gen-unknown-field", "generate", gen(colour="red"), needles=("ds.yaml", "colour"))
add("gen-rig-missing", "generate", gen(rig="configs/rigs/nope.yaml"), needles=("ds.yaml", "rig", "nope.yaml", "missing"))
add("gen-recipe-family", "generate", gen_recipe(family="motorway"), needles=("r.yaml", "family"))
add("gen-recipe-seed-negative", "generate", gen_recipe(seed=-1), needles=("r.yaml", "seed"))
add("gen-recipe-density-nan", "generate", gen_recipe(traffic={"density": float("nan")}), needles=("r.yaml", "traffic.density"))
add("gen-recipe-speed-inf", "generate", gen_recipe(ego={"speed_kmh": float("inf")}), needles=("r.yaml", "ego.speed_kmh"))
add("gen-recipe-count-zero", "generate", gen_recipe(frames={"count": 0}), needles=("r.yaml", "frames.count"))
add("gen-recipe-unknown-key", "generate", gen_recipe(layout={"lanes": 2}), needles=("r.yaml", "layout.lanes"))
add("gen-recipe-ego-lane", "generate", gen_recipe(ego={"lane": 3}), needles=("r.yaml", "ego.lane"))
add("gen-recipe-range-reversed", "generate", gen_recipe(traffic={"speed_kmh": [60, 30]}), needles=("r.yaml", "traffic.speed_kmh"))

RIG_CAM = ("    intrinsics: {model: opencv_fisheye, width: 64, height: 40, fx: 20, fy: 20, cx: 31.5, cy: 19.5, k: [0, 0, 0, 0]}\n"
           "    extrinsics: {translation: %s, rotation: {yaw_deg: 0, pitch_deg: 20, roll_deg: 0}}\n")
add("gen-rig-translation-nan", "generate", gen_rig("cameras:\n  front:\n" + RIG_CAM % "[.nan, 0, 1]"),
    needles=("rig.yaml", "translation"))
add("gen-rig-translation-short", "generate", gen_rig("cameras:\n  front:\n" + RIG_CAM % "[1, 0]"),
    needles=("rig.yaml", "translation"))
add("gen-rig-no-cameras", "generate", gen_rig("cameras: {}\n"), needles=("rig.yaml", "cameras"))
add("gen-rig-fx-negative", "generate", gen_rig("cameras:\n  front:\n" + (RIG_CAM % "[1, 0, 1]").replace("fx: 20", "fx: -20")),
    needles=("rig.yaml", "fx"))
add("gen-rig-non-utf8", "generate", gen_rig(b"cameras: {front: \xff}\n"), needles=("rig.yaml", "UTF-8"))


def woodscape(intrinsic: dict | None = None, quaternion="[0.5, -0.5, 0.5, -0.5]", raw=None) -> str:
    i = {"width": 64, "height": 40, "cx_offset": 0.5, "cy_offset": -0.5, "aspect_ratio": 1.0,
         "k1": 20.0, "k2": -1.0, "k3": 0.5, "k4": -0.05, "model": "radial_poly"}
    i.update(intrinsic or {})
    body = ", ".join(f'"{k}": {v if not isinstance(v, str) or v in ("NaN", "Infinity", "null") else json.dumps(v)}'
                     for k, v in i.items())
    return raw if raw is not None else (
        '{"name": "front", "intrinsic": {' + body + '}, "extrinsic": {"quaternion": ' + quaternion
        + ', "translation": [3.7, 0.0, 0.6]}}')


for _id, _intr, _field in [("width-nan", {"width": "NaN"}, "width"), ("width-inf", {"width": "Infinity"}, "width"),
                           ("width-null", {"width": "null"}, "width"), ("width-string", {"width": "wide"}, "width"),
                           ("width-fractional", {"width": 64.5}, "width"), ("cx-offset-huge", {"cx_offset": 1e6}, "cx_offset"),
                           ("k1-nan", {"k1": "NaN"}, "k1"), ("model-other", {"model": "pinhole"}, "model")]:
    add(f"gen-woodscape-{_id}", "generate", gen_rig(woodscape(_intr), "front.json"), needles=("front.json", _field))
add("gen-woodscape-quaternion-nan", "generate", gen_rig(woodscape(quaternion="[NaN, 0, 0, 1]"), "front.json"),
    needles=("front.json", "quaternion"))
add("gen-woodscape-quaternion-zero", "generate", gen_rig(woodscape(quaternion="[0, 0, 0, 0]"), "front.json"),
    needles=("front.json", "quaternion"))
add("gen-woodscape-non-utf8", "generate", gen_rig(b'{"intrinsic": "\xff"}', "front.json"), needles=("front.json", "UTF-8"))
add("gen-woodscape-not-json", "generate", gen_rig("{intrinsic", "front.json"), needles=("front.json", "JSON"))


def gen_args(*extra):
    def build(ctx):
        return ["--config", str(ctx.dataset_config()), "--out", str(ctx.out), "--no-progress", *extra]
    return build


add("gen-shard-bad", "generate", gen_args("--shard", "2/1"), needles=("--shard",))
add("gen-workers-zero", "generate", gen_args("--workers", "0"), needles=("--workers",))
add("gen-workers-text", "generate", gen_args("--workers", "many"), needles=("--workers",))


@case("gen-out-is-a-file", "generate", needles=("--out", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return ["--config", str(ctx.dataset_config()), "--out", str(ctx.out), "--no-progress"]


add("gen-config-missing", "generate", lambda ctx: ["--config", str(ctx.ws / "none.yaml"), "--out", str(ctx.out)],
    needles=("--config", "none.yaml", "missing"))
add("gen-config-folder", "generate", lambda ctx: ["--config", str(ctx.ws), "--out", str(ctx.out)], needles=("--config", "folder"))

# ------------------------------------------------------------------ data set commands


def on_ds(*extra, edit=None):
    """A command on a copy of the two-frame fused data set after `edit(ds)`."""
    def build(ctx):
        ds = ctx.ds()
        if edit:
            edit(ctx, ds)
        return [str(ds), *extra]
    return build


def manifest_line(text: bytes):
    def edit(ctx, ds):
        with open(ds / "manifest.jsonl", "ab") as f:
            f.write(text + b"\n")
    return edit


def index_json(text: str):
    def edit(ctx, ds):
        (ds / "index.json").write_text(text)
    return edit


def first_frame(ds):
    return ds / json.loads((ds / "manifest.jsonl").read_text().splitlines()[0])["dir"]


def meta(text: bytes):
    def edit(ctx, ds):
        (first_frame(ds) / "meta.json").write_bytes(text)
    return edit


def semantic_out_of_range(ctx, ds):
    import cv2

    p = first_frame(ds) / "labels" / "semantic.png"
    a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    a[0, 0] = 9
    cv2.imwrite(str(p), a)


def png_garbage(name):
    def edit(ctx, ds):
        (first_frame(ds) / name).write_bytes(b"\x89PNG\r\n\x1a\n not really")
    return edit


def exr_garbage(name):
    def edit(ctx, ds):
        (first_frame(ds) / name).write_bytes(b"v/1\x01 not an exr at all")
    return edit


MANIFEST_BAD = [("dir-int", b'{"scene": "s", "frame": 0, "split": "train", "dir": 7}', "dir"),
                ("dir-escapes", b'{"scene": "s", "frame": 0, "split": "train", "dir": "../../x"}', "dir"),
                ("non-utf8", b'{"scene": "s\xff", "frame": 0, "split": "train", "dir": "s/000000"}', "UTF-8"),
                ("list", b'[1, 2]', "JSON object"),
                ("frame-negative", b'{"scene": "s", "frame": -1, "split": "train", "dir": "s/000000"}', "frame"),
                ("files-int", b'{"scene": "s", "frame": 0, "split": "train", "dir": "s/000000", "files": 7}', "files"),
                ("files-escape", b'{"scene": "s", "frame": 0, "split": "train", "dir": "s/000000", "files": ["../../x"]}', "files")]
for _id, _line, _field in MANIFEST_BAD:
    add(f"index-manifest-{_id}", "index", on_ds(edit=manifest_line(_line)), needles=("manifest.jsonl", "line 3", _field))
add("fuse-manifest-dir-int", "fuse", on_ds("--no-progress", edit=manifest_line(MANIFEST_BAD[0][1])), needles=("manifest.jsonl", "dir"))
add("fuse-manifest-non-utf8", "fuse", on_ds("--no-progress", edit=manifest_line(MANIFEST_BAD[2][1])), needles=("manifest.jsonl", "UTF-8"))
add("fuse-manifest-files-int", "fuse", on_ds("--no-progress", edit=manifest_line(MANIFEST_BAD[5][1])), needles=("manifest.jsonl", "line 3", "files"))
# validate lists every problem (stdout) and exits 1 (problems found); its one stderr line names the first
add("validate-manifest-files-int", "validate", on_ds(edit=manifest_line(MANIFEST_BAD[5][1])), code=1,
    needles=("1 problem", "manifest.jsonl", "line 3", "files"))
add("index-meta-list", "index", on_ds(edit=meta(b"[1, 2]")), needles=("meta.json", "JSON object"))
add("index-meta-non-utf8", "index", on_ds(edit=meta(b'{"a": "\xff"}')), needles=("meta.json", "UTF-8"))
add("index-meta-not-json", "index", on_ds(edit=meta(b'{"a": ')), needles=("meta.json", "JSON"))
add("index-no-manifest", "index", lambda ctx: [str(ctx.ws / "empty")], needles=("manifest.jsonl", "missing"))
add("index-empty-manifest", "index", on_ds(edit=lambda ctx, ds: (ds / "manifest.jsonl").write_text("")), needles=("manifest.jsonl", "no frames"))
add("fuse-no-manifest", "fuse", lambda ctx: [str(ctx.ws / "empty"), "--no-progress"], needles=("dataset", "manifest.jsonl", "missing"))
add("fuse-workers-zero", "fuse", on_ds("--workers", "0"), needles=("--workers",))
add("fuse-config-bomb", "fuse", lambda ctx: [str(ctx.ds()), "--config", str(ctx.write("cfg/l.yaml", BILLION_LAUGHS))],
    needles=("l.yaml", "aliases"))
add("fuse-config-labels-bad", "fuse", lambda ctx: [str(ctx.ds()), "--config", str(ctx.write("cfg/l.yaml", "labels: {tau: -1}\n"))],
    needles=("l.yaml", "labels.tau"))
add("fuse-config-labels-list", "fuse", lambda ctx: [str(ctx.ds()), "--config", str(ctx.write("cfg/l.yaml", "labels: [1]\n"))],
    needles=("l.yaml", "labels"))
add("fuse-meta-list", "fuse", on_ds("--force", "--no-progress", edit=meta(b"[]")), needles=("meta.json", "JSON object"))
add("merge-option-unknown", "merge", lambda ctx: [str(ctx.out), str(ctx.ds()), "--bogus"], needles=("--bogus",))
add("merge-part-missing", "merge", lambda ctx: [str(ctx.out), str(ctx.ws / "none")], needles=("none", "not a directory"))
add("merge-part-not-generated", "merge", lambda ctx: [str(ctx.out), str(ctx.write("part/x.txt", "x").parent), "--no-progress"],
    code=1, needles=("part", "manifest.jsonl"))
add("audit-metric-unknown", "audit", on_ds("--metric", "bogus"), needles=("--metric", "bogus"))
add("report-frames-text", "report", on_ds("--frames-per-scene", "many"), needles=("--frames-per-scene",))
add("dataset-workers-text", "dataset", lambda ctx: ["--config", str(ctx.dataset_config()), "--out", str(ctx.out), "--workers", "many"],
    needles=("--workers",))
add("dataset-config-missing", "dataset", lambda ctx: ["--config", str(ctx.ws / "none.yaml"), "--out", str(ctx.out)],
    needles=("--config", "none.yaml", "missing"))
add("fuse-camera-exr-garbage", "fuse", on_ds("--force", "--no-progress", edit=exr_garbage("cam_front.exr")), code=1,
    needles=("cam_front.exr", "EXR"))


def nan_distance(ctx, ds):
    from dataset_tools.format.exr import read_exr, write_exr

    p = first_frame(ds) / "cam_front.exr"
    ch = read_exr(p)
    key = next(k for k in ch if k.lower().endswith("distance") or k.lower().endswith("depth"))
    a = ch[key].astype(np.float32).copy()
    a[: a.shape[0] // 2] = np.nan
    ch[key] = a.astype(ch[key].dtype)
    write_exr(p, ch)


add("fuse-distance-nan", "fuse", on_ds("--force", "--no-progress", edit=nan_distance), code=1, needles=("cam_front.exr", "distance", "NaN"))

INDEX_BAD = [("splits-list", '{"version": 1, "class_names": ["a", "b"], "grid": {"bound": 25, "res": 0.5}, "splits": []}', "splits"),
             ("not-object", "[1]", "JSON object"),
             ("not-json", "{", "JSON"),
             ("class-names-empty", '{"version": 1, "class_names": [], "grid": {}, "splits": {}}', "class_names"),
             ("split-entry-escapes", '{"version": 1, "class_names": ["a"], "grid": {}, "splits": {"train": [{"dir": "../x", "scene": "s", "frame": 0}]}}', "splits.train[0]"),
             ("version-other", '{"version": 2, "class_names": ["a"], "grid": {}, "splits": {}}', "version")]
for _id, _text, _field in INDEX_BAD:
    add(f"stats-index-{_id}", "stats", on_ds("--no-cameras", edit=index_json(_text)), needles=("index.json", _field))
    add(f"consistency-index-{_id}", "consistency", on_ds(edit=index_json(_text)), needles=("index.json", _field))
add("stats-class-out-of-range", "stats", on_ds("--no-cameras", edit=semantic_out_of_range), needles=("semantic.png", "class"))
add("consistency-class-out-of-range", "consistency", on_ds(edit=semantic_out_of_range), needles=("semantic.png", "class"))
add("inspect-exr-empty", "inspect", lambda ctx: [str(ctx.write("in/x.exr", b"")), "--out", str(ctx.out)], needles=("x.exr", "EXR"))
add("stats-label-garbage", "stats", on_ds("--no-cameras", edit=png_garbage("labels/visibility.png")), needles=("visibility.png",))
add("stats-meta-list", "stats", on_ds(edit=meta(b"[]")), needles=("meta.json", "JSON object"))


@case("stats-out-is-a-file", "stats", needles=("--out", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return [str(ctx.ds()), "--no-cameras", "--out", str(ctx.out)]


add("stats-no-dataset", "stats", lambda ctx: [str(ctx.ws / "nothing")], needles=("nothing",))
add("consistency-threshold-nan", "consistency", on_ds("--threshold", "nan"), needles=("--threshold",))
add("consistency-min-visibility", "consistency", on_ds("--min-visibility", "5"), needles=("--min-visibility",))
add("consistency-tolerance-negative", "consistency", on_ds("--tolerance", "-1"), needles=("--tolerance",))
add("consistency-meta-list", "consistency", on_ds(edit=meta(b"[]")), needles=("meta.json", "JSON object"))
add("inspect-missing", "inspect", lambda ctx: [str(ctx.ws / "nope.exr")], needles=("nope.exr",))
add("inspect-not-exr", "inspect", lambda ctx: [str(ctx.write("a.txt", "x"))], needles=("a.txt",))
add("inspect-exr-garbage", "inspect", lambda ctx: [str(ctx.write("in/x.exr", b"garbage")), "--out", str(ctx.out)],
    needles=("x.exr", "EXR"))
add("inspect-meta-list", "inspect", lambda ctx: [str(first_frame(ctx.ds(edit=meta(b"[]")))), "--out", str(ctx.out)],
    needles=("meta.json", "JSON object"))
add("inspect-topdown-garbage", "inspect", lambda ctx: [str(first_frame(ctx.ds(edit=exr_garbage("topdown.exr")))), "--out", str(ctx.out)],
    needles=("topdown.exr", "EXR"))


@case("inspect-out-is-a-file", "inspect", needles=("--out", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return [str(first_frame(ctx.ds())), "--out", str(ctx.out)]


add("contact-sheet-missing", "contact_sheet", lambda ctx: [str(ctx.ws / "nothing")], needles=("nothing",))
add("contact-sheet-frame-negative", "contact_sheet", on_ds("--frame", "-1"), needles=("--frame",))
add("contact-sheet-png-garbage", "contact_sheet", on_ds(edit=png_garbage("cam_front.png")), needles=("cam_front.png",))
add("validate-index-splits-list", "validate", on_ds(edit=index_json(INDEX_BAD[0][1])), code=1, needles=("problem",))
add("validate-bad-flag", "validate", on_ds("--frobnicate"), needles=("--frobnicate",))
add("stitch-images-missing", "stitch", lambda ctx: [str(ctx.ws / "nothing"), "--out", str(ctx.out / "s.png")], needles=("nothing",))
add("stitch-bound-negative", "stitch", lambda ctx: [str(first_frame(ctx.ds())), "--out", str(ctx.out / "s.png"), "--bound", "-1"],
    needles=("--bound",))
add("stitch-meta-list", "stitch", lambda ctx: [str(first_frame(ctx.ds(edit=meta(b"[]")))), "--out", str(ctx.out / "s.png")],
    needles=("meta.json", "JSON object"))
add("export-woodscape-index-splits-list", "export-woodscape", lambda ctx: [str(ctx.ds(edit=index_json(INDEX_BAD[0][1]))), str(ctx.out)],
    needles=("index.json", "splits"))


@case("export-woodscape-out-is-a-file", "export-woodscape", needles=("OUT", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return [str(ctx.ds()), str(ctx.out)]


add("validate-no-dataset", "validate", lambda ctx: [str(ctx.ws / "nothing")], code=1, needles=("dataset", "nothing", "missing"))

# ------------------------------------------------------------------ train.py


def train(extra_args=(), raw=None, **sections):
    def build(ctx):
        cfg = ctx.write("cfg/t.yaml", raw) if raw is not None else ctx.train_config(**sections)
        return ["--config", str(cfg), "--out", str(ctx.out), "--quiet", *extra_args]
    return build


add("train-lr-inf", "train", train(train={"lr": float("inf")}), needles=("t.yaml", "train.lr"))
add("train-lr-zero", "train", train(train={"lr": 0}), needles=("t.yaml", "train.lr"))
add("train-lr-string", "train", train(train={"lr": "fast"}), needles=("t.yaml", "train.lr"))
add("train-dropout-2", "train", train(model={"dropout": 2}), needles=("t.yaml", "model.dropout"))
add("train-hue-5", "train", train(augment={"color_jitter": {"hue": 5}}), needles=("t.yaml", "augment.color_jitter.hue"))
add("train-occlusion-weight-negative", "train", train(loss={"occlusion_weight": -5}), needles=("t.yaml", "loss.occlusion_weight"))
add("train-val-split-typo", "train", train(data={"val_split": "eassy"}), needles=("data.val_split", "eassy"))
def _has_cuda() -> bool:
    import torch

    return torch.cuda.is_available()


add("train-device-cuda", "train", train(train={"device": "cuda"}), code=1, needles=("train.device", "no CUDA"))
if _has_cuda():
    CASES[-1].skip = "this machine has CUDA"
add("train-device-tpu", "train", train(train={"device": "tpu"}), needles=("t.yaml", "train.device"))
add("train-threads-negative", "train", train(train={"threads": -1}), needles=("t.yaml", "train.threads"))
add("train-epochs-zero", "train", train(train={"epochs": 0}), needles=("t.yaml", "train.epochs"))
add("train-batch-too-big", "train", train(train={"batch_size": 64}), needles=("batch_size",))
add("train-input-size-zero", "train", train(data={"input_size": [0, 40]}), needles=("t.yaml", "data.input_size"))
add("train-grid-res-zero", "train", train(data={"grid": {"bound": 25.0, "res": 0}}), needles=("t.yaml", "data.grid"))
add("train-grid-mismatch", "train", train(data={"grid": {"bound": 20.0, "res": 0.625}}), needles=("index.json", "grid"))
add("train-unknown-field", "train", train(train={"lrate": 1}), needles=("t.yaml", "train.lrate"))
add("train-class-weights", "train", train(loss={"class_weights": [1, 2]}), needles=("t.yaml", "loss.class_weights"))
add("train-non-utf8", "train", train(raw=NON_UTF8), needles=("t.yaml", "UTF-8"))
add("train-bomb", "train", train(raw=BILLION_LAUGHS), needles=("t.yaml", "aliases"))
add("train-deep", "train", train(raw=DEEP), needles=("t.yaml", "nested"))
add("train-base-missing", "train", train(raw="_base: nope.yaml\n"), needles=("nope.yaml", "missing"))
add("train-base-circular", "train", train(raw="_base: t.yaml\n"), needles=("t.yaml", "circular"))
add("train-top-level-list", "train", train(raw="[1]\n"), needles=("t.yaml", "mapping"))
add("train-set-not-yaml", "train", train(extra_args=("--set", "train.lr=[")), needles=("train.lr",))
add("train-set-no-equals", "train", train(extra_args=("--set", "train.lr")), needles=("train.lr",))
add("train-set-unknown", "train", train(extra_args=("--set", "train.bogus=1")), needles=("train.bogus",))
add("train-set-lr-nan", "train", train(extra_args=("--set", "train.lr=.nan")), needles=("train.lr",))
add("train-data-missing", "train", train(data={"root": "/nonexistent/ds"}), needles=("/nonexistent/ds", "index.json"))


@case("train-out-is-a-file", "train", needles=("--out", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return ["--config", str(ctx.train_config()), "--out", str(ctx.out), "--quiet"]


@case("train-index-splits-list", "train", needles=("index.json", "splits"))
def _(ctx):
    ds = ctx.ds(edit=index_json(INDEX_BAD[0][1]))
    return ["--config", str(ctx.train_config(data={"root": str(ds)})), "--out", str(ctx.out), "--quiet"]


@case("train-class-out-of-range", "train", needles=("semantic.png", "class"))
def _(ctx):
    ds = ctx.ds(edit=semantic_out_of_range)
    return ["--config", str(ctx.train_config(data={"root": str(ds)})), "--out", str(ctx.out), "--quiet"]


def resume_from(make):
    """train.py on an --out whose latest.pt is `make(ctx)` (saved with torch.save)."""
    def build(ctx):
        import torch

        ctx.out.mkdir(parents=True)
        obj = make(ctx)
        if isinstance(obj, bytes):
            (ctx.out / "latest.pt").write_bytes(obj)
        else:
            torch.save(obj, ctx.out / "latest.pt")
        return ["--config", str(ctx.train_config()), "--out", str(ctx.out), "--quiet"]
    return build


def ckpt_without(*keys):
    def make(ctx):
        c = dict(ctx.checkpoint_dict())
        for k in keys:
            c.pop(k)
        return c
    return make


def ckpt_reshaped(ctx):
    import torch

    c = dict(ctx.checkpoint_dict())
    c["model"] = {k: (torch.zeros(*[s + 1 for s in v.shape]) if v.ndim else v) for k, v in c["model"].items()}
    return c


add("train-resume-foreign-dict", "train", resume_from(lambda ctx: {"weights": [1, 2, 3]}), needles=("latest.pt", "checkpoint"))
add("train-resume-list", "train", resume_from(lambda ctx: [1, 2, 3]), needles=("latest.pt", "checkpoint"))
add("train-resume-no-optimizer", "train", resume_from(ckpt_without("optimizer")), needles=("latest.pt", "checkpoint"))
add("train-resume-other-shape", "train", resume_from(ckpt_reshaped), needles=("latest.pt", "fit"))
add("train-resume-garbage", "train", resume_from(lambda ctx: b"not a checkpoint"), needles=("latest.pt", "checkpoint"))
add("train-resume-empty", "train", resume_from(lambda ctx: b""), needles=("latest.pt", "checkpoint"))

# ------------------------------------------------------------------ eval.py


def evaluate(*extra, ckpt=None, data=True):
    def build(ctx):
        c = ckpt(ctx) if ckpt else ctx.checkpoint
        args = ["--checkpoint", str(c), "--out", str(ctx.out), "--pictures", "0", *extra]
        if data is True:
            args += ["--data", str(ctx.ds())]
        elif data:
            args += ["--data", str(data(ctx))]
        return args
    return build


def ckpt_file(make):
    def build(ctx):
        import torch

        p = ctx.ws / "in" / "model.pt"
        p.parent.mkdir(parents=True, exist_ok=True)
        obj = make(ctx)
        if isinstance(obj, bytes):
            p.write_bytes(obj)
        else:
            torch.save(obj, p)
        return p
    return build


add("eval-pictures-negative", "eval", evaluate("--pictures", "-1"), needles=("--pictures",))
add("eval-threads-negative", "eval", evaluate("--threads", "-1"), needles=("--threads",))
add("eval-device-cuda-without-one", "eval", evaluate("--device", "cuda"), needles=("--device", "CUDA"))
add("eval-split-unknown", "eval", evaluate("--split", "eassy"), needles=("--split", "eassy"))
add("eval-checkpoint-missing", "eval", evaluate(ckpt=lambda ctx: ctx.ws / "none.pt"), needles=("none.pt",))
add("eval-checkpoint-garbage", "eval", evaluate(ckpt=ckpt_file(lambda ctx: b"garbage")), needles=("model.pt", "checkpoint"))
add("eval-checkpoint-foreign-dict", "eval", evaluate(ckpt=ckpt_file(lambda ctx: {"a": 1})), needles=("model.pt", "checkpoint"))
add("eval-checkpoint-list", "eval", evaluate(ckpt=ckpt_file(lambda ctx: [1])), needles=("model.pt", "checkpoint"))
add("eval-checkpoint-other-shape", "eval", evaluate(ckpt=ckpt_file(ckpt_reshaped)), needles=("model.pt", "fit"))
add("eval-checkpoint-config-garbage", "eval", evaluate(ckpt=ckpt_file(lambda ctx: {**ctx.checkpoint_dict(), "config": 7})),
    needles=("model.pt", "config"))
add("eval-checkpoint-rig-garbage", "eval", evaluate(ckpt=ckpt_file(lambda ctx: {**ctx.checkpoint_dict(), "rig": {"cameras": 3}})),
    needles=("model.pt", "rig"))
add("eval-class-out-of-range", "eval", evaluate(data=lambda ctx: ctx.ds(edit=semantic_out_of_range)), needles=("semantic.png", "class"))
add("eval-index-splits-list", "eval", evaluate(data=lambda ctx: ctx.ds(edit=index_json(INDEX_BAD[0][1]))), needles=("index.json", "splits"))
add("eval-data-missing", "eval", evaluate(data=lambda ctx: ctx.ws / "nothing"), needles=("nothing", "index.json"))
add("eval-config-bomb", "eval", lambda ctx: evaluate("--config", str(ctx.write("cfg/t.yaml", BILLION_LAUGHS)))(ctx),
    needles=("t.yaml", "aliases"))


@case("eval-out-is-a-file", "eval", needles=("--out", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return ["--checkpoint", str(ctx.checkpoint), "--out", str(ctx.out), "--data", str(ctx.ds())]



# ------------------------------------------------------------------ stitch, export-woodscape

def _first_frame(ds):
    return ds / json.loads((ds / "manifest.jsonl").read_text().splitlines()[0])["dir"]


def _stitch_with_rig(rig_text, **files):
    def build(ctx):
        for name, text in files.items():
            ctx.write(f"r/{name}.yaml", text)
        return [str(_first_frame(ctx.ds())), "--out", str(ctx.out / "bev.png"), "--rig", str(ctx.write("r/rig.yaml", rig_text))]
    return build


add("stitch-no-folder", "stitch", lambda ctx: [str(ctx.ws / "nowhere"), "--out", str(ctx.out / "bev.png")], needles=("nowhere", "no such folder"))
add("stitch-no-rig", "stitch", lambda ctx: [str(ctx.write("imgs/front.png", b"x").parent), "--out", str(ctx.out / "bev.png")],
    needles=("imgs", "give --rig"))
add("stitch-rig-calibration-missing", "stitch",
    _stitch_with_rig("cameras:\n  front: {calibration: gone.yaml, extrinsics: {translation: [0, 0, 1], rotation: {}}}\n"),
    needles=("rig.yaml", "cameras.front", "gone.yaml"))
add("stitch-rig-kalibr-bad-model", "stitch",
    _stitch_with_rig("cameras:\n  front: {calibration: chain.yaml, camera: cam0}\n",
                     chain="cam0:\n  camera_model: fov\n  intrinsics: [1, 1, 1, 1]\n  resolution: [64, 40]\n"),
    needles=("chain.yaml", "cam0", "camera_model"))
add("stitch-rig-opencv-no-distortion", "stitch",
    _stitch_with_rig("cameras:\n  front: {calibration: cv.yaml, extrinsics: {translation: [0, 0, 1], rotation: {}}}\n",
                     cv="K: [[20, 0, 31.5], [0, 20, 19.5], [0, 0, 1]]\nimage_size: [64, 40]\n"),
    needles=("cv.yaml", "distortion coefficients"))
add("stitch-rig-not-a-rig", "stitch", lambda ctx: [str(ctx.write("imgs/front.png", b"x").parent), "--out", str(ctx.out / "bev.png"),
                                                   "--rig", str(_first_frame(ctx.ds()) / "meta.json")],
    needles=("meta.json",))
add("stitch-res-not-whole", "stitch", lambda ctx: [str(_first_frame(ctx.ds())), "--out", str(ctx.out / "bev.png"), "--res", "0.3"],
    needles=("--bound/--res",))
add("export-woodscape-no-index", "export-woodscape", lambda ctx: [str(ctx.ws / "empty"), str(ctx.out)], needles=("index.json", "missing"))


@case("export-woodscape-exr-missing", "export-woodscape", needles=("cam_front.exr",))
def _(ctx):
    ds = ctx.ds()
    (_first_frame(ds) / "cam_front.exr").unlink()
    return [str(ds), str(ctx.out)]


# ------------------------------------------------------------------ calibrations, images, rigs, exports, comparisons


def png_header(width: int, height: int) -> bytes:
    """A PNG that is only a header (IHDR) promising width x height pixels, and an empty image."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def tiny_png(ctx, path):
    import cv2

    cv2.imwrite(str(path), np.zeros((1, 1, 3), np.uint8))


def _frame_with(edit):
    """A copy of the first rendered frame after `edit(ctx, frame_dir)`."""
    def build(ctx):
        f = _first_frame(ctx.ds())
        edit(ctx, f)
        return f
    return build


def _stitch_frame(edit, *extra):
    def build(ctx):
        return [str(_frame_with(edit)(ctx)), "--out", str(ctx.out / "bev.png"), *extra]
    return build


add("stitch-bound-inf", "stitch", _stitch_frame(lambda ctx, f: None, "--bound", "inf"), needles=("--bound", "inf"))
add("stitch-bound-1000", "stitch", _stitch_frame(lambda ctx, f: None, "--bound", "1000"), needles=("--bound", "1000"))
add("stitch-res-1e9", "stitch", _stitch_frame(lambda ctx, f: None, "--res", "1e9"), needles=("--res",))
add("stitch-res-nan", "stitch", _stitch_frame(lambda ctx, f: None, "--res", "nan"), needles=("--res",))
add("stitch-cells-too-many", "stitch", _stitch_frame(lambda ctx, f: None, "--bound", "400", "--res", "0.01"),
    needles=("--bound/--res", "cells"))
add("stitch-image-1x1", "stitch", _stitch_frame(lambda ctx, f: tiny_png(ctx, f / "cam_front.png")),
    needles=("cam_front.png", "1x1", "not a resize"))
add("stitch-image-bomb", "stitch", _stitch_frame(lambda ctx, f: (f / "cam_front.png").write_bytes(png_header(60000, 40000))),
    needles=("cam_front.png", "60000x40000"))
add("stitch-image-empty", "stitch", _stitch_frame(lambda ctx, f: (f / "cam_front.png").write_bytes(b"")),
    needles=("cam_front.png", "not a readable image"))

CV_FRONT = ("%YAML:1.0\n---\nK: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 20., 0., 31.5, 0., 20., 19.5, 0., 0., 1. ]\n"
            "D: !!opencv-matrix\n   rows: 4\n   cols: 1\n   dt: d\n   data: [ 0., 0., 0., 0. ]\nimage_width: 64\nimage_height: 40\n")
RIG_CV = "cameras:\n" + "".join(f"  {n}: {{calibration: cv.yaml, extrinsics: {{translation: [0, 0, 1], rotation: {{yaw_deg: {y}}}}}}}\n"
                                for n, y in (("front", 0), ("left", 90), ("rear", 180), ("right", -90)))
add("stitch-rig-opencv-pp-outside", "stitch", _stitch_with_rig(RIG_CV, cv=CV_FRONT.replace("image_width: 64", "image_width: 6")),
    needles=("rig.yaml", "cameras.front", "cv.yaml", "outside the 6x40 image"))
add("stitch-rig-opencv-rows-negative", "stitch", _stitch_with_rig(RIG_CV, cv=CV_FRONT.replace("rows: 4\n   cols: 1", "rows: -3\n   cols: -3")),
    needles=("cv.yaml", "D", "rows"))
add("stitch-rig-opencv-aliases", "stitch",
    _stitch_with_rig(RIG_CV, cv=CV_FRONT + BILLION_LAUGHS.replace("a:", "za:").replace("&a", "&za").replace("*a", "*za")),
    needles=("cv.yaml", "aliases"))
add("stitch-rig-opencv-oversized", "stitch", _stitch_with_rig(RIG_CV, cv=CV_FRONT + "# " + "x" * (5 * 1024 * 1024) + "\n"),
    needles=("cv.yaml", "bytes"))
add("stitch-rig-opencv-size-huge", "stitch", _stitch_with_rig(RIG_CV, cv=CV_FRONT.replace("image_width: 64", "image_width: 6400000")),
    needles=("cv.yaml", "image_width/image_height"))

CHAIN_REFLECT = ("cam0:\n  T_cam_imu: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]\n  camera_model: pinhole\n"
                 "  distortion_coeffs: [0, 0, 0, 0]\n  distortion_model: equidistant\n  intrinsics: [20, 20, 31.5, 19.5]\n  resolution: [64, 40]\n")
add("stitch-rig-kalibr-reflection", "stitch",
    _stitch_with_rig("cameras:\n" + "".join(f"  {n}: {{calibration: chain.yaml, camera: cam0}}\n" for n in ("front", "left", "rear", "right")),
                     chain=CHAIN_REFLECT),
    needles=("chain.yaml", "cam0", "T_cam_imu", "reflection"))
add("stitch-rig-kalibr-pp-outside", "stitch",
    _stitch_with_rig("cameras:\n" + "".join(f"  {n}: {{calibration: chain.yaml, camera: cam0}}\n" for n in ("front", "left", "rear", "right")),
                     chain=CHAIN_REFLECT.replace("[0, 0, -1, 0]", "[0, 0, 1, 0]").replace("31.5, 19.5", "315, 19.5")),
    needles=("chain.yaml", "cam0", "intrinsics", "outside"))


def _ocam(center="19.5 31.5", size="40 64"):
    return ("#pol\n3 -20.0 0.0 0.001\n#invpol\n1 20.0\n#center\n" + center + "\n#affine\n1 0 0\n#size\n" + size + "\n")


def _stitch_ocam(text):
    def build(ctx):
        ctx.write("r/calib_results.txt", text)
        rig = "cameras:\n" + "".join(f"  {n}: {{calibration: calib_results.txt, extrinsics: {{translation: [0, 0, 1], rotation: {{}}}}}}\n"
                                      for n in ("front", "left", "rear", "right"))
        return [str(_first_frame(ctx.ds())), "--out", str(ctx.out / "bev.png"), "--rig", str(ctx.write("r/rig.yaml", rig))]
    return build


add("stitch-rig-ocam-centre-outside", "stitch", _stitch_ocam(_ocam(center="195 315")), needles=("calib_results.txt", "center", "outside"))
add("stitch-rig-ocam-size-huge", "stitch", _stitch_ocam(_ocam(size="4000000 6400000")), needles=("calib_results.txt", "image size"))


def _predict(*extra, frame=None, rig=None):
    """predict.py on a copy of the first rendered frame (after `frame(ctx, dir)`), with `rig(ctx)` as --rig."""
    def build(ctx):
        f = _first_frame(ctx.ds())
        if frame:
            frame(ctx, f)
        args = ["--checkpoint", str(ctx.checkpoint), "--frames", str(f), "--out", str(ctx.out), "--no-pictures", *extra]
        return args + (["--rig", str(rig(ctx))] if rig else [])
    return build


def _rig_of_frame(keep=None, rename=None):
    def make(ctx):
        import yaml

        d = json.loads((_first_frame(ctx.ds()) / "meta.json").read_text())["rig"]
        cams = {(rename or {}).get(n, n): c for n, c in d["cameras"].items() if keep is None or n in keep}
        return ctx.write("r/mine.yaml", yaml.safe_dump({"name": "mine", "cameras": cams}))
    return make


add("predict-rig-3-cameras", "predict", _predict(rig=_rig_of_frame(keep=("front", "left", "rear"))),
    needles=("--rig", "mine.yaml", "3 cameras"))
add("predict-rig-other-names", "predict", _predict(rig=_rig_of_frame(rename={"rear": "back"})),
    needles=("--rig", "mine.yaml", "--cameras"))
add("predict-cameras-twice", "predict", _predict("--cameras", "front,front,left,right", rig=_rig_of_frame()), needles=("--cameras",))
add("predict-image-1x1", "predict", _predict(frame=lambda ctx, f: tiny_png(ctx, f / "cam_rear.png")),
    needles=("cam_rear.png", "not a resize"))
add("predict-image-bomb", "predict", _predict(frame=lambda ctx, f: (f / "cam_left.png").write_bytes(png_header(60000, 40000))),
    needles=("cam_left.png", "60000x40000"))
# one frame of another simulator: its own meta.json (not ours), its own rig file, its own camera
# layout (nuScenes' six cameras) and its own image names
SIM_META = ('{"simulator": "CARLA 0.9.15", "frame": 12, "sensors": [{"id": "front", "type": "sensor.camera.rgb", "fov": 190, '
            '"transform": {"x": 3.7, "z": 0.6, "pitch": -20}}]}')
SIM_RIG = ("sensors:\n" + "".join(f"  - {{type: sensor.camera.rgb, id: {n}, x: 2.0, z: 1.0, pitch: -30, yaw: {y}, width: 64, height: 40, fov: 190}}\n"
                                   for n, y in (("front", 0), ("left", -90), ("rear", 180), ("right", 90))))
NUSCENES = ("CAM_FRONT", "CAM_FRONT_LEFT", "CAM_FRONT_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_BACK_RIGHT")


def _other_simulator_meta(ctx, f):
    (f / "meta.json").write_text(SIM_META)


def _our_rig_cameras(ctx) -> dict:
    return json.loads((_first_frame(ctx.mini) / "meta.json").read_text())["rig"]["cameras"]  # the data set's, unedited


def _nuscenes_rig(ctx):
    import copy

    import yaml

    front = _our_rig_cameras(ctx)["front"]
    return ctx.write("r/nus.yaml", yaml.safe_dump({"name": "nuscenes", "cameras": {n: copy.deepcopy(front) for n in NUSCENES}}))


def _our_rig(ctx):
    import yaml

    return ctx.write("r/ours.yaml", yaml.safe_dump({"name": "ours", "cameras": _our_rig_cameras(ctx)}))


def _images_named_otherwise(ctx, f):
    """The frame's images as another simulator names them (CAM_FRONT.png, ...), without our meta.json."""
    (f / "meta.json").unlink()
    for ours, theirs in (("front", "CAM_FRONT"), ("left", "CAM_LEFT"), ("rear", "CAM_BACK"), ("right", "CAM_RIGHT")):
        (f / f"cam_{ours}.png").rename(f / f"{theirs}.png")


add("stitch-frame-other-simulator", "stitch", _stitch_frame(_other_simulator_meta), needles=("meta.json", "simulator", "--rig"))
add("predict-frame-other-simulator", "predict", _predict(frame=_other_simulator_meta), needles=("meta.json", "simulator", "--rig"))
add("stitch-rig-other-simulator", "stitch", lambda ctx: [str(_first_frame(ctx.ds())), "--out", str(ctx.out / "bev.png"),
                                                         "--rig", str(ctx.write("r/carla.yaml", SIM_RIG))],
    needles=("carla.yaml", "cameras"))
add("predict-rig-other-simulator", "predict", _predict(rig=lambda ctx: ctx.write("r/carla.yaml", SIM_RIG)), needles=("carla.yaml", "cameras"))
add("predict-rig-other-simulator-layout", "predict", _predict(rig=_nuscenes_rig), needles=("--rig", "nus.yaml", "6 cameras"))
add("predict-frame-other-simulator-names", "predict", _predict(frame=_images_named_otherwise, rig=_our_rig),
    needles=("no image for camera 'front'", "front.png"))
add("stitch-frame-other-simulator-names", "stitch",
    lambda ctx: [str(_frame_with(_images_named_otherwise)(ctx)), "--out", str(ctx.out / "bev.png"), "--rig", str(_our_rig(ctx))],
    needles=("no image for camera 'front'", "front.png"))
add("predict-frames-missing", "predict", lambda ctx: ["--checkpoint", str(ctx.ws / "none.pt"), "--frames", str(ctx.ws / "nothing"),
                                                      "--out", str(ctx.out)], needles=("nothing", "no such folder"))


@case("export-woodscape-png-missing", "export-woodscape", needles=("cam_front.png", "missing"))
def _(ctx):
    ds = ctx.ds()
    (_first_frame(ds) / "cam_front.png").unlink()
    return [str(ds), str(ctx.out)]


@case("export-woodscape-png-empty", "export-woodscape", needles=("cam_right.png", "0 bytes"))
def _(ctx):
    ds = ctx.ds()
    (_first_frame(ds) / "cam_right.png").write_bytes(b"")
    return [str(ds), str(ctx.out)]


@case("export-woodscape-png-truncated", "export-woodscape", needles=("cam_left.png", "not a whole PNG"))
def _(ctx):
    ds = ctx.ds()
    p = _first_frame(ds) / "cam_left.png"
    p.write_bytes(p.read_bytes()[:100])
    return [str(ds), str(ctx.out)]


# ------------------------------------------------------------------ issue 35: WebDataset export, training from shards
add("export-webdataset-no-data", "export-webdataset", lambda ctx: [str(ctx.ws / "nothing"), str(ctx.out)], needles=("DATA", "nothing", "missing"))
add("export-webdataset-data-is-a-file", "export-webdataset", lambda ctx: [str(ctx.write("f.txt", "x")), str(ctx.out)],
    needles=("DATA", "is a file"))
add("export-webdataset-no-index", "export-webdataset", lambda ctx: [str(ctx.write("empty/notes.txt", "x").parent), str(ctx.out)],
    needles=("index.json", "missing"))
add("export-webdataset-shard-size-0", "export-webdataset", lambda ctx: [str(ctx.ds()), str(ctx.out), "--shard-size", "0"],
    needles=("--shard-size",))


@case("export-webdataset-out-is-a-file", "export-webdataset", needles=("OUT", "is a file"))
def _(ctx):
    ctx.out_is_a_file()
    return [str(ctx.ds()), str(ctx.out)]


@case("export-webdataset-out-not-an-export", "export-webdataset", needles=("OUT", "shards.json"))
def _(ctx):
    ctx.out.mkdir(parents=True)
    (ctx.out / "mine.txt").write_text("not an export\n")
    return [str(ctx.ds()), str(ctx.out)]


@case("export-webdataset-png-empty", "export-webdataset", needles=("cam_right.png", "0 bytes"))
def _(ctx):
    ds = ctx.ds()
    (_first_frame(ds) / "cam_right.png").write_bytes(b"")
    return [str(ds), str(ctx.out)]


@case("export-webdataset-label-missing", "export-webdataset", needles=("visibility.png", "missing"))
def _(ctx):
    ds = ctx.ds()
    (_first_frame(ds) / "labels" / "visibility.png").unlink()
    return [str(ds), str(ctx.out)]


add("train-shards-missing", "train", train(data={"shards": "nowhere/train-{000000..000003}.tar"}), needles=("shards.json", "missing"))
add("train-shards-index-not-json", "train", lambda ctx: train(data={"shards": str(ctx.ws / "x/train-000000.tar"),
                                                                    "shards_index": str(ctx.write("x/shards.json", "{"))})(ctx),
    needles=("shards.json", "JSON"))


@case("export-woodscape-out-not-an-export", "export-woodscape", needles=("OUT", "export.json"))
def _(ctx):
    ctx.out.mkdir(parents=True)
    (ctx.out / "mine.txt").write_text("not an export\n")
    return [str(ctx.ds()), str(ctx.out)]


def _other_rig(rig: dict) -> dict:
    """The same rig (same camera names) with the front camera's focal length changed: another calibration."""
    import copy

    rig = copy.deepcopy(rig)
    rig["cameras"]["front"]["intrinsics"]["fx"] *= 1.5
    return rig


def _index_with_other_rig(ctx, ds):
    d = json.loads((ds / "index.json").read_text())
    d["rig"] = _other_rig(d["rig"])
    (ds / "index.json").write_text(json.dumps(d))


add("eval-data-other-rig", "eval", evaluate(data=lambda ctx: ctx.ds(edit=_index_with_other_rig)),
    needles=("ds", "another rig", "camera front", "fx"))


def _compare(a, b, data=True):
    def build(ctx):
        args = ["--compare", str(a(ctx)), str(b(ctx)), "--out", str(ctx.out)]
        return args + (["--data", str(ctx.ds())] if data else [])
    return build


def _ckpt(ctx):
    return ctx.checkpoint


add("eval-compare-b-missing", "eval", _compare(_ckpt, lambda ctx: ctx.ws / "none.pt"), needles=("--compare B", "none.pt"))
add("eval-compare-a-garbage", "eval", _compare(ckpt_file(lambda ctx: b"garbage"), _ckpt), needles=("--compare A", "model.pt", "checkpoint"))
add("eval-compare-b-other-rig", "eval", _compare(_ckpt, ckpt_file(lambda ctx: {**ctx.checkpoint_dict(), "rig": _other_rig(ctx.checkpoint_dict()["rig"])})),
    needles=("--compare B", "another rig", "camera front"))
add("eval-compare-a-other-rig", "eval", _compare(ckpt_file(lambda ctx: {**ctx.checkpoint_dict(), "rig": _other_rig(ctx.checkpoint_dict()["rig"])}), _ckpt),
    needles=("--compare A", "model.pt", "another rig"))
