"""The rig the model sees: the data set's fisheye rig, or its cylindrical rectification
(`data.rectify: cylindrical`, the paper's LSS baseline; see geometry.rectify), decided here once
for the data set, `build_model`, evaluation and inference:

    view = model_view(rig, cfg)    # cached by calibration and the config's model part
    view.rig                       # the model's cameras (native size): the fisheye rig or its cylinders
    view.rectifier                 # None, or fisheye image -> the model's image, per camera
    view.frustum                   # the lift geometry (model.frustum.Frustum) of view.rig
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from threading import Lock

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


@dataclass(frozen=True)
class ModelView:
    """A rig as a model config sees it (see the module doc)."""

    fisheye: Rig
    rig: Rig
    rectifier: Rectifier | None
    frustum: object  # model.frustum.Frustum


_VIEWS: OrderedDict = OrderedDict()
_VIEWS_MAX = 32  # calibrations kept (a data set of jittered rigs has one per scene)
_VIEWS_LOCK = Lock()


def model_view(rig: Rig, cfg: dict) -> ModelView:
    """The ModelView of `rig` under `cfg`, built once per calibration (and model part of the config)."""
    from .frustum import Frustum

    key = repr((rig.to_dict(), cfg["model"], cfg["data"]["input_size"], cfg["data"]["grid"], _cylinder(cfg)))
    with _VIEWS_LOCK:
        if key in _VIEWS:
            _VIEWS.move_to_end(key)
            return _VIEWS[key]
    rect = rectifier(rig, cfg)
    seen = rect.rig if rect else rig
    view = ModelView(rig, seen, rect, Frustum(seen, cfg))
    with _VIEWS_LOCK:
        _VIEWS[key] = view
        while len(_VIEWS) > _VIEWS_MAX:
            _VIEWS.popitem(last=False)
    return view


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
