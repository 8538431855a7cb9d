// Batch ray casting against the patch BVH. Used by the BVH tests,
// the ray-throughput bench and any host code that needs a handful of hits.
#include "bvh.cl"

// origins, directions: 3 floats per ray (unpadded). tmax: per ray upper bound of t.
// Outputs per ray: the nearest patch (-1 on a miss), its t (INFINITY on a miss) and whether
// the ray met the patch's front side. Work-item g casts rays g * BVH_PACKET ... as one packet:
// consecutive rays are usually coherent (a hemicube scanline, an image row); a tail packet
// repeats the last ray in its spare lanes and writes only the real ones.
__kernel void cast_closest(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                           __global const float *origins, __global const float *directions,
                           __global const float *tmax, int n_rays,
                           __global int *patch, __global float *t, __global char *front)
{
    int first = get_global_id(0) * BVH_PACKET;
    if (first >= n_rays) return;
    float ox[BVH_PACKET], oy[BVH_PACKET], oz[BVH_PACKET], dx[BVH_PACKET], dy[BVH_PACKET], dz[BVH_PACKET];
    float tm[BVH_PACKET];
    for (int i = 0; i < BVH_PACKET; ++i) {
        int k = min(first + i, n_rays - 1);
        float3 o = vload3(k, origins), d = vload3(k, directions);
        ox[i] = o.x; oy[i] = o.y; oz[i] = o.z;
        dx[i] = d.x; dy[i] = d.y; dz[i] = d.z;
        tm[i] = tmax[k];
    }
    RayPacket r = {bvh_vloadP(0, ox), bvh_vloadP(0, oy), bvh_vloadP(0, oz),
                   bvh_vloadP(0, dx), bvh_vloadP(0, dy), bvh_vloadP(0, dz)};
    HitPacket h = bvh_closest_packet(nodes, tris, order, &r, 0.0f, bvh_vloadP(0, tm));
    int hp[BVH_PACKET], hf[BVH_PACKET];
    float ht[BVH_PACKET];
    bvh_vstoreP(h.patch, 0, hp);
    bvh_vstoreP(h.front, 0, hf);
    bvh_vstoreP(h.t, 0, ht);
    for (int i = 0; i < BVH_PACKET && first + i < n_rays; ++i) {
        patch[first + i] = hp[i];
        t[first + i] = hp[i] >= 0 ? ht[i] : INFINITY;
        front[first + i] = hp[i] >= 0 ? (char)hf[i] : 0;
    }
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
