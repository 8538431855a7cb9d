"""How every kernel splits its work on a device: one place for the CPU and GPU choices.

* Layouts per kernel family, chosen from what the device reports (its
  :class:`~pydynrad.device.devices.DeviceTraits`: a CPU or not, compute units, preferred vector widths,
  work-group and local-memory limits): :func:`spmv_layout` (the full solve,
  ``kernels/spmv.cl``), :func:`gemm_layout` (the multibounce build, ``kernels/gemm.cl``),
  :func:`matvec_layout` (products with K, ``kernels/matvec.cl``) and :class:`UpdateLayout`
  (the local update of K, ``kernels/update.cl``). Each takes a Device or bare DeviceTraits,
  so a layout can be chosen for (and tested on) a device that is not here.
  For the ray kernels: the packet width (:func:`bvh_packet`, from the preferred float width),
  the hemicube tiles (:func:`hemicube_tiles`) and their work-groups (:func:`ray_work_group`).
* The constants the kernels are built with: each layout's ``defines`` become ``-D`` options.
  The ``.cl`` files have no defaults for them (a build without one fails), so no number that
  host and kernel must agree on is written twice.
* :func:`global_size`: a global size rounded up to whole work-groups; every kernel launched
  so guards ``if (gid >= n) return;``.
* :func:`enqueue_kernel`: the one way a kernel is enqueued. Every launch states its work-group size
  (never ``None``, which leaves it to the runtime), fitted to the device's
  ``max_work_group_size`` and work-item sizes and to the kernel's own
  ``CL_KERNEL_WORK_GROUP_SIZE`` (:func:`kernel_work_group_limit`), and rounds the global size
  up to whole work-groups.

CPU layouts give a few fat work-items long contiguous runs and vectors as wide as the SIMD
registers the device reports (16 floats with AVX-512, 8 with AVX2, 4 with SSE or NEON: a
wider OpenCL vector than the registers splits every value in two and spills the kernels'
accumulators); PoCL runs one work-group per core at a time. GPU layouts give many items
that read adjacent addresses (coalesced loads), in work-groups the device allows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError

__all__ = [
    "WG",
    "RED_WG",
    "PANEL",
    "GEMM_GRAIN",
    "WIDTHS",
    "round_up",
    "global_size",
    "kernel_work_group_limit",
    "fit_work_group",
    "enqueue_kernel",
    "float4",
    "BVH_PACKETS",
    "bvh_packet",
    "RAY_WG_CPU",
    "ray_work_group",
    "HemicubeTiles",
    "hemicube_tiles",
    "cpu_vector_width",
    "SpmvLayout",
    "spmv_layout",
    "SellLayout",
    "SELL_WINDOW_SLICES",
    "sell_layout",
    "GemmLayout",
    "gemm_layout",
    "MatvecLayout",
    "matvec_layout",
    "UpdateLayout",
]

#: Work-group size of the element-wise kernels (one item per patch, pixel, row or column).
WG = 64
#: Items of the one-group tree reduction ``double_reflection`` (a power of two).
RED_WG = 64
#: Vector widths (elements) the kernels are written for: OpenCL's 4-, 8- and 16-element types.
WIDTHS = (4, 8, 16)
#: Widths the packet traversal (``kernels/bvh.cl``, ``kernels/hemicube.h``) is written for.
BVH_PACKETS = (4, 8, 16)
#: Scanlines per hemicube tile (``HC_TILE_Y``) for each packet width: square tiles where the
#: width allows (4 x 4, 2 x 2), else 4 x 2.
_TILE_ROWS = {4: 2, 8: 2, 16: 4}


def bvh_packet(device) -> int:
    """Rays per work-item of the packet traversal (``BVH_PACKET``), one per vector lane.

    The device's preferred float vector width (PoCL: 16 with AVX-512, 8 with AVX2), within
    :data:`BVH_PACKETS`: a packet's box test costs one vector operation per lane group, so
    lanes beyond the hardware's width cost as much as a second packet while visiting at least
    as many nodes as it would. GPUs report 1 and get the narrowest packets."""
    width = int(_traits(device).float_width)
    return max(p for p in BVH_PACKETS if p <= max(width, BVH_PACKETS[0]))


#: Work-items per work-group of the packet ray kernels on a CPU (hemicube_runs, cast_closest).
#: Left to itself PoCL cuts a launch into a few equal groups (12,288 items: 3 groups of 4,096
#: for 2 threads, so one thread idled for a third of the launch; 3,072: 2 groups, as unequal as
#: the rows in them); small groups let its threads share the work as they free up. A group of
#: 8 hemicube bands is still far more tracing than the cost of starting it
#: (docs/decisions/0011-ray-tracing.md).
RAY_WG_CPU = 8


def ray_work_group(device) -> int:
    """Work-items per work-group of the ray kernels: :data:`RAY_WG_CPU` on a CPU, :data:`WG` otherwise."""
    return RAY_WG_CPU if _traits(device).cpu else WG


@dataclass(frozen=True)
class HemicubeTiles:
    """How ``hemicube_runs`` (``kernels/hemicube.cl``) splits a hemicube: one work-item per
    band of ``rows`` scanlines of a face, traced in tiles of ``packet // rows`` pixels by
    ``rows`` scanlines, one packet each (see ``kernels/hemicube.h``)."""

    packet: int
    rows: int

    def defines(self, resolution: int) -> dict[str, int]:
        return {"HC_RES": int(resolution), "BVH_PACKET": self.packet, "HC_TILE_Y": self.rows}

    def bands(self, resolution: int) -> int:
        """Work-items per hemicube: each face cut into bands of ``rows`` scanlines (HC_BANDS)."""
        R = int(resolution)
        return -(-R // self.rows) + 4 * -(-(R // 2) // self.rows)


def hemicube_tiles(device) -> HemicubeTiles:
    """The hemicube tiles for ``device``: its packet width (:func:`bvh_packet`) in tiles of
    4 x 4 (16 lanes), 4 x 2 (8) or 2 x 2 (4) pixels by scanlines."""
    packet = bvh_packet(device)
    return HemicubeTiles(packet, _TILE_ROWS[packet])


def float4(a) -> np.ndarray:
    """(n, k <= 4) values as the (n, 4) float32 rows a kernel's ``float4`` buffer reads (zero padded)."""
    a = np.asarray(a, dtype=np.float32).reshape(len(a), -1)
    out = np.zeros((len(a), 4), dtype=np.float32)
    out[:, : a.shape[1]] = a
    return out


