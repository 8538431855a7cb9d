// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): the host launches at most
// BLOCK_POINTS (4,096) points at a time, 3R * R rays each: 4 M rays at R = 32 (~80 ms).
// Irradiance gathered by a hemicube at arbitrary points (sensors, patch centres): one
// work-item per (point, scanline), rays as hemicube.h lays them out.
//
// Each pixel's ray adds its delta form factor (weights, (3R, R) from
// pydynrad.formfactors.pixel_form_factors) times what it meets: the radiosity of a patch seen
// from the front (not the point's own patch), nothing for a back face, and pi times the sky's
// luminance (sky.h) for a ray that leaves the scene. Sum over a hemicube: irradiance.
#include "hemicube.h"  // and bvh.cl
#include "sky.h"

// points, normals: float4 per point; keys: each point's rotation key; own: the patch a point
// lies on (-1: none). This launch does points first .. first + n_points - 1. Output:
// partial[k * 3R + s].xyz, scanline s's share of point first + k.
__kernel void hemicube_gather(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                              __global const float4 *points, __global const float4 *normals,
                              __global const int *keys, __global const int *own, int first, int n_points, float eps,
                              __global const float *weights, __global const float4 *radiosity,
                              __global const float4 *sky, __global float4 *partial)
{
    const int R = HC_RES;
    int g = get_global_id(0);
    if (g >= n_points * 3 * R) return;
    int k = g / (3 * R), s = g % (3 * R), q = first + k;
    float3 n = normals[q].xyz;
    float3 org = points[q].xyz + eps * n;
    const int self = own[q];
    float3 base, step_dir;
    hc_scanline(n, (uint)keys[q], s, &base, &step_dir);

    float3 acc = (float3)(0.0f);
    for (int x0 = 0; x0 < R; x0 += BVH_PACKET) {
        int ids[BVH_PACKET], fronts[BVH_PACKET];
        hc_trace_packet(nodes, tris, order, org, base, step_dir, x0, ids, fronts);
        for (int l = 0; l < BVH_PACKET && x0 + l < R; ++l) {
            const float w = weights[s * R + x0 + l];
            const int id = ids[l];
            if (id < 0) {
                float3 d = base + (float)(x0 + l) * step_dir;
                d *= 1.0f / sqrt(BVH_DOT(d, d));
                acc += (float3)(w * 3.14159265358979f * sky_luminance(sky, d));
            } else if (fronts[l] && id != self) {
                acc += w * radiosity[id].xyz;
            }
        }
    }
    partial[g] = (float4)(acc, 0.0f);
}
