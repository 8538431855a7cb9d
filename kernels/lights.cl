// Direct irradiance from analytic lights at patch centres, with one shadow ray per light.
//
// lights: 3 float4 per light (packed by pydynrad/lights.py):
//   [0] position.xyz, type (0 point, 1 spot, 2 directional)
//   [1] direction.xyz (unit; for spot: the axis; directional: the way the light travels),
//       1 / (cos_inner - cos_outer) (spot falloff slope; huge for a hard edge)
//   [2] intensity.rgb (point/spot: W/sr; directional: irradiance W/unit^2), cos_outer
// Only the front side of a patch (the side its normal faces) is lit.
#include "bvh.cl"

__kernel void direct_irradiance(const int n, __global const float4 *centers, __global const float4 *normals,
                                const int n_lights, __global const float4 *lights,
                                __global const float4 *nodes, __global const float4 *tris,
                                const float eps, const float far, __global float4 *irradiance)
{
    const int i = get_global_id(0);
    if (i >= n) return;
    const float3 c = centers[i].xyz, nrm = normals[i].xyz;
    // Off the surface along the normal, so the ray cannot hit the patch it starts on.
    const float3 org = c + eps * nrm;
    float3 e = (float3)(0.0f);
    for (int l = 0; l < n_lights; ++l) {
        const float4 a = lights[3 * l], b = lights[3 * l + 1], p = lights[3 * l + 2];
        const int type = (int)a.w;
        float3 wi;        // unit direction from the patch towards the light
        float dist, scale;
        if (type == 2) {
            wi = -b.xyz;
            dist = far;
            scale = 1.0f;
        } else {
            // The law uses the true centre; only the shadow ray starts off the surface.
            const float3 d = a.xyz - c;
            dist = length(d);
            if (dist <= 0.0f) continue;
            wi = d / dist;
            scale = 1.0f / (dist * dist);
            if (type == 1) {
                const float t = clamp((dot(b.xyz, -wi) - p.w) * b.w, 0.0f, 1.0f);
                scale *= t * t * (3.0f - 2.0f * t);
            }
        }
        const float cosine = dot(nrm, wi);
        if (cosine <= 0.0f || scale <= 0.0f) continue;
        if (bvh_occluded(nodes, tris, org, wi, 0.0f, dist - 2.0f * eps)) continue;
        e += p.xyz * (scale * cosine);
    }
    irradiance[i] = (float4)(e, 0.0f);
}
