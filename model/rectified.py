"""The rig the model sees: the data set's fisheye rig, or its cylindrical rectification
(`data.rectify: cylindrical`, the paper's LSS baseline; see geometry.rectify)."""

from __future__ import annotations

from geometry.rectify import Rectifier, cylindrical_rig
from geometry.rig import Rig


def _cylinder(cfg: dict) -> tuple[float, float] | None:
    d = cfg["data"]
    if d["rectify"] == "none":
        return None
    c = d["cylinder"]
    return c["hfov_deg"], c["vfov_deg"]


def model_rig(rig: Rig, cfg: dict) -> Rig:
    fov = _cylinder(cfg)
    return rig if fov is None else cylindrical_rig(rig, *fov)


def rectifier(rig: Rig, cfg: dict) -> Rectifier | None:
    fov = _cylinder(cfg)
    return None if fov is None else Rectifier(rig, *fov)


def rectify_part(cfg: dict) -> dict:
    """What of `data` decides the model's cameras (for checkpoint compatibility)."""
    fov = _cylinder(cfg)
    return {"rectify": "none"} if fov is None else {"rectify": cfg["data"]["rectify"], "cylinder": list(fov)}


def source_maps(rect: Rectifier, name: str):
    """(map_x, map_y) float32 (H, W): the fisheye position each rectified pixel of camera `name`
    samples, as cv2.remap applies the rectifier's fixed-point tables (negative: no fisheye pixel)."""
    import cv2

    m1, m2 = rect.maps[name]
    return cv2.convertMaps(m1, m2, cv2.CV_32FC1)
