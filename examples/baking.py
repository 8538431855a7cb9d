"""
Baking: vertex colours and a lightmap
=====================================

A radiosity solution as files other tools open: a mesh with per-vertex colours (``.glb`` or
``.ply``), and a lightmap (a linear EXR image) with a ``.glb`` that carries its UVs in
``TEXCOORD_1`` and the lightmap embedded as an 8-bit sRGB texture.
"""

# %%
# The Cornell box solved in full with a point light.
import os

import matplotlib.pyplot as plt
import trimesh

import pydynrad

SMALL = os.environ.get("PYDYNRAD_DOCS_SMALL") == "1"
scene = pydynrad.scenes.cornell_box(max_edge=150.0 if SMALL else 100.0)
light = pydynrad.PointLight(position=[278, 450, 280], intensity=[0.2] * 3)
B = pydynrad.solve(scene, pydynrad.form_factors(scene, resolution=32), lights=[light]).radiosity

# %%
# Vertex colours: linear radiosity is stored unscaled beside display colours at the
# exposure (``-1.65``, log2 1/pi, shows radiance). Any glTF viewer opens the file.
pydynrad.export_mesh(scene, B, "cbox.glb", exposure=-1.65)
mesh = trimesh.load("cbox.glb", force="mesh")
print(f"cbox.glb: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles")

# %%
# A lightmap at 0.1 texels per millimetre (one texel per 10 mm; 0.2 in the full-size run):
# UV charts from xatlas, the solution rasterised into them, padded by dilation.
lm = pydynrad.bake_lightmap(scene, B, texels_per_unit=0.1 if SMALL else 0.2)
lm.write("cbox-lightmap.exr")
lm.write_mesh("cbox-lightmap.glb", exposure=-1.65, image_name="cbox-lightmap.exr")
h, w = lm.shape
print(f"lightmap {w} x {h} texels, {100 * lm.coverage:.0f}% in charts")

# %%
# The lightmap's texels written as a PNG at the same exposure, to look at.
pydynrad.image_io.write_image("cbox-lightmap.png", lm.image, exposure=-1.65)
fig, ax = plt.subplots(figsize=(5, 5 * h / w))
ax.imshow(plt.imread("cbox-lightmap.png"))
ax.set_title("cbox-lightmap.exr")
ax.axis("off")
plt.show()
