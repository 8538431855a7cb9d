// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): one item's n_lights shadow rays per
// point; pydynrad/lights/sources.py splits the points into launches of at most
// LIGHT_RAYS_PER_LAUNCH (2^22) / n_lights points (a global offset; n is the chunk's end), so one
// launch traces at most ~4.2 M rays (~84 ms; one point's n_lights rays if more lights than 2^22).
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
