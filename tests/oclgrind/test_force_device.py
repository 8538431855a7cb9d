"""PYDYNRAD_FORCE_DEVICE: the one switch that turns off every host shortcut taken beside a CPU
device (pydynrad.host.shortcuts.host_shortcuts), so the passes a GPU runs are tested on PoCL
too, against the host's answers."""

import numpy as np
import pytest

import pydynrad
from pydynrad.bounces import multibounce
from pydynrad.comparison import radiosity_error
from pydynrad.device.csr import DeviceCSR
from pydynrad.device.matrix import DeviceMatrix
from pydynrad.farfield import FarField
from pydynrad.farfield.estimate import DEFAULT_TOLERANCE
from pydynrad.host.product import HOST_PRODUCT_BYTES, HostBounce, HostMatrix, on_host
from pydynrad.host.shortcuts import FORCE_DEVICE_ENV, host_shortcuts
from pydynrad.scenes.analytic import closed_box


@pytest.fixture(scope="module")
def box(device):
    scene = closed_box(subdivisions=2)  # 192 patches
    emission = np.zeros((len(scene), 3))
    emission[np.argmax(scene.centers[:, 1])] = 5.0
    scene = scene.with_materials(albedo=np.tile([0.7, 0.5, 0.3], (len(scene), 1)), emission=emission)
    return scene, pydynrad.form_factors(scene, resolution=16, device=device)


def test_one_switch_turns_every_shortcut_off(device, monkeypatch):
    if not device.traits.cpu:
        pytest.skip("no host shortcuts beside a GPU")
    monkeypatch.delenv(FORCE_DEVICE_ENV, raising=False)
    assert host_shortcuts(device) and on_host(device, HOST_PRODUCT_BYTES)
    assert not host_shortcuts(device.with_traits(cpu=False)) and not on_host(device.with_traits(cpu=False), 1)
    for off in ("", "0"):
        monkeypatch.setenv(FORCE_DEVICE_ENV, off)
        assert host_shortcuts(device)
    monkeypatch.setenv(FORCE_DEVICE_ENV, "1")
    assert not host_shortcuts(device) and not on_host(device, 1)


def test_forced_multibounce_build_equals_the_hosts(device, box, monkeypatch):
    if not device.traits.cpu:
        pytest.skip("the device path is the only one beside a GPU")
    scene, F = box
    S = np.arange(0, len(scene), 3)
    monkeypatch.delenv(FORCE_DEVICE_ENV, raising=False)
    host = multibounce(scene, F, patches=S, device=device)  # numpy beside a CPU device
    monkeypatch.setenv(FORCE_DEVICE_ENV, "1")
    forced = multibounce(scene, F, patches=S, device=device)  # gemm_acc's Gauss-Jordan on the device
    assert forced.shape == host.shape == (3, len(S), len(S))
    np.testing.assert_allclose(forced, host, rtol=2e-5, atol=2e-6 * host.max())


@pytest.mark.parametrize("storage, rtol", [("fp32", 2e-5), ("fp16", 3e-3)])
def test_forced_far_field_runs_on_the_device_and_agrees(device, box, monkeypatch, storage, rtol):
    if not device.traits.cpu:
        pytest.skip("the device path is the only one beside a GPU")
    scene, F = box
    L = scene.emission.astype(np.float64)
    monkeypatch.delenv(FORCE_DEVICE_ENV, raising=False)
    host = FarField(scene, F, clusters=len(scene) // 8, coarse="dense", coarse_storage=storage, device=device)
    assert isinstance(host.K_c, HostMatrix) and isinstance(host._G_product, HostBounce) and host._F_cols is not None
    monkeypatch.setenv(FORCE_DEVICE_ENV, "1")
    forced = FarField(scene, F, clusters=host.clusters, coarse="dense", coarse_storage=storage, device=device)
    # Every product as on a GPU: K_c and G on the device, F L by a device pass of F's rows.
    assert isinstance(forced.K_c, DeviceMatrix) and isinstance(forced._G_product, DeviceCSR)
    assert forced._F_cols is None and forced._F_dev is not None
    want = host.light(L)
    np.testing.assert_allclose(forced.light(L), want, rtol=rtol, atol=rtol * want.max())


def test_forced_dynamic_radiosity_agrees(device, box, monkeypatch):
    """The frame loop with its far field, every shortcut off, against the default: the same
    answer without refinement; refined, both within the tolerance of the full solve (the sweeps
    solve the trapped patches before a sweep with F's columns on the host, after it without)."""
    if not device.traits.cpu:
        pytest.skip("the device path is the only one beside a GPU")
    scene, F = box
    light = pydynrad.PointLight((0.5, 0.6, 0.5), (2.0, 2.0, 2.0))

    def frames(**kw):
        dyn = pydynrad.DynamicRadiosity(
            scene, F, local_size=64, max_swaps_per_frame=4, observer=[0.2, 0.5, 0.2], device=device, **kw
        )
        for p in ([0.4, 0.5, 0.4], [0.8, 0.5, 0.7]):
            dyn.update(p)
        return dyn.radiosity([light])

    L = pydynrad.light_vector(scene, [light], device=device)
    full = pydynrad.solve(scene, F, light=L, tol=1e-10, device=device).radiosity
    monkeypatch.delenv(FORCE_DEVICE_ENV, raising=False)
    want, refined = frames(tolerance=None), frames()
    monkeypatch.setenv(FORCE_DEVICE_ENV, "1")
    np.testing.assert_allclose(frames(tolerance=None), want, rtol=1e-4, atol=1e-5 * want.max())
    for B in (refined, frames()):
        assert radiosity_error(B, full, scene.areas, emission=np.minimum(scene.emission, L)) <= DEFAULT_TOLERANCE
