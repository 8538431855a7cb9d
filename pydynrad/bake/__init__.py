"""Baked results other tools open: vertex-coloured meshes (:mod:`.vertex`), lightmaps
(:mod:`.lightmap`), and light groups combined after the solve (:mod:`.groups`)."""

from .groups import EMISSION, GroupRadiosity, LightGroups
from .lightmap import Lightmap, bake_lightmap
from .vertex import MESH_FORMATS, export_mesh

__all__ = ["bake_lightmap", "EMISSION", "export_mesh", "GroupRadiosity", "Lightmap", "LightGroups", "MESH_FORMATS"]
