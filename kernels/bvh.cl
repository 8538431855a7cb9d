// BVH traversal shared by every kernel that casts rays (hemicubes, shadows, rendering,
// path tracing). Include it; pass the three buffers of pydynrad.geometry.bvh.BVH.buffers() (or of
// pydynrad.geometry.bvh.InstancedBVH.buffers(): the static tree plus moving objects, see below).
//
// nodes: 4-wide nodes of 8 float4 each (csrc/bvh.c): the four children's boxes as
//        minx, maxx, miny, maxy, minz, maxz (one float4 per plane, a lane per child), then
//        the child references as int bits, then padding. child > 0: a wide node; 0: an empty
//        slot (inverted box, never entered); < 0: a leaf ~(first << 3 | (count - 1)).
// tris : 3 float4 per triangle in BVH order: its corners v0, v1, v2 (w unused). Corners, not
//        edges: two triangles sharing an edge then see bit-identical endpoints, which the
//        watertight test below needs.
// order: patch index of each triangle in BVH order.
#ifndef PYDYNRAD_BVH_CL
#define PYDYNRAD_BVH_CL

#define BVH_NODE 8  // float4 per wide node
// Traversal stack: a wide node pushes at most four children and the walk pops one, so a tree
// of D wide levels needs 3 D + 1 entries; pydynrad/geometry/bvh.py refuses deeper trees (MAX_DEPTH).
#define BVH_STACK 96

// The hot loops below use operators, not OpenCL builtins (fmin, fma, dot, cross, select).
// PoCL's kernel library can be compiled for a CPU whose features differ from the device's
// target (on the development machine: library skylake-avx512 with clwb, device rocketlake
// without); LLVM then refuses to inline any builtin, and each becomes an out-of-line call that
// spills every vector register. a * b + c is contracted to one FMA all the same.
#define BVH_MIN(a, b) ((a) < (b) ? (a) : (b))
#define BVH_MAX(a, b) ((a) > (b) ? (a) : (b))
#define BVH_DOT(a, b) ((a).x * (b).x + (a).y * (b).y + (a).z * (b).z)
#define BVH_CROSS(a, b) ((a).yzx * (b).zxy - (a).zxy * (b).yzx)

// Triangles (BVH order) of a leaf reference ref < 0: first .. first + BVH_LEAF_SIZE(ref) - 1.
#define BVH_LEAF_FIRST(ref) (~(ref) >> 3)
#define BVH_LEAF_SIZE(ref) ((~(ref) & 7) + 1)

typedef struct {
    float t;     // ray parameter of the hit
    float u, v;  // barycentrics of v1 and v2
    int patch;   // patch index, -1 for a miss
    int front;   // 1 when the ray hits the triangle's front (the side its normal faces)
} Hit;

// ---- Watertight ray-triangle test (Woop, Benthin and Wald 2013, "Watertight Ray/Triangle
// Intersection", JCGT 2(1)), in a per-ray frame instead of their axis permutation ----
//
// Each corner is moved into the ray's frame once, from the same float32 corner and ray by
// the same arithmetic, so a corner shared by two triangles lands on the same 2-D point (X, Y)
// in both. The sign of each edge function X_a Y_b - Y_a X_b is then exact or zero (rounding
// is monotone, and with contraction off both products are rounded alike), and an edge shared
// by two triangles gets exactly opposite values from them. A ray through a shared edge or
// corner therefore hits at least one of the triangles (zeros count as inside): no leaks in a
// closed mesh, no slack. The frame is (P, Q, D / |D|) with P, Q perpendicular to D (Duff et
// al. 2017, branchless), in place of Woop et al.'s shear along the dominant axis, which would
// need a per-lane permutation in ray packets. t comes from the same barycentrics (hit point
// = (U A + V B + W C) / det, dotted with D / |D|^2).

// The edge function of corners a -> b; contraction off so that edge(a, b) == -edge(b, a) bit
// for bit (an FMA would round the two products differently).
inline float bvh_edge(float ax, float ay, float bx, float by)
{
#pragma OPENCL FP_CONTRACT OFF
    return ax * by - ay * bx;
}

