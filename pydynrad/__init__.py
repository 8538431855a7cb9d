"""pydynrad: Dynamic Radiosity (Shcherbakov and Frolov) on OpenCL.

Diffuse global illumination where a local multibounce form-factor matrix over the M patches
nearest the observer is kept up to date frame by frame. Kernels live in ``kernels/`` and run
on PoCL CPU devices by default or on any OpenCL GPU (``PYOPENCL_CTX``).

The names here are the ones most programs need; the rest live in the subpackages that own
them (:mod:`pydynrad.device`, :mod:`pydynrad.geometry`, :mod:`pydynrad.lights`,
:mod:`pydynrad.photometry`, :mod:`pydynrad.rows`, :mod:`pydynrad.farfield`,
:mod:`pydynrad.dynamic`, :mod:`pydynrad.precompute`, :mod:`pydynrad.bake`,
:mod:`pydynrad.scenes`).
"""

import warnings
from importlib import import_module

from . import bake, device, dynamic, farfield, geometry, lights, photometry, precompute, rows, scenes
from ._version import __version__
from .bake import bake_lightmap, export_mesh
from .bounces import multibounce, multibounce_radiosity
from .device import default_device
from .dynamic import DynamicRadiosity, FrameStats, MovingObjects
from .errors import InvalidInputError, PydynradError
from .farfield import FarField
from .formfactors import form_factors
from .geometry import Camera, RigidObject, Scene, load
from .lights import DirectionalLight, LuminaireLight, PointLight, SkyLight, SpotLight, light_vector, read_ies, read_ldt
from .pathtracer import path_trace
from .photometry import illuminance
from .precompute import compute_store
from .renderer import render
from .rows import FormFactorStore, open_form_factors, save_form_factors
from .solution import Solution, solve
from .viewer import view
from .walks import CameraPath, WalkResult, fly_through, load_path, orbit, walk

__all__ = [
    "bake_lightmap",
    "Camera",
    "CameraPath",
    "compute_store",
    "default_device",
    "DirectionalLight",
    "DynamicRadiosity",
    "export_mesh",
    "FarField",
    "fly_through",
    "form_factors",
    "FormFactorStore",
    "FrameStats",
    "illuminance",
    "InvalidInputError",
    "light_vector",
    "load",
    "load_path",
    "LuminaireLight",
    "MovingObjects",
    "multibounce",
    "multibounce_radiosity",
    "open_form_factors",
    "orbit",
    "path_trace",
    "PointLight",
    "PydynradError",
    "read_ies",
    "read_ldt",
    "render",
    "RigidObject",
    "save_form_factors",
    "Scene",
    "SkyLight",
    "Solution",
    "solve",
    "SpotLight",
    "view",
    "walk",
    "WalkResult",
]


# Names that were top-level before the subpackages: still served, with a warning naming the new home
# (CHANGELOG.md, 'Moved').
_MOVED = {
    "as_row_source": "rows",
    "ConvergenceError": "errors",
    "CSRRows": "rows",
    "DegenerateTriangleWarning": "geometry",
    "Device": "device",
    "DeviceError": "errors",
    "DeviceMatrix": "device",
    "direct_irradiance": "lights",
    "GroupRadiosity": "bake",
    "HemicubeRows": "rows",
    "KernelBuildError": "errors",
    "LightGroups": "bake",
    "Lightmap": "bake",
    "LightTrack": "walks",
    "list_devices": "device",
    "load_form_factors": "rows",
    "load_walk": "walks",
    "ObjectIntersectionWarning": "geometry",
    "ObjectTrack": "walks",
    "OutOfMemoryError": "errors",
    "pack_lights": "lights",
    "path_trace_patches": "pathtracer",
    "PhotometricDistribution": "lights",
    "PoseRows": "precompute",
    "precompute_distributed": "precompute",
    "precompute_poses": "precompute",
    "read_image": "image_io",
    "RowCache": "rows",
    "RowSource": "rows",
    "SceneFileError": "errors",
    "SceneSpec": "precompute",
    "StoreCorruptError": "rows",
    "StoreIncompleteError": "rows",
    "StoreMismatchError": "rows",
    "stored_poses": "precompute",
    "subdivide": "geometry",
    "WalkFile": "walks",
    "write_image": "image_io",
}


def __getattr__(name: str):
    if name in _MOVED:
        home = f"pydynrad.{_MOVED[name]}"
        warnings.warn(f"pydynrad.{name} moved to {home}.{name}", DeprecationWarning, stacklevel=2)
        return getattr(import_module(home), name)
    raise AttributeError(f"module 'pydynrad' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_MOVED})
