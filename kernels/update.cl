// Launch bound (~100 ms on a small GPU: 100 GB/s, 1 TFLOP/s fp32, max_mem_alloc <= 2 GiB): a
// gather reads one channel of K once (<= max_mem_alloc_size: ~21 ms) with 2 NV <= 2 NVMAX FMAs
// per element; a rank update reads and writes it once (~43 ms) with NA <= NAMAX FMAs per
// element; read_slots, write_slots, the sparse gathers and double_reflection touch O(M k) elements.
// In-place updates of the local multibounce matrix K (one channel, M x M, row pitch ld) for
// dynamic radiosity. K's element type comes from storage.h (STORAGE_FP16/FP32/FP64); the
// small vectors are REAL (float, or double with fp64 storage).
//
// Everything that touches all of K is memory-bound, so each kernel streams K once:
//   gather (gather_rows on CPUs, gather_partial on GPUs) + gather_reduce :
//       one read pass giving K X and Y K for NV vectors at once
//   rank_update_rows (CPUs) / rank_update (GPUs) : one read-write pass, K += A B (rank NA);
//       the CPU kernel also writes a few slots' columns and rows (write_slots' job) in that pass
//   gather_sparse_cols + gather_sparse_rows : the same products for vectors with few non-zeros
//       (O(M R) for R non-zero slots; the host picks them when they touch less of K)
// and the O(M) kernels: read_slots / write_slots (columns and rows of a few slots) and
// double_reflection (Eq. 1 of the paper).
//
// CPU kernels give each work-item (one per work-group) RR rows at a time: every VW-wide
// vector of B or X read from cache serves RR rows of K, which is what makes a rank-2k pass
// stream K instead of re-reading the small factors for every row.
//
// Layout defines, all required (pydynrad/device/launch.py, UpdateLayout.defines, picks them per device):
//   VW   vector width of K loads (4, 8 or 16: a CPU's SIMD register of REALs, 4 on GPUs)
//   SW   vector width of the sparse gathers (a step of gathered entries, not register-blocked)
//   WG   work-items per row block in gather_partial (a GPU's coalesced group)
//   RR   rows per step of the CPU kernels; CWMAX the widest column strip of gather_rows
//   NVMAX, NAMAX  the most vectors per gather / terms per rank update (private array sizes)
//   RED_WG  items of double_reflection's one work-group (a power of two)
//   PDR_CLANG_VECTORS  aligned vector access instead of vload/vstore (see storage.h).
// Host guarantees: ld % 64 == 0, K's padding columns M..ld are zero, X and B hold ld entries
// per vector with zeros past M (so padding stays zero after a rank update); the per-(i, m)
// kernels run on a global size rounded up past M and return for i >= M.
#include "storage.h"

#if !defined(VW) || !defined(SW) || !defined(WG) || !defined(RR) || !defined(CWMAX) || !defined(NVMAX) || !defined(NAMAX) || !defined(RED_WG)
#error "update.cl needs VW, SW, WG, RR, CWMAX, NVMAX, NAMAX and RED_WG from the host (pydynrad/device/launch.py)"
#endif

