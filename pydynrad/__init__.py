"""pydynrad: Dynamic Radiosity (Shcherbakov and Frolov) on OpenCL.

Diffuse global illumination where a local multibounce form-factor matrix over the M patches
nearest the observer is kept up to date frame by frame. Kernels live in ``kernels/`` and run
on PoCL CPU devices by default or on any OpenCL GPU (``PYOPENCL_CTX``).
"""

from .device import Device, default_device, list_devices
from .errors import (
    ConvergenceError,
    DeviceError,
    InvalidInputError,
    KernelBuildError,
    OutOfMemoryError,
    PydynradError,
    SceneFileError,
)
from .scene import DegenerateTriangleWarning, Scene
from .objects import ObjectIntersectionWarning, RigidObject
from .formfactors import form_factors
from .patching import subdivide
from .loading import load
from . import scenes
from .camera import Camera
from .render import render
from .image_io import read_image, write_image
from .walk import CameraPath, LightTrack, ObjectTrack, WalkFile, WalkResult, fly_through, load_path, load_walk, orbit, walk
from .matvec import DeviceMatrix
from .dynamic import DynamicRadiosity, FrameStats
from .dynamic.moves import PoseRows, precompute_poses, stored_poses
from .lights import DirectionalLight, PointLight, SpotLight, direct_irradiance, light_vector, pack_lights
from .solve import Solution, solve
from .multibounce import multibounce, multibounce_radiosity
from .pathtrace import path_trace, path_trace_patches
from . import photometry
from .photometry import LuminaireLight, PhotometricDistribution, SkyLight, illuminance, read_ies, read_ldt
from .rows.store import FormFactorStore, StoreCorruptError, StoreIncompleteError, StoreMismatchError, compute_store
from .rows.cache import RowCache
from .rows.sources import CSRRows, HemicubeRows, RowSource, as_row_source
from .rows.distributed import SceneSpec, precompute_distributed
from .rows.files import load_form_factors, open_form_factors, save_form_factors
from .bake import GroupRadiosity, Lightmap, LightGroups, bake_lightmap, export_mesh

__version__ = "0.1.0"

__all__ = [
    "as_row_source",
    "bake_lightmap",
    "Camera",
    "CameraPath",
    "compute_store",
    "ConvergenceError",
    "CSRRows",
    "default_device",
    "DegenerateTriangleWarning",
    "Device",
    "DeviceError",
    "DeviceMatrix",
    "direct_irradiance",
    "DirectionalLight",
    "DynamicRadiosity",
    "export_mesh",
    "fly_through",
    "form_factors",
    "FormFactorStore",
    "FrameStats",
    "GroupRadiosity",
    "HemicubeRows",
    "illuminance",
    "InvalidInputError",
    "KernelBuildError",
    "light_vector",
    "LightGroups",
    "Lightmap",
    "LightTrack",
    "LuminaireLight",
    "list_devices",
    "load",
    "load_form_factors",
    "load_path",
    "load_walk",
    "WalkFile",
    "multibounce",
    "multibounce_radiosity",
    "ObjectTrack",
    "ObjectIntersectionWarning",
    "open_form_factors",
    "orbit",
    "OutOfMemoryError",
    "pack_lights",
    "path_trace",
    "path_trace_patches",
    "PhotometricDistribution",
    "photometry",
    "PointLight",
    "PoseRows",
    "precompute_poses",
    "precompute_distributed",
    "PydynradError",
    "read_ies",
    "read_image",
    "read_ldt",
    "render",
    "RigidObject",
    "RowCache",
    "RowSource",
    "save_form_factors",
    "Scene",
    "SceneFileError",
    "scenes",
    "SceneSpec",
    "SkyLight",
    "Solution",
    "solve",
    "SpotLight",
    "stored_poses",
    "StoreCorruptError",
    "StoreIncompleteError",
    "StoreMismatchError",
    "subdivide",
    "walk",
    "WalkResult",
    "write_image",
]
