"""Leak scenes: the far field at its defaults with a local set covering part of the
lit region leaves dark what the full solve leaves dark, and its answer and estimate hold."""

import numpy as np
import pytest
from leak_scenes import LEAK_SCENES

import pydynrad
from pydynrad import DynamicRadiosity
from pydynrad.comparison import radiosity_error


@pytest.fixture(scope="module", params=list(LEAK_SCENES))
def leak_case(request, device):
    scene, lights, observer = LEAK_SCENES[request.param]()
    F = pydynrad.form_factors(scene, resolution=32, device=device, progress=False)
    L = pydynrad.light_vector(scene, lights, device=device)
    ref = pydynrad.solve(scene, F, light=L, tol=1e-10, device=device).radiosity
    return request.param, scene, F, L, ref, observer


@pytest.mark.parametrize("tolerance", ["default", None])
def test_dark_stays_dark(device, leak_case, tolerance):
    name, scene, F, L, ref, observer = leak_case
    kw = {} if tolerance == "default" else {"tolerance": tolerance}
    n = len(scene)
    dyn = DynamicRadiosity(scene, F, local_size=n // 8, observer=observer, device=device, **kw)
    B = dyn.radiosity(light=L)
    local = dyn.local_mask
    lit = ref.max(axis=1) > 1e-2 * ref.mean()
    assert local.sum() < 0.5 * lit.sum()  # M covers only part of the lit region
    dark = ref.max(axis=1) < 1e-3 * ref.mean()
    # Observed on PoCL: none lit in any scene, B = 0 exactly on the sealed ones.
    assert B[dark].max(initial=0.0) < 1e-2 * ref.mean()
    err = radiosity_error(B, ref, scene.areas, emission=np.minimum(scene.emission, L))
    est = dyn.error_estimate
    # Observed: 0.41-1.37% at tolerance=None; 0.03-0.11% at the default (0.1%), the 0.11% where
    # the estimate read 0.85 of the truth (the sun through a window).
    assert err < (0.015 if tolerance is None else 0.0015)
    assert 0.5 * err <= est.error <= 3 * err or err < 1e-4
    assert est.bound >= err  # F nearly reciprocal: the bound holds


def test_sealed_parts_are_dark_in_the_full_solve(leak_case):
    name, scene, F, L, ref, observer = leak_case
    dark = ref.max(axis=1) < 1e-3 * ref.mean()
    if name in ("sealed room", "box in a box", "closed corner"):
        assert dark.sum() >= 100  # a real test of leaks
