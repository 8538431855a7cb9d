"""The far field: every patch's radiosity at a coarse level, and its light injected into the local set.

docs/design.md, 'Far field', gives the algebra. With clusters c (pure albedo), an area-weighted
restriction R (C x N), a prolongation Pr (N x C, R Pr = I) and the patch-to-cluster form factors
G = F Pr (N x C):

    F_c = R G                         the coarse (Galerkin) form factors, C x C
    L_c = R L ;  B_c = L_c + P_c F_c B_c                     (per light change)
    B_far = L + P (G B_c)             every patch, at the coarse level's accuracy

and per frame, for the local set S and X the patches outside it,

    L'_S = L_S + P_S F[S, X] B_far[X]                         (from the local set's kept rows)
    B_S  = L'_S + P_S K_S L'_S        the local lighting product, exact given B_far.

With C = N (every patch its own cluster) G = F and B_far is the full solution.

The coarse system x = s + P_c F_c x (s = L_c, or R D1 below) is solved per light change either
with a dense coarse multibounce matrix K_c = (I - F_c P_c)^-1 F_c per channel (x = s + P_c K_c s:
one product, K_c built once by :mod:`pydynrad.bounces`'s builder, stored fp16/fp32/fp64 on
the device, or on the host in the type it computes in where that is a CPU device and K_c is
small: :mod:`pydynrad.host.product`), or by Jacobi sweeps of the sparse F_c on the device (Anderson-mixed, :data:`COARSE_MIXING`), warm-started from the best
combination of earlier solutions (x is linear in s: lights switched back, or summed, start at
their answer) (``coarse="auto"``: dense up to :data:`DENSE_CLUSTERS` clusters; bench/farfield.py
measured the switch-over). Every patch's B_far then comes from one of three gathers (``gather=``, measured in
bench/farfield.py; docs/design.md, 'Far field', 'As built'):

* ``"first_bounce"`` (the default with F): B_far = L + D1 + P G D_c with the exact first bounce
  D1 = P F L and the clusters' indirect light D_c = R D1 + P_c F_c D_c (the coarse system with
  the restricted first bounce as its source). The direct light's first bounce is exact per
  patch; only light that has bounced at least once is gathered from the clusters. F L needs
  only F's columns where L is non-zero (2% of the village's patches at night, 37% under a sun):
  on a CPU device it is the host's product over those columns of F held by column; on a GPU one
  pass of F's rows on the device. Linear in L.
* ``"shared"``: B_far = L + P F (L + D), where every patch's indirect light D is its cluster's
  D_c shared in proportion to the patch's own first bounce P F L; a second pass over all of F.
  The most accurate per pass over F (with ``fine_sweeps=1``, the default before the first-bounce
  gather). Not linear in L (the shares depend on L): answers for separate lights sum to the
  answer for their sum within about 1e-4 of the maximum.
* ``"cluster"``: B_far = L + P G B_c, the plain gather; the only one without F (stores, rows on
  demand). With ``prolongation="linear"`` (the default without F): G = F Pr for three functions
  per cluster (:func:`pydynrad.farfield.clusters.linear_basis`; 3C columns), so the gather sees a
  linear variation over each cluster instead of one value. The coarse solve stays the
  indicator's (F_c = R G_1 with G_1 the sum of each cluster's three columns, exactly F times the
  indicator), then ``fine_sweeps`` sweeps B <- L + P G (R_lin B) of the linear level, R_lin its
  least-squares fit, start from B = L + P G_1 B_c: each is one pass over G, and they converge to
  the linear Galerkin solution without its 3C x 3C coarse matrix (9x the indicator's F_c). Needs
  no F: the far field of stores (G left in the store and read per pass,
  :mod:`pydynrad.farfield.streamed`) and of rows on demand (bench/farstore.py).

Every gather but the shared one is linear in L, so a light vector that is a combination of the
last ones the far field computed (switched back, dimmed, recoloured, summed) gets the same
combination of their answers, with no pass over F or G (:meth:`FarField._combined`,
:mod:`pydynrad.farfield.history`).

With F and one value per cluster (the indicator or exposure basis; the linear basis sweeps its own level,
as above), ``fine_sweeps`` bounces B <- L + P F B of the full F follow the gather (each about halves the
error; one pass over F each). ``prolongation="exposure"``: Pr_w[i, c] = w_i / mean_c(w)
(area-weighted mean; the indicator where the mean is 0) with w the radiosity under a uniform sky
of directional lights, so a cluster's light goes to its exposed members and not to shadowed or
enclosed ones. Needs F. It lost at night (the sky is not where lamps shine).
"""

from __future__ import annotations

import functools
import threading
import time

import numpy as np
import scipy.sparse as sp

from ..bounces import multibounce_block
from ..checks import check_form_factors, finite, integer
from ..device.csr import DeviceCSR
from ..device.devices import default_device, real_dtype
from ..device.matrix import DeviceMatrix
from ..errors import ConvergenceError, InvalidInputError, PydynradError
from ..geometry.loading import checked_scene
from ..host.colproduct import columns_product, rows_product
from ..host.csrgraph import columns_float32, sum_by_label
from ..host.product import HostBounce, HostMatrix, on_host
from ..host.shortcuts import host_shortcuts
from ..lights.sources import DirectionalLight, check_radiosity_range, light_vector
from ..precision import compute_dtype, storage_dtype
from ..rows.prolongation import LINEAR_FUNCTIONS, check_prolongation
from ..rows.sources import CSRRows, HemicubeRows
from ..rows.store import FormFactorStore
from .clusters import Clusters, cluster_patches, light_components, linear_basis
from .gather import (
    basis_prolongation,
    check_store,
    checked_cluster_form_factors,
    cluster_form_factors_for,
    clusters_without_f,
)
from .history import Answers
from .streamed import StoredG

__all__ = [
    "FarField",
    "far_field_for",
    "exposure_weights",
    "weighted_prolongation",
    "sky_directions",
    "PROLONGATIONS",
    "GATHERS",
    "COARSE_SOLVES",
    "DENSE_CLUSTERS",
]

