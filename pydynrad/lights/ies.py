"""IES LM-63 photometric files (LM-63-1986, -1991, -1995, -2002, -2019, type C photometry) as
:class:`~pydynrad.lights.luminaires.PhotometricDistribution`.

Layout (LM-63-2002, section 5): an optional ``IESNA:LM-63-...`` line, keyword lines
``[KEYWORD] text``, ``TILT=NONE`` or ``TILT=INCLUDE`` (then the lamp-to-luminaire geometry,
the number of tilt angles, the angles and their multiplying factors), then whitespace- or
comma-separated numbers over any number of lines: number of lamps, lumens per lamp (-1:
absolute photometry), candela multiplier, number of vertical and of horizontal angles,
photometric type (1 = C), units type, width, length, height, ballast factor, ballast-lamp
photometric factor ("future use" in 2002), input watts; the vertical angles; the horizontal
angles; the candela values, one horizontal angle after another.

Candela values are multiplied by the candela multiplier, the ballast factor and, in files
before LM-63-2002 (no header line, ``IESNA91``, ``IESNA:LM-63-1995``), the ballast-lamp factor:
LM-63-2002 makes that field "future use" and LM-63-2019 its file generation type (a code,
1.00001 to 1.11011, not a factor). Horizontal angles 0 (rotational symmetry), 0..90 (symmetry in each
quadrant), 0..180 (about the 0-180 plane), 90..270 (about the 90-270 plane) or 0..360 are
expanded to a full 0..360 table. Tilt factors are read; ``tilt`` picks the factor of an
installed lamp tilt (degrees, linear between the file's angles; 0 by default).

Every error names the line it found the problem on.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..checks import number
from ..errors import InvalidInputError
from .luminaires import PhotometricDistribution

__all__ = ["read_ies", "parse_ies", "IESFormatError", "expand_c_symmetry"]


#: The largest photometric file read (/dev/zero or a wrong file would be read without end).
MAX_PHOTOMETRIC_BYTES = 64 * 2**20


class IESFormatError(InvalidInputError):
    """A photometric file that does not follow its format; the message names the line."""


class _Numbers:
    """The numbers of a file after a given line, each with its line number, read in order."""

    def __init__(self, lines: list[str], first: int, where: str) -> None:
        self.items = [
            (tok, k + 1) for k in range(first, len(lines)) for tok in re.split(r"[,\s]+", lines[k].strip()) if tok
        ]
        self.pos = 0
        self.where = where
        self.last_line = len(lines) + 1  # the line that would hold the next number

    def take(self, count: int, what: str) -> tuple[np.ndarray, int]:
        """``count`` numbers and the line the first was on."""
        if self.pos + count > len(self.items):
            have = len(self.items) - self.pos
            raise IESFormatError(
                f"{self.where}: line {self.last_line} (end of file): expected {count} {what}, found {have}"
            )
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
    360 added as a copy of 0 when missing (at most one step of the table's). Every output plane
    is one of the input planes, but C = 0 of a 90..270 table whose images miss it: the linear
    interpolation across it, as the circle is interpolated everywhere else.
    """
    if len(c) == 1:
        return np.array([0.0]), cd
    rule = _SYMMETRIES.get((float(c[0]), float(c[-1])))
    if rule is None:
        # The whole circle, 0..360; a table that stops one step short of 360 (its last plane
        # dropped as a copy of the first) is read as closing on C = 0, a wider gap is refused.
        if not (c[0] == 0 and 180 < c[-1] <= 360 and 360 - c[-1] <= np.diff(c).max() + 1e-9):
            raise IESFormatError(
                f"{where}: C angles {c[0]:g}..{c[-1]:g} are not a symmetry this reader knows "
                "(0, 0-90, 0-180, 90-270, 270-90, 0-360)"
            )
        rule = lambda a: [a]  # noqa: E731 (the whole circle: no images)
    angles, source = [], []
    for i, a in enumerate(c):
        for image in rule(float(a)):
            angles.append(image % 360.0)
            source.append(i)
    angles, first = np.unique(np.round(angles, 9), return_index=True)
    planes = cd[np.asarray(source)[first]]
    if angles[0] != 0:
        # A 90-270 table whose images miss C = 0 (planes 90 and 270 only, or steps that do not
        # divide 90): C = 0 is where the circle's interpolation crosses it, between the last
        # plane and the first.
        t = (360.0 - angles[-1]) / (360.0 - angles[-1] + angles[0])
        angles = np.concatenate([[0.0], angles])
        planes = np.concatenate([(planes[-1] * (1 - t) + planes[0] * t)[None], planes])
    return np.append(angles, 360.0), np.concatenate([planes, planes[:1]])


