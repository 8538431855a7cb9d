"""Light groups: solve once per group of lights, then dim or recolour groups for the cost of
one weighted sum.

Radiosity is linear in the light vector: ``B = (I - P F)^-1 L``, ``B_S = L_S + P_S K L_S``
and the dynamic solution are each a linear map of L, so for groups of lights with light
vectors ``L_g`` and weights ``w_g`` (a scalar or RGB per group),

    B(sum_g w_g L_g) = sum_g w_g B(L_g).

:class:`LightGroups` holds the ``L_g`` (the scene's emission is a group of its own, named
``"emission"``, so emitters dim too); its :meth:`~LightGroups.solve`,
:meth:`~LightGroups.multibounce` and :meth:`~LightGroups.dynamic` run one solve per group and
return a :class:`GroupRadiosity`, whose :meth:`~GroupRadiosity.combine` is the one pass:

    groups = LightGroups(scene, {"sun": [sun], "lamps": [lamp1, lamp2]})
    per_group = groups.solve(F)                                   # one solve per group
    B = per_group.combine({"sun": 0.3, "lamps": (1.0, 0.8, 0.6)}) # dusk: one weighted sum

Weights may be any finite numbers (a negative one subtracts a group: the result then need not
be non-negative, so a solve of it would be refused). See docs/design.md, 'Baking'.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..bounces import multibounce_radiosity
from ..checks import flag, floats
from ..dynamic import DynamicRadiosity
from ..errors import InvalidInputError
from ..geometry.loading import checked_scene
from ..lights.sources import checked_light_vector, direct_irradiance
from ..solution import RadiositySolver, solve

__all__ = ["LightGroups", "GroupRadiosity", "EMISSION"]

#: Name of the group holding the scene's own emission.
EMISSION = "emission"


def _weights(names: tuple[str, ...], weights) -> np.ndarray:
    """(G, 3) float64 weights from a mapping name -> scalar or RGB (missing groups: 1), or a
    sequence of G scalars / RGB triples in group order."""
    out = np.ones((len(names), 3))
    if weights is None:
        return out
    if isinstance(weights, Mapping):
        unknown = sorted(set(weights) - set(names))
        if unknown:
            raise InvalidInputError(
                f"unknown light group(s) {', '.join(map(repr, unknown))}; the groups are {', '.join(map(repr, names))}"
            )
        items = [(names.index(k), v) for k, v in weights.items()]
    else:
        try:
            seq = list(weights)
        except TypeError:  # combine(0.5): one number is no list of weights
            raise InvalidInputError(
                f"weights must map group names to weights, or list one per group ({', '.join(names)}); got {weights!r}"
            ) from None
        if len(seq) != len(names):
            raise InvalidInputError(
                f"give one weight per light group ({len(names)}: {', '.join(names)}); got {len(seq)}"
            )
        items = list(enumerate(seq))
    for i, value in items:
        w = floats(value, f"the weight of light group {names[i]!r}")
        if w.shape not in ((), (3,)) or not np.all(np.isfinite(w)):
            raise InvalidInputError(
                f"the weight of light group {names[i]!r} must be a finite number or RGB triple; got {value!r}"
            )
        out[i] = w
    return out


@dataclass
class GroupRadiosity:
    """The radiosity of each light group, ready to be combined.

    Attributes
    ----------
    names : tuple of str
        Group names, in order.
    radiosity : (G, N, 3) float64
        B of each group's light alone.
    """

    names: tuple
    radiosity: np.ndarray

    def __getitem__(self, name: str) -> np.ndarray:
        """(N, 3) radiosity of one group."""
        if name not in self.names:
            raise InvalidInputError(f"unknown light group {name!r}; the groups are {', '.join(map(repr, self.names))}")
        return self.radiosity[self.names.index(name)]

    def combine(self, weights=None) -> np.ndarray:
        """(N, 3) float64 ``sum_g w_g B_g``: ``weights`` maps group names to a scalar or an RGB
        triple (groups not named keep weight 1), or lists one per group in order."""
        with np.errstate(over="ignore", invalid="ignore"):
            out = np.einsum("gc,gnc->nc", _weights(self.names, weights), self.radiosity)
        if not np.all(np.isfinite(out)):  # each weight finite, their products with B not
            raise InvalidInputError(f"the weights {weights!r} take the combined radiosity past float64's range")
        return out


class LightGroups:
    """Lights in named groups, each solved once, combined with weights afterwards.

    Parameters
    ----------
    scene : Scene
    groups : mapping of name -> lights or light vector
        Each value is a sequence of light objects (PointLight, SpotLight, DirectionalLight), one
        light, or a precomputed (N, 3) light vector, added as it is (so it must not hold the
        emission when ``emission`` is True). Names must be unique strings.
    emission : bool
        Add the scene's emission as the group ``"emission"`` (default True).
    device : Device, optional
        For the lights' shadow rays.
    """

    def __init__(self, scene, groups: Mapping, *, emission: bool = True, device=None) -> None:
        self.scene = checked_scene(scene)
        if not isinstance(groups, Mapping):
            raise InvalidInputError(f"groups must map group names to lights; got {type(groups).__name__}")
        names, vectors = [], []
        if flag(emission, "emission"):
            names.append(EMISSION)
            vectors.append(self.scene.emission.astype(np.float64))
        albedo = self.scene.albedo.astype(np.float64)
        for name, value in groups.items():
            if not isinstance(name, str) or not name:
                raise InvalidInputError(f"light group names must be non-empty strings; got {name!r}")
            if name in names:
                raise InvalidInputError(f"light group {name!r} given twice (or named like the emission group)")
            if isinstance(value, np.ndarray):
                L = checked_light_vector(value, len(self.scene))
            else:
                L = albedo * direct_irradiance(self.scene, value, device)
            names.append(name)
            vectors.append(L)
        if not names:
            raise InvalidInputError("no light groups: give at least one group, or emission=True")
        self.names = tuple(names)
        #: (G, N, 3) float64 light vector of each group.
        self.light_vectors = np.stack(vectors)
        self.device = device

    def light(self, weights=None) -> np.ndarray:
        """(N, 3) float64 combined light vector ``sum_g w_g L_g`` (see :meth:`GroupRadiosity.combine`)."""
        return np.einsum("gc,gnc->nc", _weights(self.names, weights), self.light_vectors)

    def _per_group(self, solve_one) -> GroupRadiosity:
        return GroupRadiosity(
            self.names, np.stack([np.asarray(solve_one(L), dtype=np.float64) for L in self.light_vectors])
        )

    def solve(self, F, method: str = "iterative", dtype=np.float32, **options) -> GroupRadiosity:
        """Full radiosity per group (:func:`pydynrad.solve`; ``options`` are its tol,
        max_iterations, bounces, raise_on_failure). The iterative method keeps F on the device
        across the groups."""
        if method == "iterative":
            solver = RadiositySolver(self.scene, F, dtype=dtype, device=self.device)
            return self._per_group(lambda L: solver.solve(L, **options).radiosity)
        return self._per_group(
            lambda L: solve(self.scene, F, method=method, dtype=dtype, device=self.device, light=L, **options).radiosity
        )

    def multibounce(self, K, patches=None) -> GroupRadiosity:
        """Radiosity per group through a multibounce matrix K (:func:`pydynrad.multibounce_radiosity`)."""
        return self._per_group(
            lambda L: multibounce_radiosity(self.scene, K, light=L, patches=patches, device=self.device)
        )

    def dynamic(self, dynamic) -> GroupRadiosity:
        """Radiosity per group from a :class:`~pydynrad.DynamicRadiosity` at its current local set
        (call again after each ``update``: the local matrix changed). With its far field built
        from F, the combination matches the weighted lights' answer to about 1e-4 of the maximum,
        not to rounding: the far field shares indirect light by each light's own first bounce."""
        if not isinstance(dynamic, DynamicRadiosity):
            raise InvalidInputError(f"dynamic must be a DynamicRadiosity; got {type(dynamic).__name__}")
        if dynamic.scene is not self.scene:
            moved = (
                " (its objects moved since: the world's light vectors changed with them; make the light "
                "groups again from dynamic.scene)"
                if getattr(dynamic, "objects", None)
                else ""
            )
            raise InvalidInputError(f"the DynamicRadiosity was built for another scene than these light groups{moved}")
        return self._per_group(lambda L: dynamic.radiosity(light=L))