def round_up(n: int, multiple: int) -> int:
    """The least multiple of ``multiple`` that is >= ``n``."""
    return -(-int(n) // int(multiple)) * int(multiple)


def global_size(n: int, local: int = WG) -> int:
    """``n`` work-items rounded up to whole work-groups of ``local`` (at least one group).

    A fixed multiple also spares PoCL a kernel compile per new local size: with an awkward n
    (a prime) it would otherwise pick a local size that divides n."""
    return max(int(local), round_up(n, local))


def _traits(device):
    """A Device's traits, or the DeviceTraits given."""
    return getattr(device, "traits", device)


def kernel_work_group_limit(kernel, device) -> int:
    """The most work-items one work-group of ``kernel`` may have on ``device``: the smaller of
    the device's ``max_work_group_size`` (as its traits say) and the kernel's own
    ``CL_KERNEL_WORK_GROUP_SIZE`` (lower where its registers or local memory are many). The
    kernel's value is queried once and kept on the kernel object."""
    return max(1, min(_kernel_limits(kernel, device)[0], int(_traits(device).max_work_group)))


def _kernel_limits(kernel, device) -> tuple[int, tuple[int, ...]]:
    """(the kernel's ``CL_KERNEL_WORK_GROUP_SIZE``, the device's ``max_work_item_sizes``),
    queried once and kept on the kernel object (a kernel belongs to one device's program)."""
    limits = getattr(kernel, "_pdr_limits", None)
    if limits is None:
        import pyopencl as cl

        d = device.cl_device
        own = int(kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, d))
        limits = kernel._pdr_limits = (own, tuple(int(v) for v in d.max_work_item_sizes))
    return limits


