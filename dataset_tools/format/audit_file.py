"""`<dataset>/audit.json`, the line-of-sight audit of the labels (dataset_tools.qa.audit writes the
figures): the one writer and reader, and the metric its threshold applies to."""

from __future__ import annotations

from pathlib import Path

from common.files import read_json, write_json_atomic

from .layout import AUDIT, DatasetError

DEFAULT_METRIC = "visible_no_los"  # an audit.json without 'metric' (older audits) checked this one


def write_audit(root, audit: dict) -> Path:
    path = Path(root) / AUDIT
    write_json_atomic(path, audit)
    return path


def read_audit(root, missing_ok: bool = False) -> dict | None:
    """<root>/audit.json with its shape checked ('frames' a mapping of '<scene>/<frame>' to figures,
    'overall' a mapping, 'threshold' a number); 'frames' defaults to {}. Missing: None when
    missing_ok, else DatasetError."""
    path = Path(root) / AUDIT
    if not path.is_file():
        if missing_ok:
            return None
        raise DatasetError(f"{path}: missing (run python -m dataset_tools audit {root})")
    a = read_json(path, DatasetError)
    if not isinstance(a, dict) or not isinstance(a.get("frames", {}), dict):
        raise DatasetError(f"{path}: field 'frames' must be a mapping of '<scene>/<frame>' to figures")
    for name, fig in a.get("frames", {}).items():
        if not isinstance(fig, dict):
            raise DatasetError(f"{path}: frames.{name}: must be a mapping of figures")
    th = a.get("threshold")
    if th is not None and (isinstance(th, bool) or not isinstance(th, (int, float))):
        raise DatasetError(f"{path}: field 'threshold' must be a number")
    if not isinstance(a.get("overall") or {}, dict):
        raise DatasetError(f"{path}: field 'overall' must be a mapping of figures")
    a.setdefault("frames", {})
    return a


def audit_metric(audit: dict) -> str:
    """The figure the audit's threshold applies to (`python -m dataset_tools audit --metric`)."""
    m = audit.get("metric")
    return m if isinstance(m, str) else DEFAULT_METRIC
