"""Comparison pictures readable alone: titled rows and columns, each row on its own
error scale with its colour bar."""

import numpy as np

import pydynrad
from pydynrad.comparison import comparison_image, reference_frame


def test_titles_add_a_band_of_text_above_the_panels():
    h, w = 120, 160
    ref = np.full((h, w, 3), 0.5, dtype=np.float32)
    plain, _ = comparison_image(ref * 1.1, ref, exposure=0.0, vmax=0.2)
    titled, stats = comparison_image(ref * 1.1, ref, exposure=0.0, vmax=0.2, titles=("dynamic", "full solve", "error"))
    band = titled.shape[0] - h
    assert band > 0 and titled.shape[1] == plain.shape[1]
    np.testing.assert_array_equal(titled[band:], plain)  # the panels unchanged below the band
    gap = max(2, w // 64)
    for k in range(3):  # white text over each of the three panels
        assert titled[:band, k * (w + gap) : (k + 1) * w + k * gap].max() > 0.5, k


def test_each_row_has_its_own_scale(device):
    scene = pydynrad.scenes.cornell_box(max_edge=250.0)
    F = pydynrad.form_factors(scene, resolution=8, device=device, progress=False)
    light = pydynrad.PointLight([278, 450, 280], 0.2)
    dyn = pydynrad.DynamicRadiosity(scene, F, local_size=60, device=device)
    cam = pydynrad.Camera([278, 273, -800], [278, 273, 0], fov_y=39.3, width=64, height=48)
    dyn.update(cam.position)
    ref = reference_frame(
        scene,
        F,
        dyn.radiosity([light]),
        cam,
        lights=[light],
        local_only=dyn.radiosity([light], far_field=False),
        device=device,
    )
    # Independent of the picture: the rows' scales are their own 99th percentiles.
    assert ref.local_only_pixel_error["vmax"] == max(ref.local_only_pixel_error["p99"], 1e-3)
    assert ref.pixel_error["vmax"] == max(ref.pixel_error["p99"], 1e-3)
    assert ref.pixel_error["vmax"] < ref.local_only_pixel_error["vmax"]
    assert ref.image.shape[0] > 2 * 48 and ref.exposure != 0.0
