"""WebDataset shards of a fused data set: the one writer (`write_shards`) and reader
(`read_shard_index`, `shard_samples`, `decode_sample`) of an export.

    <out>/shards.json                  version, format, shard_size, the data set's index (class names,
                                       grid, rig, splits -> frames), per split: frames, pattern, shards
                                       [{file, frames, bytes}]
    <out>/<split>-<000000>.tar         one tar per `shard_size` frames of a split, frames in index order
    <out>/README.md                    the dataset card (dataset_tools.card)

A shard follows the conventions of PyPI `webdataset`: a sample is the run of tar members sharing
one key (the name up to the first dot of its last path part), here `<scene>/<frame:06d>` (a '.' of
a scene name written `%2E`); its members are `<key>.<name>` for each name of `sample_files`:

    cam_<camera>.png        the 8-bit camera image, as in the frame folder
    cam_<camera>_ego.png    the camera's self-occlusion mask (when the frame has one)
    camera_targets.npy      the compact per-camera passes of the camera-view losses
                            (format.camera_targets: distance in cm and fine class per pixel;
                            left out of a frame that has neither it nor its EXRs)
    semantic.png, instance.png, visibility.png   the BEV labels (format.labels)
    meta.json               the frame's metadata (format.meta)
    frame.json              scene, frame, split, weather, own_rig, position (the frame's place
                            in its split, which seeds its augmentation as the folder loader's index)

Members are stored in a fixed order with zero times and owners, so equal frames give equal
shards. Reading needs no checkout: `read_shard_index` (a local folder or shards.json) and
`shard_samples(urls)` (local paths, `file:` or `pipe:` URLs: webdataset's `gopen`). A local shard
is memory-mapped, its ustar headers read by `_tar_members` and its members handed out as views
(no copies: a training sample touches only the bytes it decodes, as the folder loader reads only
its files; exports replace shards atomically, so a mapped shard never changes under a reader);
any other tar (compressed, pax headers) and every URL go through webdataset's tarfile reader.
`decode_sample` decodes what a sample needs with the folder reader's decoders.
"""

from __future__ import annotations

import io
import json
import mmap
import re
import tarfile
from pathlib import Path

from common.files import read_json, write_json_atomic, write_with

from .camera_targets import camera_targets_bytes, decode_camera_targets
from .labels import PNG_END, PNG_SIGNATURE, decode_labels
from .layout import LABEL_PNGS, META, DatasetError, FrameFiles, frame_dir_name
from .meta import decode_meta
from .png import decode_png

SHARDS_INDEX = "shards.json"
SHARDS_VERSION = 1
FRAME_JSON = "frame.json"
TARGETS = "camera_targets.npy"
DEFAULT_SHARD_SIZE = 64


def sample_key(scene: str, frame: int) -> str:
    """The webdataset key of a frame: `<scene>/<frame:06d>` with no '.' (the key ends at the first dot)."""
    return frame_dir_name(scene.replace("%", "%25").replace(".", "%2E"), frame)


def shard_name(split: str, n: int) -> str:
    return f"{split}-{n:06d}.tar"


def shard_pattern(split: str, count: int) -> str:
    """The brace pattern of a split's shards (`train-{000000..000012}.tar`), as webdataset expands it."""
    return shard_name(split, 0) if count == 1 else f"{split}-{{{0:06d}..{count - 1:06d}}}.tar"


def sample_files(cameras, ego_masks: bool) -> list[str]:
    """The member names of one sample, in the order they are written."""
    names = [f"cam_{c}.png" for c in cameras] + ([f"cam_{c}_ego.png" for c in cameras] if ego_masks else [])
    return names + [TARGETS, *LABEL_PNGS, META, FRAME_JSON]


def frame_members(ref, cameras, position: int) -> dict[str, bytes]:
    """{member name: bytes} of one frame (`ref`: a format.reader.FrameRef)."""
    files = FrameFiles(ref.dir)
    out = {}
    ego = all(files.camera_ego_mask(c).is_file() for c in cameras)
    for name in sample_files(cameras, ego):
        path = files.dir / name
        if name == TARGETS:
            if (files.dir / TARGETS).is_file() or any(files.camera_exr(c).is_file() for c in cameras):
                out[name] = camera_targets_bytes(files.dir, cameras)  # else a frame shipped without passes
        elif name == FRAME_JSON:
            out[name] = json.dumps({"scene": ref.scene, "frame": ref.frame, "split": ref.split, "weather": ref.weather,
                                    "own_rig": ref.own_rig, "position": position}, sort_keys=True).encode()
        else:
            if name in LABEL_PNGS:
                path = files.labels / name
            try:
                out[name] = path.read_bytes()
            except FileNotFoundError:
                raise DatasetError(f"{path}: missing (every exported frame needs it)") from None
            except IsADirectoryError:
                raise DatasetError(f"{path}: is a folder, not a file") from None
            if name.endswith(".png") and not (out[name].startswith(PNG_SIGNATURE) and out[name].endswith(PNG_END)):
                raise DatasetError(f"{path}: " + ("empty (0 bytes)" if not out[name] else "not a whole PNG file"))
    return out


