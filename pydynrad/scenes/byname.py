"""Scenes by name: the one resolver behind the CLI's SCENE argument, the Dask workers'
:class:`~pydynrad.precompute.distributed.SceneSpec` and the benchmarks.

A name is a built-in (:data:`BUILTIN_SCENES`, functions of :mod:`pydynrad.scenes`) or a mesh
file :func:`pydynrad.load` reads. ``max_edge`` works for all of them: built-ins whose
function has no ``max_edge`` of its own (the village, the analytic plates and box) are built
with their defaults and then split by :func:`pydynrad.geometry.patching.subdivide_scene`.
"""

from __future__ import annotations

import inspect
from pathlib import Path

from .. import scenes
from ..errors import InvalidInputError
from ..geometry.loading import load
from ..geometry.patching import subdivide_scene

__all__ = ["BUILTIN_SCENES", "is_builtin", "scene_by_name"]

#: Names that mean a built-in scene rather than a mesh file.
BUILTIN_SCENES = ("cornell_box", "village", "closed_box", "parallel_plates", "perpendicular_plates")


def is_builtin(name: str) -> bool:
    """Whether ``name`` is one of :data:`BUILTIN_SCENES`."""
    return name in BUILTIN_SCENES


def scene_by_name(name: str, **params):
    """The scene ``name`` (a built-in or a mesh file) built with ``params``.

    Built-ins take their function's keyword arguments plus ``max_edge``; mesh files take
    :func:`pydynrad.load`'s. Raises :class:`~pydynrad.InvalidInputError` for an unknown name
    or parameter, :class:`~pydynrad.errors.SceneFileError` for an unreadable file.
    """
    if is_builtin(name):
        make = getattr(scenes, name)
        accepted = inspect.signature(make).parameters
        split = params.pop("max_edge", None) if "max_edge" not in accepted else None
        unknown = sorted(set(params) - set(accepted))
        if unknown:
            raise InvalidInputError(
                f"the built-in scene {name!r} has no parameter {', '.join(map(repr, unknown))}; "
                f"it takes {', '.join(['max_edge', *(p for p in accepted if p != 'max_edge')])}"
            )
        scene = make(**params)
        if split is None:
            return scene

        return subdivide_scene(scene, max_edge=split)
    path = Path(name)
    if not path.exists() and not path.suffix:
        raise InvalidInputError(
            f"scene {name!r} is neither a mesh file nor a built-in scene ({', '.join(BUILTIN_SCENES)})"
        )

    return load(path, **params)
