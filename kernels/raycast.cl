// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): pydynrad/geometry/bvh.py launches
// both kernels in chunks of at most CAST_CHUNK (2^18) rays, ~5 ms (cast_occluded's chunks a whole
// number of packets, so each packet holds the rays it would in one launch).
// Batch ray casting against the patch BVH. Used by the BVH tests,
// the ray-throughput bench and any host code that needs a handful of hits.
#include "bvh.cl"

// origins, directions: 3 floats per ray (unpadded). tmax: per ray upper bound of t.
// Work-item g casts rays g * BVH_PACKET ... as one packet: consecutive rays are usually
// coherent (a hemicube scanline, an image row, a patch's rows); a tail packet repeats the last
// ray in its spare lanes and writes only the real ones.

// The rays first .. first + BVH_PACKET - 1 as one packet, and their tmax.
inline RayPacket load_packet(__global const float *origins, __global const float *directions,
                             __global const float *tmax, int first, int n_rays, bvh_floatP *tm_out)
{
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
    *tm_out = bvh_vloadP(0, tm);
    return r;
}

// Outputs per ray: the nearest patch (-1 on a miss), its t (INFINITY on a miss) and whether
// the ray met the patch's front side.
__kernel void cast_closest(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                           __global const float *origins, __global const float *directions,
                           __global const float *tmax, int n_rays,
                           __global int *patch, __global float *t, __global char *front)
{
    int first = get_global_id(0) * BVH_PACKET;
    if (first >= n_rays) return;
    bvh_floatP tm;
    RayPacket r = load_packet(origins, directions, tmax, first, n_rays, &tm);
    HitPacket h = bvh_closest_packet(nodes, tris, order, &r, 0.0f, tm, -1);
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

// Any-hit (shadow) query: 1 where some triangle lies at t in (0, tmax[k]); BVH_PACKET
// consecutive rays per work-item as one packet, as in cast_closest. Against one work-item per
// ray (bvh_occluded), packets are faster for coherent rays (a move's occlusion rays, shadow
// rays to a point), no slower for random directions, and slower for coherent rays in a random
// order (docs/decisions/0011-ray-tracing.md): callers keep coherent rays consecutive.
__kernel void cast_occluded(__global const float4 *nodes, __global const float4 *tris,
                            __global const float *origins, __global const float *directions,
                            __global const float *tmax, int n_rays, __global char *occluded)
{
    int first = get_global_id(0) * BVH_PACKET;
    if (first >= n_rays) return;
    bvh_floatP tm;
    RayPacket r = load_packet(origins, directions, tmax, first, n_rays, &tm);
    int hit[BVH_PACKET];
    bvh_vstoreP(bvh_occluded_packet(nodes, tris, &r, 0.0f, tm), 0, hit);
    for (int i = 0; i < BVH_PACKET && first + i < n_rays; ++i) occluded[first + i] = hit[i] != 0;
}
