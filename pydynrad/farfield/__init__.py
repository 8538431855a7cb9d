"""The far field: light from the patches outside the local set, through a coarse level of clusters.

:func:`cluster_patches` partitions a scene into pure, compact clusters; :func:`cluster_form_factors`
gives their patch-to-cluster form factors G by hemicube without forming F; :class:`FarField` holds
the coarse form factors and solves every patch's far radiosity per light change (a store's G left in
the store: :class:`StoredG`); a
:class:`~pydynrad.DynamicRadiosity` (``far_field=True``, the default) injects it into its local set.
"""

from .clusters import Clusters, cluster_patches, default_cluster_count
from .gather import cluster_form_factors, cluster_form_factors_for
from .level import FarField, far_field_for
from .streamed import StoredG

__all__ = [
    "Clusters",
    "cluster_patches",
    "default_cluster_count",
    "cluster_form_factors",
    "cluster_form_factors_for",
    "FarField",
    "far_field_for",
    "StoredG",
]
