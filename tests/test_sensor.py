"""The camera's effects on the image (dataset_tools.generation.sensor) and the render quality presets:
seeded, switchable one by one, each doing what it says on a known image; presets fill in defaults
that explicit fields override; a bad preset name is one line."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from common.errors import ConfigError
from dataset_tools.generation import sensor
from dataset_tools.generation.dataset_config import QUALITY, load_config
from geometry.rig import load_rig

ALL = {e: True for e in sensor.EFFECTS}


@pytest.fixture(scope="module")
def front():
    cam = load_rig("configs/rigs/default.yaml")["front"].camera.resized(96, 60)
    return cam, *sensor.camera_geometry(cam)


def test_draws_are_seeded_and_switching_one_off_keeps_the_others():
    a = sensor.draw(ALL, np.random.default_rng([5, 7, 0]))
    assert a == sensor.draw(ALL, np.random.default_rng([5, 7, 0]))
    assert a != sensor.draw(ALL, np.random.default_rng([6, 7, 0]))
    b = sensor.draw(dict(ALL, vignetting=False), np.random.default_rng([5, 7, 0]))
    assert "vignetting" not in b and all(b[k] == a[k] for k in b)
    assert sensor.draw(sensor.OFF, np.random.default_rng(0)) == {}


def test_nothing_switched_on_leaves_the_image_alone(front):
    _, theta, pp = front
    img = np.random.default_rng(0).integers(0, 256, theta.shape + (3,), dtype=np.uint8)
    assert sensor.apply(img, {}, theta, pp) is img


def test_geometry_comes_from_the_camera_model(front):
    cam, theta, (u, v) = front
    assert abs(u - (cam.width - 1) / 2) < 0.1 * cam.width and abs(v - (cam.height - 1) / 2) < 0.1 * cam.height
    r = np.hypot(*np.meshgrid(np.arange(cam.width) - u, np.arange(cam.height) - v))
    ok = np.isfinite(theta)
    assert np.corrcoef(r[ok], theta[ok])[0, 1] > 0.99  # the ray angle grows with the radius


def test_vignetting_darkens_the_edge_not_the_centre(front):
    _, theta, pp = front
    img = np.full(theta.shape + (3,), 128, np.uint8)
    out = sensor.apply(img, {"vignetting": 0.4}, theta, pp).astype(int)
    cy, cx = int(round(pp[1])), int(round(pp[0]))
    assert abs(out[cy, cx, 1] - 128) <= 1
    assert out[0, 0, 1] < 110 and out[-1, -1, 1] < 110


def test_chromatic_aberration_moves_red_and_blue_never_green(front):
    _, theta, pp = front
    img = np.zeros(theta.shape + (3,), np.uint8)
    img[:, 80:] = 200  # a vertical edge right of the centre
    out = sensor.apply(img, {"chromatic_aberration": 0.02}, theta, pp)
    assert np.array_equal(out[..., 1], img[..., 1])
    assert not np.array_equal(out[..., 0], img[..., 0]) and not np.array_equal(out[..., 2], img[..., 2])
    # red scaled outward: the red edge lies right of the green one, blue left of it
    row = out[30].astype(int)
    assert row[79:82, 0].sum() < row[79:82, 1].sum() < row[79:82, 2].sum()


def test_noise_is_seeded_and_of_the_drawn_size(front):
    _, theta, pp = front
    img = np.full(theta.shape + (3,), 128, np.uint8)
    p = {"shot_gain": 0.002, "read_sd": 0.003, "noise_seed": 3}
    a, b = sensor.apply(img, p, theta, pp), sensor.apply(img, p, theta, pp)
    assert np.array_equal(a, b)
    sd = a.astype(float).std()
    assert 0.5 < sd < 8.0
    assert not np.array_equal(a, sensor.apply(img, dict(p, noise_seed=4), theta, pp))


def test_exposure_white_balance_and_jpeg(front):
    _, theta, pp = front
    img = np.full(theta.shape + (3,), 100, np.uint8)
    brighter = sensor.apply(img, {"exposure_ev": 0.5}, theta, pp)
    darker = sensor.apply(img, {"exposure_ev": -0.5}, theta, pp)
    assert (brighter > darker + 10).all()
    warm = sensor.apply(img, {"wb_gains": [1.1, 1.0, 0.9]}, theta, pp)
    assert warm[0, 0, 0] > warm[0, 0, 1] > warm[0, 0, 2]
    ramp = np.tile(np.linspace(0, 255, theta.shape[1]).astype(np.uint8)[None, :, None], (theta.shape[0], 1, 3))
    jpg = sensor.apply(ramp, {"jpeg_quality": 70}, theta, pp)
    assert jpg.shape == ramp.shape and jpg.dtype == np.uint8 and 0 < np.abs(jpg.astype(int) - ramp).mean() < 4


def test_auto_exposure_lengthens_the_exposure_then_raises_the_gain():
    """Day: the exposure time alone brings the scene to the key (no analog gain). Night: the longest
    exposure, then analog gain for the square root of what is left, so a darker scene ends darker."""
    day = np.full((8, 8, 3), 0.09, np.float32)  # a log-average of 0.09: twice the key's exposure
    p = {"exposure_ev": 0.0, "motion_blur": True}
    g = sensor.meter(day, p)
    assert p["exposure_ms"] == pytest.approx(2.0, rel=0.02) and p["analog_gain"] == 1.0 and g == pytest.approx(2.0, rel=0.02)
    out = {}
    for lum in (0.0003, 0.0001):  # needs 450x and 900x
        p = {"exposure_ev": 0.0}
        g = sensor.meter(np.full((8, 8, 3), lum, np.float32), p)
        assert p["exposure_ms"] == sensor.EXPOSURE_MS[1] and 1.0 < p["analog_gain"] <= sensor.ANALOG_GAIN[1]
        out[lum] = lum * g
        assert out[lum] < sensor.KEY  # darker than day
    assert out[0.0001] < out[0.0003]
    assert sensor.meter(day, {"motion_blur": True}) == 1.0  # no exposure effect: the light as rendered
    assert sensor.meter(day, {}) == 1.0


def test_hdr_tone_mapping_compresses_the_bright_large_scale_and_keeps_its_detail():
    """A car face 6 stops above the key on a street below it: the face comes down by about
    (1 - c) x 6 stops, the street is left alone, the face's own texture keeps its contrast."""
    h, w = 60, 96
    lin = np.full((h, w, 3), 0.05, np.float32)  # the street, below the key
    texture = 1 + 0.2 * np.sign(np.sin(np.arange(w) / 1.5))[None, 20:60, None]  # +-20 % stripes on the face
    lin[20:40, 20:60] = sensor.KEY * 64 * texture  # the lit face
    out = sensor.local_tone(lin, 0.3)
    face = out[25:35, 30:50, 1] / lin[25:35, 30:50, 1]
    assert np.log2(face.mean()) == pytest.approx(-0.7 * 6, abs=0.6)
    assert np.allclose(out[:5, :5], lin[:5, :5])  # far from the face: untouched
    rel = lambda x: x[25:35, 30:50, 1].std() / x[25:35, 30:50, 1].mean()  # noqa: E731
    assert rel(out) > 0.7 * rel(lin)  # the detail survives
    assert np.allclose(sensor.local_tone(lin, 1.0), lin)
    # an 8-bit image alone: metered, then compressed (the clipped face comes off white)
    img = np.rint(sensor._to_srgb(lin / 20) * 255).astype(np.uint8)
    theta = np.zeros((h, w), np.float32)
    plain = sensor.apply(img, {"exposure_ev": 0.0}, theta, (w / 2, h / 2))
    toned = sensor.apply(img, {"exposure_ev": 0.0, "hdr_compression": 0.3}, theta, (w / 2, h / 2))
    assert plain[25:35, 30:50].min() == 255 and toned[25:35, 30:50].max() < 250


