// One bounce of the radiosity iteration on a CSR form-factor matrix F:
//     y = L + P (F x)
// per patch i and colour channel, and the convergence measures of the same pass. Each bounce
// is exactly one pass over F's values and column indices (the only large arrays); everything
// else (x, y, L, P) is O(N) and x stays in cache while F streams.
//
// Channels travel together (NCH = 4: RGB in a REAL4 with an unused fourth lane) so F is read
// once per bounce for all of them; NCH = 1 when albedos and the light vector are grey.
// REAL is float or double (STORAGE_FP32 / STORAGE_FP64, storage.h).
//
// Work split: work-group g owns the rows [blk[g], blk[g + 1]), blocks chosen by the host so
// each holds about the same number of non-zeros (a core's share does not depend on how long
// its rows happen to be). It also writes max_i |y_i - x_i| (the residual of the equation at
// x, since y - x = L + P F x - x) and max_i |y_i| of its rows to partial[2g], partial[2g + 1],
// so the host checks convergence by reading 2 numbers per block instead of both vectors.
//   LX == 1 (CPUs): one work-item walks its block row by row, 4 or 8 entries of values and
//           indices per vector load, gathering x from cache. A tight loop of one thread.
//   LX > 1  (GPUs, CSR-vector): the group's LX items share each row, reading adjacent
//           entries (coalesced), and reduce in local memory.
// NCH and LX are required: pydynrad/solve.py picks NCH, pydynrad/launch.py (SpmvLayout) LX.
#include "storage.h"

#if !defined(NCH) || !defined(LX)
#error "spmv.cl needs NCH and LX from the host (pydynrad/solve.py, pydynrad/launch.py)"
#endif

#if NCH == 1
typedef REAL VEC;
#define VABSMAX(v) fabs(v)
#else
typedef REALV(4) VEC;
#define VABSMAX(v) fmax(fmax(fabs((v).x), fabs((v).y)), fabs((v).z))
#endif

// sum_k vals[k] x[cols[k]] over k in [k, end) for one work-item, several entries per step.
// Indices and values are read element by element, not by vload: PoCL does not inline its
// vload builtins, and a call per step cost the RGB loop 1.6-1.7x (village, 35 M non-zeros,
// float32, PoCL pthread AMD EPYC, 2026-12-02); the compiler combines the plain loads itself.
inline VEC row_dot(__global const int *cols, __global const REAL *vals, __global const VEC *x, int k, const int end)
{
    VEC acc = (VEC)(0);
#if NCH == 1
    // Eight independent partial sums in one vector register; lanes of x gathered from cache.
    REALV(8) accv = (REALV(8))(0);
    for (; k + 8 <= end; k += 8) {
        const int8 c = (int8)(cols[k], cols[k + 1], cols[k + 2], cols[k + 3], cols[k + 4], cols[k + 5],
                              cols[k + 6], cols[k + 7]);
        const REALV(8) xv = (REALV(8))(x[c.s0], x[c.s1], x[c.s2], x[c.s3], x[c.s4], x[c.s5], x[c.s6], x[c.s7]);
        const REALV(8) v = (REALV(8))(vals[k], vals[k + 1], vals[k + 2], vals[k + 3], vals[k + 4], vals[k + 5],
                                      vals[k + 6], vals[k + 7]);
        accv = fma(v, xv, accv);
    }
    acc = HSUM(8, accv);
#elif defined(STORAGE_FP64)
    // Entries in pairs: one 8-wide vector holds two whole RGB(A) gathers of x.
    REALV(8) a8 = (REALV(8))(0), b8 = (REALV(8))(0);
    for (; k + 4 <= end; k += 4) {
        const int4 c = (int4)(cols[k], cols[k + 1], cols[k + 2], cols[k + 3]);
        const REALV(4) v = (REALV(4))(vals[k], vals[k + 1], vals[k + 2], vals[k + 3]);
        a8 = fma((REALV(8))((VEC)(v.x), (VEC)(v.y)), (REALV(8))(x[c.x], x[c.y]), a8);
        b8 = fma((REALV(8))((VEC)(v.z), (VEC)(v.w)), (REALV(8))(x[c.z], x[c.w]), b8);
    }
    a8 += b8;
    acc = a8.lo + a8.hi;
#else
    // Entries in fours: one 16-wide vector holds four whole RGB(A) gathers of x (a 512-bit
    // register; four separate float4 accumulators ran 1.6x slower on PoCL/AVX-512).
    REALV(16) a16 = (REALV(16))(0);
    for (; k + 4 <= end; k += 4) {
        const int4 c = (int4)(cols[k], cols[k + 1], cols[k + 2], cols[k + 3]);
        const REALV(4) v = (REALV(4))(vals[k], vals[k + 1], vals[k + 2], vals[k + 3]);
        const REALV(16) vv = (REALV(16))((VEC)(v.x), (VEC)(v.y), (VEC)(v.z), (VEC)(v.w));
        a16 = fma(vv, (REALV(16))(x[c.x], x[c.y], x[c.z], x[c.w]), a16);
    }
    acc = (a16.lo.lo + a16.lo.hi) + (a16.hi.lo + a16.hi.hi);
#endif
    for (; k < end; ++k) acc = fma((VEC)(vals[k]), x[cols[k]], acc);
    return acc;
}

__kernel __attribute__((reqd_work_group_size(LX, 1, 1)))
void bounce(__global const int *blk, __global const int *rowptr, __global const int *cols, __global const REAL *vals,
            __global const VEC *L, __global const VEC *rho, __global const VEC *x, __global VEC *y,
            __global REAL *partial)
{
    const int g = get_group_id(0);
    const int r0 = blk[g], r1 = blk[g + 1];
    REAL d = 0, m = 0;
#if LX == 1
    for (int i = r0; i < r1; ++i) {
        const VEC yi = L[i] + rho[i] * row_dot(cols, vals, x, rowptr[i], rowptr[i + 1]);
        y[i] = yi;
        d = fmax(d, VABSMAX(yi - x[i]));
        m = fmax(m, VABSMAX(yi));
    }
    partial[2 * g] = d;
    partial[2 * g + 1] = m;
#else
    __local VEC part[LX];
    const int lid = get_local_id(0);
    for (int i = r0; i < r1; ++i) {
        VEC acc = (VEC)(0);
        const int end = rowptr[i + 1];
        for (int k = rowptr[i] + lid; k < end; k += LX) acc = fma((VEC)(vals[k]), x[cols[k]], acc);
        part[lid] = acc;
        for (int s = LX / 2; s > 0; s >>= 1) {
            barrier(CLK_LOCAL_MEM_FENCE);
            if (lid < s) part[lid] += part[lid + s];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid == 0) {
            const VEC yi = L[i] + rho[i] * part[0];
            y[i] = yi;
            d = fmax(d, VABSMAX(yi - x[i]));
            m = fmax(m, VABSMAX(yi));
        }
        barrier(CLK_LOCAL_MEM_FENCE);  // part[0] read before the next row overwrites it
    }
    if (lid == 0) {
        partial[2 * g] = d;
        partial[2 * g + 1] = m;
    }
#endif
}
