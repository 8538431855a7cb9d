// Hemicube form factors by ray casting: one work-item per hemicube scanline.
//
// A hemicube of resolution R (HC_RES) at patch i has a top face of R x R pixels and four
// side faces of R x R/2, i.e. 3R scanlines of R pixels each:
//   s <  R : top face z = 1, pixel (x, s) centred at (u, v) = (-1 + (x + .5) 2/R, -1 + (s + .5) 2/R)
//   s >= R : side f = (s - R) / (R/2), row r = (s - R) % (R/2), height h = (r + .5) 2/R,
//            across a = -1 + (x + .5) 2/R; f = 0: (1, a, h), 1: (-1, -a, h), 2: (-a, 1, h), 3: (a, -1, h)
// in the patch's frame (T, B, N), T rotated about N by a per-patch pseudo-random angle so that
// regular structures do not alias the same way at every patch. pydynrad/formfactors.py
// computes the pixels' delta form factors with the same layout.
//
// Each scanline's pixels are run-length encoded: consecutive pixels that see the same patch
// form one run (id, end pixel). The host turns runs into weights with a prefix sum of the
// pixel form factors, so nothing N-sized per row ever exists on the device.
//
// With HC_CLUSTERS defined (the far field's patch-to-cluster form factors G = F Pr) the kernel
// takes three more arguments: labels (int per patch: its cluster, or -1 for none), scale (float
// per patch: its entry of Pr, 1 for the indicator) and pixel_weights (the delta form factors,
// 3R x R as above). It records labels[patch] instead of the patch, so neighbouring pixels on
// different patches of one cluster form one run, and sums each run's weight on the device:
// run_end holds that float weight instead of an end pixel. (Summing here measured faster than
// the host's prefix sums, bench/gather.py.)
#include "bvh.cl"

#ifndef HC_RES
#error "HC_RES (the hemicube resolution) must be defined"
#endif
// The lane offsets of a scanline's packet below are written out for 16 lanes.
#if BVH_PACKET != 16
#error "hemicube.cl needs BVH_PACKET == 16 from the host (pydynrad/launch.py)"
#endif

#ifdef HC_CLUSTERS
#define HC_EXTRA_ARGS , __global const int *labels, __global const float *scale, __global const float *pixel_weights
#define HC_END_TYPE float
#else
#define HC_EXTRA_ARGS
#define HC_END_TYPE int
#endif

// A 32-bit integer hash (lowbias32): the rotation angle of patch i, fixed for all runs.
inline uint hc_hash(uint x)
{
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

// centers, normals: float4 per patch. rows: the patches whose hemicubes this block renders.
// Outputs per (row k, scanline s): run_patch / run_end at [(k * 3R + s) * R + j] for the j-th
// run (patch -1: nothing front-facing visible), run_count at [k * 3R + s].
__kernel void hemicube_runs(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                            __global const float4 *centers, __global const float4 *normals,
                            __global const int *rows, int n_rows, float eps,
                            __global int *run_patch, __global HC_END_TYPE *run_end, __global int *run_count
                            HC_EXTRA_ARGS)
{
    const int R = HC_RES, H = HC_RES / 2;
    int g = get_global_id(0);
    if (g >= n_rows * 3 * R) return;
    int k = g / (3 * R), s = g % (3 * R);
    int i = rows[k];
    float3 n = normals[i].xyz;
    float3 org = centers[i].xyz + eps * n;

    // Orthonormal basis around n without a branch on its direction (Duff et al. 2017),
    // then rotated about n by the patch's angle.
    float sg = copysign(1.0f, n.z);
    float a = -1.0f / (sg + n.z);
    float b = n.x * n.y * a;
    float3 t0 = (float3)(1.0f + sg * n.x * n.x * a, sg * b, -sg * n.x);
    float3 b0 = (float3)(b, sg + n.y * n.y * a, -n.y);
    float ang = (float)hc_hash((uint)i) * (6.283185307179586f / 4294967296.0f);
    float cs = cos(ang), sn = sin(ang);
    float3 T = cs * t0 + sn * b0, B = cs * b0 - sn * t0;

    // Per scanline: dir(x) = base + x * step_dir, both in world space.
    float px = 2.0f / R;
    float3 base, step_dir;
    if (s < R) {
        float v = -1.0f + (s + 0.5f) * px;
        base = -T + v * B + n;
        step_dir = T;
    } else {
        int f = (s - R) / H, r = (s - R) % H;
        float h = (r + 0.5f) * px;
        float3 out = f == 0 ? T : (f == 1 ? -T : (f == 2 ? B : -B));
        float3 across = f == 0 ? B : (f == 1 ? -B : (f == 2 ? -T : T));
        base = out - across + h * n;
        step_dir = across;
    }
    base += 0.5f * px * step_dir;
    step_dir *= px;

    size_t slot = (size_t)g * R;
    int runs = 0, current = -2;
#ifdef HC_CLUSTERS
    float acc = 0.0f;
    __global const float *pw = pixel_weights + (size_t)s * R;
#endif
    // BVH_PACKET pixels of the scanline per traversal, one per vector lane (a short last
    // packet repeats its last pixel in the spare lanes).
    const bvh_floatP lane = (bvh_floatP)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    RayPacket r;
    r.ox = (bvh_floatP)org.x;
    r.oy = (bvh_floatP)org.y;
    r.oz = (bvh_floatP)org.z;
    for (int x0 = 0; x0 < R; x0 += BVH_PACKET) {
        bvh_floatP xs = BVH_MIN((bvh_floatP)x0 + lane, (bvh_floatP)(R - 1));
        r.dx = base.x + xs * step_dir.x;
        r.dy = base.y + xs * step_dir.y;
        r.dz = base.z + xs * step_dir.z;
        HitPacket hp = bvh_closest_packet(nodes, tris, order, &r, 0.0f, (bvh_floatP)INFINITY);
        int ids[BVH_PACKET], fronts[BVH_PACKET];
        bvh_vstoreP(hp.patch, 0, ids);
        bvh_vstoreP(hp.front, 0, fronts);
        for (int l = 0; l < BVH_PACKET && x0 + l < R; ++l) {
            // A back face occludes and receives nothing; a planar patch cannot see itself.
            int hit = (ids[l] >= 0 && fronts[l] && ids[l] != i) ? ids[l] : -1;
#ifdef HC_CLUSTERS
            int id = hit >= 0 ? labels[hit] : -1;
#else
            int id = hit;
#endif
            if (id != current) {
                if (current != -2) {
                    run_patch[slot + runs] = current;
#ifdef HC_CLUSTERS
                    run_end[slot + runs] = acc;
                    acc = 0.0f;
#else
                    run_end[slot + runs] = x0 + l;
#endif
                    ++runs;
                }
                current = id;
            }
#ifdef HC_CLUSTERS
            if (id >= 0) acc += pw[x0 + l] * scale[hit];
#endif
        }
    }
    run_patch[slot + runs] = current;
#ifdef HC_CLUSTERS
    run_end[slot + runs] = acc;
#else
    run_end[slot + runs] = R;
#endif
    run_count[g] = runs + 1;
}