def parse_ies(text: str, where: str = "<string>", tilt: float = 0.0) -> PhotometricDistribution:
    """A distribution from the text of an LM-63 file (see the module docstring)."""
    if not isinstance(text, str):
        raise InvalidInputError(
            f"parse_ies takes the file's text (str); got {type(text).__name__} (read_ies reads a file)"
        )
    # A UTF-8 byte-order mark read as text, and a DOS end-of-file mark (Ctrl-Z) after the table.
    lines = text.removeprefix("\ufeff").rstrip().rstrip("\x1a").splitlines()
    keywords: dict[str, str] = {}
    k = 0
    version = re.search(r"LM-63-(\d{4})", lines[0].upper()) if lines else None
    year = int(version.group(1)) if version else (1991 if lines and lines[0].strip().upper() == "IESNA91" else 1986)
    # A free-text line of a 1986 file may begin with the word "Tilt": only TILT= ends the header.
    while k < len(lines) and not re.match(r"\s*TILT\s*=", lines[k], re.IGNORECASE):
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
    tilt = number(tilt, "tilt (the installed lamp tilt, degrees)")
    if tilt_kind == "INCLUDE":
        nums.one("lamp-to-luminaire geometry")
        n_tilt, line = nums.one("number of tilt angles")
        if n_tilt < 1 or n_tilt != int(n_tilt):
            raise IESFormatError(f"{where}: line {line}: the number of tilt angles must be a positive integer")
        angles, aline = nums.take(int(n_tilt), "tilt angles")
        factors, _ = nums.take(int(n_tilt), "tilt multiplying factors")
        if np.any(np.diff(angles) <= 0):  # np.interp reads decreasing angles as garbage
            raise IESFormatError(f"{where}: line {aline}: tilt angles must increase")
        if np.any(factors < 0):
            raise IESFormatError(f"{where}: line {aline}: tilt multiplying factors must be >= 0")
        tilt_factor = float(np.interp(tilt, angles, factors))
    elif tilt_kind != "NONE":
        raise IESFormatError(
            f"{where}: line {k + 1}: TILT={tilt_kind or '?'} is not supported "
            "(TILT=NONE or TILT=INCLUDE; a separate tilt file is not read)"
        )
    head, head_line = nums.take(10, "luminaire header values (lamps, lumens, multiplier, angles, type, units, sizes)")
    n_lamps, lumens, multiplier, n_vert, n_horiz, ptype = head[:6]
    for value, what, least in ((n_vert, "number of vertical angles", 2), (n_horiz, "number of horizontal angles", 1)):
        if value < least or value != int(value):
            raise IESFormatError(f"{where}: line {head_line}: the {what} must be an integer >= {least}; got {value:g}")
    if ptype != 1:
        raise IESFormatError(
            f"{where}: line {head_line}: photometric type {ptype:g} is not supported "
            "(only type C, 1, the type of building luminaires)"
        )
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
        raise IESFormatError(
            f"{where}: line {line}: {len(nums.items) - nums.pos} value(s) after the candela table "
            f"(first {tok!r}): the counts in line {head_line} ({int(n_vert)} vertical, "
            f"{int(n_horiz)} horizontal angles) do not match the file"
        )
    lamp_factor = factors[1] if year < 2002 else 1.0
    scale = multiplier * factors[0] * lamp_factor
    with np.errstate(over="ignore", invalid="ignore"):
        cd = cd.reshape(int(n_horiz), int(n_vert)) * (scale * tilt_factor)
    if not (scale >= 0 and np.all(np.isfinite(cd))):
        parts = [f"candela multiplier {multiplier:g}", f"ballast factor {factors[0]:g}"]
        parts += [f"ballast-lamp factor {lamp_factor:g}"] if year < 2002 else []
        parts += [f"tilt factor {tilt_factor:g}"] if tilt_kind == "INCLUDE" else []
        raise IESFormatError(
            f"{where}: line {head_line}: the {', '.join(parts)} must be >= 0 and keep the candela values finite"
        )
    c, cd = expand_c_symmetry(horiz, cd, where)
    flux = None if lumens < 0 else float(n_lamps * lumens)
    return PhotometricDistribution(c, vert, cd, name=name, lumens=flux, source=where)


def read_photometric_text(path) -> str:
    """The text of a photometric file: UTF-8 where it decodes as such (a byte-order mark
    dropped), else Latin-1, in which older files write their names; InvalidInputError naming
    the file where it cannot be read."""
    if not isinstance(path, (str, Path)) and not hasattr(path, "__fspath__"):
        raise InvalidInputError(f"a photometric file's path must be a str or a path; got {type(path).__name__}")
    path = Path(path)
    try:
        unusable = path.exists() and (not path.is_file() or path.stat().st_size > MAX_PHOTOMETRIC_BYTES)
    except ValueError:  # a NUL byte in the path: refused below, by the read
        unusable = False
    if unusable:
        raise InvalidInputError(
            f"cannot read {str(path)!r}: not a regular file of at most "
            f"{MAX_PHOTOMETRIC_BYTES // 2**20} MiB (a photometric file is a few kB)"
        )
    try:
        raw = path.read_bytes().removeprefix(b"\xef\xbb\xbf")
    except OSError as e:
        raise InvalidInputError(f"cannot read {str(path)!r}: {e.strerror}") from None
    except ValueError as e:  # a NUL byte in the path
        raise InvalidInputError(f"cannot read {str(path)!r}: {e}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def read_ies(path, tilt: float = 0.0) -> PhotometricDistribution:
    """Read an IES LM-63 file (type C photometry); ``tilt``: installed lamp tilt for TILT=INCLUDE, degrees."""
    return parse_ies(read_photometric_text(path), str(path), tilt)