// The ray's frame: P, Q (unit, perpendicular to dir and to each other, right-handed with dir),
// and dir / |dir|^2 (a corner's dot with it is its distance along the ray in units of |dir|).
typedef struct {
    float3 p, q, w;
} RayFrame;

inline RayFrame bvh_ray_frame(float3 dir)
{
    float3 d = dir * rsqrt(BVH_DOT(dir, dir));
    // copysign(1, d.z), -0 included, in bits: Oclgrind 21.10 cannot run the llvm.copysign.f32
    // intrinsic that clang makes of the scalar builtin (and of a select on the sign).
    float sg = as_float((as_uint(d.z) & 0x80000000u) | 0x3f800000u);
    float a = -1.0f / (sg + d.z), b = d.x * d.y * a;
    RayFrame f;
    f.p = (float3)(1.0f + sg * d.x * d.x * a, sg * b, -sg * d.x);
    f.q = (float3)(b, sg + d.y * d.y * a, -d.y);
    f.w = dir / BVH_DOT(dir, dir);
    return f;
}

// Double-sided; updates hit when closer than hit->t.
inline bool bvh_tri_hit(__global const float4 *tris, int k, float3 org, const RayFrame *f, float tmin, Hit *hit)
{
    float3 a = tris[3 * k].xyz - org, b = tris[3 * k + 1].xyz - org, c = tris[3 * k + 2].xyz - org;
    float ax = BVH_DOT(a, f->p), ay = BVH_DOT(a, f->q);
    float bx = BVH_DOT(b, f->p), by = BVH_DOT(b, f->q);
    float cx = BVH_DOT(c, f->p), cy = BVH_DOT(c, f->q);
    float U = bvh_edge(cx, cy, bx, by), V = bvh_edge(ax, ay, cx, cy), W = bvh_edge(bx, by, ax, ay);
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return false;
    float det = U + V + W;
    if (det == 0.0f) return false;
    float inv = 1.0f / det;
    float t = (U * BVH_DOT(a, f->w) + V * BVH_DOT(b, f->w) + W * BVH_DOT(c, f->w)) * inv;
    if (t <= tmin || t >= hit->t) return false;
    hit->t = t;
    hit->u = V * inv;
    hit->v = W * inv;
    hit->patch = k;            // BVH order until bvh_closest maps it to the patch index
    hit->front = det > 0.0f;   // the frame keeps handedness: det > 0 when dir opposes the normal
    return true;
}

// 1 / dir with zero components nudged to a tiny signed value: 0 * inf in the slab test would
// give NaN for a ray lying in a box's face plane and silently drop that box.
inline float3 bvh_inv_dir(float3 dir)
{
    float3 tiny = copysign((float3)(1e-30f), dir);
    return 1.0f / select(dir, tiny, isless(fabs(dir), (float3)(1e-30f)));
}

// The traversal stack: subtrees waiting to be visited (refs), each with the entry distance its
// box had when pushed (entries), sp of them; plain locals of the walk, and the push a macro on
// them (as a struct, or an inline function updating sp through a pointer, the walk ran 4-5%
// slower on PoCL).
#define BVH_STACK_DECL int refs[BVH_STACK], sp = 0; float entries[BVH_STACK]

// Push keeping the entries pushed since `base` sorted far to near: the nearest pops first.
#define BVH_PUSH(base, ref, entry)                          \
    do {                                                    \
        int j_ = sp++;                                      \
        while (j_ > (base) && entries[j_ - 1] < (entry)) {  \
            refs[j_] = refs[j_ - 1];                        \
            entries[j_] = entries[j_ - 1];                  \
            --j_;                                           \
        }                                                   \
        refs[j_] = (ref);                                   \
        entries[j_] = (entry);                              \
    } while (0)

// Pop the next subtree into *ref, skipping those that start beyond reach (a hit found since
// they were pushed is nearer); false when none is left.
inline bool bvh_pop(const int *refs, const float *entries, int *sp, float reach, int *ref)
{
    do {
        if (*sp == 0) return false;
        *ref = refs[--*sp];
    } while (entries[*sp] > reach);
    return true;
}

