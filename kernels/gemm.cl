// Launch bound (~100 ms on a small GPU at 1 TFLOP/s fp32): one launch is m n kdim FMAs.
// pydynrad/bounces.py (_Builder.gemm) splits every product into launches of whole TM-row blocks
// of out (through u_off, b_off and o_off) of at most GEMM_FLOPS_PER_LAUNCH (8e10) flops, ~80 ms:
// series() (kdim = Mp) in blocks of ~4e10 / Mp^2 rows (144 at Mp = 16,384), the elimination's
// (kdim = PANEL) once Mp passes ~17,000. A single TM-row block exceeds it only past Mp ~ 70,000.
// out = base + U V  (out, base: m x n; U: m x kdim; V: kdim x n), all row-major in REAL
// (float or double: STORAGE_FP32 / STORAGE_FP64 via storage.h), each with its own leading
// dimension and element offset. out may alias base (an in-place update: every element is
// read and written by one work-item only).
//
// Each work-item owns a TM x VW block of out: TM rows times one VW-wide vector of columns,
// held in TM vector accumulators. Per k it loads one VW-vector of V's row k and TM scalars
// of U's column k: a register-blocked outer product, 2 TM VW flops per (TM + VW) loads. A
// work-group stacks its items along the rows (local size (1, LY)), so they share the same
// V strip (kdim x VW), which stays in the nearest cache. The host guarantees n % VW == 0
// (buffers are padded) and m % TM == 0 or pads U with zero rows.
// VW and TM are required: pydynrad/device/launch.py (GemmLayout) picks them per device.
#include "storage.h"

#if !defined(VW) || !defined(TM)
#error "gemm.cl needs VW and TM from the host (pydynrad/device/launch.py)"
#endif

__kernel void gemm_acc(const int m, const int n, const int kdim,
                       __global const REAL *U, const int ldu, const int u_off,
                       __global const REAL *V, const int ldv, const int v_off,
                       __global const REAL *base, const int ldb, const int b_off,
                       __global REAL *out, const int ldo, const int o_off)
{
    const int j = get_global_id(0) * VW;
    const int i0 = get_global_id(1) * TM;
    if (j >= n || i0 >= m) return;
    REALV(VW) acc[TM];
    for (int t = 0; t < TM; ++t) acc[t] = (REALV(VW))(0);
    __global const REAL *u = U + u_off + (size_t)i0 * ldu;
    __global const REAL *v = V + v_off + j;
    for (int k = 0; k < kdim; ++k) {
        const REALV(VW) vk = VLOADR(VW, v, (size_t)k * ldv);
        for (int t = 0; t < TM; ++t) acc[t] += u[(size_t)t * ldu + k] * vk;
    }
    for (int t = 0; t < TM && i0 + t < m; ++t) {
        const size_t bi = b_off + (size_t)(i0 + t) * ldb + j, oi = o_off + (size_t)(i0 + t) * ldo + j;
        PDR_XCAT(vstore, VW)(VLOADR(VW, base, bi) + acc[t], 0, out + oi);
    }
}
