"""Radiosity baked into vertex colours: meshes other tools open (Blender, game engines, web viewers).

The mesh is the scene's patches, in the scene's units (glTF readers assume metres: a scene in
millimetres, like the Cornell box, stays in millimetres), triangle i being patch i. Vertices
are the scene's smooth vertices (:mod:`pydynrad.smoothing`): one per smoothing group, so the
colours are smooth across the faces of one surface and split at creases and material
borders, exactly the corner values the renderer's smooth shading interpolates.

Formats, by the path's extension:

* ``.glb`` (glTF 2.0): ``_RADIOSITY``, float32 linear radiosity (unclipped, the unit of the
  scene's emission); ``COLOR_0``, float32 linear ``radiosity * 2**exposure`` clipped to
  [0, 1] (glTF colours are linear; viewers clamp), on an unlit material (a lightmap's mesh,
  :meth:`~pydynrad.bake.lightmap.Lightmap.write_mesh`, shows its embedded lightmap instead);
* ``.ply``: float32 ``radiosity_r/g/b`` (linear, unclipped) and the 8-bit ``red green blue``
  viewers show: ``radiosity * 2**exposure`` clipped to [0, 1] and sRGB-encoded.

Either file states the exposure, the encoding and the units in its metadata (glTF
``asset.extras["pydynrad"]``, PLY header comments). Files are written whole and checked
(:func:`pydynrad.bake.files.write_checked`). See docs/design.md, 'Baking'.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import check_file_target
from ..checks import stops
from ..errors import InvalidInputError
from ..geometry.loading import checked_scene
from ..geometry.scene import rotation_to
from ..image_io import srgb_encode
from ..smoothing import smooth_vertices
from .files import write_checked
from .gltf import glb_bytes
from .ply import ply_bytes

__all__ = ["export_mesh", "MESH_FORMATS"]

MESH_FORMATS = (".glb", ".ply")


def checked_mesh_path(path, formats: tuple[str, ...] = MESH_FORMATS) -> Path:
    """``path`` as a Path whose extension is one of ``formats``, whose folder exists and where no
    folder stands."""
    path = Path(path)
    if path.suffix.lower() not in formats:
        raise InvalidInputError(
            f"cannot tell the mesh format of {str(path)!r}: use one of the extensions {', '.join(formats)}"
        )
    return check_file_target(path)


def mesh_metadata(
    scene_name: str, n_patches: int, exposure: float, crease_angle: float, unit: float | None = None, up=None
) -> dict:
    """What a baked file's values mean, for its metadata. With ``unit`` (metres per scene unit)
    and ``up`` (the scene's up axis) :func:`mesh_bytes` writes positions in metres, +y up (glTF's
    convention); without them, in the scene's own coordinates."""
    frame = {"length_unit": "the scene's own unit (not rescaled to metres)"}
    if unit is not None and up is not None:
        frame = {
            "length_unit": "metres, +y up (the scene's coordinates scaled and rotated on write)",
            "scene_unit_metres": float(unit),
            "scene_up": [float(x) for x in up],
        }
    return {
        "scene": scene_name,
        "patches": n_patches,
        "triangles": "triangle i is patch i of the scene",
        **frame,
        "radiosity": (
            "linear radiosity (radiant exitance, the unit of the scene's emission); radiance is radiosity / pi"
        ),
        "exposure": exposure,
        "display_encoding": "radiosity * 2**exposure, clipped to [0, 1]; 8-bit values are sRGB-encoded (IEC 61966-2-1)",
        "crease_angle_degrees": crease_angle,
    }


def to_metres_y_up(positions, unit: float, up) -> np.ndarray:
    """(V, 3) float32 ``positions`` of a scene of ``unit`` metres per unit and up axis ``up`` in
    metres, +y up: the smallest rotation taking ``up`` to +y (a rotation: windings and normals
    keep their sides), then the scale."""
    p = np.asarray(positions, np.float64)
    r = rotation_to(up, (0.0, 1.0, 0.0))
    return ((p @ r.T) * float(unit)).astype(np.float32)