def test_noise_grows_with_the_analog_gain_not_the_exposure_time(front):
    _, theta, pp = front
    img = np.full(theta.shape + (3,), 60, np.uint8)
    p = {"shot_gain": 0.0003, "read_sd": 0.001, "noise_seed": 3}
    quiet = sensor.apply(img, dict(p, analog_gain=1.0), theta, pp, exposed=True).astype(float).std()
    loud = sensor.apply(img, dict(p, analog_gain=8.0), theta, pp, exposed=True).astype(float).std()
    assert loud > 2 * quiet > 0


def test_noise_reduction_smooths_the_grain_and_keeps_edges(front):
    """The ISP's noise reduction: on a flat grey the grain falls to well under its raw size; an edge
    of 80 grey levels (far above the threshold) stays as sharp as without it."""
    _, theta, pp = front
    img = np.full(theta.shape + (3,), 110, np.uint8)
    img[:, 48:] = 190
    p = {"shot_gain": 0.0004, "read_sd": 0.0015, "noise_seed": 3, "analog_gain": 2.0}
    raw = sensor.apply(img, p, theta, pp, exposed=True).astype(float)
    nr = sensor.apply(img, dict(p, nr_strength=2.5), theta, pp, exposed=True).astype(float)
    flat = np.s_[5:-5, 5:40, 1]
    assert nr[flat].std() < 0.6 * raw[flat].std() and raw[flat].std() > 1.5
    assert abs(nr[flat].mean() - raw[flat].mean()) < 0.5  # no shift of the grey
    step = lambda x: x[5:-5, 49:52, 1].mean() - x[5:-5, 44:47, 1].mean()  # noqa: E731
    assert step(nr) > 0.95 * step(raw) > 60
    # the threshold follows the noise the gain gives: twice the gain, at least sqrt(2) x the sd (shot
    # noise grows with its square root, read noise with the gain)
    assert sensor.noise_sd_srgb(dict(p, analog_gain=4.0)) > 1.4 * sensor.noise_sd_srgb(p)