// Instances: moving rigid objects (pydynrad.geometry.bvh.InstancedBVH), each a tree of its own built once
// in object space and stored after the static tree in the same three buffers. Node 0's padding
// float4 holds, as int bits, (count, table, 0, 0); the table at nodes[table] has BVH_INSTANCE
// float4 per object: the rows of its world-to-object transform (xyz: rotation, w: translation),
// then int bits (root node, 0, 0, 0). A rigid map keeps lengths and handedness, so t, the
// barycentrics and the front flag of an object-space hit are those of the world-space ray.
// A plain BVH has zero padding: no instances.
#define BVH_INSTANCE 4

inline int4 bvh_instances(__global const float4 *nodes) { return as_int4(nodes[7]); }

inline float3 bvh_to_object(__global const float4 *m, float3 p, float w)
{
    return (float3)(BVH_DOT(m[0], p) + w * m[0].w, BVH_DOT(m[1], p) + w * m[1].w, BVH_DOT(m[2], p) + w * m[2].w);
}

// One tree from node `root`: shrinks hit to the nearest triangle (BVH order) closer than hit->t;
// true when any_hit and something was hit. The four children's slabs as float4 lanes, near and
// far planes picked once per ray by the direction's signs (an inverted empty slot then has
// entry > exit on every axis, so it needs no check).
inline bool bvh_walk_tree(__global const float4 *nodes, __global const float4 *tris, int root, float3 org,
                          float3 dir, float tmin, bool any_hit, Hit *hit)
{
    RayFrame frame = bvh_ray_frame(dir);
    float3 inv = bvh_inv_dir(dir), oi = org * inv;
    int nx = inv.x < 0.0f, ny = 2 + (inv.y < 0.0f), nz = 4 + (inv.z < 0.0f);
    int fx = nx ^ 1, fy = ny ^ 1, fz = nz ^ 1;
    BVH_STACK_DECL;
    int ref = root;
    for (;;) {
        if (ref < 0) {
            for (int k = BVH_LEAF_FIRST(ref), end = k + BVH_LEAF_SIZE(ref); k < end; ++k)
                if (bvh_tri_hit(tris, k, org, &frame, tmin, hit) && any_hit) return true;
        } else {
            __global const float4 *n = nodes + BVH_NODE * ref;
            float4 enter = BVH_MAX(BVH_MAX(n[nx] * inv.x - oi.x, n[ny] * inv.y - oi.y),
                                   BVH_MAX(n[nz] * inv.z - oi.z, (float4)tmin));
            float4 leave = BVH_MIN(BVH_MIN(n[fx] * inv.x - oi.x, n[fy] * inv.y - oi.y),
                                   BVH_MIN(n[fz] * inv.z - oi.z, (float4)hit->t));
            enter = enter <= leave ? enter : (float4)INFINITY;
            int4 child = as_int4(n[6]);
            int base = sp;
            if (enter.x != INFINITY) BVH_PUSH(base, child.x, enter.x);
            if (enter.y != INFINITY) BVH_PUSH(base, child.y, enter.y);
            if (enter.z != INFINITY) BVH_PUSH(base, child.z, enter.z);
            if (enter.w != INFINITY) BVH_PUSH(base, child.w, enter.w);
        }
        if (!bvh_pop(refs, entries, &sp, hit->t, &ref)) return false;
    }
}

// The walk shared by bvh_closest and bvh_occluded (any_hit: stop at the first hit): the static
// tree, then each instance's tree with the ray in its object space. Returns the hit with its
// triangle in BVH order.
inline Hit bvh_walk(__global const float4 *nodes, __global const float4 *tris, float3 org, float3 dir,
                    float tmin, float tmax, bool any_hit)
{
    Hit hit = {tmax, 0.0f, 0.0f, -1, 0};
    if (bvh_walk_tree(nodes, tris, 0, org, dir, tmin, any_hit, &hit)) return hit;
    int4 inst = bvh_instances(nodes);
    for (int i = 0; i < inst.x; ++i) {
        __global const float4 *m = nodes + inst.y + BVH_INSTANCE * i;
        if (bvh_walk_tree(nodes, tris, as_int4(m[3]).x, bvh_to_object(m, org, 1.0f), bvh_to_object(m, dir, 0.0f),
                          tmin, any_hit, &hit))
            return hit;
    }
    return hit;
}

