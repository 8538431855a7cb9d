"""Light as lighting people measure it: photometric units, sensors and work planes, sky, luminaires.

See docs/design.md, 'Units and photometry', 'Sensors and work planes' and 'Sky'.
"""

from .ies import IESFormatError, parse_ies, read_ies
from .ldt import parse_ldt, read_ldt
from .luminaires import LuminaireLight, PhotometricDistribution
from .report import IlluminanceStats, illuminance_statistics, plot_work_plane, write_illuminance_csv
from .sensors import illuminance
from .sky import CIE_GENERAL_SKIES, SkyLight
from .units import (exitance_from_luminance, isotropic_intensity, lambertian_peak_intensity,
                    luminance_from_exitance, photometric)
from .workplane import WorkPlane, en12464_spacing, work_plane

__all__ = ["CIE_GENERAL_SKIES", "en12464_spacing", "exitance_from_luminance", "IESFormatError", "illuminance",
           "illuminance_statistics", "IlluminanceStats", "isotropic_intensity", "lambertian_peak_intensity",
           "luminance_from_exitance", "LuminaireLight", "parse_ies", "parse_ldt", "photometric",
           "PhotometricDistribution", "plot_work_plane", "read_ies", "read_ldt", "SkyLight", "work_plane",
           "WorkPlane", "write_illuminance_csv"]