def test_edge_enhancement_steepens_a_soft_edge_by_its_drawn_amount(front):
    """The unsharp mask: drawn within sensor.SHARPEN; a flat grey stays as it was, a soft edge (a
    3-px ramp, as the denoised renders have) gets steeper the larger the amount."""
    amounts = [sensor.draw(ALL, np.random.default_rng([k, 7, 0]))["sharpen"] for k in range(200)]
    assert sensor.SHARPEN[0] <= min(amounts) < sensor.SHARPEN[0] + 0.05 and sensor.SHARPEN[1] - 0.05 < max(amounts) <= sensor.SHARPEN[1]
    _, theta, pp = front
    img = np.full(theta.shape + (3,), 100, np.uint8)
    img[:, 47], img[:, 48], img[:, 49:] = 120, 140, 160
    slope = lambda x: np.abs(np.diff(x[5:-5, 40:56, 1].astype(float), axis=1)).max(1).mean()  # noqa: E731
    flat = np.s_[5:-5, 5:30, 1]
    out = {a: sensor.apply(img, {"sharpen": a}, theta, pp) for a in (0.0, 0.4, 1.0)}
    assert all(np.array_equal(o[flat], img[flat]) for o in out.values())
    assert slope(out[0.0]) < slope(out[0.4]) - 2 < slope(out[1.0]) - 4


