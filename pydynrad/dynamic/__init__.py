"""The paper's method: a local multibounce matrix kept up to date as the observer moves.

* :mod:`.radiosity`: :class:`DynamicRadiosity`, the frame loop (select, fetch rows, update K,
  light);
* :mod:`.selection`: which patches enter and leave the local set (the M nearest the observer);
* :mod:`.localrows`: the form-factor rows of the local set, kept in slot order;
* :mod:`.exact`: the exact batched swap (block elimination; K equals a fresh build);
* :mod:`.paper`: the paper's own update (double reflection, rank-one update, bitset);
* :mod:`.kupdate`: the device kernels both updates drive (gathers, rank-2k, slot reads/writes).

See docs/design.md, 'Paper mode', 'Exact mode', 'Batched swap' and 'Local set'.
"""

from .moves import MovingObjects
from .radiosity import DynamicRadiosity, FrameStats

__all__ = ["DynamicRadiosity", "FrameStats", "MovingObjects"]
