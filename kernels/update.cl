// In-place updates of the local multibounce matrix K (one channel, M x M, row pitch ld) for
// dynamic radiosity. K's element type comes from storage.h (STORAGE_FP16/FP32/FP64); the
// small vectors are REAL (float, or double with fp64 storage).
//
// Everything that touches all of K is memory-bound, so each kernel streams K once:
//   gather_partial + gather_reduce : one read pass giving K X and Y K for NV vectors at once
//   rank_update                    : one read-write pass, K += A B (rank NA)
// and the O(M) kernels: read_slots / write_slots (columns and rows of a few slots) and
// double_reflection (Eq. 1 of the paper).
//
// Layout defines (the host picks them per device):
//   VW   vector width of K loads (16 on CPUs, 4 on GPUs)
//   WG   work-items per row block in gather_partial: 1 on a CPU (one item streams whole rows),
//        64 on a GPU (adjacent items read adjacent vectors: coalesced)
//   NVMAX, NAMAX  the most vectors per gather / terms per rank update (private array sizes)
// Host guarantees: ld % VW == 0, K's padding columns M..ld are zero, X and B hold ld entries
// per vector with zeros past M (so padding stays zero after rank_update).
#include "storage.h"

#ifndef VW
#define VW 16
#endif
#ifndef WG
#define WG 1
#endif
#ifndef NVMAX
#define NVMAX 1
#endif
#ifndef NAMAX
#define NAMAX 2
#endif

// Pass 1 of the gather. Item (lid, b) owns the column vectors j = (lid + t*WG)*VW of the rows
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

// Pass 2: KX[m*M + i] = sum_lid rowpart, YK[m*M + j] = sum_b colpart. Item (i, m).
__kernel void gather_reduce(__global const REAL *rowpart, __global const REAL *colpart, const int M, const int ld,
                            const int NV, const int n_blocks, __global REAL *KX, __global REAL *YK)
{
    const int i = get_global_id(0), m = get_global_id(1);
    if (i >= M) return;
    REAL r = 0, c = 0;
    for (int l = 0; l < WG; ++l) r += rowpart[((size_t)l * NV + m) * M + i];
    for (int b = 0; b < n_blocks; ++b) c += colpart[((size_t)b * NV + m) * ld + i];
    KX[(size_t)m * M + i] = r;
    YK[(size_t)m * M + i] = c;
}

// K[i, j] += sum_{n < NA} A[n*M + i] B[n*ld + j]. Item (g, i) handles the column vectors
// j = (g + t*G)*VW of row i, G = get_global_size(0): G = 1 on a CPU (a row per item,
// streamed with wide vectors), G = ld/VW on a GPU (one vector per item, coalesced).
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
#ifndef RED_WG
#define RED_WG 64
#endif
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