def test_auto_white_balance_greys_a_cast_and_ignores_coloured_surfaces(front):
    """A street under warm lamps (its greys 10 % red, 10 % short of blue, as our night frames) comes
    out grey; a large saturated green (grass) beside it neither counts nor turns magenta."""
    _, theta, pp = front
    lin = np.zeros(theta.shape + (3,), np.float32)
    lin[:, :48] = np.array([0.11, 0.1, 0.09]) * np.linspace(0.5, 1.5, theta.shape[0])[:, None, None]  # warm greys
    lin[:, 48:] = (0.02, 0.15, 0.02)  # grass
    img = np.rint(sensor._to_srgb(lin) * 255).astype(np.uint8)
    out = sensor._to_linear(sensor.apply(img, {"wb_gains": [1.0, 1.0, 1.0]}, theta, pp).astype(np.float32) / 255)
    street = out[:, :48].reshape(-1, 3).mean(0)
    assert street[0] / street[1] == pytest.approx(1.0, abs=0.03) and street[2] / street[1] == pytest.approx(1.0, abs=0.03)
    grass = out[:, 48:].reshape(-1, 3).mean(0)
    assert grass[1] > 5 * max(grass[0], grass[2])  # still green, its own balance untouched but for the street's gains
    assert sensor.grey_world(np.full((4, 4, 3), 0.3, np.float32)).tolist() == [1.0, 1.0, 1.0]  # too few pixels: none


def test_noise_reduction_is_drawn_only_with_the_noise():
    assert "nr_strength" in sensor.draw(ALL, np.random.default_rng(1))
    assert "nr_strength" not in sensor.draw(dict(ALL, noise=False), np.random.default_rng(1))
    assert "nr_strength" not in sensor.draw(dict(ALL, noise_reduction=False), np.random.default_rng(1))


def _cfg(tmp_path, render):
    p = tmp_path / "cfg.yaml"
    p.write_text(yaml.safe_dump({"rig": "configs/rigs/default.yaml", "render": render,
                                 "scenes": [{"recipe": "scenes/highway_straight.yaml"}]}))
    return p


def test_quality_presets_fill_defaults_that_explicit_fields_override(tmp_path):
    draft = load_config(_cfg(tmp_path, {"quality": "draft"}))["render"]
    assert draft["samples"] == QUALITY["draft"]["samples"] and not any(draft["sensor"].values())
    photo = load_config(_cfg(tmp_path, {}))["render"]
    assert photo["quality"] == "photo" and photo["denoise"] and photo["sensor"]["noise"] and not photo["sensor"]["jpeg"]
    mine = load_config(_cfg(tmp_path, {"quality": "photo", "samples": 8, "sensor": {"noise": False, "jpeg": True}}))["render"]
    assert mine["samples"] == 8 and not mine["sensor"]["noise"] and mine["sensor"]["jpeg"] and mine["sensor"]["vignetting"]


def test_night_scenes_render_with_at_least_the_night_settings(tmp_path):
    from dataset_tools.generation.dataset_config import for_weather

    photo = load_config(_cfg(tmp_path, {"samples": 2, "denoise_quality": "fast"}))["render"]
    night = for_weather(photo, {"sun_elevation_deg": -12.0, "lights_on": True})
    assert (night["samples"], night["denoise_quality"]) == (4, "high") and night["max_bounces"] == photo["max_bounces"]
    assert for_weather(photo, {"sun_elevation_deg": 30.0, "lights_on": True}) == photo  # headlights in the rain
    draft = load_config(_cfg(tmp_path, {"quality": "draft"}))["render"]
    assert for_weather(draft, {"sun_elevation_deg": -12.0}) == draft  # no night settings: as the day
    mine = load_config(_cfg(tmp_path, {"night": {"samples": 16}}))["render"]
    assert for_weather(mine, {"sun_elevation_deg": -12.0})["samples"] == 16
    assert for_weather(mine, {"sun_elevation_deg": -12.0})["denoise_quality"] == "high"  # the preset's, not given
    paper = load_config(_cfg(tmp_path, {"samples": 16, "denoise_quality": "high"}))["render"]
    assert for_weather(paper, {"sun_elevation_deg": -12.0}) == paper  # never fewer samples than the day's


