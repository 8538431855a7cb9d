"""
The far field on and off
========================

The paper's method lights only the local set (the M patches nearest the observer) by
multibounce; every other patch shows emitted and direct light only. The far field (the
default) lights them too, from a coarse level of clusters of the whole scene. This example
measures both against a full radiosity solve.
"""

# %%
# One scene, one F, one light, one observer.
import os

import matplotlib.pyplot as plt
import numpy as np

import pydynrad

SMALL = os.environ.get("PYDYNRAD_DOCS_SMALL") == "1"
size = 128 if SMALL else 384

scene = pydynrad.scenes.cornell_box(max_edge=150.0 if SMALL else 100.0)
F = pydynrad.form_factors(scene, resolution=32)
light = pydynrad.PointLight(position=[278, 450, 280], intensity=[0.2] * 3)
observer = [278, 273, -200]

# %%
# The reference: the full radiosity solution over every patch.
full = pydynrad.solve(scene, F, lights=[light]).radiosity

# %%
# Dynamic radiosity with a local set of half the patches. ``radiosity()`` answers with the
# far field; ``radiosity(far_field=False)`` gives the paper's answer from the same matrix.
dyn = pydynrad.DynamicRadiosity(scene, F, local_size=len(scene) // 2, observer=observer)
dyn.update(observer)
with_far = dyn.radiosity([light])
local_only = dyn.radiosity([light], far_field=False)


def relative_error(B, reference):
    """Area-weighted relative RMS error over the patches."""
    w = scene.areas[:, None]
    return float(np.sqrt(np.sum(w * (B - reference) ** 2) / np.sum(w * reference**2)))


for name, B in (("far field", with_far), ("local only", local_only)):
    print(f"{name:10s}: relative RMS error {100 * relative_error(B, full):.2f}% against the full solve")

# %%
# The three answers from a camera that sees the whole box. The local set is the half of the
# box nearest the observer at the open side: the back wall is outside it, and without the far
# field it gets no indirect light.
camera = pydynrad.Camera(position=[278, 273, -800], look_at=[278, 273, 0], fov_y=39.3, width=size, height=size)
names = ("full solve", "far field", "local only")
fig, axes = plt.subplots(1, 3, figsize=(9, 3.3))
for ax, name, B in zip(axes, names, (full, with_far, local_only)):
    path = f"far-field-{name.replace(' ', '-')}.png"
    pydynrad.image_io.write_image(path, pydynrad.render(scene, B, camera), exposure=-1.65)
    ax.imshow(plt.imread(path))
    ax.set_title(name if B is full else f"{name}: {100 * relative_error(B, full):.2g}% off")
    ax.axis("off")
fig.tight_layout()
plt.show()