def _add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode, info.uid, info.gid, info.uname, info.gname = len(data), 0, 0o644, 0, 0, "", ""
    tar.addfile(info, io.BytesIO(data))


def write_shard(path: Path, samples) -> int:
    """One tar of `samples` ([(key, {name: bytes})]), atomically; returns its size in bytes."""
    def write(tmp):
        with tarfile.open(tmp, "w", format=tarfile.USTAR_FORMAT) as tar:
            for key, members in samples:
                for name, data in members.items():
                    _add(tar, f"{key}.{name}", data)
    write_with(path, write)
    return path.stat().st_size


def write_shards(index, out, shard_size: int = DEFAULT_SHARD_SIZE, progress=None) -> dict:
    """Every frame of `index` (a format.reader.DatasetIndex) into `<split>-NNNNNN.tar` shards of
    `shard_size` frames in `out`, then shards.json; returns what shards.json holds. `progress`:
    called once per frame written."""
    out = Path(out)
    cameras = index.rig.names
    splits = {}
    for split, refs in index.splits.items():
        if not refs:
            continue
        shards = []
        for n, start in enumerate(range(0, len(refs), shard_size)):
            batch = []
            for pos, ref in enumerate(refs[start:start + shard_size], start):
                batch.append((sample_key(ref.scene, ref.frame), frame_members(ref, cameras, pos)))
                if progress:
                    progress()
            size = write_shard(out / shard_name(split, n), batch)
            shards.append({"file": shard_name(split, n), "frames": len(batch), "bytes": size})
        splits[split] = {"frames": len(refs), "pattern": shard_pattern(split, len(shards)), "shards": shards}
    summary = {"version": SHARDS_VERSION, "format": "webdataset", "shard_size": shard_size, "cameras": list(cameras),
               "sample_files": sample_files(cameras, ego_masks=True), "index": index.data, "splits": splits}
    write_json_atomic(out / SHARDS_INDEX, summary, indent=1)
    return summary


def shards_base(pattern: str) -> str:
    """The folder (or URL prefix) of a shard pattern: everything up to its last '/' (the pattern
    names the shard files last: `OUT/train-{...}.tar`, `pipe:curl -s https://host/x/train-{...}.tar`)."""
    first = pattern.split("::")[0]
    return first[: first.rfind("/") + 1]


