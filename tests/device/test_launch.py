"""pydynrad.device.launch: global sizes, the kernels' required layout defines, and the per-device
cache of scene arrays beside the BVH buffers."""

from dataclasses import replace

import numpy as np
import pytest
from helpers import box_scene

import pydynrad
from pydynrad.device.launch import WG, global_size, round_up


def test_global_size_rounds_up_to_whole_work_groups():
    assert [global_size(n) for n in (0, 1, WG - 1, WG, WG + 1, 1000)] == [WG, WG, WG, WG, 2 * WG, 1024]
    assert global_size(5, 4) == 8 and round_up(96, 128) == 128 and round_up(256, 128) == 256


@pytest.mark.parametrize(
    "filename,missing",
    [
        ("update.cl", "VW, SW, WG, RR, CWMAX, NVMAX, NAMAX and RED_WG"),
        ("matvec.cl", "VW, LX, NRHS and RI"),
        ("spmv.cl", "NCH and LX (with RGB_STEP) or SELL_C"),
        ("gemm.cl", "VW and TM"),
    ],
)
def test_kernels_take_layout_defines_from_the_host(device, filename, missing):
    with pytest.raises(pydynrad.errors.KernelBuildError) as info:
        device.program(filename, {"STORAGE_FP32": 1})
    assert f"needs {missing} from the host" in info.value.build_log


def test_spmv_needs_the_rgb_step_with_lx(device):
    with pytest.raises(pydynrad.errors.KernelBuildError) as info:
        device.program("spmv.cl", {"STORAGE_FP32": 1, "NCH": 4, "LX": 1})
    assert "needs NCH and LX (with RGB_STEP) or SELL_C from the host" in info.value.build_log


def test_path_tracer_needs_the_bounce_limit(device):
    with pytest.raises(pydynrad.errors.KernelBuildError) as info:
        device.program("pathtrace.cl")
    assert "MAX_DEPTH (the bounce limit) must come from the host" in info.value.build_log


def test_hemicube_needs_the_hosts_packet_width_and_tiles(device):
    for defines, missing in (
        ({"HC_RES": 8, "HC_TILE_Y": 2}, "needs BVH_PACKET of 4, 8 or 16"),
        ({"HC_RES": 8, "BVH_PACKET": 12, "HC_TILE_Y": 2}, "needs BVH_PACKET of 4, 8 or 16"),
        ({"HC_RES": 8, "BVH_PACKET": 8}, "needs HC_TILE_Y"),
        ({"HC_RES": 8, "BVH_PACKET": 8, "HC_TILE_Y": 3}, "needs HC_TILE_Y"),
    ):
        with pytest.raises(pydynrad.errors.KernelBuildError) as info:
            device.program("hemicube.cl", defines)
        assert missing in info.value.build_log


def test_packet_width_follows_the_device(device):
    from pydynrad.device.launch import BVH_PACKETS, bvh_packet, hemicube_tiles

    width = device.cl_device.preferred_vector_width_float
    packet = bvh_packet(device)
    assert packet in BVH_PACKETS and (packet <= width or packet == min(BVH_PACKETS))
    assert all(p > width for p in BVH_PACKETS if p > packet)
    tiles = hemicube_tiles(device)
    assert tiles.packet == packet and packet % tiles.rows == 0  # that the bands cover every
    # scanline once is tests/test_formfactors.py's test_rows_are_the_hemicube_rays_cast_one_by_one


def test_patch_buffers_once_per_device_and_per_geometry(device):
    import pyopencl as cl

    s = box_scene(2)
    centers, normals = s.patch_buffers(device)
    assert s.patch_buffers(device) == (centers, normals)  # uploaded once
    host = np.empty((len(s), 4), np.float32)
    cl.enqueue_copy(device.queue, host, normals, is_blocking=True)
    assert np.array_equal(host[:, :3], s.normals) and not host[:, 3].any()
    # Same geometry (with_materials shares the BVH): the same buffers; other geometry: its own.
    assert s.with_materials(albedo=0.3).patch_buffers(device) == (centers, normals)
    other = box_scene(2, size=2.0)
    c2, _ = other.patch_buffers(device)
    cl.enqueue_copy(device.queue, host, c2, is_blocking=True)
    # Centres go up in the scene's device frame (re-centred and scaled: docs/design.md, 'Device frame').
    assert np.array_equal(host[:, :3], other.frame.points(other.centers)) and not np.array_equal(
        other.centers, s.centers
    )


def test_sell_layout_only_for_grey_solves_on_wide_simd_cpus():
    from pydynrad.device.devices import DeviceTraits
    from pydynrad.device.launch import SELL_WINDOW_SLICES, sell_layout

    avx512 = DeviceTraits(
        cpu=True, compute_units=2, float_width=16, double_width=8, max_work_group=4096, local_mem_bytes=1 << 20
    )
    s = sell_layout(avx512, 4, 1)
    assert (s.c, s.sigma, s.blocks, s.defines) == (16, 16 * SELL_WINDOW_SLICES, 32, {"SELL_C": 16})
    assert sell_layout(avx512, 8, 1).c == 8
    assert sell_layout(avx512, 4, 3) is None  # RGB: CSR's float4 loads beat three gathers
    assert sell_layout(replace(avx512, float_width=8, double_width=4), 4, 1) is None  # AVX2
    assert sell_layout(replace(avx512, cpu=False), 4, 1) is None
