"""The viewer in a real browser: headless Chromium driven by selenium (Debian's ``chromium`` and
``chromium-driver``; ``.ci/run`` installs them with apt-get where they are missing).

On the Cornell box and a small village: the page draws, a camera move from the test changes the
picture and the local set follows it, a sun set on the page's controls relights it, and nothing
reaches the browser's console. With ``PYDYNRAD_VIEWER_SHOTS=DIR`` the screenshots are kept in DIR
(docs/_static holds the documentation's copies: docs/guide/viewer.md).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

import pydynrad
from pydynrad.viewer import view


def _browser() -> tuple[str, str] | None:
    chrome = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
    driver = shutil.which("chromedriver")
    return (chrome, driver) if chrome and driver else None


_MISSING = [name for name in ("selenium", "websockets") if importlib.util.find_spec(name) is None]
pytestmark = [
    pytest.mark.skipif(
        bool(_MISSING), reason=f"the viewer test needs {', '.join(_MISSING)}: pip install 'pydynrad[view]' selenium"
    ),
    pytest.mark.skipif(
        _browser() is None,
        reason="no Chromium and chromedriver on PATH (Debian: apt-get install chromium chromium-driver)",
    ),
]

SHOTS = os.environ.get("PYDYNRAD_VIEWER_SHOTS")


@pytest.fixture(scope="module")
def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    chrome, driver = _browser()
    options = Options()
    options.binary_location = chrome
    # WebGL 2 without a GPU: ANGLE on SwiftShader, which Chromium enables only when asked.
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--window-size=1000,640",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--ignore-gpu-blocklist",
        "--hide-scrollbars",
    ):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    d = webdriver.Chrome(service=Service(driver), options=options)
    yield d
    d.quit()


def _wait(predicate, timeout: float = 30.0, what: str = "the page"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _open(browser, viewer):
    browser.get(viewer.url)
    _wait(
        lambda: browser.execute_script(
            "return window.pydynrad && window.pydynrad.stats.framesReceived > 0 && window.pydynrad.stats.drawn > 0"
        ),
        what="the first frame drawn",
    )


def _frames_received(browser) -> int:
    return browser.execute_script("return window.pydynrad.stats.framesReceived")


def _settled(browser, viewer) -> dict:
    """The solver caught up with the browser's camera and the browser drew its last frame."""
    stats = viewer.wait_idle(timeout=60)
    _wait(
        lambda: browser.execute_script("return window.pydynrad.stats.lastFrame") >= stats["frame"],
        what="the last frame to reach the browser",
    )
    time.sleep(0.8)  # the exposure's easing (0.15 s time constant)
    return stats


def _shot(viewer, name: str) -> np.ndarray:
    image = viewer.screenshot(Path(SHOTS) / f"viewer-{name}.png" if SHOTS else None)
    return image[..., :3].astype(np.float64)


def _console_errors(browser) -> list:
    return [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]


def _distance_to_local(viewer, point) -> float:
    centres = viewer.dynamic.scene.centers[viewer.dynamic.local_patches]
    return float(np.median(np.linalg.norm(centres - np.asarray(point), axis=1)))


def _set_sun_on_page(browser, elevation: float, azimuth: float, irradiance: float) -> None:
    browser.execute_script(
        """
        const [el, az, irr] = arguments;
        document.getElementById('sun-on').checked = true;
        document.getElementById('sun-elevation').value = el;
        document.getElementById('sun-azimuth').value = az;
        document.getElementById('sun-irradiance').value = irr;
        document.getElementById('sun-azimuth').dispatchEvent(new Event('input'));""",
        elevation,
        azimuth,
        irradiance,
    )


def _check_walkthrough(browser, viewer, far_camera, near_camera, sun, name: str) -> None:
    """Open, move the camera from far to near from the page, then relight with the sun from the page."""
    _open(browser, viewer)
    browser.execute_script("window.pydynrad.setCamera(arguments[0], arguments[1])", *far_camera)
    _settled(browser, viewer)
    far_local = set(viewer.dynamic.local_patches.tolist())
    before = _distance_to_local(viewer, near_camera[0])
    a = _shot(viewer, f"{name}-far")

    browser.execute_script("window.pydynrad.setCamera(arguments[0], arguments[1])", *near_camera)
    stats = _settled(browser, viewer)
    assert np.allclose(viewer.camera.position, near_camera[0], atol=1e-3 * viewer.dynamic.scene.scale)
    near_local = set(viewer.dynamic.local_patches.tolist())
    after = _distance_to_local(viewer, near_camera[0])
    b = _shot(viewer, f"{name}-near")
    assert near_local != far_local, "the local set did not move with the camera"
    assert after < 0.8 * before, f"the local set did not come nearer the camera: median distance {before} -> {after}"
    assert np.abs(a - b).mean() > 2.0, "the picture did not change with the camera"

    lit = viewer.dynamic.radiosity(viewer.lights).sum()
    frames = _frames_received(browser)
    _set_sun_on_page(browser, *sun)
    _wait(
        lambda: viewer.lights and any(isinstance(x, pydynrad.DirectionalLight) for x in viewer.lights),
        what="the page's sun to reach the viewer",
    )
    stats = _settled(browser, viewer)
    assert _frames_received(browser) > frames
    relit = viewer.dynamic.radiosity(viewer.lights).sum()
    c = _shot(viewer, f"{name}-sun")
    assert relit > 1.05 * lit, f"the sun did not relight the scene: {lit} -> {relit}"
    assert np.abs(c - b).mean() > 2.0, "the picture did not change with the sun"
    assert stats["M"] == viewer.dynamic.M and stats["t_frame"] > 0
    if SHOTS:
        browser.save_screenshot(str(Path(SHOTS) / f"viewer-{name}-page.png"))
    assert not _console_errors(browser)


def test_cornell_box_in_chromium(browser):
    scene = pydynrad.scenes.cornell_box(max_edge=100.0)
    F = pydynrad.form_factors(scene, resolution=16)
    with view(scene, F, port=0, local_size=192) as viewer:
        # Outside the open side, then inside near the back wall; a low sun from the north (-z)
        # shines in through the open side.
        _check_walkthrough(
            browser,
            viewer,
            ([278, 273, -900], [278, 273, 0]),
            ([450, 330, 480], [150, 120, 150]),
            (20.0, 0.0, 40.0),
            "cornell",
        )
        viewer.set_overlay("local")
        stats = viewer.wait_idle()
        assert stats["local"] == viewer.dynamic.M
        assert not _console_errors(browser)


def test_village_in_chromium(browser):
    scene = pydynrad.scenes.village(houses=2, detail=0.25)
    F = pydynrad.form_factors(scene, resolution=16)
    lo, hi = scene.bbox
    with view(scene, F, port=0, local_size=256) as viewer:
        # Over one end of the street at eye height, then the other; the sun high in the south-east.
        far = ([lo[0] + 2.0, 1.7, 2.5], [lo[0] + 8.0, 1.7, 2.5])
        near = ([hi[0] - 2.0, 1.7, 2.5], [hi[0] - 8.0, 1.7, 6.0])
        _check_walkthrough(browser, viewer, far, near, (45.0, 135.0, 40.0), "village")
        assert viewer.stats["clients"], "the browser reported no statistics"
