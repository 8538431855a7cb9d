// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): one ray per pixel of one image:
// 2 M rays at 1920 x 1080 (~40 ms).
// Primary visibility for images: one work-item per pixel casts the camera ray that
// pydynrad.geometry.camera.Camera.ray_directions() computed on the host (so host and device agree on
// every pixel's ray) and records what it sees. Shading happens afterwards from these records.
#include "bvh.cl"

// origin: camera position (w unused); dirs: one unit direction per pixel.
// patch: hit patch index, -1 where the ray leaves the scene.
// uvf  : barycentrics of the patch's corners 1 and 2, and 1.0 for a front-face hit else 0.0.
// depth: distance along the ray (INFINITY for a miss).
__kernel void primary_visibility(__global const float4 *nodes, __global const float4 *tris,
                                 __global const int *order, const float4 origin,
                                 __global const float4 *dirs, const int n_pixels,
                                 __global int *patch, __global float4 *uvf, __global float *depth)
{
    const int i = get_global_id(0);
    if (i >= n_pixels) return;
    Hit hit = bvh_closest(nodes, tris, order, origin.xyz, dirs[i].xyz, 0.0f, INFINITY);
    patch[i] = hit.patch;
    uvf[i] = (float4)(hit.u, hit.v, hit.front ? 1.0f : 0.0f, 0.0f);
    depth[i] = hit.patch >= 0 ? hit.t : INFINITY;
}