@pytest.mark.parametrize("render,field", [({"quality": "cinema"}, "render.quality"),
                                          ({"sensor": {"blur": True}}, "render.sensor.blur"),
                                          ({"sensor": {"noise": "yes"}}, "render.sensor.noise"),
                                          ({"night": {"samples": 0}}, "render.night.samples"),
                                          ({"night": {"denoise_quality": "best"}}, "render.night.denoise_quality")])
def test_bad_quality_or_sensor_field_is_one_line(tmp_path, render, field):
    with pytest.raises(ConfigError) as e:
        load_config(_cfg(tmp_path, render))
    assert field in str(e.value) and "\n" not in str(e.value)


def _ego_at(x: float) -> list:
    """world-to-ego of an ego at (x, 0) looking along +x."""
    m = np.eye(4)
    m[0, 3] = -x
    return m.tolist()


def test_motion_flow_from_the_scene_moving_through_the_camera_model(front):
    cam, theta, pp = front
    rc = load_rig("configs/rigs/default.yaml")["front"]
    h, w = theta.shape
    # every pixel sees a point 6 m ahead of the front camera on its own ray (instance 1), the top-left
    # corner the sky (instance 0)
    rays, valid = cam.unproject(cam.pixel_grid().numpy())
    rays = np.asarray(rays, float)
    cam_pts = rays / np.linalg.norm(rays, axis=-1, keepdims=True) * 6.0
    world = (np.concatenate([cam_pts, np.ones((h, w, 1))], -1) @ np.asarray(rc.cam_to_ego).T)[..., :3]  # ego = world at t
    inst = np.ones((h, w), np.int64)
    inst[:5, :5] = 0
    motion = {"dt": 0.04, "world_to_ego": [_ego_at(-0.2), _ego_at(0.2)], "instances": {}}  # 10 m/s forward
    flow = sensor.motion_flow(cam, rc.cam_to_ego, world.astype(np.float32), inst, motion)
    assert flow.shape == (h, w, 2) and np.all(flow[:5, :5] == 0)
    ok = np.asarray(valid, bool) & (theta < np.radians(60))
    centre = np.array(pp)
    v, u = np.mgrid[0:h, 0:w]
    out = np.stack([u - centre[0], v - centre[1]], -1)
    # driving forward, what the front camera sees streams out from the centre of expansion
    assert (np.sum(flow[ok] * out[ok], -1) > 0).mean() > 0.95
    # a vehicle moving with the ego (same motion) does not move in the image
    same = {"dt": 0.04, "world_to_ego": motion["world_to_ego"],
            "instances": {1: [np.linalg.inv(_ego_at(-0.2)).tolist(), np.linalg.inv(_ego_at(0.2)).tolist()]}}
    assert np.abs(sensor.motion_flow(cam, rc.cam_to_ego, world.astype(np.float32), inst, same)).max() < 1e-2


def test_motion_blur_smears_at_night_and_leaves_a_bright_day_alone(front):
    _, theta, pp = front
    h, w = theta.shape
    flow = np.zeros((h, w, 2), np.float32)
    flow[..., 0] = 500.0  # px/s along the rows
    for level, blurred in ((2, True), (200, False)):
        img = np.full((h, w, 3), level, np.uint8)
        img[:, w // 2:] = min(255, level * 4)  # a vertical edge
        p = {"motion_blur": True}
        out = sensor.apply(img, p, theta, pp, flow)
        assert 0.1 <= p["exposure_ms"] <= 33.0
        if blurred:  # dark: a long exposure, 500 px/s x ~23 ms = ~12 px of smear across the edge
            assert p["exposure_ms"] > 20
            row = out[h // 2].astype(int)[:, 1]
            assert row[w // 2 - 2] > level + 1 and row[w // 2 + 1] < level * 4 - 1
        else:  # bright: well under 1 ms, a third of a pixel: untouched
            assert p["exposure_ms"] < 2 and np.array_equal(out, img)
