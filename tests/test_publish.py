"""Issue 35: WebDataset export (shards read back to the folder's pixels, labels and metadata), the
dataset card (YAML front matter naming every split with its frame count), training that streams
the shards (one process through a pipe: URL, DDP with 2 processes under gloo)."""

import json
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from dataset_tools.format.camera_targets import camera_targets
from dataset_tools.format.card import read_card
from dataset_tools.format.reader import DatasetIndex, read_frame
from dataset_tools.format.shards import decode_sample, expand_urls, read_shard_index, shard_samples

from test_train import run_train, write_config

ROOT = Path(__file__).resolve().parents[1]


def export(data, out, *extra):
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "export-webdataset", str(data), str(out), "--no-progress", *extra],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return r


@pytest.fixture(scope="module")
def tiny_shards(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("wds") / "tiny_wds"
    export(tiny_dataset, out, "--shard-size", "4")
    return out


def test_shards_read_back_as_the_folder(tiny_dataset, tiny_shards, tmp_path):
    idx = DatasetIndex(tiny_dataset)
    shards = read_shard_index(tiny_shards)
    counts = {s: len(r) for s, r in idx.splits.items() if r}
    assert {s: v["frames"] for s, v in shards["splits"].items()} == counts
    assert shards["splits"]["train"]["pattern"] == "train-{000000..000003}.tar"  # 14 frames, 4 a shard
    cams = idx.rig.names
    seen = 0
    for split, v in shards["splits"].items():
        urls = [str(tiny_shards / s["file"]) for s in v["shards"]]
        assert [s["frames"] for s in v["shards"]] == [len(list(tarfile.open(u).getnames())) // len(shards["sample_files"]) for u in urls]
        for n, (url, key, members) in enumerate(shard_samples(urls)):
            ref = idx.splits[split][n]
            assert key == f"{ref.scene}/{ref.frame:06d}"
            got = decode_sample(url, key, members, cams, len(idx.class_names))
            want = read_frame(ref, cameras=cams, num_classes=len(idx.class_names))
            for c in cams:
                np.testing.assert_array_equal(got["images"][c], want["images"][c])
                d, s = camera_targets(ref.dir, cams)[c]
                np.testing.assert_array_equal(got["camera_targets"][c][0], d)
                np.testing.assert_array_equal(got["camera_targets"][c][1], s)
                assert members[f"cam_{c}_ego.png"] == (ref.dir / f"cam_{c}_ego.png").read_bytes()
            for k in ("semantic", "instance", "visibility"):
                np.testing.assert_array_equal(got[k], want[k])
            assert got["meta"].to_dict() == want["meta"].to_dict()
            assert got["frame"] == {"scene": ref.scene, "frame": ref.frame, "split": split, "weather": ref.weather,
                                    "own_rig": ref.own_rig, "position": n}
            seen += 1
    assert seen == sum(counts.values()) and seen > 0
    # the shards.json index is the data set's (a model is built from it as from the folder)
    assert shards["index"]["splits"] == json.loads((tiny_dataset / "index.json").read_text())["splits"]
    # equal frames give equal shards: a second export is byte for byte the same
    again = tmp_path / "again"
    export(tiny_dataset, again, "--shard-size", "4")
    for f in sorted(tiny_shards.glob("*.tar")):
        assert (again / f.name).read_bytes() == f.read_bytes(), f.name



def test_mapped_shards_read_as_webdataset_reads_them(tiny_shards, tmp_path):
    """A local shard is memory-mapped and its headers read by _tar_members; what it yields is what
    webdataset's tarfile reader yields (through a pipe: URL), member for member; a damaged shard
    is one DatasetError line; training decodes no instance labels."""
    from dataset_tools.format.layout import DatasetError
    from dataset_tools.format.shards import _tar_members

    url = str(tiny_shards / "train-000000.tar")
    mapped, piped = list(shard_samples([url])), list(shard_samples(["pipe:cat " + url]))
    assert [k for _, k, _ in mapped] == [k for _, k, _ in piped] and len(mapped) == 4
    for (_, _, a), (_, _, b) in zip(mapped, piped):
        assert sorted(a) == sorted(b) and all(bytes(a[n]) == b[n] for n in a)
    raw = (tiny_shards / "train-000000.tar").read_bytes()
    second = _tar_members(raw)[1][1] - 512  # the second member's header
    cut, flipped = tmp_path / "cut.tar", tmp_path / "flipped.tar"
    cut.write_bytes(raw[: len(raw) // 2 + 100])
    flipped.write_bytes(raw[:second + 5] + bytes([raw[second + 5] ^ 0x41]) + raw[second + 6:])
    for bad, why in ((cut, "unexpected end of data"), (flipped, "checksum")):
        with pytest.raises(DatasetError, match=why) as e:
            list(shard_samples([str(bad)]))
        assert str(bad) in str(e.value) and "\n" not in str(e.value)
    _, key, members = mapped[0]
    cams = read_shard_index(tiny_shards)["cameras"]
    lean = decode_sample(url, key, members, cams, instance=False)
    full = decode_sample(url, key, members, cams)
    assert "instance" not in lean and "instance" in full
    np.testing.assert_array_equal(lean["semantic"], full["semantic"])
    assert not lean["camera_targets"][cams[0]][0].flags.writeable  # a view of the mapped shard, not a copy

def test_card_front_matter_names_every_split(tiny_dataset, tiny_shards):
    idx = DatasetIndex(tiny_dataset)
    counts = {s: len(r) for s, r in idx.splits.items() if r}
    front, body = read_card(tiny_shards)
    text = (tiny_shards / "README.md").read_text()
    assert yaml.safe_load(text.split("---\n")[1]) == front  # plain YAML, as the Hub reads it
    assert {s["name"]: s["num_examples"] for s in front["dataset_info"]["splits"]} == counts
    assert front["license"] and front["task_categories"] == ["image-segmentation"] and front["size_categories"] == ["n<1K"]
    assert {d["split"]: d["path"] for d in front["configs"][0]["data_files"]} == {s: f"{s}-*.tar" for s in counts}
    assert front["fisheye_bev"]["cameras"] == idx.rig.names and front["fisheye_bev"]["class_names"] == idx.class_names
    assert 'wds.WebDataset("train-{000000..000003}.tar")' in body
    for name in idx.class_names:
        assert f"| {name} |" in body
    for rc in idx.rig:
        assert f"| {rc.name} | {rc.camera.model} |" in body


def test_dataset_card_carries_the_config_into_the_export(tiny_dataset, tmp_path):
    import shutil

    from dataset_tools.card import write_dataset_card

    ds = tmp_path / "ds"
    shutil.copytree(tiny_dataset, ds)
    write_dataset_card(ds, config=ROOT / "configs/dataset/tiny.yaml", license="cc-by-sa-4.0")
    front, body = read_card(ds)
    assert front["license"] == "cc-by-sa-4.0" and front["fisheye_bev"]["config"]["text"].startswith("# Tests")
    assert "fisheye_size: [64, 40]" in body
    export(ds, tmp_path / "wds", "--shard-size", "100")
    front2, body2 = read_card(tmp_path / "wds")
    assert front2["license"] == "cc-by-sa-4.0" and front2["fisheye_bev"]["config"] == front["fisheye_bev"]["config"]
    assert read_shard_index(tmp_path / "wds")["splits"]["train"]["pattern"] == "train-000000.tar"


def _grid(ds) -> dict:
    g = DatasetIndex(ds).grid
    return {"x_min": g.x_min, "x_max": g.x_max, "y_min": g.y_min, "y_max": g.y_max, "res": g.res}


def _stream_config(tmp_path, shards, grid):
    return write_config(tmp_path / "cfg.yaml", "unused", data={"shards": shards, "shuffle_buffer": 3, "num_workers": 1, "grid": grid},
                        train={"epochs": 1, "max_steps": 2, "batch_size": 2, "log_every": 1})


def test_train_streams_shards_through_a_pipe(tiny_dataset, tiny_shards, tmp_path):
    urls = "pipe:cat " + str(tiny_shards / "train-{000000..000003}.tar")
    assert len(expand_urls(urls)) == 4
    cfg = _stream_config(tmp_path, urls, _grid(tiny_dataset))
    run_train(cfg, tmp_path / "run")
    import torch

    ckpt = torch.load(tmp_path / "run" / "latest.pt", map_location="cpu", weights_only=False)
    assert ckpt["step"] == 2 and ckpt["config"]["data"]["shards"] == urls


def test_train_streams_shards_with_ddp(tiny_dataset, tiny_shards, tmp_path):
    """2 processes (gloo), each reading its own 2 of the 4 shards, for 2 steps."""
    cfg = _stream_config(tmp_path, str(tiny_shards / "train-{000000..000003}.tar"), _grid(tiny_dataset))
    r = run_train(cfg, tmp_path / "run", nproc=2)
    import torch

    ckpt = torch.load(tmp_path / "run" / "latest.pt", map_location="cpu", weights_only=False)
    assert ckpt["step"] == 2, r.stderr[-2000:]


def test_stream_shares_and_seeds(tiny_dataset, tiny_shards):
    """Each rank and worker gets its own shards; the stream yields exactly the epoch's batches."""
    from model.config import validate
    from model.shards import shard_datasets

    cfg = validate({"data": {"shards": str(tiny_shards / "train-{000000..000003}.tar"), "val_split": "", "input_size": [64, 40],
                             "grid": _grid(tiny_dataset), "shuffle_buffer": 4}, "augment": {"enabled": False}})
    keys = []
    for rank in (0, 1):
        _, stream, val = shard_datasets(cfg, rank, 2, 2)
        assert val is None and len(stream) == 14 and stream.steps() == 3
        urls, stride, offset = stream._share(0, 1)
        assert urls == stream.urls[rank::2] and stride == 1
        stream.set_epoch(0)
        got = [int(s["index"]) for s in stream]
        assert len(got) == 3 * 2 and len(set(got)) == len(got)  # a pass over the rank's 8 frames repeats none
        keys.append(got)
        stream.set_epoch(0)
        assert [int(s["index"]) for s in stream] == got  # seeded
        stream.set_epoch(1)
        assert [int(s["index"]) for s in stream] != got  # another order next epoch
    by_shard = {0: set(range(0, 4)) | set(range(8, 12)), 1: set(range(4, 8)) | set(range(12, 14))}
    assert set(keys[0]) <= by_shard[0] and set(keys[1]) <= by_shard[1]
