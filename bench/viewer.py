"""The viewer's targets, on the 66k-patch village at the default M, in one run.

* radiosity updates per second that reach the browser while the camera moves (target >= 10);
* a camera move to its first radiosity on the page, median and 90th percentile (target <= 200 ms);
* the browser's own frame rate with the solver idle and while it works (independent of it);
* the solver's frame (update + lighting) inside the viewer against the same frames in
  :func:`pydynrad.walk` without images written (target: within 1.5x).

Needs the ``view`` extra, selenium and a Chromium with chromedriver (headless, WebGL on
SwiftShader), and the village's form factors::

    pydynrad formfactors village -o village32.npz --resolution 32
    python -m bench.viewer village32.npz
"""

from __future__ import annotations

import argparse
import json
import shutil
import time

import numpy as np

#: Metres per second the browser's camera flies along the street (a brisk walk), for SECONDS.
SPEED, SECONDS = 2.0, 12.0
EYE = 1.7


def _browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--window-size=960,600",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--ignore-gpu-blocklist",
    ):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=options)


FLY = """
const [x0, x1, y, z, speed, seconds] = arguments, done = arguments[arguments.length - 1];
const t0 = performance.now(), lat0 = window.pydynrad.stats.latencies.length, got0 = window.pydynrad.stats.framesReceived;
let frames = 0;
function step(now) {
  const t = (now - t0) / 1e3, x = Math.min(x1, x0 + speed * t);
  window.pydynrad.setCamera([x, y, z], [x + 6, y, z + 0.5]);
  frames++;
  if (t < seconds) requestAnimationFrame(step);
  else done({ seconds: t, browserFrames: frames, received: window.pydynrad.stats.framesReceived - got0,
              latencies: window.pydynrad.stats.latencies.slice(lat0) });
}
requestAnimationFrame(step);
"""

IDLE_FPS = """
const done = arguments[arguments.length - 1], t0 = performance.now();
let frames = 0;
function step(now) { frames++; if (now - t0 < 3000) requestAnimationFrame(step); else done(frames * 1e3 / (now - t0)); }
requestAnimationFrame(step);
"""


def main(argv=None) -> int:
    import pydynrad
    from pydynrad.rows.files import open_form_factors
    from pydynrad.viewer import view

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("form_factors", help="the village's F (.npz from pydynrad formfactors village)")
    ap.add_argument("--local-size", type=int, default=1024)
    ap.add_argument("--json", default=None, help="also write the numbers here")
    args = ap.parse_args(argv)

    scene = pydynrad.scenes.village()
    F = open_form_factors(scene, args.form_factors)
    x0, x1 = 1.0, 1.0 + SPEED * SECONDS
    lights = []  # the village's lamps (emission)

    # walk(): the same street, one frame per 1/10 s of the flight, no images written.
    frames = int(SECONDS * 10)
    xs = np.linspace(x0, x1, frames)
    path = pydynrad.CameraPath(
        [[x, EYE, 2.5] for x in xs], [[x + 6, EYE, 3.0] for x in xs], frames, width=64, height=48
    )
    dyn = pydynrad.DynamicRadiosity(scene, F, local_size=args.local_size, observer=[x0, EYE, 2.5])
    result = pydynrad.walk(scene, path, dyn, lights=lights, progress=False)
    walk_frames = np.array([r.seconds["update"] + r.seconds["lighting"] for r in result.frames[2:]])
    walk_swaps = np.array([r.stats.swaps for r in result.frames[2:]])

    dyn = pydynrad.DynamicRadiosity(scene, F, local_size=args.local_size, observer=[x0, EYE, 2.5])
    driver = _browser()
    out = {}
    try:
        with view(dyn, F, lights=lights, port=0) as viewer:
            driver.get(viewer.url)
            t0 = time.monotonic()
            while driver.execute_script("return window.pydynrad.stats.framesReceived") < 1:
                time.sleep(0.05)
            first = time.monotonic() - t0
            driver.execute_script(
                "window.pydynrad.setCamera(arguments[0], arguments[1])", [x0, EYE, 2.5], [x0 + 6, EYE, 3.0]
            )
            viewer.wait_idle()
            driver.set_script_timeout(120)
            idle_fps = driver.execute_async_script(IDLE_FPS)
            n0 = len(viewer.history)
            fly = driver.execute_async_script(FLY, x0, x1, EYE, 2.5, SPEED, SECONDS)
            viewer.wait_idle()
            hist = viewer.history[n0:]
            view_frames = np.array([h["t_frame"] for h in hist])
            moving = np.array([h["swaps"] > 0 for h in hist])
            colours = np.array([h["t_colours"] for h in hist])
            lat = np.array(fly["latencies"])
            out = {
                "patches": len(scene),
                "M": dyn.M,
                "page_first_frame_s": first,
                "updates_per_second_in_browser": fly["received"] / fly["seconds"],
                "latency_ms_median": float(np.median(lat)),
                "latency_ms_p90": float(np.percentile(lat, 90)),
                "browser_fps_idle": idle_fps,
                "browser_fps_while_solving": fly["browserFrames"] / fly["seconds"],
                "viewer_frame_ms_median": 1e3 * float(np.median(view_frames[moving])) if moving.any() else None,
                "viewer_colours_ms_median": 1e3 * float(np.median(colours)),
                "walk_frame_ms_median": 1e3 * float(np.median(walk_frames[walk_swaps > 0])),
                "solver_frames_in_viewer": len(hist),
            }
            out["viewer_over_walk"] = out["viewer_frame_ms_median"] / out["walk_frame_ms_median"]
            out["viewer_with_colours_over_walk"] = (
                out["viewer_frame_ms_median"] + out["viewer_colours_ms_median"]
            ) / out["walk_frame_ms_median"]
        # The same flight driven from Python with no browser connected: the viewer's own overhead,
        # without a software-rendering browser sharing the CPU cores.
        dyn = pydynrad.DynamicRadiosity(scene, F, local_size=args.local_size, observer=[x0, EYE, 2.5])
        with view(dyn, F, lights=lights, port=0) as viewer:
            viewer.set_camera([x0, EYE, 2.5], [x0 + 6, EYE, 3.0])
            viewer.wait_idle()
            n0, t0 = len(viewer.history), time.monotonic()
            while (t := time.monotonic() - t0) < SECONDS:
                x = min(x1, x0 + SPEED * t)
                viewer.set_camera([x, EYE, 2.5], [x + 6, EYE, 3.0])
                time.sleep(1 / 30)
            viewer.wait_idle()
            hist = [h for h in viewer.history[n0:] if h["swaps"] > 0]
            out["viewer_frame_ms_median_no_browser"] = 1e3 * float(np.median([h["t_frame"] for h in hist]))
            out["viewer_no_browser_over_walk"] = out["viewer_frame_ms_median_no_browser"] / out["walk_frame_ms_median"]
    finally:
        driver.quit()
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