PROLONGATIONS = ("indicator", "exposure", "linear")
GATHERS = ("first_bounce", "shared", "cluster")
COARSE_SOLVES = ("auto", "dense", "sweeps")

#: The most clusters for which ``coarse="auto"`` builds a dense K_c (bench/farfield.py: above it
#: the build's 3 C^3 flops per channel outgrow the far field's precompute budget and the sweeps
#: of the sparse F_c cost no more than one dense product).
DENSE_CLUSTERS = 2048

#: Swaps the injection is carried over (:meth:`FarField.follow_swap`) before it is multiplied
#: again: each carry adds ~1e-16 of the largest entry in rounding (5.6e-16 after 11 frames on
#: the Cornell box); a full product every 1,024 swap frames caps it at ~1e-13 whatever the walk.
MAX_CARRIED_SWAPS = 1024
#: Earlier coarse solutions the sweeps' warm start combines (:meth:`FarField._warm_start`).
WARM_STARTS = 4

#: Steps that the coarse sweeps' Anderson mixing combines (0: plain Jacobi sweeps;
#: :meth:`pydynrad.device.csr.DeviceCSR.jacobi`).
COARSE_MIXING = 3

#: A light vector within this much of its maximum (per channel) of a combination of the last
#: WARM_STARTS ones is answered by the same combination of their B_far (:meth:`FarField._combined`):
#: far below the coarse solve's own tolerance, above float32's rounding of the ones held.
COMBINED_TOLERANCE = 1e-6
#: ... and only where sum_i |a_i| max|L_i| <= this times max|L| per channel: the combination's
#: error is the recorded answers' own (float rounding; the coarse sweeps' tolerance) scaled by
#: that ratio, which is 1 for a light switched back, dimmed or recoloured, at most 2 for two
#: lights summed, and large where the combination cancels (a dim lamp as the difference of
#: a sunlit scene with and without it: 1e-3 of max B off with coarse sweeps, measured) or
#: extrapolates near-parallel lights; those are computed instead.
COMBINED_GAIN = 2.0

#: Light changes whose first bounce on the host is the last one's plus that of the change (over
#: the columns whose light changed, where they are fewer than the lit ones) before a whole product
#: again, so float32 rounding cannot build up.
DELTA_BOUNCES = 16

#: Directional lights of the uniform sky that the exposure weights are solved under.
SKY_DIRECTIONS = 128


