"""A moving object's rows at each of its poses, made before a walk (the paper's variant: every
pose of a path precomputed), in memory or in a store, and read back from one.

See docs/design.md, 'Moving objects'.
"""

from __future__ import annotations

import numpy as np

from ..checks import floats
from ..checks import resolution as checked_resolution
from ..defaults import RESOLUTION
from ..dynamic.occlusion import refresh_order
from ..dynamic.poses import PoseRows
from ..errors import InvalidInputError
from ..formfactors import form_factors
from ..geometry.loading import checked_scene
from ..geometry.objects import _objects, instanced, rigid_transform
from ..progress import progress_bar
from ..rows.store import StoreMismatchError

__all__ = ["precompute_poses", "stored_poses"]


def _configurations(objs, poses):
    """Each configuration of ``poses`` as a list of validated transforms, one per object."""
    try:
        poses = list(poses)
    except TypeError:
        raise InvalidInputError(f"poses must be a sequence of configurations; got {type(poses).__name__}") from None
    for config in poses:
        config = floats(config, "a configuration of poses")
        transforms = [rigid_transform(t) for t in (config[None] if config.ndim == 2 else config)]
        if len(transforms) != len(objs):
            raise InvalidInputError(
                f"a configuration needs one transform per object ({len(objs)}); got {len(transforms)}"
            )
        yield transforms


def stored_poses(scene, objects, store, resolution: int = RESOLUTION) -> PoseRows:
    """The per-pose rows in form-factor ``store`` (a :class:`~pydynrad.FormFactorStore` of the
    static ``scene``) as :class:`PoseRows` for ``MovingObjects(poses=...)``. Raises
    :class:`~pydynrad.rows.store.StoreMismatchError` for a store of another scene, or whose
    poses are of other objects or another resolution."""

    objs = _objects(objects)
    if store.header["geometry_hash"] != scene.geometry_hash() or store.n_patches != len(scene):
        raise StoreMismatchError(f"form-factor store {store.path} is of another scene than {scene.name!r}")
    R = checked_resolution(resolution)
    store.check_pose_objects(objs, resolution=R)
    return PoseRows(len(scene) + sum(len(o) for o in objs), R, PoseRows.geometry_of(scene, objs), store=store)


def precompute_poses(
    scene, objects, poses, resolution: int = RESOLUTION, device=None, store=None, progress: bool | None = None
) -> PoseRows:
    """The rows of each configuration in ``poses`` for :class:`pydynrad.MovingObjects`'s ``poses=``.

    ``poses``: a sequence of configurations, each a (4, 4) transform per object (a single
    (4, 4) per entry for one object): a keyframed path. Costs one hemicube per object patch
    and per static patch that may see an object, per configuration. With ``store`` (a
    :class:`~pydynrad.FormFactorStore` of ``scene``) the rows go into the store's per-pose part
    (a file per configuration; configurations already there are kept, so an interrupted run
    resumes) and the result reads them from there. ``resolution``: of the hemicubes (default
    64, as everywhere: :mod:`pydynrad.defaults`); ``progress``: a bar over the configurations
    (:mod:`pydynrad.progress`).
    """

    scene = checked_scene(scene)
    objs = _objects(objects)
    R = checked_resolution(resolution)
    n_static = len(scene)
    if store is None:
        out = PoseRows(n_static + sum(len(o) for o in objs), R, PoseRows.geometry_of(scene, objs))
    else:
        store.set_pose_objects(objs, resolution=R)
        out = stored_poses(scene, objs, store, R)
    configurations = list(_configurations(objs, poses))
    for transforms in progress_bar(progress, iterable=configurations, desc="poses", unit="pose"):
        world = instanced(scene, objs, transforms)
        if world.bvh.transforms in out:
            continue
        spheres = [o.bounding_sphere(T) for o, T in zip(objs, transforms)]
        seeing, _ = refresh_order(world.centers[:n_static], world.normals[:n_static], spheres)
        patches = np.concatenate([seeing, np.arange(n_static, len(world))])
        out.add(world.bvh.transforms, patches, form_factors(world, R, rows=patches, device=device, progress=False))
    return out