// Nearest hit along org + t dir for t in (tmin, tmax). Returns hit.patch = -1 on a miss.
inline Hit bvh_closest(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                       float3 org, float3 dir, float tmin, float tmax)
{
    Hit hit = bvh_walk(nodes, tris, org, dir, tmin, tmax, false);
    if (hit.patch >= 0) hit.patch = order[hit.patch];
    return hit;
}

// True when anything lies along org + t dir for t in (tmin, tmax): shadow rays.
inline bool bvh_occluded(__global const float4 *nodes, __global const float4 *tris,
                         float3 org, float3 dir, float tmin, float tmax)
{
    return bvh_walk(nodes, tris, org, dir, tmin, tmax, true).patch >= 0;
}

// ---- Ray packets: BVH_PACKET rays per work-item, one per vector lane ----
//
// A CPU OpenCL device (PoCL) runs each work-item's divergent traversal loop as scalar code, so
// SIMD for a single ray has to come from vector types inside the work-item. Coherent rays (a
// hemicube scanline: one origin, smoothly varying directions) visit nearly the same nodes, so
// one walk tests a box or triangle against all lanes in a few vector instructions. Lanes need
// no activity mask: a ray that misses a box cannot hit the triangles inside it, so testing it
// anyway changes nothing; the lanes' entry distances only steer which subtrees the packet enters.
// BVH_PACKET (the host's pydynrad.device.launch.bvh_packet) selects this part: programs that trace
// one ray per work-item leave it undefined. BVH_SHARED_ORIGIN (defined by hemicube.h) builds
// it for packets whose rays all leave one point: the origin is then a scalar, and each
// triangle's corners are moved to it once per packet instead of once per lane.
#ifdef BVH_PACKET
#define BVH_CAT_(a, b) a##b
#define BVH_CAT(a, b) BVH_CAT_(a, b)
#define bvh_floatP BVH_CAT(float, BVH_PACKET)
#define bvh_intP BVH_CAT(int, BVH_PACKET)
#define bvh_vloadP BVH_CAT(vload, BVH_PACKET)
#define bvh_vstoreP BVH_CAT(vstore, BVH_PACKET)
#define bvh_hmaxP BVH_CAT(bvh_hmax, BVH_PACKET)

inline float bvh_hmax4(float4 v) { float2 m = BVH_MAX(v.lo, v.hi); return BVH_MAX(m.x, m.y); }
inline float bvh_hmax8(float8 v) { return bvh_hmax4(BVH_MAX(v.lo, v.hi)); }
inline float bvh_hmax16(float16 v) { return bvh_hmax8(BVH_MAX(v.lo, v.hi)); }

#ifdef BVH_SHARED_ORIGIN
typedef float bvh_originP;
#else
typedef bvh_floatP bvh_originP;
#endif

typedef struct {
    bvh_originP ox, oy, oz;  // origins (one for every lane with BVH_SHARED_ORIGIN)
    bvh_floatP dx, dy, dz;   // directions (any length; t is in units of |dir|)
} RayPacket;

typedef struct {
    bvh_floatP t, u, v;     // as in Hit, per lane
    bvh_intP patch, front;  // patch -1 on a miss
} HitPacket;

// RayFrame per lane (bvh_ray_frame, same arithmetic).
typedef struct {
    bvh_floatP px, py, pz, qx, qy, qz, wx, wy, wz;
} RayFrameP;

