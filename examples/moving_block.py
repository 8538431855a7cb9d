"""
A moving block
==============

A :class:`~pydynrad.RigidObject` is a rigid body that casts shadows, reflects and receives
light. ``DynamicRadiosity`` keeps its patches in the local set; ``move`` gives it a new pose
(a rigid 4 x 4 transform), applied by the next ``update``, without rebuilding anything.
"""

# %%
# The Cornell box, its form factors (of the static scene), a point light and a green cube
# of 100 mm (48 patches).
import os

import matplotlib.pyplot as plt
import numpy as np

import pydynrad

SMALL = os.environ.get("PYDYNRAD_DOCS_SMALL") == "1"
size, poses = (128, 3) if SMALL else (384, 6)

scene = pydynrad.scenes.cornell_box(max_edge=150.0 if SMALL else 100.0)
F = pydynrad.form_factors(scene, resolution=32)
light = pydynrad.PointLight(position=[278, 450, 280], intensity=[0.2] * 3)


def pose(z, degrees):
    """A rigid transform: a turn about the vertical axis, then a move to (160, 230, z)."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = (160.0, 230.0, z)
    return T


cube = pydynrad.RigidObject(pydynrad.scenes.block(100.0, 1, albedo=(0.14, 0.45, 0.091)), pose(460, 0), name="cube")
observer = [278, 273, -200]
dyn = pydynrad.DynamicRadiosity(scene, F, local_size=len(scene) // 2, objects=[cube], observer=observer)

# %%
# Glide the cube forward and turn it. Each frame: ``move`` then ``update``; ``dyn.scene`` is
# the world at the current poses (the static scene plus the objects' patches), which is what
# ``radiosity`` answers for and what ``render`` draws.
camera = pydynrad.Camera(position=[278, 273, -800], look_at=[278, 273, 0], fov_y=39.3, width=size, height=size)
fig, axes = plt.subplots(1, poses, figsize=(3 * poses, 3.3))
for k, ax in enumerate(np.atleast_1d(axes)):
    t = k / (poses - 1)
    dyn.move(cube, pose(460 - 130 * t, 45 * t))
    stats = dyn.update(observer)
    B = dyn.radiosity([light])
    path = f"moving-block-{k}.png"
    pydynrad.image_io.write_image(path, pydynrad.render(dyn.scene, B, camera), exposure=-1.65)
    ax.imshow(plt.imread(path))
    ax.set_title(f"pose {k}")
    ax.axis("off")
fig.tight_layout()
plt.show()

# %%
# The answer at the last pose against a full solve of the same world: the static scene with
# the cube where it now stands (form factors from fresh hemicubes).
world = dyn.scene
full = pydynrad.solve(world, pydynrad.form_factors(world, resolution=32), lights=[light]).radiosity
w = world.areas[:, None]
error = np.sqrt(np.sum(w * (B - full) ** 2) / np.sum(w * full**2))
print(f"{len(world)} patches; relative RMS error against the full solve: {100 * error:.2f}%")
