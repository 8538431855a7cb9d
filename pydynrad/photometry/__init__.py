"""Light as lighting people measure it: photometric units, sensors, work planes and their reports.

The light sources themselves (luminaires, IES and EULUMDAT files, skies) are in
:mod:`pydynrad.lights`.

See docs/design.md, 'Units and photometry' and 'Sensors and work planes'.
"""

from .report import IlluminanceStats, illuminance_statistics, plot_work_plane, write_illuminance_csv
from .sensors import illuminance
from .units import (
    exitance_from_luminance,
    isotropic_intensity,
    lambertian_peak_intensity,
    luminance_from_exitance,
    photometric,
)
from .workplane import WorkPlane, en12464_spacing, work_plane

__all__ = [
    "en12464_spacing",
    "exitance_from_luminance",
    "illuminance",
    "illuminance_statistics",
    "IlluminanceStats",
    "isotropic_intensity",
    "lambertian_peak_intensity",
    "luminance_from_exitance",
    "photometric",
    "plot_work_plane",
    "work_plane",
    "WorkPlane",
    "write_illuminance_csv",
]
