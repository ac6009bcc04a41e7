"""Fine semantic classes of the rendered scenes and the map to the paper's training classes.

Every material's `pass_index` is its fine class id, so Cycles' IndexMA pass is the fine semantic
pass; every object's `pass_index` is its instance id (unique, > 0), so IndexOB is the instance
pass. Background (sky) is 0 in both.
"""

from __future__ import annotations

import numpy as np

from ..format.index import DEFAULT_CLASS_NAMES

# id, name, overhead occluder?, colour for pictures (RGB 0-255)
FINE_CLASSES = [
    (0, "unlabelled", False, (0, 0, 0)),  # sky / nothing hit
    (1, "road", False, (128, 64, 128)),
    (2, "lane_marking", False, (255, 255, 255)),  # lane lines, parking-bay lines
    (3, "crosswalk", False, (255, 230, 120)),
    (4, "stop_line", False, (255, 160, 40)),
    (5, "sidewalk", False, (244, 35, 232)),
    (6, "curb", False, (190, 150, 150)),
    (7, "parking", False, (160, 100, 160)),  # parking-lot asphalt
    (8, "vehicle", False, (0, 0, 142)),
    (9, "building", False, (70, 70, 70)),
    (10, "vegetation", False, (107, 142, 35)),  # trunks, bushes
    (11, "canopy", True, (60, 200, 60)),  # tree crowns: overhead occluder
    (12, "pole", False, (153, 153, 153)),  # poles, street lights
    (13, "bridge", True, (150, 100, 100)),  # bridge / overpass deck: overhead occluder
    (14, "pillar", False, (180, 165, 180)),  # bridge supports
    (15, "terrain", False, (152, 251, 152)),  # grass, verge
    (16, "barrier", False, (102, 102, 156)),  # guard rails, median walls
    (17, "ego", False, (255, 0, 255)),  # the ego car's own body (camera self-occlusion); never a label
    (18, "pedestrian", False, (220, 20, 60)),  # people on the pavements, riders
    (19, "bicycle", False, (119, 11, 32)),  # parked or ridden on the pavements
    (20, "motorcycle", False, (0, 0, 230)),
    (21, "street_furniture", False, (180, 120, 60)),  # benches, litter bins
]

CLASS_IDS = {name: cid for cid, name, _, _ in FINE_CLASSES}
CLASS_NAMES = {cid: name for cid, name, _, _ in FINE_CLASSES}
NUM_FINE_CLASSES = len(FINE_CLASSES)
OVERHEAD_OCCLUDERS = frozenset(cid for cid, _, occ, _ in FINE_CLASSES if occ)
PALETTE = np.array([c for _, _, _, c in FINE_CLASSES], dtype=np.uint8)

# The paper's training classes (named in the data format: index.json's default class_names).
TRAIN_CLASSES = list(DEFAULT_CLASS_NAMES)

DEFAULT_CLASS_MAP = {
    "unlabelled": "invalid",
    "road": "street",
    "lane_marking": "lane_marking",
    "crosswalk": "lane_marking",
    "stop_line": "lane_marking",
    "sidewalk": "background",
    "curb": "background",
    "parking": "street",
    "vehicle": "vehicle",
    "building": "background",
    "vegetation": "background",
    "canopy": "background",
    "pole": "background",
    "bridge": "background",
    "pillar": "background",
    "terrain": "background",
    "barrier": "background",
    "ego": "invalid",
    "pedestrian": "background",  # the paper's classes have no people: not drivable, not a vehicle
    "bicycle": "background",  # nor two-wheelers (its vehicles are cars, vans, trucks and buses)
    "motorcycle": "background",
    "street_furniture": "background",
}


def class_lut(class_map: dict | None = None, train_classes: list[str] | None = None) -> np.ndarray:
    """Lookup table fine id -> training id (uint8), from a name -> name map (default the paper's)."""
    class_map = DEFAULT_CLASS_MAP if class_map is None else class_map
    train_classes = TRAIN_CLASSES if train_classes is None else train_classes
    lut = np.zeros(NUM_FINE_CLASSES, dtype=np.uint8)
    for fine, coarse in class_map.items():
        if fine not in CLASS_IDS:
            raise ValueError(f"class map: unknown fine class '{fine}'")
        if coarse not in train_classes:
            raise ValueError(f"class map: '{fine}' maps to unknown training class '{coarse}'")
        lut[CLASS_IDS[fine]] = train_classes.index(coarse)
    return lut


def colorize(semantic: np.ndarray) -> np.ndarray:
    """Fine semantic ids (H, W) -> RGB uint8 picture."""
    return PALETTE[np.clip(semantic.astype(np.int64), 0, NUM_FINE_CLASSES - 1)]

# Colours of the training classes for pictures (invalid, vehicle, lane marking, street, background).
TRAIN_PALETTE = np.array([[0, 0, 0], [220, 40, 40], [250, 250, 250], [110, 110, 120], [70, 150, 70]], dtype=np.uint8)


def colorize_train(semantic: np.ndarray, visibility: np.ndarray | None = None) -> np.ndarray:
    """Training-class ids (H, W) -> RGB uint8 picture; with `visibility`, cells with p(o) < 0.5
    are dimmed (what no camera sees)."""
    img = TRAIN_PALETTE[np.clip(np.asarray(semantic).astype(np.int64), 0, len(TRAIN_PALETTE) - 1)]
    if visibility is None:
        return img
    dim = 0.35 + 0.65 * (np.asarray(visibility) >= 0.5)
    return (img * dim[..., None]).astype(np.uint8)