#define IMIN(a, b) ((a) < (b) ? (a) : (b))
// CPU gather. Item (s, b) owns columns [s*CW, s*CW + CW) of rows [b*RB, b*RB + RB). For RR
// rows at a time it converts that tile of K once into private memory, then for each vector m
//   rowpart[(s*NV + m)*M + i] = sum over its columns of K[i, j] X[m, j]  (partial K X)
//   colpart[(b*NV + m)*ld + j] += sum over the RR rows of Y[m, i] K[i, j]  (partial Y K)
// colpart's slab for block b is owned strip-wise by one item, so the += needs no atomics.
__kernel void gather_rows(__global const STORE_T *K, const int M, const int ld, const int RB, const int CW,
                          const int NV, __global const REAL *X, __global const REAL *Y,
                          __global REAL *rowpart, __global REAL *colpart)
{
    const int s = get_global_id(0), b = get_global_id(1);
    const int j0 = s * CW, nc = IMIN(ld - j0, CW);
    const int i0 = b * RB, i1 = IMIN(M, i0 + RB);
    __global REAL *cp = colpart + (size_t)b * NV * ld + j0;
    for (int m = 0; m < NV; ++m)
        for (int c = 0; c < nc; c += VW) RV_STORE((realv)(0), cp + (size_t)m * ld + c);
    realv tile[RR][CWMAX / VW];
    for (int i = i0; i < i1; i += RR) {
        const int nr = IMIN(RR, i1 - i);
        // The RR rows are read side by side (RR streams at once keep more loads in flight than
        // one row after another). Rows past the block read a valid row and contribute zeros.
        __global const STORE_T *rows[RR];
#pragma unroll
        for (int r = 0; r < RR; ++r) rows[r] = K + (size_t)IMIN(i + r, M - 1) * ld + j0;
        for (int c = 0; c < nc; c += VW) {
#pragma unroll
            for (int r = 0; r < RR; ++r) tile[r][c / VW] = r < nr ? KV(rows[r] + c) : (realv)(0);
        }
        for (int m = 0; m < NV; ++m) {
            REAL y[RR];
            realv racc[RR];
#pragma unroll
            for (int r = 0; r < RR; ++r) {
                y[r] = r < nr ? Y[(size_t)m * M + i + r] : 0;
                racc[r] = (realv)(0);
            }
            __global const REAL *x = X + (size_t)m * ld + j0;
            __global REAL *col = cp + (size_t)m * ld;
            for (int c = 0; c < nc; c += VW) {
                const realv xv = RV(x + c);
                // Four partial column sums: one chain of RR dependent FMAs would stall on latency.
                realv cv[4] = {RV(col + c), (realv)(0), (realv)(0), (realv)(0)};
#pragma unroll
                for (int r = 0; r < RR; ++r) {
                    racc[r] += tile[r][c / VW] * xv;
                    cv[r % 4] += y[r] * tile[r][c / VW];
                }
                RV_STORE((cv[0] + cv[1]) + (cv[2] + cv[3]), col + c);
            }
#pragma unroll
            for (int r = 0; r < RR; ++r)
                if (r < nr) rowpart[((size_t)s * NV + m) * M + i + r] = HSUM(VW, racc[r]);
        }
    }
}

// GPU gather. Item (lid, b) owns the column vectors j = (lid + t*WG)*VW of the rows
// [b*RB, min(M, b*RB+RB)). It writes
//   rowpart[(lid*NV + m)*M + i] = sum over its columns of K[i, j] X[m, j]  (partial K X)
//   colpart[(b*NV + m)*ld + j]  = sum over the block's rows of Y[m, i] K[i, j]  (partial Y K)
// colpart's slab for block b is owned column-wise by one item, so the += needs no atomics;
// it is NV*ld REALs per block and stays in cache while the block's rows stream past.
__kernel void gather_partial(__global const STORE_T *K, const int M, const int ld, const int RB, const int NV,
                             __global const REAL *X, __global const REAL *Y,
                             __global REAL *rowpart, __global REAL *colpart)
{
    const int lid = get_global_id(0), b = get_global_id(1);
    const int i0 = b * RB, i1 = min(M, i0 + RB);
    __global REAL *cp = colpart + (size_t)b * NV * ld;
    for (int j = lid * VW; j < ld; j += WG * VW)
        for (int m = 0; m < NV; ++m) PDR_XCAT(vstore, VW)((REALV(VW))(0), 0, cp + (size_t)m * ld + j);
    for (int i = i0; i < i1; ++i) {
        __global const STORE_T *row = K + (size_t)i * ld;
        REALV(VW) racc[NVMAX];
        REAL y[NVMAX];
        for (int m = 0; m < NV; ++m) {
            racc[m] = (REALV(VW))(0);
            y[m] = Y[(size_t)m * M + i];
        }
        for (int j = lid * VW; j < ld; j += WG * VW) {
            const REALV(VW) v = LOADV(VW, row, j);
            for (int m = 0; m < NV; ++m) {
                racc[m] += v * VLOADR(VW, X, (size_t)m * ld + j);
                __global REAL *c = cp + (size_t)m * ld + j;
                PDR_XCAT(vstore, VW)(VLOADR(VW, c, 0) + y[m] * v, 0, c);
            }
        }
        for (int m = 0; m < NV; ++m) rowpart[((size_t)lid * NV + m) * M + i] = HSUM(VW, racc[m]);
    }
}