inline RayFrameP bvh_ray_frame_p(const RayPacket *r)
{
    bvh_floatP len2 = r->dx * r->dx + r->dy * r->dy + r->dz * r->dz, s = rsqrt(len2), il2 = 1.0f / len2;
    bvh_floatP x = r->dx * s, y = r->dy * s, z = r->dz * s;
    bvh_floatP sg = copysign((bvh_floatP)1.0f, z);
    bvh_floatP a = -1.0f / (sg + z), b = x * y * a;
    RayFrameP f;
    f.px = 1.0f + sg * x * x * a;
    f.py = sg * b;
    f.pz = -sg * x;
    f.qx = b;
    f.qy = sg + y * y * a;
    f.qz = -y;
    f.wx = r->dx * il2;
    f.wy = r->dy * il2;
    f.wz = r->dz * il2;
    return f;
}

inline bvh_floatP bvh_edge_p(bvh_floatP ax, bvh_floatP ay, bvh_floatP bx, bvh_floatP by)
{
#pragma OPENCL FP_CONTRACT OFF
    return ax * by - ay * bx;
}

// Per-lane slab constants: inverse direction and origin * inverse direction.
typedef struct {
    bvh_floatP ix, iy, iz, oix, oiy, oiz;
} BvhSlabs;

inline bvh_floatP bvh_inv_p(bvh_floatP d)
{
    bvh_floatP tiny = copysign((bvh_floatP)(1e-30f), d);
    return 1.0f / select(d, tiny, isless(fabs(d), (bvh_floatP)(1e-30f)));
}

// A packet's lanes (bvh_floatP) brought to four by a min over each lane group.
#if BVH_PACKET == 16
#define BVH_MIN4(v) BVH_MIN(BVH_MIN((v).lo.lo, (v).lo.hi), BVH_MIN((v).hi.lo, (v).hi.hi))
#elif BVH_PACKET == 8
#define BVH_MIN4(v) BVH_MIN((v).lo, (v).hi)
#else
#define BVH_MIN4(v) (v)
#endif

// Child c's entry distance per lane into wide node n, INFINITY where the lane misses it within
// [tmin, tmax], brought to four lanes (BVH_MIN4). Lanes differ in direction signs, so each
// takes min/max of its two planes (an empty slot's inverted box would pass this test: callers
// skip it).
__attribute__((always_inline)) inline float4 bvh_child_entry4_p(__global const float *f, int c, const BvhSlabs *s, float tmin,
                                                                bvh_floatP tmax)
{
    bvh_floatP ax = f[c] * s->ix - s->oix, bx = f[4 + c] * s->ix - s->oix;
    bvh_floatP ay = f[8 + c] * s->iy - s->oiy, by = f[12 + c] * s->iy - s->oiy;
    bvh_floatP az = f[16 + c] * s->iz - s->oiz, bz = f[20 + c] * s->iz - s->oiz;
    bvh_floatP enter = BVH_MAX(BVH_MAX(BVH_MIN(ax, bx), BVH_MIN(ay, by)), BVH_MAX(BVH_MIN(az, bz), (bvh_floatP)tmin));
    bvh_floatP leave = BVH_MIN(BVH_MIN(BVH_MAX(ax, bx), BVH_MAX(ay, by)), BVH_MIN(BVH_MAX(az, bz), tmax));
    bvh_floatP e = enter <= leave ? enter : (bvh_floatP)INFINITY;
    return BVH_MIN4(e);
}

// Least entry distance over the lanes into each of wide node n's four children (x, y, z, w),
// INFINITY where every lane misses it. The four children's minima are taken together, two
// children per vector, not one after another: each child's own reduction across its lanes
// was a chain of dependent shuffles, the walk's hottest instructions (perf on PoCL's kernel),
// and together they shorten that chain (docs/decisions/0011-ray-tracing.md).
// Min is exact, so the distances are those of a child-by-child reduction. Inlined by force:
// left to itself PoCL's LLVM called it, its arguments through memory.
__attribute__((always_inline)) inline float4 bvh_child_entries_p(__global const float4 *n, const BvhSlabs *s, float tmin,
                                                                 bvh_floatP tmax)
{
    __global const float *f = (__global const float *)n;
    float4 a = bvh_child_entry4_p(f, 0, s, tmin, tmax), b = bvh_child_entry4_p(f, 1, s, tmin, tmax);
    float4 c = bvh_child_entry4_p(f, 2, s, tmin, tmax), d = bvh_child_entry4_p(f, 3, s, tmin, tmax);
    float4 ab = BVH_MIN((float4)(a.lo, b.lo), (float4)(a.hi, b.hi));
    float4 cd = BVH_MIN((float4)(c.lo, d.lo), (float4)(c.hi, d.hi));
    return BVH_MIN((float4)(ab.even, cd.even), (float4)(ab.odd, cd.odd));
}

