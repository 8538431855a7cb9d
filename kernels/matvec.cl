// Launch bound (~100 ms on a small GPU: 100 GB/s, 1 TFLOP/s fp32, max_mem_alloc <= 2 GiB): each
// launch streams one channel of K once (matvec, rmatvec_partial) or reads n_blocks * ld partials
// (rmatvec_reduce); a channel is one buffer, so <= max_mem_alloc_size (DeviceMatrix refuses more):
// <= 2 GiB / 100 GB/s ~ 21 ms (M = 16,384 fp16: 512 MiB, ~5 ms).
// Dense matrix-vector products with one M x M row-major matrix K (leading dimension ld).
// Storage type from storage.h (STORAGE_FP16/FP32/FP64); vectors x, y are REAL.
//
// Both products are memory-bound: they stream K exactly once.
//   VW: vector width of the loads (4, 8 or 16: two SIMD registers on a CPU, 4 on GPUs); rows and
//       the x vectors start on multiples of ld elements (ld % 64 == 0), so the LX == 1 loads
//       take storage.h's aligned access.
//   LX: work-items per row in `matvec`. LX == 1 gives one row per work-item (a CPU core then
//       streams whole rows with vector loads); LX > 1 gives one work-group per row whose
//       items read adjacent vectors (coalesced on a GPU) and reduce in local memory.
//   NRHS: right-hand sides of `matvec` per pass over K (1 to 4: the colour channels of a
//       light vector sharing one grey K).
//   RI: rows per work-item of the LX == 1 `matvec` (1 to 4), streamed side by side so that
//       RI * NRHS accumulator chains hide the FMA latency (1 where LX > 1).
// All four are required; pydynrad/device/launch.py (MatvecLayout.defines) picks them per device.
// Requirements (the host guarantees them): ld % VW == 0, K's padding columns M..ld hold 0,
// x holds ld entries (zeros past M); with LX == 1 the global size is rounded up past M / RI (items
// past M return), with LX > 1 it is exactly M work-groups.
#include "storage.h"

#if !defined(VW) || !defined(LX) || !defined(NRHS) || !defined(RI)
#error "matvec.cl needs VW, LX, NRHS and RI from the host (pydynrad/device/launch.py)"
#endif

// Y[q, i] = sum_j K[i, j] X[q, j] for i < M and the NRHS right-hand sides q: X holds NRHS
// vectors of ld entries each (stride ld), Y NRHS vectors of M entries (stride M). Each element
// of K is loaded once for all NRHS products, so r products cost one pass over K, not r.
__kernel void matvec(__global const STORE_T *K, const int M, const int ld,
                     __global const REAL *x, __global REAL *y)
{
#if LX == 1
    // RI rows at a time, each with its own accumulators: RI * NRHS independent FMA chains per
    // step (one chain waits on the FMA's latency: an fp16 K in cache, one zmm chain per row, ran
    // markedly slower; docs/decisions/0007-kernel-widths-from-device.md), and each x vector is loaded once for RI rows. Every row's
    // sum is the same sequence of operations as with RI = 1. Rows past M repeat row M - 1
    // (in bounds, never written). The loops over rows and vectors are unrolled so that the
    // accumulators stay in registers (PoCL's LLVM 14 kept RI = 4 arrays in memory otherwise).
    REALV(VW) acc[RI][NRHS];
    __global const STORE_T *r[RI];
    const int row0 = get_global_id(0) * RI;
    if (row0 >= M) return;
    PDR_UNROLL
    for (int i = 0; i < RI; ++i) {
        r[i] = K + (size_t)min(row0 + i, M - 1) * ld;
        PDR_UNROLL
        for (int q = 0; q < NRHS; ++q) acc[i][q] = (REALV(VW))(0);
    }
    for (int j = 0; j < ld; j += VW) {
        REALV(VW) k[RI];
        PDR_UNROLL
        for (int i = 0; i < RI; ++i) k[i] = KV(r[i] + j);
        PDR_UNROLL
        for (int q = 0; q < NRHS; ++q) {
            const REALV(VW) xv = RV(x + q * ld + j);
            PDR_UNROLL
            for (int i = 0; i < RI; ++i) acc[i][q] += k[i] * xv;
        }
    }
    PDR_UNROLL
    for (int i = 0; i < RI; ++i)
        if (row0 + i < M)
            PDR_UNROLL
            for (int q = 0; q < NRHS; ++q) y[q * M + row0 + i] = HSUM(VW, acc[i][q]);
#else
    REALV(VW) acc[NRHS];
    for (int q = 0; q < NRHS; ++q) acc[q] = (REALV(VW))(0);
    __local REAL part[NRHS][LX];
    const int row = get_group_id(0), lid = get_local_id(0);
    __global const STORE_T *r = K + (size_t)row * ld;
    for (int j = lid * VW; j < ld; j += LX * VW) {
        const REALV(VW) k = LOADV(VW, r, j);
        for (int q = 0; q < NRHS; ++q) acc[q] += k * VLOADR(VW, x + q * ld, j);
    }
    for (int q = 0; q < NRHS; ++q) part[q][lid] = HSUM(VW, acc[q]);
    for (int s = LX / 2; s > 0; s >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid < s)
            for (int q = 0; q < NRHS; ++q) part[q][lid] += part[q][lid + s];
    }
    if (lid == 0 && row < M)
        for (int q = 0; q < NRHS; ++q) y[q * M + row] = part[q][0];
#endif
}

// Transposed product, first pass: partial[b, j] = sum_{i in row block b} x[i] K[i, j].
// Work-item (c, b) owns columns c*VW .. c*VW+VW of the rows [b*RB, min(M, b*RB+RB)); items of
// one row block read adjacent vectors of the same rows, so each row is read contiguously.
__kernel void rmatvec_partial(__global const STORE_T *K, const int M, const int ld, const int RB,
                              __global const REAL *x, __global REAL *partial)
{
    const int c = get_global_id(0), b = get_global_id(1);
    const int j = c * VW;
    if (j >= ld) return;
    const int i_end = min(M, (b + 1) * RB);
    REALV(VW) acc = (REALV(VW))(0);
    for (int i = b * RB; i < i_end; ++i) acc += x[i] * LOADV(VW, K, (size_t)i * ld + j);
    PDR_XCAT(vstore, VW)(acc, 0, partial + (size_t)b * ld + j);
}

// Second pass: y[j] = sum_b partial[b, j] for j < M.
__kernel void rmatvec_reduce(__global const REAL *partial, const int M, const int ld, const int n_blocks,
                             __global REAL *y)
{
    const int j = get_global_id(0);
    if (j >= M) return;
    REAL s = 0;
    for (int b = 0; b < n_blocks; ++b) s += partial[(size_t)b * ld + j];
    y[j] = s;
}