// Second pass of both gathers: KX[m*M + i] = sum over the n_parts row partials,
// YK[m*M + j] = sum over the n_blocks column partials. Item (i, m).
__kernel void gather_reduce(__global const REAL *rowpart, __global const REAL *colpart, const int M, const int ld,
                            const int NV, const int n_parts, const int n_blocks, __global REAL *KX, __global REAL *YK)
{
    const int i = get_global_id(0), m = get_global_id(1);
    if (i >= M) return;
    REAL r = 0, c = 0;
    for (int l = 0; l < n_parts; ++l) r += rowpart[((size_t)l * NV + m) * M + i];
    for (int b = 0; b < n_blocks; ++b) c += colpart[((size_t)b * NV + m) * ld + i];
    KX[(size_t)m * M + i] = r;
    YK[(size_t)m * M + i] = c;
}

// Sparse gathers, in vectors of SW elements. A swap batch's vectors are the entering
// patches' form factors, zero on all but R of the M slots (the union over the batch's vectors, idx sorted ascending, padded by
// the host with slot 0 and zero values to Rp entries). Cost O(M R NV) instead of the dense
// gather's O(M^2 NV); K traffic: R whole rows, and per row of K at most the cache lines
// holding idx's columns (never more than a dense pass).
//
// gather_sparse_cols, item i (a row of K), Rp % SW == 0, vals (NV, Rp) row-major:
//   KX[m*M + i] = sum_t K[i, idx[t]] vals[m*Rp + t]
// SW scattered entries of the row at a time form one vector, so each vector of vals feeds SW
// products and the NV accumulators are touched once per SW entries.
__kernel void gather_sparse_cols(__global const STORE_T *K, const int M, const int ld, const int Rp,
                                 __global const int *idx, __global const REAL *vals, const int NV,
                                 __global REAL *KX)
{
    const int i = get_global_id(0);
    if (i >= M) return;
    __global const STORE_T *row = K + (size_t)i * ld;
    REALV(SW) acc[NVMAX];
    for (int m = 0; m < NV; ++m) acc[m] = (REALV(SW))(0);
    for (int t0 = 0; t0 < Rp; t0 += SW) {
#if defined(PDR_CLANG_VECTORS) && defined(STORAGE_FP16)
        // fp16: the 32-bit words holding the entries, then one vector shift and one vector
        // conversion (F16C) for all SW, not a conversion and a lane select per entry: 1.1-1.25x
        // faster gathers (CPU time, M = 1024-4096, 3-10% non-zero slots, AVX-512).
        PDR_XCAT(uint, SW) w, sh;
        __global const uint *words = (__global const uint *)row;
#pragma unroll
        for (int r = 0; r < SW; ++r) {
            const int c = idx[t0 + r];
            w[r] = words[c >> 1];
            sh[r] = (c & 1) << 4;
        }
        const PDR_XCAT(ushort, SW) h = __builtin_convertvector(w >> sh, PDR_XCAT(ushort, SW));
        const REALV(SW) k = __builtin_convertvector(__builtin_astype(h, PDR_XCAT(pdr_half, SW)), REALV(SW));
#else
        REAL kv[SW];
#pragma unroll
        for (int r = 0; r < SW; ++r) kv[r] = K1(row, idx[t0 + r]);
        const REALV(SW) k = PDR_XCAT(vload, SW)(0, kv);
#endif
        for (int m = 0; m < NV; ++m) acc[m] += k * RVN(SW, vals + (size_t)m * Rp + t0);
    }
    for (int m = 0; m < NV; ++m) KX[(size_t)m * M + i] = HSUM(SW, acc[m]);
}

