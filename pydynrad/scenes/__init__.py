"""Built-in scenes: the Cornell box, the analytic form-factor yardsticks and a procedural village.

Each returns a :class:`~pydynrad.Scene`, e.g. ``pydynrad.scenes.cornell_box()``.
"""

from .analytic import block, closed_box, parallel_plates, perpendicular_plates
from .cornell import cornell_box
from .village import village

__all__ = ["cornell_box", "village", "parallel_plates", "perpendicular_plates", "closed_box", "block"]
