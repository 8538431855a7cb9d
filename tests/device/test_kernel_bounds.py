"""Inputs that would make a kernel index past a buffer are refused with a clear error before
any launch (an audit of the kernels against their launchers, after bounce's read past x)."""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import grid_scene

import pydynrad
from pydynrad import InvalidInputError
from pydynrad.device.csr import DeviceCSR
from pydynrad.device.matrix import DeviceMatrix
from pydynrad.dynamic.kupdate import UpdateKernels
from pydynrad.lights.areas import emitter_irradiance
from pydynrad.lights.sources import point_irradiance


def test_one_normal_serves_every_point_and_bad_normals_are_refused(device):
    # float4 of a (3,) normal made three rows: the kernel read a normal per point past them.
    scene = grid_scene(4, z=0.0)
    points = np.array([[0.5, 0.5, 1.0], [1.5, 2.5, 1.0], [3.0, 1.0, 2.0], [2.2, 3.1, 0.5], [1.0, 1.0, 3.0]])
    light = [pydynrad.PointLight((2.0, 2.0, 5.0), (100.0,) * 3)]
    down = np.tile([0.0, 0.0, -1.0], (5, 1))
    want = point_irradiance(scene, points, down, light, device)
    np.testing.assert_array_equal(point_irradiance(scene, points, [0.0, 0.0, -1.0], light, device), want)
    for bad in (down[:3], np.zeros((5, 3))):
        with pytest.raises(InvalidInputError, match="sensor normals"):
            point_irradiance(scene, points, bad, light, device)
    lit = scene.with_materials(emission=np.full((len(scene), 3), 1.0))
    with pytest.raises(InvalidInputError, match="sensor normals"):
        emitter_irradiance(lit, points, down[:2], device=device)
    np.testing.assert_array_equal(
        emitter_irradiance(lit, points, [0.0, 0.0, -1.0], device=device),
        emitter_irradiance(lit, points, down, device=device),
    )


def test_device_csr_refuses_what_its_kernel_would_overrun(device):
    G = sp.random(30, 4, density=0.3, format="csr", random_state=2)
    A = DeviceCSR(device, G, np.float64)
    ones = np.ones((30, 1))
    with pytest.raises(InvalidInputError, match="square"):
        A.jacobi(ones, ones, ones, 1e-6, 3)  # x and y swap: each would need 30 rows and 4
    with pytest.raises(InvalidInputError, match=r"x \(4, 1\)"):
        A.bounce(ones, ones, ones)  # x must have a row per column of A
    np.testing.assert_allclose(A.bounce(ones, ones, np.ones((4, 1))), 1.0 + G @ np.ones((4, 1)), rtol=1e-14)


def test_slots_out_of_range_or_repeated_are_refused(device):
    m = DeviceMatrix(device, np.zeros((1, 16, 16)), "fp32")
    uk = UpdateKernels(m, 4)
    for slots in ([16], [-1], [3, 3]):
        with pytest.raises(InvalidInputError, match="distinct indices"):
            uk.read_slots(0, slots)
    with pytest.raises(InvalidInputError, match="double_reflection"):
        uk.double_reflection(np.ones(15), np.ones(16), np.ones(16))