def sky_directions(n: int = SKY_DIRECTIONS) -> np.ndarray:
    """(n, 3) unit directions evenly over the sphere (a Fibonacci lattice): deterministic."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5**0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), z, r * np.sin(phi)])


def exposure_weights(scene, F: sp.csr_matrix, device, tol: float = 1e-4) -> np.ndarray:
    """(N,) radiosity (grey, channel mean) under a uniform sky of :data:`SKY_DIRECTIONS` lights."""

    sky = [DirectionalLight(tuple(d), (1.0 / SKY_DIRECTIONS,) * 3) for d in sky_directions()]
    L = light_vector(scene.with_materials(emission=0.0), sky, device=device).mean(axis=1, keepdims=True)
    rho = scene.albedo.astype(np.float64).mean(axis=1, keepdims=True)
    # At most 200 sweeps, converged or not: the weights only shape the prolongation (no answer
    # is read from them), and a sky solve cut short near albedo 1 still ranks the patches by
    # exposure, short of the later bounces in enclosed parts; a ConvergenceError here would
    # refuse the exposure prolongation exactly where a scene is brightest.
    w = DeviceCSR(device, F).jacobi(L, rho, L, tol, 200)[0]
    return np.maximum(w[:, 0], 0.0)


def weighted_prolongation(clusters: Clusters, areas: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    """(N, C) Pr_w[i, c] = w_i / mean_c(w), the area-weighted mean; the indicator where the mean is 0."""
    a = np.asarray(areas, dtype=np.float64)
    lab = clusters.labels
    mean = np.bincount(lab, weights=a * w, minlength=clusters.count) / np.bincount(
        lab, weights=a, minlength=clusters.count
    )
    scale = np.where(mean[lab] > 0, w / np.where(mean[lab] > 0, mean[lab], 1.0), 1.0)
    n = len(lab)
    return sp.csr_matrix((scale, (np.arange(n), lab)), shape=(n, clusters.count))


def _checked_clusters(clusters: Clusters, scene) -> Clusters:
    if clusters.scene_hash != scene.content_hash() or len(clusters.labels) != len(scene):
        raise InvalidInputError("these clusters were made for another scene (content hash differs)")
    return clusters


def _checked_linear(linear, n: int, C: int) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """A given (Pr, R_lin) of the linear basis, InvalidInputError unless (N, 3C) and (3C, N) sparse."""
    try:
        Pr, fit = linear
    except (TypeError, ValueError):
        raise InvalidInputError(
            "linear must be the (Pr, R_lin) pair of pydynrad.farfield.clusters.linear_basis"
        ) from None
    K = LINEAR_FUNCTIONS * C
    if not (sp.issparse(Pr) and sp.issparse(fit) and Pr.shape == (n, K) and fit.shape == (K, n)):
        raise InvalidInputError(
            f"linear must be sparse (Pr, R_lin) of shapes ({n}, {K}) and ({K}, {n}) for these clusters; "
            f"got {getattr(Pr, 'shape', None)} and {getattr(fit, 'shape', None)}"
        )
    return sp.csr_matrix(Pr), sp.csr_matrix(fit)


def _differing_rows(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """Rows of A (N, k) with an entry other than 0 (B None) or than B's, column by column:
    numpy's any(axis=1) over so few columns is several times slower than a pass per column
    (run twice per light change)."""
    out = A[:, 0] != (0.0 if B is None else B[:, 0])
    for c in range(1, A.shape[1]):
        out |= A[:, c] != (0.0 if B is None else B[:, c])
    return np.flatnonzero(out)


def _gather_product(device, G: sp.csr_matrix, dtype):
    """G's bounce product L + P (G x): on the host where that is the device and G is small
    (:mod:`pydynrad.host.product`: a small G costs less there than one device call), else on the
    device."""
    if on_host(device, HostBounce.nbytes_of(G, dtype)):
        return HostBounce(G, dtype)
    return DeviceCSR(device, G, dtype)


#: How far a given G's row sums may stray from those of F Pr where F is in memory: per row
#: (absolute + relative to F Pr's) and area-weighted over the scene. A G of hemicubes at another
#: resolution than F stays within a few percent; an all-zero G (23% error against 1.4%) does not.
G_ROW_TOLERANCE = (0.05, 0.25)
G_MEAN_TOLERANCE = (0.01, 0.05)


def _check_g_against_f(G, F, Pr, areas) -> None:
    """InvalidInputError where a given G contradicts F: its row sums (the light a patch gathers
    from every cluster) against those of F Pr, per row and area-weighted (:data:`G_ROW_TOLERANCE`,
    :data:`G_MEAN_TOLERANCE`)."""
    want = np.asarray(F @ np.asarray(Pr.sum(axis=1), dtype=np.float64).ravel(), dtype=np.float64).ravel()
    have = np.asarray(G.sum(axis=1), dtype=np.float64).ravel()
    d = np.abs(have - want)
    a = np.asarray(areas, np.float64) / float(np.sum(areas))
    worst = int(np.argmax(d - G_ROW_TOLERANCE[1] * want))
    if d[worst] > G_ROW_TOLERANCE[0] + G_ROW_TOLERANCE[1] * want[worst] or float(a @ d) > G_MEAN_TOLERANCE[
        0
    ] + G_MEAN_TOLERANCE[1] * float(a @ want):
        raise InvalidInputError(
            f"cluster_form_factors (G) contradicts the form factors F: patch {worst}'s row of G sums to "
            f"{have[worst]:.4g} where F Pr's sums to {want[worst]:.4g} (area-weighted mean difference {float(a @ d):.3g}); "
            "G must be F Pr for these clusters (pydynrad.farfield.gather.cluster_form_factors), or leave it out"
        )


def _cluster_columns(F, Pr) -> sp.csr_matrix:
    """G = F Pr (N, C) float64: natively where Pr is float64 with one entry per row (the
    indicator and the exposure-weighted prolongations: F's columns summed by cluster), else
    scipy's product (which a float32 F times a float32 Pr would sum in float32)."""
    n = Pr.shape[0]
    if Pr.dtype == np.float64 and Pr.nnz == n and np.array_equal(Pr.indptr, np.arange(n + 1)):
        return sum_by_label(F, Pr.indices, Pr.data, Pr.shape[1])
    return sp.csr_matrix(F @ Pr, dtype=np.float64)


def _locked(method):
    """Run ``method`` holding the far field's :attr:`FarField.lock`."""

    @functools.wraps(method)
    def locked(self, *args, **kwargs):
        with self.lock:
            return method(self, *args, **kwargs)

    return locked


class FarField:
    """The coarse level of a scene: clusters, F_c, G, and the far radiosity B_far per light vector.

    Threads: :meth:`light`, :meth:`injection` and :meth:`follow_swap` change the per-light state
    (B_far, the last injection, the answers later lights are fitted to) and each holds
    :attr:`lock`, a re-entrant lock; a caller that needs B_far and the injection of one light
    together (two solutions sharing this far field, each with its own lights) holds ``lock``
    around both calls, as :meth:`pydynrad.DynamicRadiosity.radiosity` does.

    Parameters
    ----------
    scene : pydynrad.Scene
    form_factors : (N, N) sparse, optional
        F in memory. Without it ``G`` must be given (from
        :func:`pydynrad.farfield.gather.cluster_form_factors` or a form-factor store).
    clusters : Clusters or int, optional
        A partition (:func:`cluster_patches`), or C for one; default C from N.
    G : (N, C) sparse or StoredG, optional
        The patch-to-cluster form factors F Pr for these clusters (computed from F if omitted);
        a :class:`pydynrad.farfield.streamed.StoredG` (without F) stays in its store and is read
        chunk by chunk on every pass over it.
    prolongation : "indicator" | "exposure" | "linear"
        Default: "indicator" with F, "linear" without.
    gather : "first_bounce" | "shared" | "cluster", optional
        How every patch's B_far is gathered (module docstring); default "first_bounce" with F
        and "cluster" without it or with the linear basis (the others need F and one value per
        cluster).
    fine_sweeps : int, optional
        With F's gathers: bounces B <- L + P F B of the full F after the gather; with the
        linear basis: sweeps of the linear level after the coarse solve. 0 for none; default 0,
        or 2 with the linear basis.
    coarse : "auto" | "dense" | "sweeps"
        The coarse solve: the dense K_c product, or Jacobi sweeps of F_c; "auto": dense for
        C <= :data:`DENSE_CLUSTERS`.
    coarse_storage : "fp16" | "fp32" | "fp64", optional
        Element type of the dense K_c on the device (:class:`pydynrad.device.matrix.DeviceMatrix`; held on
        the host, :class:`pydynrad.host.product.HostMatrix`, its entries are rounded to it and kept
        in the type products compute in); default "fp64" for ``dtype=np.float64``, else "fp32".
    tol : float
        Relative max-norm change of the coarse solution at which the sweeps stop (1e-4: 17 and 14
        sweeps of the village's N/8 F_c instead of 22 and 20 at 1e-5, errors unchanged to three
        digits; bench/farfield.py); 0: always ``max_sweeps`` sweeps.
    max_sweeps : int
        The most coarse sweeps per light change; a light whose sweeps do not reach a ``tol``
        above 0 in them raises :class:`~pydynrad.errors.ConvergenceError` (nothing is kept of it).
    dtype : np.float32 | np.float64
        Precision of the sparse device products (and of K_c's build).
    device : pydynrad.device.Device, optional
    checked : bool
        ``form_factors`` already passed :func:`pydynrad.checks.check_form_factors` (a
        DynamicRadiosity's own copy): skip validating it again.
    linear : (Pr, R_lin), optional
        :func:`pydynrad.farfield.clusters.linear_basis` of these clusters, where the caller has
        built it already (``prolongation="linear"``); shapes checked, not rebuilt.

    Attributes
    ----------
    clusters : Clusters
    R, G, F_c : scipy.sparse.csr_matrix
        (C, N) restriction, (N, C) patch-to-cluster and (C, C) coarse form factors, float64
        (G: 3C columns for the linear basis; a G passed in keeps its own dtype, float32 from a
        store). Without F, G and F_c are None after construction: they are kept only where their
        products run (the device, or the host beside a CPU device where small).
    G_nnz, F_c_nnz : int
        Their non-zeros.
    K_c : pydynrad.device.matrix.DeviceMatrix, pydynrad.host.product.HostMatrix or None
        The dense coarse multibounce matrix (``coarse`` resolved to "dense"), else None: on the
        host where that is the device and K_c is small (:mod:`pydynrad.host.product`).
    B_far : (N, 3) float64 or None
        Every patch's far radiosity for the last light vector (:meth:`light`).
    sweeps : int
        Coarse sweeps the last light change took (0 with the dense K_c).
    first_bounce_columns : int
        Columns of F the last first bounce on the host multiplied: the lit ones, or those whose
        light changed where fewer (a lamp switched under a sun; :data:`DELTA_BOUNCES`).
    seconds_build, seconds_light, seconds_coarse : float
        Wall time of the construction, of the last light change and of its coarse solve (B_c).
    """

    def __init__(
        self,
        scene,
        form_factors=None,
        clusters=None,
        G=None,
        prolongation: str | None = None,
        gather: str | None = None,
        fine_sweeps: int | None = None,
        coarse: str = "auto",
        coarse_storage: str | None = None,
        tol: float = 1e-4,
        max_sweeps: int = 1000,
        dtype=np.float32,
        device=None,
        *,
        checked: bool = False,
        linear=None,
    ) -> None:

        t0 = time.perf_counter()
        self.lock = threading.RLock()  # the per-light state's (class docstring, 'Threads')
        self.scene = checked_scene(scene)
        n = len(scene)
        self.device = device or default_device()
        dtype = real_dtype(dtype, self.device)
        if prolongation is None:
            prolongation = "indicator" if form_factors is not None else "linear"
        if prolongation not in PROLONGATIONS:
            raise InvalidInputError(f"prolongation must be one of {PROLONGATIONS}; got {prolongation!r}")
        F = form_factors if form_factors is None or checked else check_form_factors(scene, form_factors)
        if gather is None:
            gather = "first_bounce" if F is not None and prolongation != "linear" else "cluster"
        if gather not in GATHERS:
            raise InvalidInputError(f"gather must be one of {GATHERS}; got {gather!r}")
        if coarse not in COARSE_SOLVES:
            raise InvalidInputError(f"coarse must be one of {COARSE_SOLVES}; got {coarse!r}")
        coarse_storage = ("fp64" if dtype == np.float64 else "fp32") if coarse_storage is None else coarse_storage
        storage_dtype(coarse_storage)
        if not (np.isfinite(tol) and tol >= 0):
            raise InvalidInputError(f"tol must be a finite number >= 0; got {tol!r}")
        max_sweeps = integer(max_sweeps, "max_sweeps", 1)
        fine_sweeps = integer(
            (2 if prolongation == "linear" else 0) if fine_sweeps is None else fine_sweeps, "fine_sweeps", 0
        )
        if F is None and G is None:
            raise InvalidInputError(
                "the far field needs F in memory or its patch-to-cluster form factors G "
                "(pydynrad.farfield.gather.cluster_form_factors, or a store holding G)"
            )
        if gather != "cluster" and prolongation == "linear":
            raise InvalidInputError(
                f"gather={gather!r} shares or gathers each cluster's one value by patch; it takes "
                "prolongation='indicator' or 'exposure', not 'linear'"
            )
        if F is None and (
            gather != "cluster" or (fine_sweeps and prolongation != "linear") or prolongation == "exposure"
        ):
            raise InvalidInputError(
                f"gather={gather!r}, fine_sweeps and prolongation='exposure' need F in memory; got "
                f"gather={gather!r}, fine_sweeps={fine_sweeps}, prolongation={prolongation!r} without F"
            )
        if clusters is None or not isinstance(clusters, Clusters):
            clusters = cluster_patches(scene, clusters, components=None if F is None else light_components(F))
        self.clusters = _checked_clusters(clusters, scene)
        C = clusters.count
        self.R = clusters.restriction(scene.areas)
        self._fit = None  # the linear level's least-squares fit R_lin (3C, N)
        if prolongation == "linear":
            self.weights = None
            Pr, self._fit = linear_basis(clusters, scene) if linear is None else _checked_linear(linear, n, C)
        elif prolongation == "exposure":
            self.weights = exposure_weights(scene, F, self.device)
            Pr = weighted_prolongation(clusters, scene.areas, self.weights)
        else:
            self.weights = None
            Pr = clusters.indicator()
        # A given G is checked like rows of F (a row of G is a row of F summed by cluster); F Pr is
        # a product of the checked F and a prolongation built here, so it needs no second check.
        self._G_stream = G if isinstance(G, StoredG) else None
        if self._G_stream is not None:
            if F is not None or tuple(G.shape) != Pr.shape:
                raise InvalidInputError(
                    f"a stored G is the far field without F, of shape {Pr.shape}; got shape "
                    f"{tuple(G.shape)}" + (" with F" if F is not None else "")
                )
            # Checked chunk by chunk while F_c is summed from it; never held whole.
            self.F_c = G.coarse_form_factors(self.R, C)
        else:
            given = G is not None
            G = _cluster_columns(F, Pr) if G is None else checked_cluster_form_factors(G, Pr.shape)
            if given and F is not None:
                _check_g_against_f(G, F, Pr, scene.areas)
            # The linear basis sums to 1 on every patch: its three column blocks add up to F times the
            # indicator. Summed after the restriction, on C x 3C, not on G (N x 3C: most of the far
            # field's memory at a million patches).
            RG = self.R @ G
            self.F_c = sp.csr_matrix(RG if self._fit is None else RG[:, :C] + RG[:, C : 2 * C] + RG[:, 2 * C :])
            del RG
        self.prolongation, self.gather, self.tol, self.max_sweeps = prolongation, gather, tol, max_sweeps
        self.fine_sweeps = fine_sweeps
        self.G = G
        self.rho = scene.albedo.astype(np.float64)
        # Pure clusters: every member has the cluster's albedo.
        first = np.zeros(C, dtype=np.int64)
        first[clusters.labels[::-1]] = np.arange(n)[::-1]
        self.rho_c = self.rho[first]
        with_F = gather != "cluster"
        # F L over the lit columns only: by column on the host where the host is the device (a
        # CPU), a pass of F's rows on a GPU. The shared gather and the fine sweeps need F's rows.
        self._F_cols = None
        if with_F and host_shortcuts(self.device):
            self._F_cols = columns_float32(F) if dtype == np.float32 else sp.csc_matrix(F, dtype=dtype)
        rows_on_device = (
            gather == "shared" or (fine_sweeps > 0 and self._fit is None) or (with_F and self._F_cols is None)
        )
        self._F_dev = DeviceCSR(self.device, F, dtype) if rows_on_device else None
        # shared: G only makes F_c; a stored G is read per pass (:meth:`_gather`).
        self._G_product = (
            None if gather == "shared" or self._G_stream is not None else _gather_product(self.device, G, dtype)
        )
        self._dtype = dtype
        # The narrowest type any of its products computes in: a float64 far field may keep K_c in fp32.
        narrow = np.dtype(dtype) == np.float32 or compute_dtype(coarse_storage) == np.float32
        self._range_dtype = np.dtype(np.float32 if narrow else np.float64)
        self.coarse = ("dense" if C <= DENSE_CLUSTERS else "sweeps") if coarse == "auto" else coarse
        self.K_c = self._dense_coarse(coarse_storage, dtype) if self.coarse == "dense" else None
        self._Fc_dev = DeviceCSR(self.device, self.F_c, dtype) if self.coarse == "sweeps" else None
        # Without F, G and F_c are the far field's largest parts: kept on the device only (on a CPU
        # device a host copy holds them twice; bench/largescale.py measures the walk's peak RSS).
        self.G_nnz, self.F_c_nnz = int(G.nnz), int(self.F_c.nnz)
        if F is None:
            self.G = self.F_c = None
        self._solved = Answers(WARM_STARTS)  # the coarse sweeps' last sources and solutions
        self._lit = Answers(WARM_STARTS, dtype)  # light()'s last L and B (k channels), answers in the device's type
        self.combined = False  # whether the last light change was a combination of earlier ones
        self._bounced = None  # the last first bounce on the host (:meth:`_first_bounce`)
        self.first_bounce_columns = 0
        self._column_seconds: float | None = None  # the host's fastest seconds per entry of F's columns
        self._L = None
        self.B_far = None
        self._injected = None  # (B_far, local rows, members, injection) of the last injection
        self._multiplied = None  # (local rows, members) the last injection multiplied (not carried)
        self._carried = 0  # swaps the injection was carried over since it was last multiplied
        self._outside_cols = None  # (local rows, members, their entries outside members or None): _far_columns
        self.sweeps = 0
        self.seconds_build = time.perf_counter() - t0
        self.seconds_light = self.seconds_coarse = 0.0  # the last light change, and its coarse solve

    def _dense_coarse(self, storage: str, dtype):
        """K_c (one channel for a grey scene, else three) in ``storage``: on the device, or on the
        host where that is the device and K_c is small (:func:`pydynrad.host.product.on_host`)."""

        channels = 1 if self.scene.is_grey else 3
        # checked: F_c is made here from checked parts, and with the exposure prolongation its
        # rows may sum above 1 (R Pr_w = I, not Pr_w's rows) while rho_c times them stays below 1.
        K = multibounce_block(
            self.F_c,
            self.rho_c[:, :channels],
            dtype=np.float64 if storage == "fp64" else dtype,
            device=self.device,
            progress=False,
            checked=True,
        )
        if on_host(self.device, HostMatrix.nbytes_of(channels, self.C, storage)):
            return HostMatrix(K, storage)
        return DeviceMatrix(self.device, K, storage)

    @property
    def C(self) -> int:
        return self.clusters.count

    @property
    def device_memory_bytes(self) -> int:
        """Device bytes of the coarse solve (K_c or F_c) and of the gather (G and/or F; a
        :class:`~pydynrad.farfield.streamed.StoredG` holds only the chunk of a pass)."""
        held = (self._G_product, self._Fc_dev, self._F_dev, self.K_c)
        return sum(m.nbytes for m in held if m is not None and not isinstance(m, (HostBounce, HostMatrix)))

    @property
    def host_memory_bytes(self) -> int:
        """Host bytes of G and F_c (with F in memory only), R, the linear fit, F by column (F's
        gathers on a CPU), G's product and K_c where they are on the host
        (:mod:`pydynrad.host.product`), the labels, B_far, the last lights' answers
        (:meth:`_combined`), the coarse sweeps' last solutions, the last first bounce and the
        local rows' entries cut out for the injection."""
        cut = None if self._outside_cols is None else self._outside_cols[2]
        mats = [m for m in (self.G, self.F_c, self.R, self._fit, self._F_cols, cut) if m is not None]
        held = sum(m.data.nbytes + m.indices.nbytes + m.indptr.nbytes for m in mats)
        held += sum(m.nbytes for m in (self._G_product, self.K_c) if isinstance(m, (HostBounce, HostMatrix)))
        far = (0 if self.B_far is None else self.B_far.nbytes) + self._lit.nbytes + self._solved.nbytes
        if self._bounced is not None:  # the last first bounce and its light (the delta bounce's start)
            far += self._bounced[0].nbytes + self._bounced[1].nbytes
        return held + self.clusters.labels.nbytes + far

    @_locked
    def light(self, L: np.ndarray) -> np.ndarray:
        """B_far (N, 3) float64 for light vector L (N, 3); cached while L is unchanged, and the
        combination of earlier answers where L combines earlier lights (:meth:`_combined`;
        :attr:`combined` says whether it was)."""
        if self._L is not None and np.array_equal(L, self._L):
            return self.B_far
        t0 = time.perf_counter()
        try:
            L_all = np.array(L, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInputError(f"L must be an (N, 3) array of numbers; got {type(L).__name__}") from None
        n = len(self.scene)
        if L_all.shape != (n, 3):
            raise InvalidInputError(f"L must have shape ({n}, 3); got {L_all.shape}")
        finite(L_all, "L")  # checked on a light change only: an unchanged L is the cached answer
        if L_all.min() < 0:
            raise InvalidInputError(f"L must be >= 0 (light is not negative); got a minimum of {L_all.min():g}")
        # Before anything is computed or recorded: an answer past float32 would be kept among the
        # answers later lights are fitted to, and poison every one of them.
        check_radiosity_range(L_all, self.scene.albedo, self._range_dtype)
        grey = self.scene.is_grey and bool(np.all(L_all[:, :1] == L_all))
        k = 1 if grey else 3
        L, rho = L_all[:, :k], self.rho[:, :k]
        B = self._combined(L)
        self.combined = B is not None
        if self.combined:
            self.sweeps, self.seconds_coarse, self.first_bounce_columns = 0, 0.0, 0
        elif self.gather == "first_bounce":
            # The coarse level solves for the indirect light D_c = R D1 + P_c F_c D_c from the exact
            # first bounce D1, not from the cluster-averaged direct light (2.8% -> 2.4% after a lamp is
            # added in the village at N/8, 0.27% -> 0.20% under a sun; bench/farfield.py).
            D1 = self._first_bounce(L)
            t1 = time.perf_counter()
            D_c = self._coarse_solve(self.R @ D1)
            self.seconds_coarse = time.perf_counter() - t1
            B = self._gather(L + D1, rho, D_c)
        else:
            L_c = self.R @ L
            B_c = self._coarse_solve(L_c)
            self.seconds_coarse = time.perf_counter() - t0
            if self.gather == "shared":
                B = self._gather_shared(L, B_c - L_c)
            elif self._fit is not None:
                # B_c on every function of its cluster is the constant B_c (they sum to 1).
                B = self._gather(L, rho, np.tile(B_c, (LINEAR_FUNCTIONS, 1)))
                for _ in range(self.fine_sweeps):
                    B = self._gather(L, rho, self._fit @ B)
            else:
                B = self._gather(L, rho, B_c)
        if self.fine_sweeps and self._fit is None and not self.combined:
            B = self._F_dev.jacobi(L, rho, B, 0.0, self.fine_sweeps)[0]
        if self.gather != "shared" and not self.combined:  # the shared gather is not linear in L
            self._lit.add(L, B)
        # Recorded as computed (answers combine linearly), answered clamped at 0: the linear basis
        # of a far field without F undershoots where a cluster's light falls off steeply, and
        # light is not negative (docs/decisions/0041-far-field-tolerance-and-light-change.md).
        B = np.maximum(B, 0.0)
        self.B_far = np.repeat(B, 3, axis=1) if k == 1 else B
        self._L = L_all
        self.seconds_light = time.perf_counter() - t0
        return self.B_far

    def _combined(self, L: np.ndarray) -> np.ndarray | None:
        """B (N, k) for light L (N, k) without a pass over F or G, where L is (to
        :data:`COMBINED_TOLERANCE` of its maximum, per channel) the combination S a of the last
        lights S whose B_far X are held: B_far is linear in L (every gather but the shared
        one), so it is X a. A light switched back, dimmed or recoloured, lights summed. The
        coefficients come from the normal equations of the recorded lights (their dot products
        kept as they are recorded); the residual decides, and a combination that cancels
        (:data:`COMBINED_GAIN`) is refused, so neither their conditioning nor cancellation can
        pass a wrong answer. None where L is no such combination (then light() computes it)."""
        fit = self._lit.fit(L)
        if fit is None:
            return None
        _, B, _, off = fit
        return B if np.all(off[:, 0] <= COMBINED_TOLERANCE) and np.all(off[:, 1] <= COMBINED_GAIN) else None

    def _gather(self, L: np.ndarray, rho: np.ndarray, x: np.ndarray) -> np.ndarray:
        """L + rho (G x) (N, k): G held (on the device, or on the host beside a CPU device where
        small), or read from its store per chunk."""
        if self._G_stream is not None:
            return self._G_stream.bounce(self.device, self._dtype, L, rho, x)
        return self._G_product.bounce(L, rho, x)

    def _coarse_solve(self, s: np.ndarray) -> np.ndarray:
        """x (C, k) = s + P_c F_c x for the source s (C, k): s + P_c K_c s, or sweeps of F_c
        from earlier solutions (:meth:`_warm_start`)."""
        k = s.shape[1]
        rho_c = self.rho_c[:, :k]
        if self.K_c is None:
            x, self.sweeps, change, _ = self._Fc_dev.jacobi(
                s, rho_c, self._warm_start(s), self.tol, self.max_sweeps, COARSE_MIXING
            )
            # As the full solve does: an unconverged answer is not returned, nor kept; tol = 0 asks
            # for max_sweeps sweeps exactly (as solve's bounces=), which never converge early.
            if self.tol > 0 and not change <= self.tol:
                raise ConvergenceError(
                    f"the far field's coarse sweeps did not reach tol={self.tol:g} in "
                    f"max_sweeps={self.max_sweeps} (last relative change {change:.3g}): raise "
                    "max_sweeps, or use coarse='dense'"
                )
            self._solved.add(s, x)
            return x
        self.sweeps = 0
        # One grey K_c serves every column in one pass; three K_c one channel each.
        KL = self.K_c.matmat(s.T[None])[0] if self.K_c.C == 1 else self.K_c.matvec(s.T)
        return s + rho_c * KL.T

    def _warm_start(self, s: np.ndarray) -> np.ndarray:
        """Where the coarse sweeps start for source s (C, k): the solution is linear in s, so the
        combination X a of the last solutions whose sources S a fit s best (least squares, per
        channel), plus the rest r = s - S a as its own first guess; s itself when none was
        solved yet. Exact when s is a combination of earlier sources (a lamp switched back on,
        lights summed), close to it when the lights move a little."""
        fit = self._solved.fit(s)
        return s.copy() if fit is None else fit[1] + fit[2]

    def share_rows(self, rows: DeviceCSR) -> None:
        """Take ``rows``, F on the device (the error estimate's copy), for the first bounce where
        a pass over it costs less than F's lit columns on the host (:meth:`_first_bounce`); kept
        only in the far field's own type, and only where it holds no copy of its own."""
        if self._F_dev is None and rows.dtype == np.dtype(self._dtype) and rows.shape == (len(self.rho),) * 2:
            self._F_dev = rows

    def _first_bounce(self, L: np.ndarray) -> np.ndarray:
        """D1 = P F L (N, k): over the lit columns of F by column (or, where fewer, the last D1 plus
        the first bounce of the columns whose light changed), or a pass of F's rows on the device
        where that is measured to cost less: a sun lights most columns, a lamp few."""
        rho = self.rho[:, : L.shape[1]]
        if self._F_cols is None:
            return self._F_dev.bounce(np.zeros_like(L), rho, L)
        cols = _differing_rows(L)
        x, D1 = L, 0.0
        last = self._bounced  # (L, D1, changes since a whole product) of the last light change
        if last is not None and last[0].shape == L.shape and last[2] < DELTA_BOUNCES:
            changed = _differing_rows(L, last[0])
            if len(changed) < len(cols):  # D1 is linear in L: add the change's first bounce
                cols, x, D1 = changed, L - last[0], last[1]
        indptr = self._F_cols.indptr
        entries = int((indptr[cols + 1] - indptr[cols]).sum())
        rows = self._F_dev
        if rows is not None and rows.seconds_bounce is not None and self._column_seconds is not None:
            if entries * self._column_seconds > rows.seconds_bounce:
                D1 = rows.bounce(np.zeros_like(L), rho, L)
                self._bounced = (L.copy(), D1, 0)
                self.first_bounce_columns = len(self.rho)
                return D1
        t0 = time.perf_counter()
        # F's entries read once in their own type, not copied out and upcast (csrc/colproduct.c).
        D1 = D1 + rho * columns_product(self._F_cols, cols, x[cols])
        if entries:
            s = (time.perf_counter() - t0) / entries
            self._column_seconds = s if self._column_seconds is None else min(self._column_seconds, s)
        self._bounced = (L.copy(), D1, 0 if last is None or x is L else last[2] + 1)
        self.first_bounce_columns = len(cols)
        return D1

    def _gather_shared(self, L: np.ndarray, D_c: np.ndarray) -> np.ndarray:
        """L + P F (L + D): the indirect light D of every patch prolongated from the clusters'
        D_c = B_c - L_c in proportion to its own first bounce D1 = P F L (the cluster's
        area-weighted mean of D1 maps to D_c; the indicator where that mean is 0), then one
        gather with F's rows. A patch no direct light reaches by one bounce gets no share of
        its cluster's indirect light, so light does not leak to shadowed members."""
        lab = self.clusters.labels
        D1 = self._first_bounce(L)
        mean = (self.R @ D1)[lab]
        share = np.where(mean > 0, D1 / np.where(mean > 0, mean, 1.0), 1.0)
        return self._F_dev.bounce(L, self.rho[:, : L.shape[1]], L + share * D_c[lab])

    @_locked
    def injection(self, local_rows: sp.csr_matrix, members: np.ndarray) -> np.ndarray:
        """L'_S - L_S = P_S F[S, X] B_far[X] (M, 3) for the local set ``members`` (slot order)
        whose F rows are ``local_rows`` (M, N)."""
        if self.B_far is None:
            raise PydynradError("light() the far field before injecting it")
        key = self._injected
        # A frame with the same lights and local set (rows replaced on every swap) reuses it.
        if key is not None and key[0] is self.B_far and key[1] is local_rows and np.array_equal(key[2], members):
            return key[3]
        far = self.B_far.copy()
        far[members] = 0.0  # X: only the patches outside S
        out = self.rho[members] * rows_product(self._far_columns(local_rows, members, self._multiplied), far)
        self._multiplied = (local_rows, np.array(members))
        self._injected, self._carried = (self.B_far, local_rows, self._multiplied[1], out), 0
        return out

    @_locked
    def follow_swap(
        self,
        before: sp.csr_matrix,
        after: sp.csr_matrix,
        members: np.ndarray,
        slots: np.ndarray,
        F_SJ: np.ndarray,
        F_SR: np.ndarray,
    ) -> None:
        """Carry the last injection over a swap, so that the next :meth:`injection` with the
        rows ``after`` and the local set ``members`` (M,) takes no pass over the rows: the
        patches J = ``members[slots]`` entered the slots ``slots`` of the local set, whose rows
        were ``before`` (M, N), in place of R; F_SJ and F_SR (M, k) are F[S, J] and F[S, R]
        over those rows. A kept slot s gathers B_far from the outside X' = X - J + R now, so
        its injection changes by rho_s (F[s, R] B_far[R] - F[s, J] B_far[J]); a swapped slot's
        is its new row's product over X'. O(M k + nnz(rows of J)) instead of O(nnz(after)):
        a walk's frames replace the rows on every swap, and the whole product would be most of
        each frame's injection (docs/decisions/0022-per-frame-injection.md). Nothing happens unless the last injection
        was of ``before`` and this local set before the swap, under the current B_far; the
        update is summed in float64, as the product is, and after :data:`MAX_CARRIED_SWAPS`
        carries the next injection multiplies the rows again (the carries' rounding, ~1e-16 of
        the largest entry each, stays bounded over any walk)."""
        key = self._injected
        if key is None or key[0] is not self.B_far or key[1] is not before:
            return
        if self._carried >= MAX_CARRIED_SWAPS:
            self._injected = None
            return
        members, slots = np.asarray(members, np.int64), np.asarray(slots, np.int64)
        leaving = key[2][slots]
        entering = members[slots]
        was = members.copy()
        was[slots] = leaving
        if not np.array_equal(key[2], was):
            return
        B, out = self.B_far, key[3].copy()
        kept = np.ones(len(members), bool)
        kept[slots] = False
        out[kept] += self.rho[members[kept]] * (F_SR[kept] @ B[leaving] - F_SJ[kept] @ B[entering])
        rows = after[slots]  # new arrays (fancy row indexing); its data replaced below
        outside = np.ones(len(B), bool)
        outside[members] = False
        rows.data = rows.data * outside[rows.indices]
        out[slots] = self.rho[entering] * rows_product(rows, B)
        self._injected, self._carried = (B, after, members.copy(), out), self._carried + 1

    def _far_columns(self, local_rows: sp.csr_matrix, members: np.ndarray, last) -> sp.csr_matrix:
        """The rows to multiply with B_far (zero on ``members``): ``local_rows`` as they are on a
        first injection with them, and from a second on (the same rows and local set: new
        lights, a moving object's frames) only their entries in the columns outside the local
        set, cut out once where they are fewer than half. Where the local set covers most of the
        scene that is a small share of the entries, and the product shrinks with it; a walk's frames,
        whose rows change with every swap, never pay for the cut. ``last``: (rows, members) of
        the last injection multiplied, not one carried over a swap (:meth:`follow_swap`): after a
        carry the rows are new to the product, and a cut of them would be dropped at the next
        swap (with new lights every frame, a cut made each time costs more than it saves;
        docs/decisions/0022-per-frame-injection.md)."""
        held = self._outside_cols
        if held is not None and held[0] is local_rows and np.array_equal(held[1], members):
            return sp.csr_matrix(local_rows) if held[2] is None else held[2]
        first = last is None or last[0] is not local_rows or not np.array_equal(last[1], members)
        given, local_rows = local_rows, sp.csr_matrix(local_rows)
        if first:
            self._outside_cols = None  # not old rows kept alive by their cut
            return local_rows
        inside = np.zeros(local_rows.shape[1], bool)
        inside[members] = True
        keep = ~inside[local_rows.indices]
        if 2 * int(keep.sum()) > local_rows.nnz:  # most entries outside (a large scene): the rows as they are
            self._outside_cols = (given, np.array(members), None)
            return local_rows
        kept_before = np.zeros(local_rows.nnz + 1, np.int64)  # entries kept before each entry
        np.cumsum(keep, out=kept_before[1:])
        cut = sp.csr_matrix(
            (local_rows.data[keep], local_rows.indices[keep], kept_before[local_rows.indptr]), shape=local_rows.shape
        )
        self._outside_cols = (given, np.array(members), cut)
        return cut


def far_field_for(scene, local_rows, clusters=None, G=None, device=None, tol: float | None = None) -> FarField:
    """The FarField a :class:`~pydynrad.DynamicRadiosity` uses for its form factors
    (:class:`pydynrad.dynamic.localrows.LocalRows`).

    F in memory (a matrix, or :class:`~pydynrad.rows.CSRRows`): everything from F. Without F the
    coarse level is piecewise linear (``prolongation="linear"``, the indicator where a store's
    G was made with it): a form-factor store (also behind a row cache) gives its own clusters
    and G (refused when it holds none), G left in the store and read per light change
    (:class:`~pydynrad.farfield.streamed.StoredG`: a million-patch G is 1.7-2 GB; pass
    ``G=store.cluster_form_factors()`` to hold it on the device instead); rows computed on
    demand: G from cluster-id hemicubes;
    any other row source: G summed from its rows, each block validated
    (:func:`pydynrad.farfield.gather.cluster_form_factors_for`). ``tol``: the coarse sweeps'
    (:class:`FarField`; None: its default).
    """
    coarse = {} if tol is None else {"tol": tol}

    if local_rows.csr is not None:
        return FarField(scene, local_rows.csr, clusters, G, device=device, checked=True, **coarse)
    inner = local_rows.source
    while not isinstance(inner, (FormFactorStore, CSRRows)) and hasattr(inner, "source"):
        inner = inner.source  # through row caches
    if isinstance(inner, CSRRows):
        return FarField(scene, inner.matrix, clusters, G, device=device, **coarse)
    basis = "linear"
    if isinstance(inner, FormFactorStore) and (G is None or inner.has_clusters):
        # A G passed in with a store that holds one is read as the store's: its clusters and basis.
        if not inner.has_clusters:
            raise InvalidInputError(
                f"form-factor store {inner.path} holds no far-field G: compute it (compute_store(..., clusters=...) or "
                "`pydynrad formfactors SCENE -o STORE --clusters C`), or pass far_field=False (--no-far-field)"
            )
        # A store's own prolongation matrix ("given") must be the indicator of its labels: checked with G below.
        basis = "linear" if inner.cluster_basis == "linear" else "indicator"
        if clusters is None:
            clusters = Clusters.from_labels(scene, inner.cluster_labels())
    if not isinstance(clusters, Clusters):
        clusters = clusters_without_f(scene, clusters, device=device)
    # Built once, for G (or the store's check of it) and the far field's own fit.
    linear = linear_basis(_checked_clusters(clusters, scene), scene) if basis == "linear" else None
    if G is None:
        pr = basis_prolongation(scene, clusters, basis) if linear is None else check_prolongation(linear[0], len(scene))
        if isinstance(inner, FormFactorStore):
            check_store(scene, inner, len(scene))
            G = StoredG(inner, pr)
        else:
            source = local_rows.source if isinstance(inner, HemicubeRows) else _CheckedRows(local_rows)
            G = cluster_form_factors_for(scene, source, pr, device=device)
    return FarField(scene, None, clusters, G, prolongation=basis, device=device, linear=linear, **coarse)


class _CheckedRows:
    """Another row source's rows as the dynamic solution reads them: every block validated, the
    bad patch named (:meth:`LocalRows.rows`), also when G is summed from them."""

    def __init__(self, local_rows) -> None:
        self.n_patches, self.rows = local_rows.n_patches, local_rows.rows
