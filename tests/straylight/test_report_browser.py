"""The study report's interactive 3-D view, opened in a real headless browser.

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
    cfg = StudyConfig(rays=500, seed=2, angles_deg=(0.0, 20.0), scene=str(GOLDEN / "tube.toml"), sweep=False)
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


def _page_screenshot(driver, attempts: int = 5) -> bytes:
    """The page's screenshot once the navigation has settled: Chrome may answer a screenshot taken
    while ``about:blank`` is still being attached with "timeout: aborted by navigation" (seen once in
    a full run); the page itself is not in question, so wait for it and ask again."""
    from selenium.common.exceptions import TimeoutException, WebDriverException

    for attempt in range(attempts):
        try:
            time.sleep(0.2 * attempt)
            if driver.execute_script("return document.readyState") != "complete":
                continue
            return driver.get_screenshot_as_png()
        except (TimeoutException, WebDriverException):
            if attempt == attempts - 1:
                raise
    return driver.get_screenshot_as_png()


def _shot(canvas) -> np.ndarray:
    time.sleep(0.2)  # let the browser composite the last frame
    return _pixels(canvas.screenshot_as_png)


def test_report_3d_view_in_a_browser(driver, report):
    """One test (one study, one browser: pytest-xdist would split separate tests over its workers)."""
    from selenium.webdriver.common.by import By

    # 1. the view renders: a WebGL canvas whose picture differs from a blank page's
    canvas = _open_view(driver, report)
    assert driver.execute_script("return !!arguments[0].getContext('webgl2') || !!arguments[0].getContext('webgl')",
                                 canvas), "no WebGL context"
    w, h = canvas.size["width"], canvas.size["height"]
    assert w > 200 and h > 200, canvas.size
    shot = _shot(canvas)
    driver.switch_to.default_content()
    driver.get("about:blank")
    blank = _pixels(_page_screenshot(driver))[: shot.shape[0], : shot.shape[1]]
    assert blank.shape == shot.shape
    assert _changed(shot, blank) > 0.03, "the 3-D view looks like a blank page"

    # 2. every part is listed with its check box; hiding one changes the picture, showing it restores it
    canvas = _open_view(driver, report)
    assert {"wall", "vane_1", "end_plate", "detector", "entrance"} <= set(driver.execute_script(
        "return window.view3d.parts"))
    before = _shot(canvas)
    box = driver.find_element(By.CSS_SELECTOR, 'input[data-part="wall"]')
    box.click()  # a real click on the panel's check box
    assert driver.execute_script("return window.view3d.isVisible('wall')") is False
    hidden = _shot(canvas)
    assert _changed(before, hidden) > 0.02, "hiding the wall did not change the view"
    box.click()
    assert driver.execute_script("return window.view3d.isVisible('wall')") is True
    assert _changed(before, _shot(canvas)) < 0.002, "showing the wall again did not restore the view"

    # 3. the first ranked path is drawn on opening in its own colour (red); unticking it removes its rays
    box.click()

    def red(img):
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        return int(np.sum((r > 170) & (g < 90) & (b < 90)))

    assert 1 in driver.execute_script("return window.view3d.shownPaths()")
    drawn = red(_shot(canvas))
    driver.find_element(By.CSS_SELECTOR, 'input[data-path="1"]').click()
    assert red(_shot(canvas)) < drawn - 50
    driver.find_element(By.CSS_SELECTOR, 'input[data-path="1"]').click()


def test_the_view_opens_showing_the_light(driver, report):
    """On opening, with nothing clicked, the instrument is cut open, the main paths' rays are drawn
    (each path its own colour, a swatch per path in the panel) and the detector is marked. The screenshot on
    opening is kept in the report folder (view3d_opening.png) for a person to look at."""
    from selenium.webdriver.common.by import By

    canvas = _open_view(driver, report)
    opening = _shot(canvas)
    (report / "view3d_opening.png").write_bytes(canvas.screenshot_as_png)
    shown = driver.execute_script("return window.view3d.shownPaths()")
    assert shown and shown[0] == 1
    colours = {driver.execute_script("return window.view3d.pathColor(arguments[0])", r) for r in shown}
    assert len(colours) == len(shown)  # distinct colours
    swatches = driver.find_elements(By.CSS_SELECTOR, "[data-path-swatch]")
    assert len(swatches) == len(driver.execute_script("return window.view3d.paths"))
    label = driver.find_element(By.CSS_SELECTOR, ".view3d-label")
    assert label.text.startswith("detector: ") and label.is_displayed()
    for rank in shown:  # untick every drawn path: what changes is the rays
        driver.find_element(By.CSS_SELECTOR, f'input[data-path="{rank}"]').click()
    without = _shot(canvas)
    assert _changed(opening, without) > 0.002, "no rays were drawn on opening"
    for rank in shown:
        driver.find_element(By.CSS_SELECTOR, f'input[data-path="{rank}"]').click()
    # cut open: closing the cut (the whole wall) hides more of the inside
    whole = driver.find_element(By.ID, "view3d-cut")
    assert whole.is_selected()
    whole.click()
    closed = _shot(canvas)
    assert _changed(opening, closed) > 0.02, "the cut-open view looks like the closed one"
    whole.click()
