"""Geometry: the patch scene, reading mesh files, patching, the BVH, rigid objects, the camera.

* :mod:`.scene`: :class:`Scene`, planar triangle patches with albedo and emission;
* :mod:`.loading`: :func:`load`, mesh files (OBJ, PLY, glTF, ...) and trimesh meshes to a Scene;
* :mod:`.patching`: :func:`subdivide`, splitting triangles to a maximum edge;
* :mod:`.bvh`: the bounding volume hierarchy and ray casts through it;
* :mod:`.objects`: :class:`RigidObject`, a mesh that moves through a static scene;
* :mod:`.convex`: the planes bounding a convex object;
* :mod:`.camera`: :class:`Camera`, a pinhole camera.
"""

from .camera import Camera
from .loading import AlbedoClampedWarning, MalformedLineWarning, MissingMaterialWarning, load
from .objects import ObjectIntersectionWarning, RigidObject
from .patching import subdivide
from .scene import DegenerateTriangleWarning, PrecisionWarning, Scene

__all__ = [
    "AlbedoClampedWarning",
    "Camera",
    "DegenerateTriangleWarning",
    "MalformedLineWarning",
    "MissingMaterialWarning",
    "ObjectIntersectionWarning",
    "PrecisionWarning",
    "RigidObject",
    "Scene",
    "load",
    "subdivide",
]
