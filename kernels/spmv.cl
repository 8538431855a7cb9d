// One bounce of the radiosity iteration on a CSR form-factor matrix F:
//     y = L + P (F x)
// per patch i and colour channel. Channels travel together (NCH = 4: RGB in a REAL4 with an
// unused fourth lane) so F is read once per bounce for all of them; NCH = 1 when albedos and
// the light vector are grey. REAL is float or double (STORAGE_FP32 / STORAGE_FP64, storage.h).
//
// Each work-group also reduces max_i |y_i - x_i| (the residual of the equation at x, since
// y - x = L + P F x - x) and max_i |y_i| into partial[2 * group], partial[2 * group + 1], so
// the host checks convergence by reading 2 numbers per group instead of both vectors.
//
// One row per work-item (scalar CSR): on a CPU a core walks its rows' entries in order; the
// gathers of x hit cache for the spatially sorted patch orders meshes usually have.
#include "storage.h"

#ifndef NCH
#define NCH 4
#endif
#define WG 64

#if NCH == 1
typedef REAL VEC;
#define VABSMAX(v) fabs(v)
#else
typedef REALV(4) VEC;
#define VABSMAX(v) fmax(fmax(fabs((v).x), fabs((v).y)), fabs((v).z))
#endif

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void bounce(const int n, __global const int *rowptr, __global const int *cols, __global const REAL *vals,
            __global const VEC *L, __global const VEC *rho, __global const VEC *x, __global VEC *y,
            __global REAL *partial)
{
    __local REAL dmax[WG], ymax[WG];
    const int i = get_global_id(0), lid = get_local_id(0);
    REAL d = 0, m = 0;
    if (i < n) {
        VEC acc = (VEC)(0);
        const int end = rowptr[i + 1];
        for (int k = rowptr[i]; k < end; ++k) acc += vals[k] * x[cols[k]];
        const VEC yi = L[i] + rho[i] * acc;
        y[i] = yi;
        d = VABSMAX(yi - x[i]);
        m = VABSMAX(yi);
    }
    dmax[lid] = d;
    ymax[lid] = m;
    for (int s = WG / 2; s > 0; s >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid < s) {
            dmax[lid] = fmax(dmax[lid], dmax[lid + s]);
            ymax[lid] = fmax(ymax[lid], ymax[lid + s]);
        }
    }
    if (lid == 0) {
        partial[2 * get_group_id(0)] = dmax[0];
        partial[2 * get_group_id(0) + 1] = ymax[0];
    }
}
