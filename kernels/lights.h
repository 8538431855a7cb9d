// Irradiance from the analytic lights (point, spot, directional), shared by the patch-centre
// light pass (lights.cl) and the path tracer's next-event estimation (pathtrace.cl).
//
// lights: 3 float4 per light (packed by pydynrad.lights.pack_lights):
//   [0] position.xyz, type (0 point, 1 spot, 2 directional)
//   [1] direction.xyz (unit; for spot: the axis; directional: the way the light travels),
//       1 / (cos_inner - cos_outer) (spot falloff slope; huge for a hard edge)
//   [2] intensity.rgb (point/spot: W/sr; directional: irradiance W/unit^2), cos_outer
// Only the side a surface's normal faces is lit.
#ifndef PYDYNRAD_LIGHTS_H
#define PYDYNRAD_LIGHTS_H

#include "bvh.cl"

// Irradiance (W/unit^2) at surface point p with unit normal n from all n_lights lights, one
// shadow ray each from the offset point org (off the surface, so the ray cannot hit the patch
// it starts on; the inverse-square law uses the true point p). A shadow ray stops 2 eps short
// of the light; a directional light's runs to distance far (past the scene). Operators, not
// builtins (dot, clamp, length), for the reason bvh.cl gives.
inline float3 analytic_irradiance(float3 p, float3 org, float3 n, const int n_lights,
                                  __global const float4 *lights, __global const float4 *nodes,
                                  __global const float4 *tris, const float eps, const float far)
{
    float3 h = (float3)(0.0f);
    for (int l = 0; l < n_lights; ++l) {
        const float4 a = lights[3 * l], b = lights[3 * l + 1], c = lights[3 * l + 2];
        const int type = (int)a.w;
        float3 wi;  // unit direction from p towards the light
        float dist, scale;
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
            }
        }
        const float cosine = BVH_DOT(n, wi);
        if (cosine <= 0.0f || scale <= 0.0f) continue;
        if (bvh_occluded(nodes, tris, org, wi, 0.0f, dist - 2.0f * eps)) continue;
        h += c.xyz * (scale * cosine);
    }
    return h;
}

#endif
