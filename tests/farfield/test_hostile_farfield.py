"""Hostile far-field input: lights past float32, coarse sweeps that do not converge."""

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import InvalidInputError


def test_a_light_past_float32_is_refused_and_leaves_the_far_field_as_it_was(device):
    """max B <= max L / (1 - max albedo): where that passes float32 the full solve, the dynamic
    solution and the far field refuse the light before computing it (the iterative solve had
    returned inf, and one such light was kept among the far field's answers and broke every
    later one: inf, or LAPACK's SVD failing); a negative L is refused by the far field as by
    the others. After the refusals the far field answers a light as a fresh one does."""
    from pydynrad.farfield import FarField

    closed_box_48 = pydynrad.scenes.cornell_box(max_edge=None)
    F = pydynrad.form_factors(closed_box_48, 16, device=device)
    L = pydynrad.light_vector(closed_box_48, [pydynrad.PointLight((278.0, 500.0, 280.0), (3e5,) * 3)], device=device)
    far = FarField(closed_box_48, F, clusters=len(closed_box_48) // 8, device=device)
    dyn = pydynrad.DynamicRadiosity(closed_box_48, F, local_size=64, observer=(278.0, 273.0, -300.0), device=device)
    for bad in (L / L.max() * 3e38, L / L.max() * 1e298):
        for call in (
            lambda: far.light(bad),
            lambda: dyn.radiosity(light=bad),
            lambda: pydynrad.solve(closed_box_48, F, light=bad, device=device),
        ):
            with pytest.raises(InvalidInputError, match="beyond float32"):
                call()
    with pytest.raises(InvalidInputError, match="L must be >= 0"):
        far.light(-L)
    # Each bound is the narrowest type its products compute in: a float64 far field with an fp32
    # K_c is float32's, a K on the device its storage's; fp64 storage takes what fits float64.
    from pydynrad.device.matrix import DeviceMatrix

    big = L / L.max() * 1e300
    far64 = FarField(
        closed_box_48,
        F,
        clusters=len(closed_box_48) // 8,
        dtype=np.float64,
        coarse="dense",
        coarse_storage="fp32",
        device=device,
    )
    K = DeviceMatrix(device, pydynrad.multibounce(closed_box_48, F, device=device), "fp32")
    for call in (lambda: far64.light(big), lambda: pydynrad.multibounce_radiosity(closed_box_48, K, light=big)):
        with pytest.raises(InvalidInputError, match="beyond float32"):
            call()
    dyn64 = pydynrad.DynamicRadiosity(
        closed_box_48, F, local_size=64, storage="fp64", far_field=False, observer=(278.0, 273.0, -300.0), device=device
    )
    huge = L / L.max() * 2e38  # radiosity past float32, within float64
    B = dyn64.radiosity(light=huge)
    assert np.all(np.isfinite(B)) and B.max() >= 2e38
    fresh = FarField(closed_box_48, F, clusters=len(closed_box_48) // 8, device=device)
    for x in (L, 2.0 * L):
        np.testing.assert_array_equal(far.light(x), fresh.light(x))


def test_coarse_sweeps_that_do_not_converge_raise_and_keep_nothing(device):
    """At albedo 0.999 one coarse sweep is far from the answer (99.6% off, returned silently
    once): the far field raises ConvergenceError as the full solve does, and a later light with
    enough sweeps is answered as by a fresh far field."""
    from pydynrad.errors import ConvergenceError
    from pydynrad.farfield import FarField

    closed_box_48 = pydynrad.scenes.closed_box(subdivisions=2, albedo=0.999, emission=1.0)
    F = pydynrad.form_factors(closed_box_48, 16, device=device)
    L = np.asarray(closed_box_48.emission, np.float64)
    far = FarField(closed_box_48, F, coarse="sweeps", max_sweeps=1, device=device)
    with pytest.raises(ConvergenceError, match="max_sweeps=1"):
        far.light(L)
    far.max_sweeps = 100_000
    fresh = FarField(closed_box_48, F, coarse="sweeps", max_sweeps=100_000, device=device)
    np.testing.assert_array_equal(far.light(L), fresh.light(L))
