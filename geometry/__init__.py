"""The one source of camera truth: camera models, rigs, the BEV grid and the Blender mapping.

    from geometry import camera_from_dict, load_rig, BevGrid
    cam = camera_from_dict({"model": "double_sphere", ...}); uv, valid = cam.project(points)
    rig = load_rig("configs/rigs/default.yaml"); grid = BevGrid()

Numpy in gives numpy out; torch in gives torch out, differentiable. Imports nothing of ours but
`common`. See docs/geometry.md.
"""

from .bev import BevGrid
from .cameras import MODELS, Camera, CameraError, camera_from_dict
from .rig import Rig, RigCamera, RigError, load_rig, rig_from_dict, woodscape_camera

__all__ = ["BevGrid", "Camera", "CameraError", "MODELS", "camera_from_dict", "Rig", "RigCamera", "RigError", "load_rig",
           "rig_from_dict", "woodscape_camera"]
