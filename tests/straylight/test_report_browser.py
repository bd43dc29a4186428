"""The study report's interactive 3-D view, opened in a real headless browser (issue #28).

Debian's ``chromium`` and ``chromium-driver`` (installed by .ci/run) driven by Selenium: the report's
``index.html`` is opened from disk (file://, no server, no network), the view's WebGL canvas must
show the instrument (its screenshot differs from a blank page's), hiding a part through its check
box must change the picture and restore it when shown again, and ticking a ranked path must draw
its sample rays (red pixels). Skipped, with the reason, only where no browser is installed.
"""
from __future__ import annotations

import io
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"
CHROMIUM = ("/usr/bin/chromium", "/usr/bin/chromium-browser")
CHROMEDRIVER = "/usr/bin/chromedriver"


def _browser_paths():
    binary = next((p for p in CHROMIUM if Path(p).exists()), shutil.which("chromium"))
    driver = CHROMEDRIVER if Path(CHROMEDRIVER).exists() else shutil.which("chromedriver")
    return binary, driver


@pytest.fixture(scope="module")
def driver():
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install -e '.[test]')")
    from selenium.webdriver.chrome.service import Service

    binary, chromedriver = _browser_paths()
    if binary is None or chromedriver is None:
        pytest.skip("no browser: Debian's chromium and chromium-driver are not installed "
                    "(apt-get install -y chromium chromium-driver; .ci/run does this where apt is available)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1200,900",
                # WebGL without a GPU: SwiftShader through ANGLE
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                # a closed network: no background connections
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--no-first-run", "--disable-quic"):
        opts.add_argument(arg)
    drv = webdriver.Chrome(service=Service(chromedriver), options=opts)
    try:
        yield drv
    finally:
        drv.quit()


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from straylight.analyses.report import StudyConfig, run_study

    out = tmp_path_factory.mktemp("report")
    cfg = StudyConfig(rays=500, seed=2, angles_deg=(0.0, 20.0), scene=str(GOLDEN / "tube.toml"), sweep=False,
                      progress=False)
    run_study(out, cfg)
    return out


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _changed(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels whose colour differs by more than 24 (of 255) in some channel."""
    return float(np.mean(np.abs(a - b).max(axis=2) > 24))


def _open_view(driver, report):
    from selenium.webdriver.common.by import By

    driver.get((report / "index.html").as_uri())
    frame = driver.find_element(By.ID, "view3d-frame")
    driver.execute_script("arguments[0].scrollIntoView(true);", frame)
    driver.switch_to.frame(frame)
    deadline = time.monotonic() + 30
    while not driver.execute_script("return !!(window.view3d && window.view3d.ready)"):
        assert time.monotonic() < deadline, "the 3-D view did not start within 30 s"
        time.sleep(0.1)
    return driver.find_element(By.ID, "view3d-canvas")


def _shot(canvas) -> np.ndarray:
    time.sleep(0.2)  # let the browser composite the last frame
    return _pixels(canvas.screenshot_as_png)


def test_report_view_renders_webgl(driver, report):
    canvas = _open_view(driver, report)
    assert driver.execute_script("return !!arguments[0].getContext('webgl2') || !!arguments[0].getContext('webgl')",
                                 canvas), "no WebGL context"
    w, h = canvas.size["width"], canvas.size["height"]
    assert w > 200 and h > 200, canvas.size
    shot = _shot(canvas)
    # the same area of a blank page (what a canvas that drew nothing looks like)
    driver.switch_to.default_content()
    driver.get("about:blank")
    driver.set_window_size(1200, 900)
    blank = _pixels(driver.get_screenshot_as_png())[: shot.shape[0], : shot.shape[1]]
    assert blank.shape == shot.shape
    assert _changed(shot, blank) > 0.03, "the 3-D view looks like a blank page"
    # every part of the scene is listed in the panel, with its check box
    canvas = _open_view(driver, report)
    parts = driver.execute_script("return window.view3d.parts")
    assert {"wall", "vane_1", "end_plate", "detector", "entrance"} <= set(parts)


def test_hiding_a_part_changes_the_picture(driver, report):
    from selenium.webdriver.common.by import By

    canvas = _open_view(driver, report)
    before = _shot(canvas)
    box = driver.find_element(By.CSS_SELECTOR, 'input[data-part="wall"]')
    box.click()  # a real click on the panel's check box
    assert driver.execute_script("return window.view3d.isVisible('wall')") is False
    hidden = _shot(canvas)
    assert _changed(before, hidden) > 0.02, "hiding the wall did not change the view"
    box.click()
    assert driver.execute_script("return window.view3d.isVisible('wall')") is True
    again = _shot(canvas)
    assert _changed(before, again) < 0.002, "showing the wall again did not restore the view"


def test_selecting_a_ranked_path_draws_its_rays(driver, report):
    from selenium.webdriver.common.by import By

    canvas = _open_view(driver, report)
    driver.find_element(By.CSS_SELECTOR, 'input[data-part="wall"]').click()  # look inside the tube

    def red(img):
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        return int(np.sum((r > 170) & (g < 90) & (b < 90)))

    before = red(_shot(canvas))
    driver.find_element(By.CSS_SELECTOR, 'input[data-path="1"]').click()
    after = red(_shot(canvas))
    assert after > before + 50, (before, after)


def test_report_tables_as_csv(report):
    """Each table of index.html is also table_<name>.csv, with the numbers of results.json."""
    import csv
    import json

    page = (report / "index.html").read_text()
    doc = json.loads((report / "results.json").read_text())
    for name in ("pst", "paths", "ancestry", "critical"):
        assert f'href="table_{name}.csv"' in page, name
    with open(report / "table_pst.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["off_axis_deg"]) for r in rows] == [p["off_axis_deg"] for p in doc["pst"]["points"]]
    assert [float(r["pst"]) for r in rows] == [p["pst"] for p in doc["pst"]["points"]]
    assert [r["flags"] for r in rows] == [p["flags"] for p in doc["pst"]["points"]]
    with open(report / "table_paths.csv", newline="") as fh:
        paths = list(csv.DictReader(fh))
    assert [r["path"] for r in paths][:5] == [g["label"] for g in doc["paths"]["groups"]][:5]
    assert sum(float(r["fraction"]) for r in paths) == pytest.approx(1.0, rel=1e-9)
    with open(report / "table_critical.csv", newline="") as fh:
        parts = {r["part"]: float(r["view_factor"]) for r in csv.DictReader(fh)}
    assert parts == {p["part"]: p["view_factor"] for p in doc["critical"]["parts"]}
