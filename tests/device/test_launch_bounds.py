"""Long launches split on the host (no launch above ~100 ms on a small GPU; each
kernel's header states its bound): with the split forced down to a few items per launch, every
split launch gives the one launch's result bit for bit, since each item stays one work-item's
and its sums keep their order.

The constants monkeypatched here are the per-launch budgets: GEMM flops
(:data:`pydynrad.bounces.GEMM_FLOPS_PER_LAUNCH`), rays (:data:`pydynrad.geometry.bvh.CAST_CHUNK`,
:data:`pydynrad.lights.sources.LIGHT_RAYS_PER_LAUNCH`,
:data:`pydynrad.lights.areas.EMITTER_RAYS_PER_LAUNCH`,
:data:`pydynrad.pathtracer.PATH_RAYS_PER_LAUNCH`).
"""

import numpy as np
import pytest
from helpers import box_scene, reciprocal_F

import pydynrad
import pydynrad.bounces as bounces_module
import pydynrad.geometry.bvh as bvh_module
import pydynrad.lights.areas as areas_module
import pydynrad.lights.sources as sources_module
import pydynrad.pathtracer as pathtracer_module
from pydynrad import Camera, PointLight
from pydynrad.device.launch import bvh_packet, enqueue_kernel


@pytest.fixture
def counted(monkeypatch):
    """Launches per kernel name while the test runs (every launch goes through enqueue_kernel)."""
    seen: dict[str, int] = {}

    def counting(device, kernel, *args, **kwargs):
        seen[kernel.function_name] = seen.get(kernel.function_name, 0) + 1
        return enqueue_kernel(device, kernel, *args, **kwargs)

    for module in (bounces_module, bvh_module, areas_module, sources_module, pathtracer_module):
        monkeypatch.setattr(module, "enqueue_kernel", counting)
    return seen


def _same(a, b) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("bounces", [None, 3])  # the elimination and series()
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_gemm_row_blocks_bit_identical(device, monkeypatch, counted, bounces, dtype):
    rng = np.random.default_rng(0)
    s = box_scene(4)  # 192 patches: two panels after padding
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)))
    F = reciprocal_F(s.areas, row_sum=0.95, density=0.2, seed=1)
    one = pydynrad.multibounce(s, F, dtype=dtype, bounces=bounces, device=device, backend="device")
    launches = counted.get("gemm_acc", 0)
    monkeypatch.setattr(bounces_module, "GEMM_FLOPS_PER_LAUNCH", 1)  # one TM-row block a launch
    split = pydynrad.multibounce(s, F, dtype=dtype, bounces=bounces, device=device, backend="device")
    assert counted["gemm_acc"] - launches > 4 * launches
    _same(split, one)


def test_occluded_chunks_bit_identical(device, monkeypatch, counted, cornell_384):
    rng = np.random.default_rng(3)
    n = 1000
    lo, hi = cornell_384.bbox
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    tmax = rng.uniform(0.01, 1.0, n) * float(np.linalg.norm(hi - lo))
    one = bvh_module.occluded(cornell_384, o, d, tmax, device=device)
    assert counted["cast_occluded"] == 1
    assert one.any() and not one.all()
    packet = bvh_packet(device)
    expected = 1
    for chunk in (37, 16, 1):  # rounded down to whole packets, one packet at least
        monkeypatch.setattr(bvh_module, "CAST_CHUNK", chunk)
        _same(bvh_module.occluded(cornell_384, o, d, tmax, device=device), one)
        expected += -(-n // max(packet, chunk // packet * packet))
    assert counted["cast_occluded"] == expected


def test_direct_irradiance_chunks_bit_identical(device, monkeypatch, counted, cornell_384):
    lo, hi = cornell_384.bbox
    lights = [PointLight(lo + (hi - lo) * f, 1e6 * (k + 1)) for k, f in enumerate((0.3, 0.5, 0.7))]
    one = sources_module.direct_irradiance(cornell_384, lights, device=device)
    assert counted["direct_irradiance"] == 1 and (one > 0).any()
    monkeypatch.setattr(sources_module, "LIGHT_RAYS_PER_LAUNCH", 100)  # 33 points a launch
    _same(sources_module.direct_irradiance(cornell_384, lights, device=device), one)
    assert counted["direct_irradiance"] == 1 + -(-len(cornell_384) // 33)


@pytest.mark.parametrize("budget", [16 * 50, 16])  # 25 points x 2 emitters; 1 point x 1 emitter (grid 4: 16 rays)
def test_emitter_irradiance_chunks_bit_identical(device, monkeypatch, counted, cornell_384, budget):
    scene = cornell_384
    assert len(scene.emitters) > 1
    rng = np.random.default_rng(5)
    ids = rng.choice(len(scene), 150, replace=False)
    points, normals = scene.centers[ids], scene.normals[ids]
    one = areas_module.emitter_irradiance(scene, points, normals, grid=4, device=device)
    assert counted["emitter_irradiance"] == 1 and (one > 0).any()
    monkeypatch.setattr(areas_module, "EMITTER_RAYS_PER_LAUNCH", budget)
    _same(areas_module.emitter_irradiance(scene, points, normals, grid=4, device=device), one)
    emitters = max(1, min(len(scene.emitters), budget // 16))
    ranges = -(-len(scene.emitters) // emitters)
    assert counted["emitter_irradiance"] == 1 + ranges * -(-len(ids) // max(1, budget // (emitters * 16)))


def test_path_trace_chunks_bit_identical(device, monkeypatch, counted, cornell_384):
    lo, hi = cornell_384.bbox
    mid = (lo + hi) / 2
    cam = Camera(tuple(mid), tuple(mid + (hi - lo) * (0.1, -0.2, 0.4)), fov_y=80, width=24, height=18)
    one = pathtracer_module.path_trace(cornell_384, cam, spp=20, seed=4, max_depth=4, device=device)
    patches = pathtracer_module.path_trace_patches(cornell_384, spp=5, seed=4, max_depth=4, device=device)
    launches = counted["trace_pixels"]
    monkeypatch.setattr(pathtracer_module, "PATH_RAYS_PER_LAUNCH", 3000)
    _same(pathtracer_module.path_trace(cornell_384, cam, spp=20, seed=4, max_depth=4, device=device), one)
    _same(pathtracer_module.path_trace_patches(cornell_384, spp=5, seed=4, max_depth=4, device=device), patches)
    assert counted["trace_pixels"] > 3 * launches and counted["gather_patches"] > 6