// gather_sparse_rows, item g (columns j = SW g .. SW g + SW - 1 of K), Rp % RR == 0, vals (Rp, NV):
//   YK[m*M + j] = sum_t vals[t*NV + m] K[idx[t], j]
// RR rows' SW-wide vectors are held at once, so each accumulator is loaded and stored once per
// RR rows. Columns past M (padding, zero) are not written.
__kernel void gather_sparse_rows(__global const STORE_T *K, const int M, const int ld, const int Rp,
                                 __global const int *idx, __global const REAL *vals, const int NV,
                                 __global REAL *YK)
{
    const int j = get_global_id(0) * SW;
    if (j >= M) return;
    REALV(SW) acc[NVMAX];
    for (int m = 0; m < NV; ++m) acc[m] = (REALV(SW))(0);
    for (int t0 = 0; t0 < Rp; t0 += RR) {
        REALV(SW) tile[RR];
#pragma unroll
        for (int r = 0; r < RR; ++r) tile[r] = KVN(SW, K + (size_t)idx[t0 + r] * ld + j);
        __global const REAL *v = vals + (size_t)t0 * NV;
        for (int m = 0; m < NV; ++m) {
            REALV(SW) a = acc[m];
#pragma unroll
            for (int r = 0; r < RR; ++r) a += v[r * NV + m] * tile[r];
            acc[m] = a;
        }
    }
    if (j + SW <= M) {
        for (int m = 0; m < NV; ++m) PDR_XCAT(vstore, SW)(acc[m], 0, YK + (size_t)m * M + j);
    } else {
        for (int m = 0; m < NV; ++m) {
            REAL out[SW];
            PDR_XCAT(vstore, SW)(acc[m], 0, out);
            for (int c = 0; c < M - j; ++c) YK[(size_t)m * M + j + c] = out[c];
        }
    }
}

// GPU rank update: K[i, j] += sum_{n < NA} A[n*M + i] B[n*ld + j]. Item (g, i) handles the
// column vectors j = (g + t*G)*VW of row i, G = get_global_size(0) = ld/VW (coalesced).
// Paper mode passes NA = 1 with the bitset's row mask already folded into A.
__kernel void rank_update(__global STORE_T *K, const int M, const int ld, const int NA,
                          __global const REAL *A, __global const REAL *B)
{
    const int g = get_global_id(0), G = get_global_size(0), i = get_global_id(1);
    if (i >= M) return;
    REAL a[NAMAX];
    for (int n = 0; n < NA; ++n) a[n] = A[(size_t)n * M + i];
    __global STORE_T *row = K + (size_t)i * ld;
    for (int j = g * VW; j < ld; j += G * VW) {
        REALV(VW) v = LOADV(VW, row, j);
        for (int n = 0; n < NA; ++n) v += a[n] * VLOADR(VW, B, (size_t)n * ld + j);
        STOREV(VW, v, row, j);
    }
}