def read_shard_index(where) -> dict:
    """shards.json (`where`: the export folder, the file itself, or a `file:`/`pipe:` URL of it),
    checked: version and fields."""
    where = str(where)
    local = local_path(where)
    if local is None:  # a URL: read through webdataset's gopen, as the shards are
        from webdataset.gopen import gopen

        path = where
        try:
            with gopen(where, "rb") as f:
                text = f.read()
            d = json.loads(text)
        except Exception as exc:  # noqa: BLE001 - any failure of the pipe or the JSON is the input's
            raise DatasetError(f"{where}: cannot read the shards index ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    else:
        path = local
        if path.is_dir() or path.name != SHARDS_INDEX:
            path = path / SHARDS_INDEX
        if not path.is_file():
            raise DatasetError(f"{path}: missing (an export of python -m dataset_tools export-webdataset has one)")
        d = read_json(path, DatasetError)
    if not isinstance(d, dict) or d.get("version") != SHARDS_VERSION:
        got = d.get("version") if isinstance(d, dict) else None
        raise DatasetError(f"{path}: field 'version' is {got!r}, this code reads version {SHARDS_VERSION}")
    for key, kind in (("index", dict), ("splits", dict), ("cameras", list)):
        if not isinstance(d.get(key), kind):
            raise DatasetError(f"{path}: field '{key}' missing or not a {'mapping' if kind is dict else 'list'}")
    for split, s in d["splits"].items():
        if not isinstance(s, dict) or not isinstance(s.get("frames"), int) or not isinstance(s.get("shards"), list):
            raise DatasetError(f"{path}: splits.{split}: needs 'frames' and 'shards'")
    return d


_URL = re.compile(r"^[a-z][a-z0-9+.-]*:")


def expand_urls(pattern: str) -> list[str]:
    """The shard URLs of a brace pattern (`train-{000000..000012}.tar`; several patterns joined
    with '::' as webdataset does); local paths stay paths."""
    import braceexpand

    return [u for part in pattern.split("::") for u in braceexpand.braceexpand(part)]


def local_path(url: str) -> Path | None:
    """The file a shard URL names on this machine (a path or `file:` URL); None for other URLs (pipe:, http:)."""
    if url.startswith("file:"):
        return Path(url[5:])
    if _URL.match(url) and not re.match(r"^[A-Za-z]:[\\/]", url):
        return None
    return Path(url)


_BLOCK = 512
_SKIP_META = re.compile(r"__[^/]*__($|/)")  # webdataset's tar_file_iterator skips these names


def _tar_members(buf) -> list[tuple[str, int, int]] | None:
    """(name, offset of its data, size) of every regular file of the uncompressed tar in `buf`,
    read from its 512-byte headers (what write_shard writes: ustar, plain files and folders);
    None for a tar this does not read (compressed, pax or GNU long names, links), which tarfile
    then reads. ValueError for a damaged one (a bad header checksum, cut short)."""
    out, pos, end = [], 0, len(buf)
    while pos < end:
        if pos + _BLOCK > end:
            raise ValueError("unexpected end of data")
        h = bytes(buf[pos:pos + _BLOCK])
        if not any(h):  # the end-of-archive blocks
            return out
        try:
            checksum = int(h[148:156].split(b"\0", 1)[0].strip(), 8)
            size = int(h[124:136].split(b"\0", 1)[0].strip() or b"0", 8)
        except ValueError:  # not octal: GNU base-256 sizes, or not a tar header at all (compressed)
            if pos == 0:
                return None
            raise ValueError(f"damaged header at byte {pos}") from None
        if sum(h[:148]) + 256 + sum(h[156:]) != checksum:  # the checksum counts its own field as spaces
            if pos == 0:
                return None
            raise ValueError(f"bad header checksum at byte {pos}")
        kind, data = h[156:157], pos + _BLOCK
        if kind in (b"0", b"\0"):
            name = h[:100].split(b"\0", 1)[0]
            if h[257:262] == b"ustar" and h[345] != 0:  # a long name: prefix '/' name
                name = h[345:500].split(b"\0", 1)[0] + b"/" + name
            if data + size > end:
                raise ValueError("unexpected end of data")
            out.append((name.decode("utf-8", "surrogateescape"), data, size))
        elif kind != b"5":  # pax headers, GNU long names, links, devices: tarfile's business
            return None
        pos = data + -(-size // _BLOCK) * _BLOCK
    return out


def _mapped_files(path: Path, url: str):
    """webdataset's tar_file_expander for a local uncompressed shard, without its copies: the
    file is memory-mapped and every member is a memoryview of it ({"fname", "data", "__url__"},
    then {} at the end); None when `_tar_members` leaves the shard to tarfile."""
    if path.stat().st_size == 0:
        return None
    with open(path, "rb") as f:
        buf = memoryview(mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ))
    members = _tar_members(buf)
    if members is None:
        return None
    files = [{"fname": name, "data": buf[at:at + size], "__url__": url} for name, at, size in members
             if not (("/" not in name and name.startswith("__") and name.endswith("__")) or _SKIP_META.match(name))]
    return files + [{}]


def shard_samples(urls):
    """(url, key, {member name: bytes-like}) of every sample of the shards at `urls`, in order
    (webdataset reads them: local paths, `file:` and `pipe:` URLs; members are bytes, or read-only
    memoryviews of a local shard, which is memory-mapped instead of read and copied member by
    member). A missing or damaged shard is one DatasetError line naming it."""
    from webdataset.gopen import gopen
    from webdataset.tariterators import group_by_keys, tar_file_expander

    for url in urls:
        path = local_path(url)
        if path is not None and not path.is_file():
            raise DatasetError(f"{url}: missing shard")
        stream = None
        try:
            files = _mapped_files(path, url) if path is not None else None
            if files is None:
                try:
                    stream = gopen(str(path) if path is not None else url, "rb")
                except Exception as exc:  # gopen raises ValueError for unknown schemes, OSError for files
                    raise DatasetError(f"{url}: cannot open ({exc})") from None
                files = tar_file_expander([{"url": url, "stream": stream}])
            for s in group_by_keys(files, lcase=False):
                key = s.pop("__key__")
                s.pop("__url__", None)
                s.pop("__local_path__", None)
                yield url, key, s
        except (tarfile.TarError, OSError, ValueError) as exc:
            raise DatasetError(f"{url}: not a readable shard ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
        finally:
            if stream is not None:
                stream.close()


def decode_sample(url: str, key: str, members: dict, cameras, num_classes: int | None = None,
                  targets: bool = True, instance: bool = True) -> dict:
    """A shard sample as format.reader.read_frame gives a frame (images, semantic, instance,
    visibility, meta) plus `frame` (frame.json) and, with `targets`, `camera_targets`
    ({camera: (distance cm, fine class)}, read-only views of the member). `instance=False` leaves
    the instance labels undecoded, as read_frame's. Errors name `<url>:<key>.<member>`."""
    def member(name):
        if name not in members:
            raise DatasetError(f"{url}: sample {key}: no member '{name}'")
        return members[name]

    where = lambda name: Path(f"{url}:{key}.{name}")  # noqa: E731
    out = {"images": {c: decode_png(member(f"cam_{c}.png"), where(f"cam_{c}.png"), "uint8", 3) for c in cameras}}
    names = {Path(n).stem: n for n in LABEL_PNGS}
    if not instance:
        names.pop("instance")
    out.update(decode_labels({k: member(n) for k, n in names.items()}, {k: where(n) for k, n in names.items()}, num_classes,
                             instance=instance))
    out["meta"] = decode_meta(bytes(member(META)), where(META))
    try:
        out["frame"] = json.loads(bytes(member(FRAME_JSON)))
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise DatasetError(f"{where(FRAME_JSON)}: not valid JSON") from None
    if targets:
        out["camera_targets"] = decode_camera_targets(member(TARGETS), where(TARGETS), cameras)
    return out
