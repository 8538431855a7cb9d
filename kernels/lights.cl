// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): n points x n_lights shadow rays
// in one launch (a frame's patches and lights: 16,384 x 8 = 131 k rays, ~3 ms); not split.
// Direct irradiance from analytic lights at patch centres or sensors, with one shadow ray per light
// (lights.h holds the light packing and the formula).
#include "lights.h"

__kernel void direct_irradiance(const int n, __global const float4 *centers, __global const float4 *normals,
                                const int n_lights, __global const float4 *lights, __global const float *tables,
                                __global const float4 *nodes, __global const float4 *tris,
                                const float eps, const float far, __global float4 *irradiance)
{
    const int i = get_global_id(0);
    if (i >= n) return;
    const float3 c = centers[i].xyz, nrm = normals[i].xyz;
    const float3 e = analytic_irradiance(c, c + eps * nrm, nrm, n_lights, lights, tables, nodes, tris, eps, far);
    irradiance[i] = (float4)(e, 0.0f);
}