// bvh_tri_hit for every lane at once (same arithmetic).
inline void bvh_tri_hit_p(__global const float4 *tris, int k, const RayPacket *r, const RayFrameP *f, float tmin,
                          HitPacket *h)
{
    float4 v0 = tris[3 * k], v1 = tris[3 * k + 1], v2 = tris[3 * k + 2];
    bvh_originP ax = v0.x - r->ox, ay = v0.y - r->oy, az = v0.z - r->oz;
    bvh_originP bx = v1.x - r->ox, by = v1.y - r->oy, bz = v1.z - r->oz;
    bvh_originP cx = v2.x - r->ox, cy = v2.y - r->oy, cz = v2.z - r->oz;
    bvh_floatP aX = ax * f->px + ay * f->py + az * f->pz, aY = ax * f->qx + ay * f->qy + az * f->qz;
    bvh_floatP bX = bx * f->px + by * f->py + bz * f->pz, bY = bx * f->qx + by * f->qy + bz * f->qz;
    bvh_floatP cX = cx * f->px + cy * f->py + cz * f->pz, cY = cx * f->qx + cy * f->qy + cz * f->qz;
    bvh_floatP U = bvh_edge_p(cX, cY, bX, bY), V = bvh_edge_p(aX, aY, cX, cY), W = bvh_edge_p(bX, bY, aX, aY);
    bvh_floatP det = U + V + W;
    bvh_floatP inv = 1.0f / det;
    bvh_floatP t = (U * (ax * f->wx + ay * f->wy + az * f->wz) + V * (bx * f->wx + by * f->wy + bz * f->wz)
                    + W * (cx * f->wx + cy * f->wy + cz * f->wz)) * inv;
    bvh_intP ok = (((U >= 0.0f) & (V >= 0.0f) & (W >= 0.0f)) | ((U <= 0.0f) & (V <= 0.0f) & (W <= 0.0f)))
                  & (det != 0.0f) & (t > tmin) & (t < h->t);
    h->t = ok ? t : h->t;
    h->u = ok ? V * inv : h->u;
    h->v = ok ? W * inv : h->v;
    h->patch = ok ? (bvh_intP)k : h->patch;
    h->front = ok ? (bvh_intP)1 & (det > 0.0f) : h->front;
}

// One tree from node `root` for every lane (bvh_walk_tree's packet twin): a subtree waits on
// the stack with its least entry distance over the lanes and is skipped when that lies beyond
// every lane's nearest hit so far. `any_hit` (a constant at every call): a lane that has hit
// anything retires (its reach drops to -inf: no box passes for it), and the walk ends once every
// lane has.
inline void bvh_walk_tree_p(__global const float4 *nodes, __global const float4 *tris, int root, const RayPacket *r,
                            float tmin, HitPacket *h, int any_hit)
{
    RayFrameP frame = bvh_ray_frame_p(r);
    BvhSlabs s;
    s.ix = bvh_inv_p(r->dx);
    s.iy = bvh_inv_p(r->dy);
    s.iz = bvh_inv_p(r->dz);
    s.oix = r->ox * s.ix;
    s.oiy = r->oy * s.iy;
    s.oiz = r->oz * s.iz;
    BVH_STACK_DECL;
    int ref = root;
    for (;;) {
        if (ref < 0) {
            for (int k = BVH_LEAF_FIRST(ref), end = k + BVH_LEAF_SIZE(ref); k < end; ++k)
                bvh_tri_hit_p(tris, k, r, &frame, tmin, h);
            if (any_hit) h->t = h->patch >= 0 ? (bvh_floatP)(-INFINITY) : h->t;
        } else {
            __global const float4 *n = nodes + BVH_NODE * ref;
            int4 child = as_int4(n[6]);
            float4 entry = bvh_child_entries_p(n, &s, tmin, h->t);
            entry = child != 0 ? entry : (float4)INFINITY;  // an empty slot is never entered
            int base = sp;
            if (entry.x != INFINITY) BVH_PUSH(base, child.x, entry.x);
            if (entry.y != INFINITY) BVH_PUSH(base, child.y, entry.y);
            if (entry.z != INFINITY) BVH_PUSH(base, child.z, entry.z);
            if (entry.w != INFINITY) BVH_PUSH(base, child.w, entry.w);
        }
        if (!bvh_pop(refs, entries, &sp, bvh_hmaxP(h->t), &ref)) return;
    }
}

