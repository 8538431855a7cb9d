// Irradiance from the analytic lights (point, spot, directional, luminaire), shared by the
// light pass at patch centres and sensors (lights.cl) and the path tracer's next-event
// estimation (pathtrace.cl).
//
// lights: 3 float4 per light (packed by pydynrad.lights.sources.pack_lights):
//   [0] position.xyz, type (0 point, 1 spot, 2 directional, 3 luminaire)
//   [1] direction.xyz (unit; for spot: the axis; directional: the way the light travels;
//       luminaire: the nadir, gamma = 0), then for a spot 1 / (cos_inner - cos_outer) (falloff
//       slope; huge for a hard edge), for a luminaire the offset of its table in `tables`
//   [2] intensity.rgb (point/spot: W/sr or cd; directional: irradiance; luminaire: RGB scale
//       on the table's cd), cos_outer (spot)
// tables (pydynrad.lights.sources.pack_light_tables), per luminaire at its offset: c0.xyz, c90.xyz,
//   nC, nG, nC C angles, nG gamma angles (radians, increasing; C spans 0..2 pi unless nC = 1),
//   nC * nG intensities C-major (cd).
// Only the side a surface's normal faces is lit.
#ifndef PYDYNRAD_LIGHTS_H
#define PYDYNRAD_LIGHTS_H

#include "bvh.cl"

// Largest i in [0, n - 2] with a[i] <= x (n >= 2, a increasing).
inline int lum_bracket(__global const float *a, const int n, const float x)
{
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        const int mid = (lo + hi) / 2;
        if (a[mid] <= x) lo = mid; else hi = mid;
    }
    return lo;
}

// Intensity (cd) of the luminaire whose table starts at tables[o] towards unit direction v
// (from the luminaire), nadir its gamma = 0 axis: bilinear in (C, gamma), 0 outside the
// table's gamma range, as PhotometricDistribution.intensity computes it on the host.
inline float luminaire_intensity(__global const float *tables, const int o, const float3 nadir, const float3 v)
{
    const float3 c0 = (float3)(tables[o], tables[o + 1], tables[o + 2]);
    const float3 c90 = (float3)(tables[o + 3], tables[o + 4], tables[o + 5]);
    const int nc = (int)tables[o + 6], ng = (int)tables[o + 7];
    __global const float *ca = tables + o + 8, *ga = ca + nc, *cd = ga + ng;
    const float gamma = acos(BVH_MIN(BVH_MAX(BVH_DOT(v, nadir), -1.0f), 1.0f));
    if (gamma < ga[0] || gamma > ga[ng - 1]) return 0.0f;
    const int j = lum_bracket(ga, ng, gamma);
    const float tg = BVH_MIN(BVH_MAX((gamma - ga[j]) / (ga[j + 1] - ga[j]), 0.0f), 1.0f);
    if (nc == 1) return cd[j] * (1.0f - tg) + cd[j + 1] * tg;
    float c = atan2(BVH_DOT(v, c90), BVH_DOT(v, c0));
    if (c < 0.0f) c += 6.283185307179586f;
    const int i = lum_bracket(ca, nc, c);
    const float tc = BVH_MIN(BVH_MAX((c - ca[i]) / (ca[i + 1] - ca[i]), 0.0f), 1.0f);
    const float lo = cd[i * ng + j] * (1.0f - tg) + cd[i * ng + j + 1] * tg;
    const float hi = cd[(i + 1) * ng + j] * (1.0f - tg) + cd[(i + 1) * ng + j + 1] * tg;
    return lo * (1.0f - tc) + hi * tc;
}

// Irradiance (W/unit^2) at surface point p with unit normal n from all n_lights lights, one
// shadow ray each from the offset point org (off the surface, so the ray cannot hit the patch
// it starts on; the inverse-square law uses the true point p). A shadow ray stops 2 eps short
// of the light; a directional light's runs to distance far (past the scene). Operators, not
// builtins (dot, clamp, length), for the reason bvh.cl gives.
inline float3 analytic_irradiance(float3 p, float3 org, float3 n, const int n_lights,
                                  __global const float4 *lights, __global const float *tables,
                                  __global const float4 *nodes,
                                  __global const float4 *tris, const float eps, const float far)
{
    float3 h = (float3)(0.0f);
    for (int l = 0; l < n_lights; ++l) {
        const float4 a = lights[3 * l], b = lights[3 * l + 1], c = lights[3 * l + 2];
        const int type = (int)a.w;
        float3 wi;  // unit direction from p towards the light
        float dist, scale, cd = 1.0f;  // cd: a luminaire's table intensity, 1 for the others
        if (type == 2) {
            wi = -b.xyz;
            dist = far;
            scale = 1.0f;
        } else {
            const float3 d = a.xyz - p;
            dist = sqrt(BVH_DOT(d, d));
            if (dist <= 0.0f) continue;
            wi = d / dist;
            scale = 1.0f / (dist * dist);
            if (type == 1) {  // spot: smoothstep from the outer to the inner cone
                const float t = BVH_MIN(BVH_MAX((-BVH_DOT(b.xyz, wi) - c.w) * b.w, 0.0f), 1.0f);
                scale *= t * t * (3.0f - 2.0f * t);
            } else if (type == 3) {
                cd = luminaire_intensity(tables, (int)b.w, b.xyz, -wi);
            }
        }
        const float cosine = BVH_DOT(n, wi);
        if (cosine <= 0.0f || scale <= 0.0f || cd <= 0.0f) continue;
        if (bvh_occluded(nodes, tris, org, wi, 0.0f, dist - 2.0f * eps)) continue;
        // c.xyz carries 1 / unit^2 of the scene's frame and scale * cosine unit^2 / dist^2: their
        // product first, the true irradiance per unit intensity, then a table's candela (cd times
        // scale in frame units had overflowed float32 before the unit's factor came in, and
        // c.xyz * scale before the cosine overflowed a grazing point light's).
        h += (c.xyz * (scale * cosine)) * cd;
    }
    return h;
}

#endif
