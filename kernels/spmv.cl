// Launch bound (~100 ms on a small GPU: 100 GB/s, max_mem_alloc <= 2 GiB): one launch is one
// bounce, one pass over F's values and column indices (each one buffer, <= max_mem_alloc_size:
// <= 4 GiB, ~43 ms) plus O(N) vectors.
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
// so the host checks convergence by reading 2 numbers per block instead of both vectors. The
// residual exists only for a square matrix (`square` != 0): a product with a non-square one
// (the far field's G, N x C) has an x of another length, which row i must not index.
//   LX == 1 (CPUs): one work-item walks its block row by row, 4 or 8 entries of values and
//           indices per vector load, gathering x from cache. A tight loop of one thread.
//   LX > 1  (GPUs, CSR-vector): the group's LX items share each row, reading adjacent
//           entries (coalesced), and reduce in local memory.
// NCH and LX (or SELL_C, below) are required: the host picks NCH, pydynrad/device/launch.py LX or SELL_C,
// and RGB_STEP (float32 RGB entries per vector step on CPUs: 4 with 16-float registers, else 2).
#include "storage.h"

#if !defined(NCH) || !(defined(LX) || defined(SELL_C)) || (defined(LX) && !defined(RGB_STEP))
#error "spmv.cl needs NCH and LX (with RGB_STEP) or SELL_C from the host (pydynrad/device/csr.py, pydynrad/device/launch.py)"
#endif

#if NCH == 1
typedef REAL VEC;
#define VABSMAX(v) fabs(v)
#else
typedef REALV(4) VEC;
#define VABSMAX(v) fmax(fmax(fabs((v).x), fabs((v).y)), fabs((v).z))
#endif