// Every tree for every lane (the static one, then each instance's in its object space but
// instance `skip`, -1 for none): bvh_walk_tree_p of each, the same `any_hit`.
inline void bvh_walk_p(__global const float4 *nodes, __global const float4 *tris, const RayPacket *r, float tmin,
                       HitPacket *h, int any_hit, int skip)
{
    bvh_walk_tree_p(nodes, tris, 0, r, tmin, h, any_hit);
    int4 inst = bvh_instances(nodes);
    for (int i = 0; i < inst.x; ++i) {
        if (i == skip) continue;
        if (any_hit && bvh_hmaxP(h->t) == -INFINITY) return;  // every lane has hit
        __global const float4 *m = nodes + inst.y + BVH_INSTANCE * i;
        RayPacket q;
        q.ox = m[0].x * r->ox + m[0].y * r->oy + m[0].z * r->oz + m[0].w;
        q.oy = m[1].x * r->ox + m[1].y * r->oy + m[1].z * r->oz + m[1].w;
        q.oz = m[2].x * r->ox + m[2].y * r->oy + m[2].z * r->oz + m[2].w;
        q.dx = m[0].x * r->dx + m[0].y * r->dy + m[0].z * r->dz;
        q.dy = m[1].x * r->dx + m[1].y * r->dy + m[1].z * r->dz;
        q.dz = m[2].x * r->dx + m[2].y * r->dy + m[2].z * r->dz;
        bvh_walk_tree_p(nodes, tris, as_int4(m[3]).x, &q, tmin, h, any_hit);
    }
}

// Nearest hit of every lane along org + t dir for t in (tmin, tmax): bvh_closest per lane,
// one shared walk per tree; instance `skip` (-1: none) is not looked at (the rays leave a
// convex object's surface outwards, where nothing of that object lies).
inline HitPacket bvh_closest_packet(__global const float4 *nodes, __global const float4 *tris,
                                    __global const int *order, const RayPacket *r, float tmin, bvh_floatP tmax,
                                    int skip)
{
    HitPacket h = {tmax, (bvh_floatP)0.0f, (bvh_floatP)0.0f, (bvh_intP)(-1), (bvh_intP)0};
    bvh_walk_p(nodes, tris, r, tmin, &h, 0, skip);
    // Map BVH order to patch indices lane by lane (OpenCL has no vector gather).
    int ids[BVH_PACKET];
    bvh_vstoreP(h.patch, 0, ids);
    for (int i = 0; i < BVH_PACKET; ++i) ids[i] = ids[i] >= 0 ? order[ids[i]] : -1;
    h.patch = bvh_vloadP(0, ids);
    return h;
}

// Per lane, whether any triangle lies along org + t dir for t in (tmin, tmax) (bvh_occluded per
// lane, one shared walk that ends when every lane has hit): nonzero where one does.
inline bvh_intP bvh_occluded_packet(__global const float4 *nodes, __global const float4 *tris, const RayPacket *r,
                                    float tmin, bvh_floatP tmax)
{
    HitPacket h = {tmax, (bvh_floatP)0.0f, (bvh_floatP)0.0f, (bvh_intP)(-1), (bvh_intP)0};
    bvh_walk_p(nodes, tris, r, tmin, &h, 1, -1);
    return h.patch >= 0;
}

#endif  // BVH_PACKET

#endif
