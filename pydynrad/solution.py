"""The full ("naive") radiosity solve over all N patches: B = L + P F B.

Two methods, both for every colour channel at once:

* ``"iterative"``: bounce (Jacobi / Neumann series) iteration ``B <- L + P F B`` from
  ``B = L``, one sparse matrix-vector kernel per bounce (``kernels/spmv.cl``) in float32
  or float64: on CSR F, or for grey scenes on wide-SIMD CPUs on SELL-C F
  (:mod:`pydynrad.device.sell`). F is uploaded once per :class:`RadiositySolver`, so re-lighting a scene costs
  a new light vector and the iterations, never a new upload.
* ``"dense"``: numpy float64 LU solve of ``(I - P F) B = L``: the reference for small N.

Convergence. The iteration contracts with factor q <= max_i rho_i * sum_j F_ij < 1, so it
always converges for valid input, but slowly when q is near 1 (about ln(tol) / ln(q)
bounces: 1,400 for q = 0.99 at tol = 1e-6). ``residual`` is the relative max-norm residual
``max |L + P F B - B| / max |B|`` of the second-to-last iterate, an upper bound on the
returned one's. The error of B is at most ``residual / (1 - q)`` relative: choose ``tol``
accordingly for albedos near 1.

See docs/design.md, 'Full solve'.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .checks import check_form_factors, flag, number
from .device.csr import DeviceCSR
from .device.devices import device_or_default, real_dtype
from .device.launch import sell_layout
from .device.sell import DeviceSELL
from .errors import ConvergenceError, InvalidInputError, OutOfMemoryError
from .geometry.loading import checked_scene
from .host.memory import available_host_bytes
from .lights.areas import analytic_emitter_light
from .lights.sources import check_radiosity_range, checked_light_vector
from .progress import progress_bar

__all__ = ["Solution", "RadiositySolver", "solve", "DENSE_MAX_PATCHES"]

#: The dense reference solve is refused above this many patches (an N x N float64 LU:
#: 8192 patches take 0.5 GiB and about a minute on 2 cores).
DENSE_MAX_PATCHES = 8192


@dataclass
class Solution:
    """Result of :func:`solve`.

    radiosity : (N, 3) float64
        B per patch and RGB channel (the units of the emission, e.g. W/m^2).
    light : (N, 3) float64
        The light vector L it was solved for (emission plus reflected direct light).
    iterations : int
        Bounces run (0 for the dense method).
    residual : float
        Relative max-norm residual max|L + P F B - B| / max|B| (see the module notes).
    converged : bool
        residual <= tol (always True for the dense method).
    method, dtype : str
        The solve method and the working precision.
    channels : int
        Colour channels actually computed (1 when albedos and L are grey).
    seconds : float
        Wall time of the solve itself (F's upload and kernel builds excluded).
    """

    radiosity: np.ndarray
    light: np.ndarray
    iterations: int
    residual: float
    converged: bool
    method: str
    dtype: str
    channels: int
    seconds: float
    history: list = field(default_factory=list, repr=False)


def _channels(scene, L: np.ndarray) -> int:
    grey_light = bool(np.all(L[:, 0] == L[:, 1]) and np.all(L[:, 0] == L[:, 2]))
    return 1 if scene.is_grey and grey_light else 3


class RadiositySolver:
    """The iterative solver with F resident on the device: build once, solve for many L.

    F is uploaded at once in the format of the scene's channels (:meth:`format`).

    Parameters
    ----------
    scene : Scene
    F : (N, N) sparse or dense
        Gathering form factors (validated by :func:`check_form_factors`).
    dtype : np.float32 | np.float64
        Working precision of the kernels.
    device : Device, optional
    layout : (LX, blocks), optional
        The CSR kernel's layout (:func:`pydynrad.device.launch.spmv_layout`); forces CSR.
    """

    def __init__(self, scene, F, dtype=np.float32, device=None, *, layout: tuple[int, int] | None = None) -> None:
        scene = checked_scene(scene)
        self.scene, self.device = scene, device_or_default(device)
        self.dtype = real_dtype(dtype, self.device)
        F = check_form_factors(scene, F)
        self._n = len(scene)
        self._host_F, self._layout, self._formats = F, layout, {}
        self.nnz = F.nnz
        # Uploaded now in the format of the scene's own channels; a grey scene lit in colour may
        # later add the other (docs/design.md, 'Full solve').
        self._matrix(1 if scene.is_grey else 3)

    def format(self, channels: int) -> str:
        """The format F takes for ``channels`` (1 or 3): "csr", or "sell-C" for grey solves on
        wide-SIMD CPUs (:func:`pydynrad.device.launch.sell_layout`); an explicit ``layout`` forces CSR."""
        sell = self._sell(channels)
        return "csr" if sell is None else f"sell-{sell.c}"

    @property
    def nbytes(self) -> int:
        """Device bytes of F in every format uploaded so far (padding included)."""
        return sum(m.nbytes for m in self._formats.values())

    def _sell(self, channels: int):
        return None if self._layout is not None else sell_layout(self.device, self.dtype.itemsize, channels)

    def _matrix(self, channels: int):
        key, sell = self.format(channels), self._sell(channels)
        if key not in self._formats:
            self._formats[key] = (
                DeviceCSR(self.device, self._host_F, self.dtype, self._layout)
                if sell is None
                else DeviceSELL(self.device, self._host_F, self.dtype, sell)
            )
        return self._formats[key]

    def solve(
        self,
        L: np.ndarray,
        tol: float = 1e-6,
        max_iterations: int = 10000,
        bounces: int | None = None,
        raise_on_failure: bool = True,
        progress: bool | None = None,
    ) -> Solution:
        """B for light vector L (N, 3). See :func:`solve` for the parameters."""
        L = checked_light_vector(L, self._n)
        check_radiosity_range(L, self.scene.albedo, self.dtype)
        tol, max_iterations = _checked_stopping(tol, max_iterations, bounces)
        raise_on_failure = flag(raise_on_failure, "raise_on_failure")
        nch = _channels(self.scene, L)
        rho = self.scene.albedo.astype(np.float64)[:, :nch]
        t0 = time.perf_counter()
        # The number of sweeps is unknown ahead (about ln(tol) / ln(albedo)): the bar counts them
        # and shows the change the stopping rule reads.
        with progress_bar(progress, desc=f"solve N={self._n}", unit="sweep") as bar:

            def step(change: float) -> None:
                bar.set_postfix_str(f"change {change:.2g}", refresh=False)
                bar.update(1)

            # A fixed number of bounces never stops early (tol < 0).
            B, it, residual, history = self._matrix(nch).jacobi(
                L[:, :nch], rho, L[:, :nch], tol if bounces is None else -1.0, max_iterations, step=step
            )
        seconds = time.perf_counter() - t0
        converged = residual <= tol
        if bounces is None and not converged and raise_on_failure:
            raise ConvergenceError(
                f"bounce iteration did not reach tol={tol:g} in {max_iterations} iterations (relative residual "
                f"{residual:.3g}); albedos near 1 need about ln(tol)/ln(max albedo) bounces: raise max_iterations, "
                "use method='dense' for small scenes, or pass raise_on_failure=False to get the partial result"
            )
        radiosity = np.repeat(B, 3, axis=1) if nch == 1 else B
        return Solution(
            radiosity=radiosity,
            light=L,
            iterations=it,
            residual=residual,
            converged=converged,
            method="iterative",
            dtype=self.dtype.name,
            channels=nch,
            seconds=seconds,
            history=history,
        )


#: The most bounces or iterations a solve runs (10**30 had been accepted, and run until killed):
#: a million is ~1e-45 of the light left at albedo 0.9999.
MAX_ITERATIONS = 1_000_000


def _whole(value, what: str, least: int) -> int:
    """``value`` as an int in least..MAX_ITERATIONS: a whole number (25.0 too), no text or bool."""
    v = None if isinstance(value, (bool, np.bool_)) else number(value, what)
    if v is None or v != int(v) or not least <= v <= MAX_ITERATIONS:
        raise InvalidInputError(f"{what} must be an integer in {least}..{MAX_ITERATIONS}; got {value!r}")
    return int(v)


def _checked_stopping(tol, max_iterations, bounces):
    if bounces is not None:
        return float(number(tol, "tol")), _whole(bounces, "bounces", 0)
    tol = number(tol, "tol")
    if not tol > 0:
        raise InvalidInputError(f"tol must be a positive number; got {tol!r}")
    return tol, _whole(max_iterations, "max_iterations", 1)


def _dense_solve(scene, F: sp.csr_matrix, L: np.ndarray) -> Solution:
    n = len(scene)
    if n > DENSE_MAX_PATCHES:
        raise InvalidInputError(
            f"method='dense' builds an N x N matrix; refused for N={n} > {DENSE_MAX_PATCHES} patches: use method='iterative'"
        )
    need = 2 * n * n * 8
    if need > available_host_bytes():
        raise OutOfMemoryError(f"the dense solve needs {need / 2**30:.2f} GiB of host memory; not available")
    nch = _channels(scene, L)
    t0 = time.perf_counter()
    Fd = F.toarray()
    B = np.empty((n, 3))
    if nch == 1:
        A = np.eye(n) - scene.albedo[:, :1].astype(np.float64) * Fd
        B[:] = np.linalg.solve(A, L[:, :1])
    else:
        for c in range(3):
            A = np.eye(n) - scene.albedo[:, c : c + 1].astype(np.float64) * Fd
            B[:, c] = np.linalg.solve(A, L[:, c])
    r = L + scene.albedo.astype(np.float64) * (F @ B) - B
    residual = float(np.abs(r).max() / max(np.abs(B).max(), np.finfo(float).tiny))
    return Solution(
        radiosity=B,
        light=L,
        iterations=0,
        residual=residual,
        converged=True,
        method="dense",
        dtype="float64",
        channels=nch,
        seconds=time.perf_counter() - t0,
    )


def solve(
    scene,
    F,
    lights=(),
    method: str = "iterative",
    tol: float = 1e-6,
    max_iterations: int = 10000,
    dtype=np.float32,
    device=None,
    bounces: int | None = None,
    raise_on_failure: bool = True,
    light=None,
    emitters: str = "hemicube",
    progress: bool | None = None,
) -> Solution:
    """Radiosity B = L + P F B over all patches.

    Parameters
    ----------
    scene : Scene
    F : (N, N) scipy.sparse or dense array
        Gathering form factors, F[i, j] = fraction of the energy leaving i that reaches j.
    lights : sequence of PointLight / SpotLight / DirectionalLight
        Analytic lights; L = emission + albedo * direct irradiance (:func:`light_vector`).
    method : "iterative" | "dense"
    tol : float
        Relative residual to stop at (iterative).
    max_iterations : int
        Iteration budget (iterative).
    dtype : np.float32 | np.float64
        Working precision of the iterative kernels (dense is always float64).
    bounces : int, optional
        Run exactly this many bounces instead (B = sum_{k <= bounces} (P F)^k L); no error.
    raise_on_failure : bool
        When the budget runs out before ``tol``: raise :class:`ConvergenceError` (default), or
        return the partial result with ``converged=False``.
    light : (N, 3) array, optional
        A precomputed light vector L, instead of ``lights`` (give one or the other).
    emitters : "hemicube" or "analytic"
        How emitting patches light the others: through F, or (for receivers close to emitters,
        where hemicube rows are coarse) by the exact point-to-polygon form factor with shadow
        rays, solving for ``B - E`` (:func:`pydynrad.lights.areas.reflected_light_vector`);
        then ``Solution.light`` is that reflected light vector. Only with ``lights=``.
    progress : bool, optional
        A tqdm bar counting the iterative solve's sweeps; None: once the solve has taken two
        seconds (:mod:`pydynrad.progress`); False: never.

    Returns
    -------
    Solution
    """
    if method not in ("iterative", "dense"):
        raise InvalidInputError(f"unknown method {method!r}; allowed: 'iterative', 'dense'")
    scene = checked_scene(scene)
    L, E = analytic_emitter_light(scene, lights, light, emitters, device)
    if method == "dense":
        sol = _dense_solve(scene, check_form_factors(scene, F), L)
    else:
        solver = RadiositySolver(scene, F, dtype=dtype, device=device)
        sol = solver.solve(
            L,
            tol=tol,
            max_iterations=max_iterations,
            bounces=bounces,
            raise_on_failure=raise_on_failure,
            progress=progress,
        )
    if E is not None:
        sol.radiosity = sol.radiosity + E
    return sol