// CPU rank update, same result. Item b owns rows [b*RB, b*RB + RB) and walks them RR at a
// time along whole rows: the RR x VW accumulators stay in registers while n runs over the NA
// terms, each VW-wide vector of B (NA*ld REALs, cache-resident) feeding RR rows.
// With NS > 0 it then does write_slots' work on the rows it just stored (same values, same
// rule at crossings: the column value wins), while they are in cache and without a second
// launch: row slots[t] becomes rows[t*M ..], and K[i, slots[t]] = cols[t*M + i].
__kernel void rank_update_rows(__global STORE_T *K, const int M, const int ld, const int NA, const int RB,
                               __global const REAL *A, __global const REAL *B, const int NS,
                               __global const int *slots, __global const REAL *cols, __global const REAL *rows)
{
    const int i0 = get_global_id(0) * RB, i1 = IMIN(M, i0 + RB);
    for (int i = i0; i < i1; i += RR) {
        const int nr = IMIN(RR, i1 - i);
        REAL a[NAMAX][RR];
        __global STORE_T *row[RR];
#pragma unroll
        for (int r = 0; r < RR; ++r) {
            // Rows past the block alias a valid row and are computed but never stored.
            const int ii = IMIN(i + r, M - 1);
            row[r] = K + (size_t)ii * ld;
            for (int n = 0; n < NA; ++n) a[n][r] = A[(size_t)n * M + ii];
        }
        for (int j = 0; j < ld; j += VW) {
            realv acc[RR];
#pragma unroll
            for (int r = 0; r < RR; ++r) acc[r] = KV(row[r] + j);
            for (int n = 0; n < NA; ++n) {
                const realv bv = RV(B + (size_t)n * ld + j);
#pragma unroll
                for (int r = 0; r < RR; ++r) acc[r] += a[n][r] * bv;
            }
#pragma unroll
            for (int r = 0; r < RR; ++r)
                if (r < nr) KV_STORE(acc[r], row[r] + j);
        }
        for (int r = 0; r < (NS > 0 ? nr : 0); ++r) {
            for (int t = 0; t < NS; ++t)
                if (slots[t] == i + r)
                    for (int j = 0; j < M; ++j) STORE(rows[(size_t)t * M + j], row[r], j);
            for (int t = 0; t < NS; ++t) STORE(cols[(size_t)t * M + i + r], row[r], slots[t]);
        }
    }
}

// cols[m*M + i] = K[i, slots[m]], rows[m*M + i] = K[slots[m], i]. Item (i, m).
__kernel void read_slots(__global const STORE_T *K, const int M, const int ld, __global const int *slots,
                         __global REAL *cols, __global REAL *rows)
{
    const int i = get_global_id(0), m = get_global_id(1);
    if (i >= M) return;
    const int s = slots[m];
    cols[(size_t)m * M + i] = LOAD(K, (size_t)i * ld + s);
    rows[(size_t)m * M + i] = LOAD(K, (size_t)s * ld + i);
}

// K[i, slots[m]] = cols[m*M + i], K[slots[m], i] = rows[m*M + i]. Where a written row crosses
// a written column only the column write happens, so no cell has two writers (fp16 stores
// of neighbouring halves by different items must never overlap a cell). Item (i, m).
__kernel void write_slots(__global STORE_T *K, const int M, const int ld, __global const int *slots, const int k,
                          __global const REAL *cols, __global const REAL *rows)
{
    const int i = get_global_id(0), m = get_global_id(1);
    if (i >= M) return;
    const int s = slots[m];
    STORE(cols[(size_t)m * M + i], K, (size_t)i * ld + s);
    bool crossing = false;
    for (int t = 0; t < k; ++t) crossing |= slots[t] == i;
    if (!crossing) STORE(rows[(size_t)m * M + i], K, (size_t)s * ld + i);
}

// Eq. 1: out[0] = sum_a f_c[a] f_r[a] rho[a]: light leaving the new patch, reflected once by
// the local set and returning to it. v holds f_c, f_r, rho back to back (3 M REALs).
// One work-group of RED_WG items, tree reduction.
__kernel void double_reflection(__global const REAL *v, const int M, __global REAL *out)
{
    __global const REAL *f_c = v, *f_r = v + M, *rho = v + 2 * M;
    __local REAL part[RED_WG];
    const int lid = get_local_id(0);
    REAL s = 0;
    for (int a = lid; a < M; a += RED_WG) s += f_c[a] * f_r[a] * rho[a];
    part[lid] = s;
    for (int h = RED_WG / 2; h > 0; h >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid < h) part[lid] += part[lid + h];
    }
    if (lid == 0) out[0] = part[0];
}
