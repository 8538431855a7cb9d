"""IES LM-63 photometric files (LM-63-1991, -1995, -2002, type C photometry) as
:class:`~pydynrad.photometry.luminaires.PhotometricDistribution`.

Layout (LM-63-2002, section 5): an optional ``IESNA:LM-63-...`` line, keyword lines
``[KEYWORD] text``, ``TILT=NONE`` or ``TILT=INCLUDE`` (then the lamp-to-luminaire geometry,
the number of tilt angles, the angles and their multiplying factors), then whitespace- or
comma-separated numbers over any number of lines: number of lamps, lumens per lamp (-1:
absolute photometry), candela multiplier, number of vertical and of horizontal angles,
photometric type (1 = C), units type, width, length, height, ballast factor, ballast-lamp
photometric factor ("future use" in 2002), input watts; the vertical angles; the horizontal
angles; the candela values, one horizontal angle after another.

Candela values are multiplied by the candela multiplier, the ballast factor and the
ballast-lamp factor. Horizontal angles 0 (rotational symmetry), 0..90 (symmetry in each
quadrant), 0..180 (about the 0-180 plane), 90..270 (about the 90-270 plane) or 0..360 are
expanded to a full 0..360 table. Tilt factors are read; ``tilt`` picks the factor of an
installed lamp tilt (degrees, linear between the file's angles; 0 by default).

Every error names the line it found the problem on.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InvalidInputError
from .luminaires import PhotometricDistribution

__all__ = ["read_ies", "parse_ies", "IESFormatError", "expand_c_symmetry"]


class IESFormatError(InvalidInputError):
    """A photometric file that does not follow its format; the message names the line."""


class _Numbers:
    """The numbers of a file after a given line, each with its line number, read in order."""

    def __init__(self, lines: list[str], first: int, where: str) -> None:
        self.items = [(tok, k + 1) for k in range(first, len(lines))
                      for tok in re.split(r"[,\s]+", lines[k].strip()) if tok]
        self.pos = 0
        self.where = where
        self.last_line = len(lines) + 1  # the line that would hold the next number

    def take(self, count: int, what: str) -> tuple[np.ndarray, int]:
        """``count`` numbers and the line the first was on."""
        if self.pos + count > len(self.items):
            have = len(self.items) - self.pos
            raise IESFormatError(f"{self.where}: line {self.last_line} (end of file): expected {count} "
                                 f"{what}, found {have}")
        out = np.empty(count)
        for k in range(count):
            tok, line = self.items[self.pos + k]
            try:
                out[k] = float(tok)
            except ValueError:
                raise IESFormatError(f"{self.where}: line {line}: expected a number ({what}), got {tok!r}") from None
            if not np.isfinite(out[k]):  # no field of the format holds one (inf counts crashed int())
                raise IESFormatError(f"{self.where}: line {line}: expected a finite number ({what}), got {tok!r}")
        first = self.items[self.pos][1] if count else self.last_line
        self.pos += count
        return out, first

    def one(self, what: str) -> tuple[float, int]:
        v, line = self.take(1, what)
        return float(v[0]), line


#: Symmetries of a table by the C range it covers: the images of a covered angle a.
_SYMMETRIES = {
    (0.0, 90.0): lambda a: [a, 180 - a, 180 + a, 360 - a],  # symmetric in each quadrant
    (0.0, 180.0): lambda a: [a, 360 - a],  # about the C0-C180 plane
    (90.0, 270.0): lambda a: [a, 180 - a],  # about the C90-C270 plane
    (-90.0, 90.0): lambda a: [a, 180 - a],  # the same, given as 270..360..90
}


def expand_c_symmetry(c: np.ndarray, cd: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """C angles (degrees) and intensities (nC, nG) of a symmetric table as a full 0..360 table.

    A single plane stays as it is (rotational symmetry). Ranges 0..90, 0..180, 90..270 and
    -90..90 are mirrored (``_SYMMETRIES``); a range from 0 past 180 is the whole circle, with
    360 added as a copy of 0 when missing. Every output plane is one of the input planes.
    """
    if len(c) == 1:
        return np.array([0.0]), cd
    rule = _SYMMETRIES.get((float(c[0]), float(c[-1])))
    if rule is None:
        if not (c[0] == 0 and 180 < c[-1] <= 360):
            raise IESFormatError(f"{where}: C angles {c[0]:g}..{c[-1]:g} are not a symmetry this reader knows "
                                 "(0, 0-90, 0-180, 90-270, 270-90, 0-360)")
        rule = lambda a: [a]  # noqa: E731 (the whole circle: no images)
    angles, source = [], []
    for i, a in enumerate(c):
        for image in rule(float(a)):
            angles.append(image % 360.0)
            source.append(i)
    angles, first = np.unique(np.round(angles, 9), return_index=True)
    source = np.asarray(source)[first]
    if angles[0] != 0:
        raise IESFormatError(f"{where}: the C angles do not reach C = 0 after symmetry expansion")
    angles, source = np.append(angles, 360.0), np.append(source, source[0])
    return angles, cd[source]


def parse_ies(text: str, where: str = "<string>", tilt: float = 0.0) -> PhotometricDistribution:
    """A distribution from the text of an LM-63 file (see the module docstring)."""
    if not isinstance(text, str):
        raise InvalidInputError(f"parse_ies takes the file's text (str); got {type(text).__name__} (read_ies reads a file)")
    # A UTF-8 byte-order mark read as text, and a DOS end-of-file mark (Ctrl-Z) after the table.
    lines = text.removeprefix("\ufeff").rstrip().rstrip("\x1a").splitlines()
    keywords: dict[str, str] = {}
    k = 0
    while k < len(lines) and not lines[k].strip().upper().startswith("TILT"):
        m = re.match(r"\s*\[(\w+)\]\s*(.*)", lines[k])
        if m:
            keywords.setdefault(m.group(1).upper(), m.group(2).strip())
        k += 1
    name = keywords.get("LUMINAIRE") or keywords.get("LUMCAT", "")
    if k == len(lines):
        raise IESFormatError(f"{where}: line {len(lines)} (end of file): no TILT= line")
    tilt_kind = lines[k].split("=", 1)[1].strip().upper() if "=" in lines[k] else ""
    nums = _Numbers(lines, k + 1, where)
    tilt_factor = 1.0
    if tilt_kind == "INCLUDE":
        nums.one("lamp-to-luminaire geometry")
        n_tilt, line = nums.one("number of tilt angles")
        if n_tilt < 1 or n_tilt != int(n_tilt):
            raise IESFormatError(f"{where}: line {line}: the number of tilt angles must be a positive integer")
        angles, aline = nums.take(int(n_tilt), "tilt angles")
        factors, _ = nums.take(int(n_tilt), "tilt multiplying factors")
        if np.any(np.diff(angles) <= 0):  # np.interp reads decreasing angles as garbage
            raise IESFormatError(f"{where}: line {aline}: tilt angles must increase")
        tilt_factor = float(np.interp(tilt, angles, factors))
    elif tilt_kind != "NONE":
        raise IESFormatError(f"{where}: line {k + 1}: TILT={tilt_kind or '?'} is not supported "
                             "(TILT=NONE or TILT=INCLUDE; a separate tilt file is not read)")
    head, head_line = nums.take(10, "luminaire header values (lamps, lumens, multiplier, angles, type, units, sizes)")
    n_lamps, lumens, multiplier, n_vert, n_horiz, ptype = head[:6]
    for value, what, least in ((n_vert, "number of vertical angles", 2), (n_horiz, "number of horizontal angles", 1)):
        if value < least or value != int(value):
            raise IESFormatError(f"{where}: line {head_line}: the {what} must be an integer >= {least}; got {value:g}")
    if ptype != 1:
        raise IESFormatError(f"{where}: line {head_line}: photometric type {ptype:g} is not supported "
                             "(only type C, 1, the type of building luminaires)")
    factors, _ = nums.take(3, "ballast factor, ballast-lamp factor and input watts")
    vert, vline = nums.take(int(n_vert), "vertical angles")
    horiz, hline = nums.take(int(n_horiz), "horizontal angles")
    if np.any(np.diff(vert) <= 0) or vert[0] < 0 or vert[-1] > 180:
        raise IESFormatError(f"{where}: line {vline}: vertical angles must increase within 0..180")
    if np.any(np.diff(horiz) <= 0):
        raise IESFormatError(f"{where}: line {hline}: horizontal angles must increase")
    cd, cline = nums.take(int(n_vert) * int(n_horiz), f"candela values ({int(n_horiz)} x {int(n_vert)})")
    if np.any(cd < 0):
        raise IESFormatError(f"{where}: line {cline}: candela values must be >= 0")
    if nums.pos < len(nums.items):  # counts that do not match the table shift every value after them
        tok, line = nums.items[nums.pos]
        raise IESFormatError(f"{where}: line {line}: {len(nums.items) - nums.pos} value(s) after the candela table "
                             f"(first {tok!r}): the counts in line {head_line} ({int(n_vert)} vertical, "
                             f"{int(n_horiz)} horizontal angles) do not match the file")
    scale = multiplier * factors[0] * factors[1] * tilt_factor
    with np.errstate(over="ignore", invalid="ignore"):
        cd = cd.reshape(int(n_horiz), int(n_vert)) * scale
    if not (scale >= 0 and np.all(np.isfinite(cd))):
        raise IESFormatError(f"{where}: line {head_line}: the candela multiplier and the ballast factors "
                             f"({multiplier:g} x {factors[0]:g} x {factors[1]:g}) must be >= 0 and keep the "
                             "candela values finite")
    c, cd = expand_c_symmetry(horiz, cd, where)
    flux = None if lumens < 0 else float(n_lamps * lumens)
    return PhotometricDistribution(c, vert, cd, name=name, lumens=flux, source=where)


def read_photometric_text(path) -> str:
    """The text of a photometric file: UTF-8 where it decodes as such (a byte-order mark
    dropped), else Latin-1, in which older files write their names; InvalidInputError naming
    the file where it cannot be read."""
    path = Path(path)
    try:
        raw = path.read_bytes().removeprefix(b"\xef\xbb\xbf")
    except OSError as e:
        raise InvalidInputError(f"cannot read {str(path)!r}: {e.strerror}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def read_ies(path, tilt: float = 0.0) -> PhotometricDistribution:
    """Read an IES LM-63 file (type C photometry); ``tilt``: installed lamp tilt for TILT=INCLUDE, degrees."""
    return parse_ies(read_photometric_text(path), str(path), tilt)
