"""Lights written as text, for the command line: ``KIND:FIELD=VALUE;FIELD=VALUE``.

    point:pos=278,500,280;intensity=5e4            # W/sr; one number is grey, or R,G,B
    spot:pos=278,540,280;dir=0,-1,0;intensity=1e5;outer=30;inner=20   # cone angles in degrees
    sun:dir=0.3,-1,0.2;irradiance=800              # W/unit^2 on a surface facing it

``directional`` is another name for ``sun``. The older ``X,Y,Z:R,G,B`` (a point light at X,Y,Z
of intensity R,G,B, or one grey number) still reads as a point light. Each kind is one entry
of :data:`LIGHT_KINDS` (its fields, their parsers and defaults, and how the light is made),
so a new light type is one more entry.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import InvalidInputError, PydynradError

__all__ = ["LightKind", "LIGHT_KINDS", "LIGHT_ALIASES", "parse_light", "light_syntax"]

_REQUIRED = object()


def _numbers(text: str, counts: tuple[int, ...], what: str) -> tuple[float, ...]:
    try:
        v = tuple(float(x) for x in text.replace(" ", "").split(","))
    except ValueError:
        v = ()
    if len(v) not in counts or not all(np.isfinite(v)):
        want = " or ".join({1: "one number", 3: "three numbers X,Y,Z"}[c] for c in counts)
        raise InvalidInputError(f"{what} must be {want}; got {text!r}")
    return v


def vector(text: str, what: str) -> tuple[float, float, float]:
    """Three finite numbers X,Y,Z."""
    return _numbers(text, (3,), what)  # type: ignore[return-value]


def colour(text: str, what: str):
    """One number (grey) or R,G,B."""
    v = _numbers(text, (1, 3), what)
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
        raise InvalidInputError(f"{kind} light: unknown field {key!r}; its fields are "
                                f"{', '.join(f.name for f in self.fields)}")


def _point(pos, intensity):
    from .lights import PointLight

    return PointLight(pos, intensity)


def _spot(pos, dir, intensity, outer, inner=None):
    from .lights import SpotLight

    if inner is not None and inner > outer:
        raise InvalidInputError(f"inner ({math.degrees(inner):g} degrees) must not exceed outer "
                                f"({math.degrees(outer):g} degrees)")
    return SpotLight(pos, dir, intensity, outer if inner is None else inner, outer)


def _sun(dir, irradiance):
    from .lights import DirectionalLight

    return DirectionalLight(dir, irradiance)


_POS = Field("pos", vector, "position X,Y,Z in scene units", aliases=("position",))
_DIR = Field("dir", vector, "direction X,Y,Z the light travels in", aliases=("direction",))
_INTENSITY = Field("intensity", colour, "W/sr, one number (grey) or R,G,B")

#: Every light kind the text form knows, by name.
LIGHT_KINDS: dict[str, LightKind] = {
    "point": LightKind(_point, (_POS, _INTENSITY), "an isotropic point light"),
    "spot": LightKind(_spot, (_POS, _DIR, _INTENSITY,
                              Field("outer", degrees, "cone half-angle in degrees where the light ends"),
                              Field("inner", degrees, "half-angle in degrees of full intensity (default: outer, "
                                                      "a hard edge)", default=None)),
                      "a point light in a cone (smooth falloff from inner to outer)"),
    "sun": LightKind(_sun, (_DIR, Field("irradiance", colour, "W/unit^2 on a surface facing it, one number or R,G,B")),
                     "a directional light at infinity"),
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
        raise InvalidInputError(f"unknown light kind {kind!r} in {text!r}; use {', '.join(LIGHT_KINDS)} "
                                f"(as KIND:FIELD=VALUE;...) or X,Y,Z:R,G,B for a point light")
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
        raise InvalidInputError(f"{name} light: missing {', '.join(missing)} (fields: "
                                f"{'; '.join(f'{f.name}=' for f in spec.fields)})")
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
