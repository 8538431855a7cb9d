"""
A store precomputed with Dask
=============================

Form factors of large scenes are precomputed once into a *store*: a folder of checksummed,
compressed row blocks that a walk streams rows from, so F never has to fit in memory.
:func:`~pydynrad.precompute.precompute_distributed` fills one on a Dask cluster (a ``LocalCluster`` of
worker processes by default, or an existing cluster's scheduler); an interrupted run resumes
where it stopped. The command line does the same: ``pydynrad formfactors SCENE -o STORE
--workers N``.

Dask needs the ``dask`` extra where it is not installed.
"""

# %%
# Workers build the scene themselves from a :class:`~pydynrad.precompute.SceneSpec` (a built-in name or
# a mesh file, with its parameters): a few bytes to send rather than the scene.
#
# Dask's worker processes import this script again when they start, so everything that
# computes sits under ``if __name__ == "__main__":``, as Dask asks of scripts.
import os
import shutil

import matplotlib.pyplot as plt
import numpy as np

import pydynrad

SMALL = os.environ.get("PYDYNRAD_DOCS_SMALL") == "1"
spec = pydynrad.precompute.SceneSpec("cornell_box", {"max_edge": 150.0 if SMALL else 100.0})
size = 128 if SMALL else 384

if __name__ == "__main__":
    shutil.rmtree("cbox-store", ignore_errors=True)  # a fresh store (an existing one would be resumed)
    store = pydynrad.precompute.precompute_distributed(
        spec, "cbox-store", resolution=32, block_rows=128, workers=2, progress=False
    )
    print(store)

# %%
# The store holds the same rows as ``form_factors`` computes in one process.
if __name__ == "__main__":
    scene = pydynrad.scenes.cornell_box(max_edge=spec.params["max_edge"])
    F = pydynrad.form_factors(scene, resolution=32)
    stored = pydynrad.open_form_factors(scene, "cbox-store")
    print("store equals form_factors:", abs(stored.to_csr() - F).max() == 0)

# %%
# A walk reads its rows from the store through a row cache of a few megabytes (least recently
# used rows are dropped, the next ones prefetched), here for a 300 mm walk towards the box.
# This store holds F alone, so the walk runs the paper's method (``far_field=False``): the far
# field of a walk without F in memory needs its coarse form factors G in the store too
# (``pydynrad formfactors SCENE -o STORE --clusters auto``).
if __name__ == "__main__":
    light = pydynrad.PointLight(position=[278, 450, 280], intensity=[0.2] * 3)
    rows = pydynrad.open_form_factors(scene, "cbox-store", cache_bytes=4 << 20)
    try:
        dyn = pydynrad.DynamicRadiosity(
            scene, rows, local_size=len(scene) // 2, far_field=False, observer=[278, 273, -500]
        )
        for z in np.linspace(-500, -200, 6):
            dyn.update([278, 273, z])
        B = dyn.radiosity([light])
    finally:
        rows.close()
    camera = pydynrad.Camera(position=[278, 273, -800], look_at=[278, 273, 0], fov_y=39.3, width=size, height=size)
    pydynrad.image_io.write_image("dask-store.png", pydynrad.render(scene, B, camera), exposure=-1.65)
    fig, ax = plt.subplots(figsize=(4, 4))
    ax.imshow(plt.imread("dask-store.png"))
    ax.set_title("a walk streamed from the store")
    ax.axis("off")
    plt.show()
