"""The static HTML QA report (dataset_tools.qa.html_report): built for the tiny data set, regenerated
incrementally, and loaded in headless Chromium (Debian's chromium + chromium-driver, installed by
`make browser` when missing)."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from dataset_tools.format.layout import AUDIT, REPORT_DIR, FrameFiles
from dataset_tools.format.png import read_png
from dataset_tools.qa.html_report import build_report, report_size

ROOT = Path(__file__).resolve().parents[1]
CHROME_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--window-size=1400,1000")


def write_ego_mask(frame_dir: Path, camera: str) -> None:
    """A self-occlusion mask (255 on the ego body: here the image's bottom fifth)."""
    files = FrameFiles(frame_dir)
    h, w = read_png(files.camera_png(camera)).shape[:2]
    mask = np.zeros((h, w), np.uint8)
    mask[-max(1, h // 5):] = 255
    assert cv2.imwrite(str(files.camera_ego_mask(camera)), mask)


@pytest.fixture(scope="module")
def report(tiny_dataset, tmp_path_factory):
    """A copy of the tiny data set with an audit.json and its report."""
    data = tmp_path_factory.mktemp("report") / "ds"
    shutil.copytree(tiny_dataset, data)
    frames = sorted(p.parent.relative_to(data).as_posix() for p in data.glob("*/*/meta.json"))
    audit = {"frames": {n: {"visible_no_los": 0.2 if i == 0 else 0.01, "los_invisible": 0.02} for i, n in enumerate(frames)},
             "overall": {"visible_no_los": 0.03, "los_invisible": 0.02}, "threshold": 0.1}
    (data / AUDIT).write_text(json.dumps(audit))
    # frames[1] keeps the ego masks the renderer wrote; the others lose theirs (a data set of
    # another renderer), so both kinds of frame are in the report
    assert all(FrameFiles(data / frames[1]).camera_ego_mask(c).is_file() for c in ("front", "left", "rear", "right"))
    for name in frames:
        if name != frames[1]:
            for p in (data / name).glob("cam_*_ego.png"):
                p.unlink()
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "report", str(data), "--no-progress"], cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return data, data / REPORT_DIR, frames


def test_report_pages_and_files(report):
    data, out, frames = report
    index = (out / "index.html").read_text()
    scenes = sorted({f.split("/")[0] for f in frames})
    for s in scenes:
        assert f'href="scenes/{s}.html"' in index
        assert (out / "scenes" / f"{s}.html").is_file() and (out / "scenes" / f"{s}_sheet.webp").stat().st_size > 0
    # the audit's failing frame (visible_no_los 0.2 > 0.1) is linked from the overview
    first = frames[0].split("/")
    assert f'href="scenes/{first[0]}.html#{first[1]}"' in index
    for name in frames:
        info = json.loads((out / "frames" / name / "info.json").read_text())
        assert set(info["cameras"]) == {"front", "left", "rear", "right"}
        for cam, passes in info["images"].items():
            assert {"rgb", "semantic", "instance", "distance"} <= set(passes)
            assert ("ego" in passes) == (name == frames[1])
        assert all((out / "frames" / name / f).stat().st_size > 0 for f in info["bev"].values())
        cells = (out / "frames" / name / "cells.js").read_text()
        assert cells.startswith(f'REPORT.cells["{name}"]') and len(cells) < 50_000
    for fig in ("rig.png", "render_time.png", "class_frequencies.png", "visibility_histogram.png"):
        assert (out / "overview" / fig).stat().st_size > 0
    assert report_size(out) < 5e6


def test_report_incremental(report, tmp_path):
    frames = report[2]
    data = tmp_path / "ds"  # its own copy: this test adds an input
    shutil.copytree(report[0], data, ignore=shutil.ignore_patterns(REPORT_DIR))
    out = tmp_path / "r"
    build_report(data, out, frames_per_scene=1, progress=False)
    infos = sorted(out.glob("frames/*/*/info.json"))
    assert len(infos) == len({f.split("/")[0] for f in frames})  # one frame per scene
    before = {p: p.stat().st_mtime_ns for p in infos}
    time.sleep(0.05)
    build_report(data, out, frames_per_scene=1, progress=False)
    assert {p: p.stat().st_mtime_ns for p in infos} == before  # nothing redone
    # a new input (an ego mask) makes that frame, and only it, be redone
    changed = infos[0]
    frame_dir = data / changed.parent.relative_to(out / "frames")
    write_ego_mask(frame_dir, "rear")
    os.utime(FrameFiles(frame_dir).camera_ego_mask("rear"), (time.time() + 5, time.time() + 5))
    build_report(data, out, frames_per_scene=1, progress=False)
    after = {p: p.stat().st_mtime_ns for p in infos}
    assert after[changed] != before[changed] and all(after[p] == before[p] for p in infos[1:])
    assert json.loads(changed.read_text())["images"]["rear"]["ego"] == "cam_rear_ego.webp"


def test_report_no_audit_and_bad_input(tiny_dataset, tmp_path):
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "report", str(tmp_path / "nothing")], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    data = tmp_path / "ds"
    shutil.copytree(tiny_dataset, data)
    (data / AUDIT).write_text("[1, 2")
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "report", str(data), "--frames-per-scene", "1"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and AUDIT in r.stderr and "Traceback" not in r.stderr
    (data / AUDIT).unlink()
    build_report(data, frames_per_scene=1, progress=False)
    assert "no audit yet (python -m dataset_tools audit DATA)" in (data / REPORT_DIR / "index.html").read_text()


# ---------------------------------------------------------------- in the browser


def _browser():
    if not (shutil.which("chromium") and shutil.which("chromedriver")):
        subprocess.run(["make", "-s", "browser"], cwd=ROOT, check=False, timeout=900)
    if not (shutil.which("chromium") and shutil.which("chromedriver")):
        pytest.fail("chromium / chromedriver missing and `make browser` could not install them")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium")
    for f in CHROME_FLAGS:
        opts.add_argument(f)
    return webdriver, opts, Service(shutil.which("chromedriver"))


def _all_images_loaded(driver):
    """(number of images, [src of every broken one]) once every image has finished loading."""
    return driver.execute_async_script("""
        var done = arguments[arguments.length - 1], imgs = Array.from(document.images);
        Promise.all(imgs.map(function (i) { return i.complete ? 0 : new Promise(function (r) { i.onload = i.onerror = r; }); }))
          .then(function () { done([imgs.length, imgs.filter(function (i) { return i.naturalWidth === 0; }).map(function (i) { return i.src; })]); });
    """)


def _screenshot(driver, path):
    """The whole page (the window grown to the page's height, at most 4000 px)."""
    driver.execute_script("window.scrollTo(0, 0)")
    # the window is the viewport plus the browser's own frame
    h = driver.execute_script("return document.documentElement.scrollHeight + window.outerHeight - window.innerHeight")
    driver.set_window_size(1400, min(max(h, 600), 4000))
    ok = driver.save_screenshot(str(path))
    driver.set_window_size(1400, 1000)
    return ok


def _severe(driver):
    return [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def test_report_in_chromium(report, tmp_path):
    data, out, frames = report
    webdriver, opts, service = _browser()
    opts.add_argument(f"--user-data-dir={tmp_path / 'profile'}")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    shots = Path(os.environ.get("REPORT_SCREENSHOTS", tmp_path))
    driver = webdriver.Chrome(options=opts, service=service)
    try:
        driver.set_script_timeout(30)
        driver.get((out / "index.html").as_uri())
        n, broken = _all_images_loaded(driver)
        assert n >= 6 and broken == []
        assert driver.find_element("css selector", "h1").text.startswith("Label QA")
        assert _screenshot(driver, shots / "report_overview.png")
        assert _severe(driver) == []

        scene, frame = frames[1].split("/")
        driver.get((out / "scenes" / f"{scene}.html").as_uri() + f"#{frame}")
        n, broken = _all_images_loaded(driver)
        assert n >= 4 + 6 and broken == []
        assert frame in driver.find_element("id", "frame-title").text
        cam = driver.find_element("css selector", "#cameras img")
        src, pixels = cam.get_attribute("src"), cam.screenshot_as_png
        assert src.endswith("_rgb.webp")
        driver.find_element("css selector", "#passes button[data-pass=semantic]").click()
        n, broken = _all_images_loaded(driver)
        cam = driver.find_element("css selector", "#cameras img")
        assert broken == [] and cam.get_attribute("src") != src and "_semantic." in cam.get_attribute("src")
        assert cam.screenshot_as_png != pixels  # the picture itself changed, not only its name
        driver.find_element("css selector", "#passes button[data-pass=ego]").click()
        assert _all_images_loaded(driver)[1] == []
        assert driver.find_element("css selector", "#cameras img").get_attribute("src").endswith("_ego.webp")
        # hovering a BEV cell reads it out of cells.js
        from selenium.webdriver import ActionChains

        bev = driver.find_element("css selector", "#bev img")
        ActionChains(driver).move_to_element_with_offset(bev, 5, 5).click().perform()
        text = driver.find_element("id", "cell").text
        assert "class:" in text and "p(o):" in text and "seen by:" in text
        # the frame strip switches frames; frames[0] has no ego masks: its ego button is off
        driver.find_element("css selector", "button.thumb[data-frame='0']").click()
        assert frames[0].split("/")[1] in driver.find_element("id", "frame-title").text
        assert not driver.find_element("css selector", "#passes button[data-pass=ego]").is_enabled()
        assert _all_images_loaded(driver)[1] == []
        driver.find_element("css selector", "button.thumb[data-frame='1']").click()
        assert _screenshot(driver, shots / "report_scene.png")
        assert _severe(driver) == []
    finally:
        driver.quit()
    assert (shots / "report_scene.png").stat().st_size > 10_000


def test_report_in_two_processes_writes_the_same_frames(report, tmp_path):
    """The frames' pictures drawn by a pool of 2 processes (what the dataset pipeline does) are the
    files one process draws, byte for byte (info.json's timings aside: none are written)."""
    data = report[0]
    one, two = tmp_path / "one", tmp_path / "two"
    build_report(data, one, frames_per_scene=1, progress=False)
    build_report(data, two, frames_per_scene=1, progress=False, workers=2)
    files = sorted(p.relative_to(one) for p in (one / "frames").rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(two) for p in (two / "frames").rglob("*") if p.is_file())
    assert all((one / f).read_bytes() == (two / f).read_bytes() for f in files)
