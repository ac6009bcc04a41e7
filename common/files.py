"""Atomic writes and safe reads.

Every file the project writes goes through `write_bytes_atomic` (or its text/JSON forms): a temp
file beside the target, then a rename, so a reader never sees half a file and a kill leaves at most
a hidden temp file, which `clean_stale_temps` removes on the next run. Reads of YAML and JSON raise
the caller's error type with one line naming the file; YAML is read without aliases (a
"billion laughs" file cannot blow up) and with a cap on size and nesting.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import yaml

from .errors import ConfigError, InputError

MAX_YAML_BYTES = 4 * 1024 * 1024
MAX_NESTING = 64
_TEMP = re.compile(r"^\..+\.\d+\.tmp(\.[A-Za-z0-9]+)?$")


def atomic_path(path) -> Path:
    """A temp name beside `path` (same folder, so the final rename is atomic); it keeps the
    suffix, so tools that pick a format by extension (OpenCV, torch) still can."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp{path.suffix}")


def _named(exc: OSError, path: Path) -> OSError:
    """The same error naming the target (not the temp file, nor nothing as a failed write does)."""
    return OSError(exc.errno, exc.strerror or str(exc), str(path)) if exc.errno else exc


def _discard(tmp: Path) -> None:
    try:
        tmp.unlink()
    except FileNotFoundError:
        pass


def write_bytes_atomic(path, data: bytes) -> None:
    write_with(path, lambda tmp: Path(tmp).write_bytes(data))


def write_text_atomic(path, text: str) -> None:
    write_bytes_atomic(path, text.encode())


def write_json_atomic(path, obj, indent: int | None = 1) -> None:
    write_text_atomic(path, json.dumps(obj, indent=indent))


def write_with(path, writer) -> None:
    """Atomically write a file produced by `writer(temp_path)` (for libraries that want a path)."""
    path = Path(path)
    tmp = atomic_path(path)
    try:
        writer(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        _discard(tmp)
        raise _named(exc, path) from None
    finally:
        if tmp.exists():
            _discard(tmp)


def output_dir(path, flag: str = "--out") -> Path:
    """An output folder, created if missing; a path that is a file is bad input (InputError)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{flag}: {path} is a file, not a folder")
    path.mkdir(parents=True, exist_ok=True)
    return path


def build_folder(out, fill, marker: str, flag: str = "OUT"):
    """Build the folder `out` atomically: `fill(tmp)` writes everything into a hidden temp folder
    beside it (`.<out>.<pid>.tmp`), which then replaces `out` (an earlier build there goes as a
    whole); a failure leaves `out` as it was. `out` must be missing, empty or an earlier build (it
    holds the file `marker`): other files are never removed (InputError). Returns fill's result."""
    import shutil

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{flag}: {out} is a file, not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / marker).is_file():
        raise InputError(f"{flag}: {out} holds files but no earlier export ({marker}); give a new or empty folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.{os.getpid()}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir()
        result = fill(tmp)
        old = out.parent / f".{out.name}.{os.getpid()}.old"
        shutil.rmtree(old, ignore_errors=True)
        if out.exists():
            os.replace(out, old)
        os.replace(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return result


def clean_stale_temps(folder, recursive: bool = True) -> int:
    """Remove temp files (`.<name>.<pid>.tmp[.ext]`) a killed run left behind; returns how many."""
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    n = 0
    for p in folder.rglob(".*.tmp*") if recursive else folder.glob(".*.tmp*"):
        if _TEMP.match(p.name) and p.is_file():
            try:
                p.unlink()
                n += 1
            except OSError:
                pass
    return n


def read_text(path, error=InputError, max_bytes: int | None = None) -> str:
    """A UTF-8 text file; `max_bytes`: refuse a bigger one (one line naming it and its size)."""
    path = Path(path)
    if max_bytes is not None:
        try:
            size = path.stat().st_size
        except OSError:
            size = 0
        if size > max_bytes:
            raise error(f"{path}: {size} bytes, more than a config may have ({max_bytes})")
    try:
        return path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise error(f"{path}: missing") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, not a file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start})") from None


def read_json(path, error=InputError):
    text = read_text(path, error)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    except RecursionError:
        raise error(f"{path}: nested too deeply") from None


class _NoAliasLoader(yaml.SafeLoader):
    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.YAMLError(f"YAML aliases (*name) are not allowed (line {event.start_mark.line + 1})")
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_NESTING:
                raise yaml.YAMLError(f"nested deeper than {MAX_NESTING} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


SafeYamlLoader = _NoAliasLoader  # subclass it (e.g. for OpenCV's tags): aliases and nesting stay limited

# YAML 1.1 (PyYAML) reads 1e-5 as a string; take YAML 1.2's floats (a dot is optional)
_NoAliasLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def parse_yaml(text: str, loader=None):
    """YAML text -> data (no aliases, at most MAX_NESTING levels); raises yaml.YAMLError.
    `loader`: a subclass of SafeYamlLoader (extra tags), by default SafeYamlLoader itself."""
    loader = loader or _NoAliasLoader
    if not issubclass(loader, _NoAliasLoader):
        raise TypeError("parse_yaml: the loader must subclass common.files.SafeYamlLoader")
    return yaml.load(text, Loader=loader)  # noqa: S506 - a SafeLoader subclass


def read_yaml(path, error=ConfigError, loader=None, text_filter=None):
    """A YAML file's content; an unreadable, oversized or malformed file raises `error` with one
    line naming it. `loader`: as parse_yaml's; `text_filter`: text -> text before parsing (e.g. to
    drop OpenCV's `%YAML:1.0` directive, which PyYAML refuses)."""
    path = Path(path)
    text = read_text(path, error, MAX_YAML_BYTES)
    if text_filter is not None:
        text = text_filter(text)
    try:
        return parse_yaml(text, loader)
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise error(f"{path}: not valid YAML ({first})") from None
    except RecursionError:
        raise error(f"{path}: not valid YAML (nested too deeply)") from None


def write_figure_atomic(fig, path, dpi: int = 100) -> None:
    """Save a matplotlib figure as a PNG, atomically, and close it."""
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
