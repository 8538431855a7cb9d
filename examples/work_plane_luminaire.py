"""
A work plane under a luminaire
==============================

Lighting as lighting people measure it: geometry in metres, a luminaire's intensities in
candela from an IES LM-63 file, illuminance in lux on an EN 12464-1 work-plane grid, with its
statistics (Em, Emin, Emax, uniformity U0) in a CSV file and a false-colour plot.

``data/downlight.ies`` is a synthetic file written for these examples (not a measured
luminaire): a rotationally symmetric downlight, I(gamma) = 800 cd cos^2(gamma) below the
horizontal and nothing above, about 1,675 lm.
"""

# %%
# A 4 m x 4 m room, 2.8 m high, with grey walls (albedo 0.5), and the luminaire 5 cm under
# the middle of the ceiling, pointing down.
import os
from pathlib import Path

import matplotlib.pyplot as plt

import pydynrad
from pydynrad.photometry import illuminance, plot_work_plane, work_plane, write_illuminance_csv

SMALL = os.environ.get("PYDYNRAD_DOCS_SMALL") == "1"
# The folder of this script (the documentation build runs it there, without __file__).
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()

room = pydynrad.scenes.closed_box((4.0, 4.0, 2.8), subdivisions=2 if SMALL else 3, albedo=0.5, emission=0.0)
downlight = pydynrad.read_ies(HERE / "data" / "downlight.ies")
lamp = pydynrad.LuminaireLight([2.0, 2.0, 2.75], downlight, nadir=(0, 0, -1))
print(room, downlight.name)

# %%
# The radiosity of the room (the light reflected between its walls) from its form factors.
F = pydynrad.form_factors(room, resolution=32)
B = pydynrad.solve(room, F, lights=[lamp]).radiosity

# %%
# The work plane at 0.75 m over the whole floor (grid spacing by EN 12464-1), its
# illuminance in lux (direct from the luminaire plus the light the walls reflect) and its
# statistics.
plane = work_plane([[0, 0], [4, 0], [4, 4], [0, 4]], height=0.75)
E = illuminance(room, B, plane.points, plane.normals, lights=[lamp])  # (n, 3) lux
stats = write_illuminance_csv("work-plane.csv", plane.points, E)
print(
    f"{len(plane)} points: Em {stats.Em:.0f} lx, Emin {stats.Emin:.0f} lx, Emax {stats.Emax:.0f} lx, U0 {stats.U0:.2f}"
)

# %%
# The false-colour plot ``plot_work_plane`` writes (it needs matplotlib).
plot_work_plane("work-plane.png", plane, E, title="downlight, 0.75 m work plane")
fig, ax = plt.subplots(figsize=(6, 5))
ax.imshow(plt.imread("work-plane.png"))
ax.axis("off")
plt.show()
