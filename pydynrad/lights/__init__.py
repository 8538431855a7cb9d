"""Every light source: analytic lights, luminaires with measured distributions, skies, emitters.

* :mod:`.sources`: point, spot and directional lights; the light vector L the solvers propagate;
* :mod:`.luminaires`: :class:`PhotometricDistribution` and :class:`LuminaireLight`;
* :mod:`.ies` and :mod:`.ldt`: IES LM-63 and EULUMDAT files;
* :mod:`.sky`: :class:`SkyLight`, the CIE standard general skies;
* :mod:`.areas`: the direct light of emitting patches, accurate near them;
* :mod:`.text`: lights written as text for the command line.

Measuring light (sensors, work planes, units) is :mod:`pydynrad.photometry`'s job.
"""

from .ies import IESFormatError, parse_ies, read_ies
from .ldt import parse_ldt, read_ldt
from .luminaires import LuminaireLight, PhotometricDistribution
from .sky import CIE_GENERAL_SKIES, SkyLight
from .sources import DirectionalLight, PointLight, SpotLight, direct_irradiance, light_vector, pack_lights
from .text import parse_light

__all__ = [
    "CIE_GENERAL_SKIES",
    "DirectionalLight",
    "IESFormatError",
    "LuminaireLight",
    "PhotometricDistribution",
    "PointLight",
    "SkyLight",
    "SpotLight",
    "direct_irradiance",
    "light_vector",
    "pack_lights",
    "parse_ies",
    "parse_ldt",
    "parse_light",
    "read_ies",
    "read_ldt",
]
