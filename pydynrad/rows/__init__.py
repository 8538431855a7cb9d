"""Rows of the form-factor matrix F, wherever they live.

* :mod:`.sources`: the ``RowSource`` protocol; in-memory rows (:class:`CSRRows`) and rows
  computed on demand by hemicube (:class:`HemicubeRows`);
* :mod:`.cache`: :class:`RowCache`, a bounded prefetching cache in front of any source;
* :mod:`.files`: one-file ``.npz`` form factors and opening any saved F for a scene;
* :mod:`.store`: :class:`FormFactorStore`, a chunked, checksummed, resumable store on disk;
* :mod:`.prolongation`: the layout of the far field's prolongation as stores keep it.

Filling a store is :mod:`pydynrad.precompute`'s job.

See docs/design.md, 'Row sources, stores and caches' and 'Distributed precompute'.
"""

from .cache import RowCache
from .files import load_form_factors, open_form_factors, save_form_factors
from .sources import CSRRows, HemicubeRows, RowSource, as_row_source
from .store import FormFactorStore, StoreCorruptError, StoreIncompleteError, StoreMismatchError

__all__ = [
    "as_row_source",
    "CSRRows",
    "FormFactorStore",
    "HemicubeRows",
    "load_form_factors",
    "open_form_factors",
    "RowCache",
    "RowSource",
    "save_form_factors",
    "StoreCorruptError",
    "StoreIncompleteError",
    "StoreMismatchError",
]
