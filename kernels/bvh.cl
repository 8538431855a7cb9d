// BVH traversal shared by every kernel that casts rays (hemicubes, shadows, rendering,
// path tracing). Include it; pass the three buffers of pydynrad.bvh.BVH.buffers().
//
// nodes: 2 float4 per node: (bmin.xyz, offset), (bmax.xyz, count); offset/count are int
//        bits. count == 0: interior with children offset, offset + 1; else a leaf.
// tris : 3 float4 per triangle in BVH order: v0, e1 = v1 - v0, e2 = v2 - v0.
// order: patch index of each triangle in BVH order.
#ifndef PYDYNRAD_BVH_CL
#define PYDYNRAD_BVH_CL

#define BVH_STACK 64

// Barycentric slack of the triangle test: a ray through the edge shared by two triangles
// could otherwise slip between them in float32 (a leak in a closed scene). Relative to the
// triangle (dimensionless), so a near-edge ray hits both and the nearer wins.
#define BVH_EDGE_EPS 1e-6f

typedef struct {
    float t;     // ray parameter of the hit
    float u, v;  // barycentrics of v1 and v2
    int patch;   // patch index, -1 for a miss
    int front;   // 1 when the ray hits the triangle's front (the side its normal faces)
} Hit;

// Slab test; returns the entry distance or INFINITY on a miss within [tmin, tmax].
// org_inv = org * inv_dir, so each plane costs one fused multiply-add.
inline float bvh_box_entry(float4 bmin, float4 bmax, float3 org_inv, float3 inv_dir, float tmin, float tmax)
{
    float3 t0 = fma(bmin.xyz, inv_dir, -org_inv);
    float3 t1 = fma(bmax.xyz, inv_dir, -org_inv);
    float3 lo = fmin(t0, t1), hi = fmax(t0, t1);
    float enter = fmax(fmax(lo.x, lo.y), fmax(lo.z, tmin));
    float leave = fmin(fmin(hi.x, hi.y), fmin(hi.z, tmax));
    return enter <= leave ? enter : INFINITY;
}

// Moller-Trumbore, double-sided; updates hit when closer than hit->t.
inline bool bvh_tri_hit(__global const float4 *tris, int k, float3 org, float3 dir, float tmin, Hit *hit)
{
    float3 v0 = tris[3 * k].xyz, e1 = tris[3 * k + 1].xyz, e2 = tris[3 * k + 2].xyz;
    float3 p = cross(dir, e2);
    float det = dot(e1, p);
    if (det == 0.0f) return false;
    float inv = 1.0f / det;
    float3 s = org - v0;
    float u = dot(s, p) * inv;
    if (u < -BVH_EDGE_EPS || u > 1.0f + BVH_EDGE_EPS) return false;
    float3 q = cross(s, e1);
    float v = dot(dir, q) * inv;
    if (v < -BVH_EDGE_EPS || u + v > 1.0f + BVH_EDGE_EPS) return false;
    float t = dot(e2, q) * inv;
    if (t <= tmin || t >= hit->t) return false;
    hit->t = t;
    hit->u = u;
    hit->v = v;
    hit->patch = k;            // BVH order until bvh_closest maps it to the patch index
    hit->front = det > 0.0f;   // det = -dot(dir, e1 x e2): positive when dir opposes the normal
    return true;
}

// 1 / dir with zero components nudged to a tiny signed value: 0 * inf in the slab test would
// give NaN for a ray lying in a box's face plane and silently drop that box.
inline float3 bvh_inv_dir(float3 dir)
{
    float3 tiny = copysign((float3)(1e-30f), dir);
    return 1.0f / select(dir, tiny, isless(fabs(dir), (float3)(1e-30f)));
}

// Nearest hit along org + t dir for t in (tmin, tmax). Returns hit.patch = -1 on a miss.
inline Hit bvh_closest(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                       float3 org, float3 dir, float tmin, float tmax)
{
    Hit hit = {tmax, 0.0f, 0.0f, -1, 0};
    float3 inv_dir = bvh_inv_dir(dir), org_inv = org * inv_dir;
    int stack[BVH_STACK];
    float stack_entry[BVH_STACK];
    int sp = 0, node = 0;
    if (bvh_box_entry(nodes[0], nodes[1], org_inv, inv_dir, tmin, hit.t) == INFINITY) return hit;
    for (;;) {
        float4 lo = nodes[2 * node], hi = nodes[2 * node + 1];
        int count = as_int(hi.w);
        if (count > 0) {
            int first = as_int(lo.w);
            for (int k = first; k < first + count; ++k) bvh_tri_hit(tris, k, org, dir, tmin, &hit);
        } else {
            int left = as_int(lo.w), right = left + 1;
            float dl = bvh_box_entry(nodes[2 * left], nodes[2 * left + 1], org_inv, inv_dir, tmin, hit.t);
            float dr = bvh_box_entry(nodes[2 * right], nodes[2 * right + 1], org_inv, inv_dir, tmin, hit.t);
            if (dl != INFINITY && dr != INFINITY) {
                // Visit the nearer child now; the farther waits with its entry distance.
                bool left_first = dl <= dr;
                stack[sp] = left_first ? right : left;
                stack_entry[sp++] = left_first ? dr : dl;
                node = left_first ? left : right;
                continue;
            }
            if (dl != INFINITY || dr != INFINITY) {
                node = dl != INFINITY ? left : right;
                continue;
            }
        }
        // Pop, skipping subtrees that start beyond the nearest hit found since they were pushed.
        do {
            if (sp == 0) {
                if (hit.patch >= 0) hit.patch = order[hit.patch];
                return hit;
            }
            node = stack[--sp];
        } while (stack_entry[sp] > hit.t);
    }
}

// True when anything lies along org + t dir for t in (tmin, tmax): shadow rays.
inline bool bvh_occluded(__global const float4 *nodes, __global const float4 *tris,
                         float3 org, float3 dir, float tmin, float tmax)
{
    Hit hit = {tmax, 0.0f, 0.0f, -1, 0};
    float3 inv_dir = bvh_inv_dir(dir), org_inv = org * inv_dir;
    int stack[BVH_STACK];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        int node = stack[--sp];
        float4 lo = nodes[2 * node], hi = nodes[2 * node + 1];
        if (bvh_box_entry(lo, hi, org_inv, inv_dir, tmin, tmax) == INFINITY) continue;
        int count = as_int(hi.w);
        if (count > 0) {
            int first = as_int(lo.w);
            for (int k = first; k < first + count; ++k)
                if (bvh_tri_hit(tris, k, org, dir, tmin, &hit)) return true;
        } else {
            int left = as_int(lo.w);
            stack[sp++] = left;
            stack[sp++] = left + 1;
        }
    }
    return false;
}

#endif
