// Batch ray casting against the patch BVH: one work-item per ray. Used by the BVH tests,
// the ray-throughput bench and any host code that needs a handful of hits.
#include "bvh.cl"

// origins, directions: 3 floats per ray (unpadded). tmax: per ray upper bound of t.
// Outputs per ray: the nearest patch (-1 on a miss), its t (INFINITY on a miss) and whether
// the ray met the patch's front side.
__kernel void cast_closest(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                           __global const float *origins, __global const float *directions,
                           __global const float *tmax, int n_rays,
                           __global int *patch, __global float *t, __global char *front)
{
    int k = get_global_id(0);
    if (k >= n_rays) return;
    float3 org = vload3(k, origins), dir = vload3(k, directions);
    Hit hit = bvh_closest(nodes, tris, order, org, dir, 0.0f, tmax[k]);
    patch[k] = hit.patch;
    t[k] = hit.patch >= 0 ? hit.t : INFINITY;
    front[k] = hit.patch >= 0 ? (char)hit.front : 0;
}

// Any-hit (shadow) query: 1 when some triangle lies at t in (0, tmax[k]).
__kernel void cast_occluded(__global const float4 *nodes, __global const float4 *tris,
                            __global const float *origins, __global const float *directions,
                            __global const float *tmax, int n_rays, __global char *occluded)
{
    int k = get_global_id(0);
    if (k >= n_rays) return;
    occluded[k] = bvh_occluded(nodes, tris, vload3(k, origins), vload3(k, directions), 0.0f, tmax[k]);
}