#ifdef LX
// sum_k vals[k] x[cols[k]] over k in [k, end) for one work-item, several entries per step.
// Indices and values are read element by element, not by vload: PoCL does not inline its
// vload builtins, and a call per step slowed the RGB loop markedly
// (docs/decisions/0004-pocl-compiler.md); the compiler combines the plain loads itself.
inline VEC row_dot(__global const int *cols, __global const REAL *vals, __global const VEC *x, int k, const int end)
{
    VEC acc = (VEC)(0);
#if NCH == 1
    // Eight independent partial sums in one vector register; lanes of x gathered from cache.
    REALV(8) accv = (REALV(8))(0);
    for (; k <= end - 8; k += 8) {  // end - 8, not k + 8: k + 8 overflows an int near 2^31 entries
        const int8 c = (int8)(cols[k], cols[k + 1], cols[k + 2], cols[k + 3], cols[k + 4], cols[k + 5],
                              cols[k + 6], cols[k + 7]);
        const REALV(8) xv = (REALV(8))(x[c.s0], x[c.s1], x[c.s2], x[c.s3], x[c.s4], x[c.s5], x[c.s6], x[c.s7]);
        const REALV(8) v = (REALV(8))(vals[k], vals[k + 1], vals[k + 2], vals[k + 3], vals[k + 4], vals[k + 5],
                                      vals[k + 6], vals[k + 7]);
        accv = fma(v, xv, accv);
    }
    acc = HSUM(8, accv);
#elif defined(STORAGE_FP64) || RGB_STEP == 2
    // Entries in pairs: one 8-wide vector holds two whole RGB(A) gathers of x. float32 takes
    // this path on CPUs with 8-float registers (AVX2): there the 16-wide loop below ran about
    // half as fast, LLVM splitting its 512-bit vectors through shuffles
    // (docs/decisions/0010-full-solve-formats.md).
    REALV(8) a8 = (REALV(8))(0), b8 = (REALV(8))(0);
    for (; k <= end - 4; k += 4) {
        const int4 c = (int4)(cols[k], cols[k + 1], cols[k + 2], cols[k + 3]);
        const REALV(4) v = (REALV(4))(vals[k], vals[k + 1], vals[k + 2], vals[k + 3]);
        a8 = fma((REALV(8))((VEC)(v.x), (VEC)(v.y)), (REALV(8))(x[c.x], x[c.y]), a8);
        b8 = fma((REALV(8))((VEC)(v.z), (VEC)(v.w)), (REALV(8))(x[c.z], x[c.w]), b8);
    }
    a8 += b8;
    acc = a8.lo + a8.hi;
#else  // RGB_STEP == 4
    // Entries in fours: one 16-wide vector holds four whole RGB(A) gathers of x (a 512-bit
    // register; four separate float4 accumulators ran markedly slower on PoCL/AVX-512).
    REALV(16) a16 = (REALV(16))(0);
    for (; k <= end - 4; k += 4) {
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
            __global REAL *partial, const int square)
{
    const int g = get_group_id(0);
    const int r0 = blk[g], r1 = blk[g + 1];
    REAL d = 0, m = 0;
#if LX == 1
    for (int i = r0; i < r1; ++i) {
        const VEC yi = L[i] + rho[i] * row_dot(cols, vals, x, rowptr[i], rowptr[i + 1]);
        y[i] = yi;
        if (square) d = fmax(d, VABSMAX(yi - x[i]));
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
            if (square) d = fmax(d, VABSMAX(yi - x[i]));
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
#endif  // LX

// ---- SELL-C: the same bounce on a sliced-ELL copy of F (grey solves on wide-SIMD CPUs) ---------
// The host renumbers the patches (rows sorted by length within windows, pydynrad/device/sell.py)
// and cuts them into slices of SELL_C consecutive rows; slice s stores its rows' entries
// column by column: entry j of lane l at sptr[s] + j SELL_C + l (short rows padded with
// value 0, column 0). One work-item walks a block of slices (blk, as for bounce); each step
// reads SELL_C values and indices contiguously and gathers x at them, one lane per row, so no
// reduction across lanes. L, rho, x, y hold NCH REALs per (renumbered) patch as for bounce,
// N rounded up to SELL_C with zero rows. Grey: faster than the CSR loop; RGB: slower (three
// gathers of 16 floats per 16 entries against CSR's one float4 load per entry), so the host
// uses it for one channel only (docs/decisions/0010-full-solve-formats.md).
#ifdef SELL_C
#define SV REALV(SELL_C)
#define IV PDR_XCAT(int, SELL_C)
// x at the lanes' columns: one vector gather. With AVX-512 through clang's builtin (LLVM
// 14's loop vectorizer split it into 8-wide gathers through the stack, and spelled out lane by
// lane it built the vector from scalar loads and inserts); elsewhere lane by lane.
#if defined(__AVX512F__) && SELL_C == 16 && defined(STORAGE_FP32)
#define GATHER(p, c) __builtin_ia32_gathersiv16sf((SV)(0), (const void *)(ulong)(p), (c), (ushort)0xffff, 4)
#elif defined(__AVX512F__) && SELL_C == 8 && defined(STORAGE_FP64)
#define GATHER(p, c) __builtin_ia32_gathersiv8df((SV)(0), (const void *)(ulong)(p), (c), (uchar)0xff, 8)
#else
inline SV gather(__global const REAL *p, const IV c)
{
    SV r;
    for (int l = 0; l < SELL_C; ++l) ((REAL *)&r)[l] = p[((const int *)&c)[l]];
    return r;
}
#define GATHER gather
#endif

#if SELL_C == 4
#define LOADC(p) (REALV(4))((p)[0], (p)[1], (p)[2], (p)[3])
#define LOADI(p) (int4)((p)[0], (p)[1], (p)[2], (p)[3])
#elif SELL_C == 8
#define LOADC(p) (REALV(8))((p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7])
#define LOADI(p) (int8)((p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7])
#elif SELL_C == 16
#define LOADC(p) (REALV(16))((p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7], \
                             (p)[8], (p)[9], (p)[10], (p)[11], (p)[12], (p)[13], (p)[14], (p)[15])
#define LOADI(p) (int16)((p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7], \
                         (p)[8], (p)[9], (p)[10], (p)[11], (p)[12], (p)[13], (p)[14], (p)[15])
#else
#error "SELL_C must be 4, 8 or 16"
#endif

__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void bounce_sell(__global const int *blk, __global const int *sptr, __global const int *cols,
                 __global const REAL *vals, __global const REAL *L, __global const REAL *rho,
                 __global const REAL *x, __global REAL *y, __global REAL *partial)
{
    const int g = get_group_id(0);
    REAL d = 0, m = 0;
    for (int s = blk[g]; s < blk[g + 1]; ++s) {
        const int end = sptr[s + 1];
        SV acc[NCH == 4 ? 3 : 1];
        for (int ch = 0; ch < (NCH == 4 ? 3 : 1); ++ch) acc[ch] = (SV)(0);
        for (int o = sptr[s]; o < end; o += SELL_C) {
            const IV c = LOADI(cols + o) * NCH;
            const SV v = LOADC(vals + o);
            acc[0] = fma(v, GATHER(x, c), acc[0]);
#if NCH == 4
            acc[1] = fma(v, GATHER(x + 1, c), acc[1]);
            acc[2] = fma(v, GATHER(x + 2, c), acc[2]);
#endif
        }
        for (int l = 0; l < SELL_C; ++l) {
            const int i = (s * SELL_C + l) * NCH;
            for (int ch = 0; ch < (NCH == 4 ? 3 : 1); ++ch) {
                const REAL yi = L[i + ch] + rho[i + ch] * ((REAL *)&acc[ch])[l];
                y[i + ch] = yi;
                d = fmax(d, fabs(yi - x[i + ch]));
                m = fmax(m, fabs(yi));
            }
        }
    }
    partial[2 * g] = d;
    partial[2 * g + 1] = m;
}
#endif  // SELL_C