def display_values(radiosity: np.ndarray, exposure: float) -> np.ndarray:
    """(V, 3) float32 linear ``radiosity * 2**exposure`` clipped to [0, 1]."""
    return np.clip(radiosity * 2.0 ** stops(exposure), 0.0, 1.0).astype(np.float32)


def mesh_bytes(path: Path, positions, faces, radiosity, meta: dict, uv=None, texture: bytes | None = None) -> bytes:
    """The GLB or PLY file (by ``path``'s extension) of a mesh with per-vertex ``radiosity`` (V, 3)
    and, for GLB, lightmap coordinates ``uv`` (V, 2) as ``TEXCOORD_0`` and ``TEXCOORD_1``, and
    a PNG ``texture`` seen through ``TEXCOORD_1`` in place of the vertex colours."""
    shown = display_values(radiosity, meta["exposure"])
    if "scene_unit_metres" in meta:
        positions = to_metres_y_up(positions, meta["scene_unit_metres"], meta["scene_up"])
    if path.suffix.lower() == ".glb":
        attributes = {"POSITION": positions, "_RADIOSITY": radiosity}
        if texture is None:  # glTF multiplies COLOR_0 into the base colour texture: one or the other
            attributes["COLOR_0"] = shown
        if uv is not None:
            # glTF numbers UV sets from 0: engines take lightmaps from the second set, and the
            # scene has no texture coordinates of its own to put in the first.
            attributes["TEXCOORD_0"] = attributes["TEXCOORD_1"] = uv
        return glb_bytes(faces, attributes, {"pydynrad": meta}, name=meta["scene"], texture=texture, texcoord=1)
    if uv is not None:
        raise InvalidInputError(f"a lightmap's mesh needs two UV sets: write it as .glb, not {path.suffix}")
    eight_bit = np.round(srgb_encode(shown) * 255.0).astype(np.uint8)
    props = {"x": positions[:, 0], "y": positions[:, 1], "z": positions[:, 2]}
    props.update({f"radiosity_{c}": radiosity[:, i].astype(np.float32) for i, c in enumerate("rgb")})
    props.update({c: eight_bit[:, i] for i, c in enumerate(("red", "green", "blue"))})
    # A PLY header is ASCII lines: a scene named 'café' or with a line break in its name is
    # written with Python's escapes (it had crashed the bake after the solve).
    comments = [f"pydynrad {k}: " + str(v).encode("unicode_escape").decode("ascii") for k, v in meta.items()]
    comments.append("pydynrad properties: radiosity_r/g/b linear float32; red/green/blue the 8-bit display encoding")
    return ply_bytes(faces, props, comments)


def export_mesh(scene, radiosity, path, *, exposure: float = 0.0, crease_angle: float = 30.0) -> Path:
    """Write a radiosity solution as a mesh with per-vertex colours.

    Parameters
    ----------
    scene : Scene
    radiosity : (N, 3) or (N,) float
        Patch radiosity (e.g. ``pydynrad.solve(...).radiosity``), finite.
    path : str or Path
        ``.glb`` or ``.ply`` (see the module docstring); the folder must exist.
    exposure : float
        Stops applied to the display colours (``COLOR_0``, 8-bit PLY colours) only; the linear
        radiosity is stored unscaled. ``-log2(pi)`` shows radiance.
    crease_angle : float
        Degrees; colours are never averaged across a sharper angle (as in :func:`pydynrad.render`).

    Returns
    -------
    The path written.
    """
    scene = checked_scene(scene)
    path = checked_mesh_path(path)
    exposure = stops(exposure)
    smooth = smooth_vertices(scene, crease_angle)
    values = smooth.radiosity(radiosity)
    meta = mesh_metadata(scene.name, len(scene), exposure, float(crease_angle), unit=scene.unit, up=scene.up)
    return write_checked(path, mesh_bytes(path, smooth.positions, smooth.corner_vertex, values, meta))
