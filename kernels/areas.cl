// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): points x emitting triangles x
// grid^2 shadow rays. pydynrad/lights/areas.py splits a call into launches of at most
// EMITTER_RAYS_PER_LAUNCH (2^22) rays, ~84 ms: ranges of emitters j0 .. n_emitters - 1 (each
// launch after the first adds to out, continuing each point's sum in the same order) and chunks
// of points (a global offset; n_points is the chunk's end). grid^2 <= 4,096, so a launch holds
// at least one point and 1,024 emitters.
// Direct irradiance from emitting patches at points, by the exact point-to-polygon form factor
// (Lambert's contour integral) times a visibility fraction from shadow rays: accurate however
// close a point is to an emitter, where a hemicube's pixels are far too coarse.
//
// emitters: 4 float4 per emitting triangle: v0, v1, v2 (xyz), its unit normal (xyz);
// exitance: its emission (float4, rgb). One work-item per point, looping over the emitters j0 ..
// n_emitters - 1 in order.
#include "bvh.cl"

// Form factor from a differential area at p with unit normal n to the convex polygon q[0..m-1]
// lying in n's half-space: |sum_k angle(r_k, r_k+1) n.(r_k x r_k+1) / |r_k x r_k+1|| / (2 pi).
inline float contour_form_factor(float3 p, float3 n, const float3 *q, int m)
{
    float sum = 0.0f;
    for (int k = 0; k < m; ++k) {
        float3 a = q[k] - p, b = q[(k + 1) % m] - p;
        float3 c = BVH_CROSS(a, b);
        float s = sqrt(BVH_DOT(c, c));
        if (s <= 0.0f) continue;
        float angle = atan2(s, BVH_DOT(a, b));
        sum += angle * BVH_DOT(n, c) / s;
    }
    return fabs(sum) * (0.5f * M_1_PI_F);
}

// The triangle t[0..2] clipped to the half-space n.(x - p) >= 0 (Sutherland-Hodgman): at most 4 corners.
inline int clip_triangle(float3 p, float3 n, const float3 *t, float3 *out)
{
    int m = 0;
    for (int k = 0; k < 3; ++k) {
        float3 a = t[k], b = t[(k + 1) % 3];
        float da = BVH_DOT(n, a - p), db = BVH_DOT(n, b - p);
        if (da >= 0.0f) out[m++] = a;
        if ((da >= 0.0f) != (db >= 0.0f)) out[m++] = a + (b - a) * (da / (da - db));
    }
    return m;
}

__kernel void emitter_irradiance(__global const float4 *points, __global const float4 *normals, const int n_points,
                                 __global const float4 *emitters, __global const float4 *exitance, const int n_emitters,
                                 __global const float4 *nodes, __global const float4 *tris,
                                 const float eps, const int grid, const int j0, __global float4 *out)
{
    const int i = get_global_id(0);
    if (i >= n_points) return;
    const float3 p = points[i].xyz, n = normals[i].xyz;
    const float3 org = p + eps * n;
    // Emitters j0 .. n_emitters - 1: a launch after the first (j0 > 0) continues the sum it left in out.
    float3 acc = j0 > 0 ? out[i].xyz : (float3)(0.0f);
    for (int j = j0; j < n_emitters; ++j) {
        float3 t[3] = {emitters[4 * j].xyz, emitters[4 * j + 1].xyz, emitters[4 * j + 2].xyz};
        const float3 ny = emitters[4 * j + 3].xyz;
        if (BVH_DOT(ny, p - t[0]) <= 0.0f) continue;  // behind the emitter: it emits from its front only
        float3 q[4];
        const int m = clip_triangle(p, n, t, q);
        if (m < 3) continue;
        const float ff = contour_form_factor(p, n, q, m);
        if (ff <= 0.0f) continue;
        // Visibility: the share of the form-factor integrand cos cos / r^2, over grid x grid
        // stratified (equal-area) points on the triangle above the point's plane, that shadow
        // rays reach (stopping 2 eps short of the emitter).
        float seen = 0.0f, total = 0.0f;
        const float3 e1 = t[1] - t[0], e2 = t[2] - t[0];
        for (int a = 0; a < grid; ++a) {
            for (int b = 0; b < grid; ++b) {
                const float su = sqrt((a + 0.5f) / grid), v = (b + 0.5f) / grid;
                const float3 y = t[0] + e1 * (su * (1.0f - v)) + e2 * (su * v);
                const float3 d = y - org;
                const float dist2 = BVH_DOT(d, d), cx = BVH_DOT(n, y - p), cy = -BVH_DOT(ny, d);
                if (cx <= 0.0f || cy <= 0.0f) continue;
                const float w = cx * cy / (dist2 * dist2);
                total += w;
                const float dist = sqrt(dist2);
                if (!bvh_occluded(nodes, tris, org, d / dist, 0.0f, dist - 2.0f * eps)) seen += w;
            }
        }
        // A sliver above the plane between the samples: taken as seen.
        const float visible = total > 0.0f ? seen / total : 1.0f;
        acc += exitance[j].xyz * (ff * visible);
    }
    out[i] = (float4)(acc, 0.0f);
}
