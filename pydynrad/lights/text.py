"""Lights written as text, for the command line: ``KIND:FIELD=VALUE;FIELD=VALUE``.

    point:pos=278,500,280;intensity=0.05           # W/sr; one number is grey, or R,G,B
    spot:pos=278,540,280;dir=0,-1,0;intensity=0.1;outer=30;inner=20   # cone angles in degrees
    sun:dir=0.3,-1,0.2;irradiance=800              # W/m^2 (lux) on a surface facing it
    sky:model=cie_overcast;zenith=3000;up=0,0,1    # cd/m2 at the zenith (or horizontal= lx)
    sky:model=clear;horizontal=20000;sun=0.5,0.2,0.6;ground=0.2
    luminaire:pos=2,2,2.8;file=lamp.ies;nadir=0,0,-1;c0=1,0,0    # an IES or EULUMDAT (.ldt) file

``directional`` is another name for ``sun``. The older ``X,Y,Z:R,G,B`` (a point light at X,Y,Z
of intensity R,G,B, or one grey number) still reads as a point light. Each kind is one entry
of :data:`LIGHT_KINDS` (its fields, their parsers and defaults, and how the light is made),
so a new light type is one more entry.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError, PydynradError
from .ies import read_ies
from .ldt import read_ldt
from .luminaires import LuminaireLight
from .sky import SkyLight
from .sources import DirectionalLight, PointLight, SpotLight

__all__ = ["LightKind", "LIGHT_KINDS", "LIGHT_ALIASES", "parse_light", "light_syntax", "plain_number"]

_REQUIRED = object()


#: A number as the light text writes one: ASCII digits, an optional point and exponent (Python's
#: float() also takes "1_000" and other scripts' digits, which a typo should not become).
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", re.ASCII)


def plain_number(text: str) -> float | None:
    """``text`` (spaces around it allowed) as a float where it is a plain ASCII number, else None."""
    text = text.strip()
    return float(text) if _NUMBER.fullmatch(text) else None


def _numbers(text: str, counts: tuple[int, ...], what: str, names: str = "X,Y,Z") -> tuple[float, ...]:
    parts = [plain_number(x) for x in text.split(",")]
    v = tuple(parts) if None not in parts else ()
    if len(v) not in counts or not all(np.isfinite(v)):
        want = " or ".join({1: "one number", 3: f"three numbers {names}"}[c] for c in counts)
        raise InvalidInputError(f"{what} must be {want}; got {text!r}")
    return v


def vector(text: str, what: str) -> tuple[float, float, float]:
    """Three finite numbers X,Y,Z."""
    return _numbers(text, (3,), what)  # type: ignore[return-value]


def colour(text: str, what: str):
    """One number (grey) or R,G,B."""
    v = _numbers(text, (1, 3), what, "R,G,B")
    return v[0] if len(v) == 1 else v


def degrees(text: str, what: str) -> float:
    """An angle in degrees, returned in radians (the lights' unit)."""
    return math.radians(_numbers(text, (1,), what)[0])


@dataclass(frozen=True)
class Field:
    """One ``FIELD=VALUE`` of a light kind: ``name`` is the keyword of ``LightKind.make``."""

    name: str
    parse: Callable[[str, str], object]
    help: str
    default: object = _REQUIRED
    aliases: tuple[str, ...] = ()


@dataclass(frozen=True)
class LightKind:
    """How one kind of light is written: its fields, and ``make(**fields)`` returning the light."""

    make: Callable[..., object]
    fields: tuple[Field, ...]
    help: str

    def field(self, key: str, kind: str) -> Field:
        for f in self.fields:
            if key == f.name or key in f.aliases:
                return f
        raise InvalidInputError(
            f"{kind} light: unknown field {key!r}; its fields are {', '.join(f.name for f in self.fields)}"
        )


def number(text: str, what: str) -> float:
    """One finite number."""
    return _numbers(text, (1,), what)[0]


def sky_model(text: str, what: str):
    """A sky model name, or a CIE general sky type 1..15."""
    text = text.strip().lower()
    return int(text) if text.isdigit() else text


def _sky(model="uniform", zenith=None, horizontal=None, sun=None, up=None, ground=0.0, resolution=64):
    return SkyLight(
        model,
        zenith_luminance=zenith,
        horizontal_illuminance=horizontal,
        sun_direction=sun,
        up=up,
        ground_reflectance=ground,
        # a whole number as an int; 64.5 is refused as it is, not cut to 64
        resolution=int(resolution) if float(resolution).is_integer() else resolution,
    )


def _luminaire(pos, file, nadir=None, c0=(1.0, 0.0, 0.0), scale=1.0):

    read = read_ldt if file.lower().endswith(".ldt") else read_ies
    return LuminaireLight(pos, read(file), nadir=nadir, c0=c0, scale=scale)


def _point(pos, intensity):
    return PointLight(pos, intensity)


def _spot(pos, dir, intensity, outer, inner=None):
    if inner is not None and inner > outer:
        raise InvalidInputError(
            f"inner ({math.degrees(inner):g} degrees) must not exceed outer ({math.degrees(outer):g} degrees)"
        )
    return SpotLight(pos, dir, intensity, outer if inner is None else inner, outer)


def _sun(dir, irradiance):
    return DirectionalLight(dir, irradiance)


_POS = Field("pos", vector, "position X,Y,Z in scene units", aliases=("position",))
_DIR = Field("dir", vector, "direction X,Y,Z the light travels in", aliases=("direction",))
_INTENSITY = Field("intensity", colour, "W/sr, one number (grey) or R,G,B")

#: Every light kind the text form knows, by name.
LIGHT_KINDS: dict[str, LightKind] = {
    "point": LightKind(_point, (_POS, _INTENSITY), "an isotropic point light"),
    "spot": LightKind(
        _spot,
        (
            _POS,
            _DIR,
            _INTENSITY,
            Field("outer", degrees, "cone half-angle in degrees where the light ends"),
            Field(
                "inner", degrees, "half-angle in degrees of full intensity (default: outer, a hard edge)", default=None
            ),
        ),
        "a point light in a cone (smooth falloff from inner to outer)",
    ),
    "sun": LightKind(
        _sun,
        (_DIR, Field("irradiance", colour, "W/unit^2 on a surface facing it, one number or R,G,B")),
        "a directional light at infinity",
    ),
    "sky": LightKind(
        _sky,
        (
            Field(
                "model", sky_model, "uniform, cie_overcast, overcast, clear or a CIE sky type 1..15", default="uniform"
            ),
            Field("zenith", number, "zenith luminance, cd/m2 (give this or horizontal)", default=None),
            Field("horizontal", number, "unobstructed horizontal illuminance, lx", default=None),
            Field("sun", vector, "direction X,Y,Z towards the sun (CIE skies that depend on it)", default=None),
            Field("up", vector, "the zenith X,Y,Z (default: the scene's up axis)", default=None),
            Field("ground", number, "ground reflectance in [0, 1)", default=0.0),
            Field("resolution", number, "hemicube resolution of the sky pass", default=64),
        ),
        "a sky over a uniform ground, seen by every patch through the scene's openings",
    ),
    "luminaire": LightKind(
        _luminaire,
        (
            _POS,
            Field("file", lambda text, what: text.strip(), "an IES LM-63 (.ies) or EULUMDAT (.ldt) file"),
            Field("nadir", vector, "direction X,Y,Z of gamma = 0 (default: down the scene's up axis)", default=None),
            Field("c0", vector, "direction X,Y,Z of the C = 0 plane", default=(1.0, 0.0, 0.0)),
            Field("scale", colour, "factor on the file's candela, one number or R,G,B", default=1.0),
        ),
        "a point source with a measured intensity distribution",
    ),
}
#: Other names of kinds.
LIGHT_ALIASES = {"directional": "sun"}


def parse_light(text: str):
    """The light object ``text`` describes (see the module docstring), or InvalidInputError
    naming what is wrong."""
    kind, sep, rest = text.partition(":")
    name = LIGHT_ALIASES.get(kind.strip().lower(), kind.strip().lower())
    if name not in LIGHT_KINDS:
        if sep and "=" not in rest and kind.count(",") == 2:  # the older X,Y,Z:R,G,B point light
            return _point(vector(kind, "point light position"), colour(rest, "point light intensity"))
        raise InvalidInputError(
            f"unknown light kind {kind!r} in {text!r}; use {', '.join(LIGHT_KINDS)} "
            f"(as KIND:FIELD=VALUE;...) or X,Y,Z:R,G,B for a point light"
        )
    spec = LIGHT_KINDS[name]
    values = {}
    for item in filter(None, (s.strip() for s in rest.split(";"))):
        key, eq, value = item.partition("=")
        if not eq:
            raise InvalidInputError(f"{name} light: expected FIELD=VALUE, got {item!r}")
        f = spec.field(key.strip().lower(), name)
        if f.name in values:
            raise InvalidInputError(f"{name} light: field {f.name!r} given twice")
        values[f.name] = f.parse(value, f"{name} light {f.name}")
    missing = [f.name for f in spec.fields if f.default is _REQUIRED and f.name not in values]
    if missing:
        raise InvalidInputError(
            f"{name} light: missing {', '.join(missing)} (fields: {'; '.join(f'{f.name}=' for f in spec.fields)})"
        )
    try:
        return spec.make(**values)
    except PydynradError as exc:
        raise InvalidInputError(f"{name} light: {exc}") from None


def light_syntax() -> str:
    """One paragraph describing every kind and field, for --help."""
    kinds = []
    for name, spec in LIGHT_KINDS.items():
        alias = [a for a, k in LIGHT_ALIASES.items() if k == name]
        fields = "; ".join(f"{f.name}= {f.help}" for f in spec.fields)
        kinds.append(f"{name}{' (or ' + ', '.join(alias) + ')' if alias else ''}: {spec.help} ({fields})")
    return " | ".join(kinds)
