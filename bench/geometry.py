"""Geometry throughput: unprojecting every pixel of a 480x302 image, per model, and projecting
as many points; on one core, float64 numpy (the arithmetic is torch's either way)."""

import torch

from bench import best_of
from geometry.cameras import camera_from_dict


def run() -> dict:
    torch.set_num_threads(1)
    base = dict(width=480, height=302, fx=150.0, fy=150.0, cx=239.5, cy=150.5)
    models = {
        "equidistant": {},
        "opencv_fisheye": {"k": [-0.02, 0.003, 0.0, 0.0]},
        "kb_theta": {"p": [1.0, 0.0, 0.04]},
        "double_sphere": {"xi": -0.2, "alpha": 0.6},
    }
    figures = {}
    for name, extra in models.items():
        cam = camera_from_dict(dict(base, model=name, **extra))
        uv = cam.pixel_grid().numpy()
        rays, _ = cam.unproject(uv)
        t_un = best_of(lambda: cam.unproject(uv))
        t_pr = best_of(lambda: cam.project(rays))
        figures[f"{name} unproject 480x302 (numpy f64)"] = {"value": t_un * 1e3, "unit": "ms", "goal": None, "met": None}
        figures[f"{name} project 145k points (numpy f64)"] = {"value": t_pr * 1e3, "unit": "ms", "goal": None, "met": None}
    return figures