def fit_work_group(device, kernel, local: tuple[int, ...], fixed: bool = False) -> tuple[int, ...]:
    """``local`` fitted to ``device`` and ``kernel``: each dimension within the device's
    ``max_work_item_sizes``, their product within :func:`kernel_work_group_limit`, by halving
    the largest dimension. ``fixed``: the kernel was built for exactly this size (its local
    memory, barriers or a ``WG``-like define depend on it), so a device or kernel that cannot
    take it raises :class:`~pydynrad.errors.DeviceError` instead."""
    from ..errors import DeviceError

    local = tuple(max(1, int(v)) for v in local)
    limit = kernel_work_group_limit(kernel, device)
    dims = _kernel_limits(kernel, device)[1]
    fits = all(v <= d for v, d in zip(local, dims)) and math.prod(local) <= limit
    if fits:
        return local
    if fixed:
        raise DeviceError(
            f"kernel {kernel.function_name} was built for work-groups of {local} items; this device "
            f"allows {limit} ({dims} per dimension) for it"
        )
    out = [min(v, d) for v, d in zip(local, dims)]
    while math.prod(out) > limit:
        k = out.index(max(out))
        out[k] = max(1, out[k] // 2)
    return tuple(out)


def enqueue_kernel(
    device,
    kernel,
    global_size: tuple[int, ...],
    local: tuple[int, ...],
    *args,
    fixed: bool = False,
    offset: tuple[int, ...] | None = None,
):
    """Enqueue ``kernel(*args)`` on ``device``'s queue over ``global_size`` items in work-groups
    of ``local`` (:func:`fit_work_group`; ``fixed`` as there), each global dimension rounded up
    to whole work-groups: the kernel returns for items past its range. Every launch in pydynrad
    goes through here, so none leaves the work-group size to the runtime (a GPU's choice can
    exceed what the kernel allows, PoCL's varies with the global size and compiles anew).

    ``offset``: the global offset (``get_global_id`` starts there), for a long launch split into
    chunks of items: the kernel's guard count is then the chunk's end, so the rounded-up items
    past it return."""
    if local is None:
        raise TypeError(f"enqueue_kernel of {kernel.function_name} needs an explicit local size")
    local = fit_work_group(device, kernel, tuple(local), fixed)
    grid = tuple(max(lo, round_up(g, lo)) for g, lo in zip(global_size, local))
    if offset is None:
        return kernel(device.queue, grid, local, *args)
    return kernel(device.queue, grid, local, *args, global_offset=tuple(int(o) for o in offset))


def _pow2_at_most(n: int, cap: int) -> int:
    return 1 << (max(1, min(int(n), int(cap))).bit_length() - 1)


def cpu_vector_width(device, real_itemsize: int, registers: int = 1) -> int:
    """Elements per vector of the CPU kernels computing in REALs of ``real_itemsize`` bytes:
    ``registers`` times the device's preferred width (its SIMD register), as the nearest of
    :data:`WIDTHS` at or below it (4 at least)."""
    t = _traits(device)
    native = t.double_width if real_itemsize == 8 else t.float_width
    want = max(WIDTHS[0], int(native) * int(registers))
    return max(w for w in WIDTHS if w <= want)


# -- the full solve: CSR bounce kernel (kernels/spmv.cl) -------------------------------------------
@dataclass(frozen=True)
class SpmvLayout:
    """Row blocks of ``bounce``: one work-group of ``lx`` items per block of about equal non-zeros;
    ``rgb_step`` float32 RGB entries per vector step of a CPU's loop (4 fill a 16-float register,
    2 an 8-float one)."""

    lx: int
    blocks: int
    rgb_step: int = 4

    @property
    def defines(self) -> dict[str, int]:
        return {"LX": self.lx, "RGB_STEP": self.rgb_step}

    @property
    def grid(self) -> tuple[tuple[int], tuple[int]]:
        return (self.blocks * self.lx,), (self.lx,)


def spmv_layout(device, n: int, override: tuple[int, ...] | None = None) -> SpmvLayout:
    """The bounce kernel's layout for an n-row F; ``override`` = (LX, blocks) or (LX, blocks,
    RGB_STEP) for tuning and tests.

    CPU: one work-item per block, 16 blocks per core so a core slowed by other work hands
    blocks to the others; float32 RGB entries in fours where a register holds 16 floats, in
    pairs where it holds 8 (on AVX2 fours split into shuffles and ran about half as fast;
    docs/decisions/0010-full-solve-formats.md). GPU: a 64-item work-group per
    row (CSR-vector), enough blocks to fill every compute unit many times over.
    """
    rgb_step = 4 if cpu_vector_width(device, 4) >= 16 else 2
    if override is not None:
        lx, blocks, *step = override
        if lx < 1 or lx & (lx - 1) or blocks < 1 or len(step) > 1 or (step and step[0] not in (2, 4)):
            raise InvalidInputError(
                f"layout must be (LX a power of two, blocks >= 1[, RGB_STEP 2 or 4]); got {override}"
            )
        rgb_step = step[0] if step else rgb_step
    else:
        t = _traits(device)
        if t.cpu:
            lx, blocks = 1, 16 * t.compute_units
        else:
            lx, blocks = _pow2_at_most(64, t.max_work_group), 256 * t.compute_units
    return SpmvLayout(int(lx), max(1, min(int(blocks), n)), rgb_step)


@dataclass(frozen=True)
class SellLayout:
    """``bounce_sell`` on SELL-C-sigma F (:mod:`pydynrad.device.sell`): slices of ``c`` rows,
    rows sorted by length within windows of ``sigma``, one work-item per block of slices."""

    c: int
    sigma: int
    blocks: int

    @property
    def defines(self) -> dict[str, int]:
        return {"SELL_C": self.c}


#: Rows per sorting window of SELL-C-sigma, in slices: long enough that a slice's rows have
#: about equal lengths (village: 1.8 % padding at C = 16), short enough to keep the patches'
#: order (x's locality) nearly as it was.
SELL_WINDOW_SLICES = 32


def sell_layout(device, real_itemsize: int, channels: int) -> SellLayout | None:
    """The SELL-C layout of a full solve in REALs of ``real_itemsize`` bytes, or None for CSR.

    Only for grey solves (``channels`` 1) on a CPU with 16-float (8-double) SIMD registers
    (AVX-512, where the gathers are one instruction): there one row per lane ran 1.2-1.35x
    CSR's loop; with RGB, three gathers per entry ran 0.6-0.7x CSR's one float4 load per entry,
    and GPUs read CSR coalesced (docs/design.md, 'Full solve')."""
    t = _traits(device)
    native = t.double_width if real_itemsize == 8 else t.float_width
    if not t.cpu or channels != 1 or native * real_itemsize < 64:
        return None
    c = cpu_vector_width(device, real_itemsize)
    return SellLayout(c, SELL_WINDOW_SLICES * c, 16 * t.compute_units)


# -- the multibounce build: register-blocked GEMM (kernels/gemm.cl) ---------------------------------
@dataclass(frozen=True)
class GemmLayout:
    """``gemm_acc``: each item owns a TM x VW block of the output; LY items per work-group
    stack along the rows and share one strip of V."""

    vw: int
    tm: int
    ly: int

    @property
    def defines(self) -> dict[str, int]:
        return {"VW": self.vw, "TM": self.tm}

    def grid(self, m: int, n: int) -> tuple[tuple[int, int], tuple[int, int]]:
        """(global, local) for an m x n output (n % VW == 0, m % TM == 0)."""
        rows = m // self.tm
        ly = min(self.ly, rows)
        return (n // self.vw, round_up(rows, ly)), (1, ly)


#: Rows per item (TM) and items per work-group (LY) of the GEMM on a CPU and on a GPU.
_GEMM_CPU_TM, _GEMM_CPU_LY = 8, 8
#: GPU: narrow vectors, more work-items.
_GEMM_GPU = GemmLayout(vw=4, tm=4, ly=16)

#: Panel width of the elimination (columns per host step).
PANEL = 128
#: Panels and padded sizes are multiples of this: of every VW and TM a layout can take.
GEMM_GRAIN = math.lcm(*WIDTHS, _GEMM_CPU_TM, _GEMM_GPU.tm)
assert PANEL % GEMM_GRAIN == 0


def gemm_layout(device, real_itemsize: int = 4) -> GemmLayout:
    """CPU: TM = 8 rows of one SIMD register's width per item (8 accumulators and the strip of V
    stay in registers); GPU: 4 x 4 blocks, work-groups of 16 items (fewer if the device allows fewer)."""
    t = _traits(device)
    if t.cpu:
        return GemmLayout(vw=cpu_vector_width(t, real_itemsize), tm=_GEMM_CPU_TM, ly=_GEMM_CPU_LY)
    return GemmLayout(vw=_GEMM_GPU.vw, tm=_GEMM_GPU.tm, ly=_pow2_at_most(_GEMM_GPU.ly, t.max_work_group))


# -- products with K (kernels/matvec.cl) ------------------------------------------------------------
#: Right-hand sides one pass of ``matvec`` multiplies (``kernels/matvec.cl``'s NRHS, 1 to this).
MAX_RHS = 4


@dataclass(frozen=True)
class MatvecLayout:
    """How ``matvec`` and the transposed product split an M x M matrix of row pitch ld.

    vw : vector width of K loads; lx : work-items per row of ``matvec`` (1: one row per item);
    rb : rows per block of the transposed product's first pass; aligned : aligned vector
    dereference instead of vload (``PDR_CLANG_VECTORS``, see ``kernels/storage.h``); regs :
    SIMD registers one vector of REALs fills on this device (CPU; 1 on a GPU); chains :
    independent accumulator chains wanted per item (:data:`MATVEC_CHAINS`, or 1: see
    :func:`matvec_layout`).
    """

    vw: int
    lx: int
    rb: int
    aligned: bool
    regs: int = 1
    chains: int = 1
    wg: int = RAY_WG_CPU

    def rows_per_item(self, nrhs: int) -> int:
        """Rows one LX == 1 item of ``matvec`` streams side by side (its RI) for nrhs vectors:
        enough for ``chains`` independent FMA chains (one per SIMD register of an
        accumulator, per row and right-hand side), no more than :data:`MATVEC_ACC_REGS`
        accumulator registers; 1 on the GPU layout."""
        if self.lx != 1:
            return 1
        per_row = self.regs * int(nrhs)
        return max(1, min(-(-self.chains // per_row), MATVEC_ACC_REGS // per_row))

    def defines(self, nrhs: int) -> dict[str, int]:
        out = {"VW": self.vw, "LX": self.lx, "NRHS": nrhs, "RI": self.rows_per_item(nrhs)}
        if self.aligned:
            out["PDR_CLANG_VECTORS"] = 1
        return out

    def matvec_grid(self, M: int, nrhs: int = 1) -> tuple[tuple[int], tuple[int]]:
        """(global, local) of ``matvec``: LX == 1, an item per RI rows in work-groups of ``wg``
        (:func:`matvec_layout`); LX > 1, a work-group of LX items per row."""
        if self.lx == 1:
            return (global_size(-(-M // self.rows_per_item(nrhs)), self.wg),), (self.wg,)
        return (M * self.lx,), (self.lx,)

    def rmatvec_grids(self, M: int, ld: int) -> tuple[tuple, tuple]:
        """(global, local) of ``rmatvec_partial`` (an item per VW columns of a row block, WG
        items along the columns) and of ``rmatvec_reduce`` (an item per column)."""
        cols = ld // self.vw
        lx = min(WG, cols)
        return ((round_up(cols, lx), -(-M // self.rb)), (lx, 1)), ((global_size(M),), (WG,))


#: Work-items per row of the GPU ``matvec`` (the most: fewer where the device allows fewer).
_MATVEC_GPU_LX = 64
#: Independent accumulator chains per CPU ``matvec`` item: an FMA's latency (a few cycles on
#: current x86 cores) over the loop's step. With one chain (one row, one vector, VW = one zmm:
#: what an AVX-512 device got) an fp16 K in cache ran markedly slower than with four
#: (docs/decisions/0007-kernel-widths-from-device.md).
MATVEC_CHAINS = 4
#: Most accumulator registers per CPU ``matvec`` item (AVX2 has 16 registers: the accumulators,
#: the NRHS x vectors and the K vectors of a step must fit).
MATVEC_ACC_REGS = 8


def matvec_layout(
    device,
    M: int,
    ld: int,
    override: tuple[int, int] | None = None,
    real_itemsize: int = 4,
    k_itemsize: int | None = None,
) -> MatvecLayout:
    """CPU: rows streamed side by side per work-item (:meth:`MatvecLayout.rows_per_item`), loads
    two SIMD registers wide where the widest kernel vector (16) allows. GPU: a work-group per
    row, coalesced float4 loads, as many items as the device's work-group size and local memory
    (one REAL per item and right-hand side) allow.
    ``override`` = (VW, LX) for tuning and for testing the GPU path on a CPU. ``k_itemsize``:
    bytes per stored element (default ``real_itemsize``).

    Rows side by side (:data:`MATVEC_CHAINS`) where K is served from cache (one channel in half
    the device's cache) or stored as wide as it computes; an fp16 K streamed from memory keeps
    one row per item: there the single-chain loop already ran at the memory's speed and four
    interleaved rows ran slower, while from cache they ran faster
    (docs/decisions/0007-kernel-widths-from-device.md)."""
    t = _traits(device)
    if override is not None:
        vw, lx = override
    elif t.cpu:
        vw, lx = cpu_vector_width(t, real_itemsize, registers=2), 1
    else:
        fit = t.local_mem_bytes // (MAX_RHS * real_itemsize)
        vw, lx = 4, _pow2_at_most(_MATVEC_GPU_LX, min(t.max_work_group, fit))
    if vw not in WIDTHS or lx < 1 or lx & (lx - 1):
        raise InvalidInputError(f"layout must be (VW in 4/8/16, LX a power of two); got {override}")
    # Row block of the transposed product's first pass: long enough to amortise the partial
    # sums (1/RB of K's traffic), short enough to give a GPU enough work-items.
    rb = 64 if t.cpu else max(16, min(256, (M * (ld // vw)) // 65536 or 16))
    native = t.double_width if real_itemsize == 8 else t.float_width
    regs = max(1, int(vw) // max(1, int(native))) if t.cpu else 1
    k_itemsize = real_itemsize if k_itemsize is None else int(k_itemsize)
    cached = 2 * M * ld * k_itemsize <= t.cache_bytes
    chains = MATVEC_CHAINS if t.cpu and (cached or k_itemsize >= real_itemsize) else 1
    # LX == 1 work-groups: up to 64 items (on 2 cores, 64 ran an fp16 M = 4,096 product 1.5x
    # faster than 8), fewer where that would leave under 2 groups per compute unit (RI <= 4).
    wg = _pow2_at_most(max(RAY_WG_CPU, M // (8 * t.compute_units)), WG)
    return MatvecLayout(int(vw), int(lx), rb, bool(t.aligned_vectors), regs, chains, wg)


# -- the local update of K (kernels/update.cl) ------------------------------------------------------
#: Work-items per row block of the GPU gather (the most: fewer where the device allows fewer).
GPU_WG = 64
#: GPU vector width of K loads.
GPU_VW = 4
#: Rows per step of the CPU kernels: RR accumulators of one SIMD register each stay in registers
#: (the gather holds RR + 5 vectors live: 13 of AVX2's 16 registers, of AVX-512's 32).
CPU_ROWS = 8
#: Widest column strip of the CPU gather: an RR x CWMAX tile of K is kept in private memory.
CPU_STRIP = 512
#: CPU gather: the shortest row block (more, shorter blocks balance the two-level split better).
CPU_MIN_BLOCK = 128
#: CPU gather: column partials (n_blocks * NV * ld REALs, written and re-read) stay under
#: 1/CPU_PARTIAL_SHARE of the bytes of K that the pass reads.
CPU_PARTIAL_SHARE = 16


@dataclass(frozen=True)
class UpdateLayout:
    """How the update kernels split K over work-items on one device (see kernels/update.cl).

    cpu : bool
        CPU kernels (a few fat work-items, RR rows at a time) or GPU kernels (coalesced).
    M, ld, k_itemsize, real_itemsize : int
        The matrix: size, row pitch, bytes per stored element and per compute REAL.
    vw : int
        Vector width (elements) of K loads: one SIMD register of REALs on a CPU, GPU_VW on a GPU.
    sw : int
        Vector width of the sparse gathers: two SIMD registers on a CPU (their entries come one
        by one from scattered columns, so a longer step amortises the NV accumulators' passes;
        faster than one register for fp64 on AVX-512; docs/decisions/0007-kernel-widths-from-device.md),
        GPU_VW on a GPU.
    wg : int
        GPU: work-items per row block of the gather.
    rank_rb : int
        CPU rank update: rows per work-item.
    gather_cw : int
        CPU gather: columns per strip.
    parts : int
        Row partial sums per row the gather leaves for gather_reduce (strips on a CPU, wg on a GPU).
    aligned : bool
        CPU kernels use aligned vector dereference (``PDR_CLANG_VECTORS``).
    """

    cpu: bool
    M: int
    ld: int
    k_itemsize: int
    real_itemsize: int
    vw: int
    sw: int
    wg: int
    rank_rb: int
    gather_cw: int
    parts: int
    aligned: bool = False

    @staticmethod
    def make(device, M: int, ld: int, k_itemsize: int, real_itemsize: int, cpu: bool | None = None) -> UpdateLayout:
        """The layout for an M x M matrix with row pitch ld; ``cpu`` overrides the device type
        (to test the GPU kernels on a CPU)."""
        t = _traits(device)
        cpu = t.cpu if cpu is None else cpu
        if not cpu:
            wg = _pow2_at_most(GPU_WG, t.max_work_group)
            return UpdateLayout(False, M, ld, k_itemsize, real_itemsize, GPU_VW, GPU_VW, wg, 0, ld, wg)
        rows = -(-M // CPU_ROWS)  # row groups of RR
        # Rank update: about 8 work-items per compute unit, each a whole number of row groups.
        rank_rb = CPU_ROWS * -(-rows // min(rows, 8 * t.compute_units))
        cw = min(ld, CPU_STRIP)
        return UpdateLayout(
            True,
            M,
            ld,
            k_itemsize,
            real_itemsize,
            cpu_vector_width(t, real_itemsize),
            cpu_vector_width(t, real_itemsize, registers=2),
            1,
            rank_rb,
            cw,
            -(-ld // cw),
            bool(t.aligned_vectors),
        )

    def defines(self, nv_max: int) -> dict[str, int]:
        """Build defines for at most ``nv_max`` vectors per gather (2 nv_max terms per rank update)."""
        out = {
            "VW": self.vw,
            "SW": self.sw,
            "WG": self.wg,
            "RR": CPU_ROWS,
            "CWMAX": CPU_STRIP,
            "NVMAX": nv_max,
            "NAMAX": 2 * nv_max,
            "RED_WG": RED_WG,
        }
        if self.cpu and self.aligned:
            out["PDR_CLANG_VECTORS"] = 1
        return out

    def gather_blocks(self, nv: int) -> tuple[int, int]:
        """(rows per block, blocks) of the gather for nv vectors.

        GPU: 64-128-row blocks, whose column partials cost NV*ld REALs each, ~1% of K's
        traffic per vector. CPU: blocks of at least CPU_MIN_BLOCK rows (whole groups of RR),
        as many as the partial-sum budget allows for nv vectors."""
        if not self.cpu:
            rb = 64 if self.M < 2048 else 128
            return rb, -(-self.M // rb)
        rows = -(-self.M // CPU_ROWS)
        budget = self.M * self.k_itemsize // (CPU_PARTIAL_SHARE * nv * self.real_itemsize)
        blocks = max(1, min(-(-self.M // CPU_MIN_BLOCK), budget, rows))
        rb = CPU_ROWS * -(-rows // blocks)
        return rb, -(-self.M // rb)

    def max_partial_blocks(self, nv_max: int) -> int:
        """The most NV*ld column-partial slabs any gather of 1..nv_max vectors uses."""
        return max(self.gather_blocks(n)[1] * n for n in range(1, nv_max + 1))

    def element_grid(self, n: int) -> tuple[tuple[int, int], tuple[int, int]]:
        """(global, local) of the per-(i, m) kernels for n vectors. The local size is fixed, not
        left to the runtime: PoCL compiles a kernel once per local size, and its own choice
        varies with n, which put a compile per kernel inside the frame loop at each new
        vector count (docs/decisions/0005-warm-up-and-fixed-local-sizes.md)."""
        return (global_size(self.M), n), (WG, 1)

    def gather_grid(self, blocks: int) -> tuple[tuple[int, int], tuple[int, int]]:
        """(global, local) of the gather over ``blocks`` row blocks: an item per (strip, block)
        on a CPU, a work-group of wg items per block on a GPU."""
        if self.cpu:
            return (self.parts, blocks), (1, 1)
        return (self.wg, blocks), (self.wg, 1)

    @property
    def rank_grid(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """(global, local) of the rank update: an item per rank_rb rows on a CPU; on a GPU an
        item per (VW-vector column, row) in work-groups of 16 columns by 4 rows (ld / VW is a
        multiple of 16; rows rounded up to 4, past M the kernel returns)."""
        if self.cpu:
            return (-(-self.M // self.rank_rb),), (1,)
        return (self.ld // self.vw, round_up(self.M, 4)), (16, 4)

    @staticmethod
    def reduction_grid() -> tuple[tuple[int], tuple[int]]:
        """``double_reflection``: one work-group of RED_WG items."""
        return (RED_WG,), (RED_WG,)
