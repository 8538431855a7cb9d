"""Work done before a walk: filling form-factor stores (in process or with Dask) and objects' poses.

* :mod:`.distributed`: :func:`precompute_distributed`, a store filled by a Dask cluster
  (the ``dask`` extra);
* :mod:`.store`: :func:`compute_store`, the same blocks computed in this process;
* :func:`precompute_poses` and :func:`stored_poses`: a moving object's rows at each of its poses.
"""

from ..dynamic.poses import PoseRows
from .distributed import SceneSpec, precompute_distributed
from .poses import precompute_poses, stored_poses
from .store import compute_store

__all__ = ["PoseRows", "SceneSpec", "compute_store", "precompute_distributed", "precompute_poses", "stored_poses"]
