"""EULUMDAT (.ldt) photometric files as :class:`~pydynrad.lights.luminaires.PhotometricDistribution`.

EULUMDAT is line-oriented, one value per line (line numbers as in the format's description):
1 company, 2 type indicator Ityp, 3 symmetry indicator Isym, 4 number of C planes Mc,
5 distance between C planes Dc, 6 number of intensities per plane Ng, 7 distance between
them Dg, 8-12 report number, luminaire name and number, file name, date/user, 13-21
luminaire and luminous-area dimensions (mm), 22 downward flux fraction, 23 light output
ratio, 24 conversion factor for the intensities, 25 tilt during measurement, 26 number of
lamp sets n, then n lines each of: number of lamps, lamp type, total lamp flux (lm),
colour, colour rendering, wattage; 10 direct ratios; Mc C angles; Ng gamma angles; the
intensities in cd per 1000 lm of lamp flux for the planes the symmetry needs, Ng per plane:
Isym 0 all Mc planes; 1 one plane (rotational symmetry); 2 C0..C180; 3 C270..C90 (through
C0); 4 C0..C90.

Intensities in cd are the table's values times the first lamp set's flux / 1000 times the
conversion factor. Every error names the line it found the problem on.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from .ies import IESFormatError, expand_c_symmetry, read_photometric_text
from .luminaires import PhotometricDistribution

__all__ = ["read_ldt", "parse_ldt"]


class _Lines:
    def __init__(self, text: str, where: str) -> None:
        self.lines = text.splitlines()
        self.k = 0
        self.where = where

    def text(self, what: str) -> str:
        if self.k >= len(self.lines):
            raise IESFormatError(f"{self.where}: line {self.k + 1} (end of file): expected {what}")
        self.k += 1
        return self.lines[self.k - 1].strip()

    def number(self, what: str) -> float:
        tok = self.text(what)
        try:
            v = float(tok.replace(",", "."))  # some writers use a decimal comma
        except ValueError:
            raise IESFormatError(f"{self.where}: line {self.k}: expected a number ({what}), got {tok!r}") from None
        if not np.isfinite(v):  # no field of the format holds one (inf counts crashed int())
            raise IESFormatError(f"{self.where}: line {self.k}: expected a finite number ({what}), got {tok!r}")
        return v

    def integer(self, what: str, lo: int, hi: int) -> int:
        v = self.number(what)
        if v != int(v) or not lo <= v <= hi:
            raise IESFormatError(f"{self.where}: line {self.k}: {what} must be an integer in {lo}..{hi}; got {v:g}")
        return int(v)

    def numbers(self, count: int, what: str) -> np.ndarray:
        return np.array([self.number(f"{what} {i + 1} of {count}") for i in range(count)])


def parse_ldt(text: str, where: str = "<string>") -> PhotometricDistribution:
    """A distribution from the text of a EULUMDAT file (see the module docstring)."""
    if not isinstance(text, str):
        raise InvalidInputError(
            f"parse_ldt takes the file's text (str); got {type(text).__name__} (read_ldt reads a file)"
        )
    r = _Lines(text.removeprefix("\ufeff").rstrip().rstrip("\x1a"), where)
    r.text("the company identification")
    r.integer("the type indicator Ityp", 0, 3)
    isym = r.integer("the symmetry indicator Isym", 0, 4)
    mc = r.integer("the number of C planes Mc", 1, 721)
    r.number("the distance between C planes Dc")
    ng = r.integer("the number of luminous intensities per C plane Ng", 2, 1441)
    r.number("the distance between intensities Dg")
    r.text("the measurement report number")
    name = r.text("the luminaire name")
    for what in ("luminaire number", "file name", "date/user"):
        r.text(f"the {what}")
    for what in (
        "luminaire length",
        "luminaire width",
        "luminaire height",
        "luminous area length",
        "luminous area width",
        "luminous area height C0",
        "C90",
        "C180",
        "C270",
        "downward flux fraction",
        "light output ratio",
    ):
        r.number(f"the {what}")
    conversion = r.number("the conversion factor for luminous intensities")
    conversion_line = r.k
    r.number("the tilt during measurement")
    n_sets = r.integer("the number of standard sets of lamps", 1, 20)
    lamps = []
    for _ in range(n_sets):
        r.text("the number of lamps")
        r.text("the type of lamps")
        lamps.append(r.number("the total luminous flux of lamps (lm)"))
        for what in ("colour appearance", "colour rendering group", "wattage including ballast"):
            r.text(f"the {what}")
    r.numbers(10, "direct ratio")
    c_line = r.k + 1
    c = r.numbers(mc, "C angle")
    g_line = r.k + 1
    gamma = r.numbers(ng, "gamma angle")
    if np.any(np.diff(c) <= 0) or c[0] < 0 or c[-1] >= 360:
        raise IESFormatError(f"{where}: line {c_line}: C angles must increase within 0..360 (360 excluded)")
    if np.any(np.diff(gamma) <= 0) or gamma[0] < 0 or gamma[-1] > 180:
        raise IESFormatError(f"{where}: line {g_line}: gamma angles must increase within 0..180")
    if isym in (2, 3, 4) and mc % (4 if isym == 4 else 2):
        raise IESFormatError(f"{where}: line 4: Mc = {mc} does not divide for symmetry Isym = {isym}")
    if isym == 0 and mc >= 2 and not (c[0] == 0 and c[-1] + (c[-1] - c[-2]) >= 360.0 - 1e-6):
        # Without symmetry the planes must go round (the last one step short of 360: C0, C180
        # do): planes over 0..90 would be mirrored as if the file declared a symmetry it did not.
        raise IESFormatError(
            f"{where}: line {c_line}: Isym = 0 (no symmetry) needs C planes from 0 round the "
            f"circle; got {mc} plane(s) over {c[0]:g}..{c[-1]:g}"
        )
    if isym == 0:
        planes = np.arange(mc)
    elif isym == 1:
        planes = np.arange(1)
    elif isym == 2:
        planes = np.arange(mc // 2 + 1)
    elif isym == 3:
        planes = (np.arange(3 * mc // 4, 3 * mc // 4 + mc // 2 + 1)) % mc
    else:
        planes = np.arange(mc // 4 + 1)
    cd_line = r.k + 1
    cd = r.numbers(len(planes) * ng, "luminous intensity (cd/klm)").reshape(len(planes), ng)
    if np.any(cd < 0):
        raise IESFormatError(f"{where}: line {cd_line}: luminous intensities must be >= 0")
    left = [k for k in range(r.k, len(r.lines)) if r.lines[k].strip()]
    if left:  # counts that do not match the file shift every value after them
        raise IESFormatError(
            f"{where}: line {left[0] + 1}: {len(left)} line(s) after the intensity table (first "
            f"{r.lines[left[0]].strip()!r}): Mc = {mc}, Ng = {ng} and Isym = {isym} (lines 3, 4, 6) "
            "do not match the file"
        )
    angles = c[planes]
    if isym == 3:
        angles = np.where(angles >= 270, angles - 360, angles)  # 270..360..90 as -90..90
    angles, cd = expand_c_symmetry(angles, cd, where)
    flux = lamps[0]
    with np.errstate(over="ignore", invalid="ignore"):
        cd = cd * (flux / 1000.0 * conversion)
    if not (flux >= 0 and conversion >= 0 and np.all(np.isfinite(cd))):
        raise IESFormatError(
            f"{where}: line {conversion_line}: the conversion factor ({conversion:g}) and the "
            f"first lamp set's flux ({flux:g} lm) must be >= 0 and keep the intensities finite"
        )
    return PhotometricDistribution(angles, gamma, cd, name=name, lumens=flux, source=where)


def read_ldt(path) -> PhotometricDistribution:
    """Read a EULUMDAT (.ldt) file."""
    return parse_ldt(read_photometric_text(path), str(path))
