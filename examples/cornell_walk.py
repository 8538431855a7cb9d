"""
The Cornell walk
================

Dynamic radiosity along a camera path: the camera walks into the Cornell box while a point
light circles above the blocks. The local multibounce matrix over the ``local_size`` patches
nearest the camera follows it frame by frame; the far field lights every other patch.

This is what ``pydynrad demo`` runs, at a smaller size.
"""

# %%
# The scene, its form factors and the walk
# ----------------------------------------
# The Cornell box is in millimetres; ``max_edge`` sets the longest patch edge (100 mm gives
# 1,128 patches, 150 mm about half that). The form factors ``F`` come from one hemicube of
# ``resolution`` x ``resolution`` pixels per patch.
import os

import matplotlib.pyplot as plt
import numpy as np

import pydynrad

SMALL = os.environ.get("PYDYNRAD_DOCS_SMALL") == "1"
frames, size = (6, 96) if SMALL else (24, 256)

scene = pydynrad.scenes.cornell_box(max_edge=150.0 if SMALL else 100.0)
F = pydynrad.form_factors(scene, resolution=32)
print(scene)

# %%
# A camera path through keyframes (Catmull-Rom between them), and a light that moves along
# its own keyframes: both are sampled once per frame.
path = pydynrad.CameraPath(
    positions=[(278, 273, -800), (278, 273, -450), (150, 320, -250), (400, 220, -200)],
    look_ats=[(278, 273, 0), (278, 260, 280), (300, 200, 300), (250, 220, 300)],
    frames=frames,
    fov_y=39.3,
    width=size,
    height=size,
)
orbit = [(130, 420, 130), (130, 420, 430), (430, 420, 430), (430, 420, 130), (130, 420, 130)]
lamp = pydynrad.walks.LightTrack(pydynrad.PointLight(orbit[0], (0.06, 0.05, 0.03)), orbit)

# %%
# Walk it. ``local_size`` is M, the size of the local set; the first and the last frame are
# also solved in full (``reference_frames``) to measure the error of the dynamic answer.
result = pydynrad.walk(
    scene,
    path,
    lights=[lamp],
    form_factors=F,
    local_size=len(scene) * 2 // 3,
    output="cornell-walk",
    exposure=-1.65,
    reference_frames=[0, -1],
    progress=False,
)
print(result.summary())

# %%
# The frames
# ----------
# ``render`` (which ``walk`` calls) returns radiosity per pixel; ``exposure=-1.65``
# (log2 1/pi) writes radiance. The frames are in ``cornell-walk/frame_NNNN.png``.
shown = np.linspace(0, frames - 1, 3).round().astype(int)
fig, axes = plt.subplots(1, len(shown), figsize=(9, 3.2))
for ax, i in zip(axes, shown):
    ax.imshow(plt.imread(f"cornell-walk/frame_{i:04d}.png"))
    ax.set_title(f"frame {i}")
    ax.axis("off")
fig.tight_layout()
plt.show()

# %%
# At the reference frames the walk also wrote ``compare_NNNN.png``: rows local only (the
# paper's method) and with the far field; columns dynamic | full | relative error.
fig, ax = plt.subplots(figsize=(9, 6))
ax.imshow(plt.imread(f"cornell-walk/compare_{frames - 1:04d}.png"))
ax.axis("off")
plt.show()
