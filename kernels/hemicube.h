// Hemicube ray generation shared by the form-factor rows (hemicube.cl) and the gathers at
// arbitrary points (gather.cl): the frame at a point, the direction of every pixel, and a
// scanline's packet of rays traced. Include bvh.cl first.
//
// A hemicube of resolution R (HC_RES) has a top face of R x R pixels and four side faces of
// R x R/2, i.e. 3R scanlines of R pixels each:
//   s <  R : top face z = 1, pixel (x, s) centred at (u, v) = (-1 + (x + .5) 2/R, -1 + (s + .5) 2/R)
//   s >= R : side f = (s - R) / (R/2), row r = (s - R) % (R/2), height h = (r + .5) 2/R,
//            across a = -1 + (x + .5) 2/R; f = 0: (1, a, h), 1: (-1, -a, h), 2: (-a, 1, h), 3: (a, -1, h)
// in the frame (T, B, N), T rotated about N by a pseudo-random angle keyed by an integer (the
// patch index for a patch's row), so regular structures do not alias the same way at every
// point. pydynrad/formfactors.py computes the pixels' delta form factors in the same layout.
#ifndef PYDYNRAD_HEMICUBE_H
#define PYDYNRAD_HEMICUBE_H

#ifndef HC_RES
#error "HC_RES (the hemicube resolution) must be defined"
#endif
// The lane offsets of hc_trace_packet are written out for 16 lanes.
#if BVH_PACKET != 16
#error "hemicube.h needs BVH_PACKET == 16 from the host (pydynrad/launch.py)"
#endif

// A 32-bit integer hash (lowbias32): the rotation angle of key, fixed for all runs.
inline uint hc_hash(uint x)
{
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

// Scanline s of the hemicube about unit normal n with rotation key: pixel x's (unnormalised)
// world direction is *base + x * *step.
inline void hc_scanline(float3 n, uint key, int s, float3 *base, float3 *step)
{
    const int R = HC_RES, H = HC_RES / 2;
    // Orthonormal basis around n without a branch on its direction (Duff et al. 2017),
    // then rotated about n by the key's angle.
    float sg = copysign(1.0f, n.z);
    float a = -1.0f / (sg + n.z);
    float b = n.x * n.y * a;
    float3 t0 = (float3)(1.0f + sg * n.x * n.x * a, sg * b, -sg * n.x);
    float3 b0 = (float3)(b, sg + n.y * n.y * a, -n.y);
    float ang = (float)hc_hash(key) * (6.283185307179586f / 4294967296.0f);
    float cs = cos(ang), sn = sin(ang);
    float3 T = cs * t0 + sn * b0, B = cs * b0 - sn * t0;

    float px = 2.0f / R;
    float3 b_, d_;
    if (s < R) {
        float v = -1.0f + (s + 0.5f) * px;
        b_ = -T + v * B + n;
        d_ = T;
    } else {
        int f = (s - R) / H, r = (s - R) % H;
        float h = (r + 0.5f) * px;
        float3 out = f == 0 ? T : (f == 1 ? -T : (f == 2 ? B : -B));
        float3 across = f == 0 ? B : (f == 1 ? -B : (f == 2 ? -T : T));
        b_ = out - across + h * n;
        d_ = across;
    }
    *base = b_ + 0.5f * px * d_;
    *step = d_ * px;
}

// Pixels x0 .. x0 + BVH_PACKET - 1 of a scanline (base, step from hc_scanline; lanes past the
// scanline's end repeat its last pixel) traced from org as one packet: each ray's nearest patch
// (-1: none) and whether it met that patch's front. Needs bvh.cl's packet part (BVH_PACKET).
inline void hc_trace_packet(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                            float3 org, float3 base, float3 step, int x0, int *ids, int *fronts)
{
    const bvh_floatP lane = (bvh_floatP)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    RayPacket r;
    r.ox = (bvh_floatP)org.x;
    r.oy = (bvh_floatP)org.y;
    r.oz = (bvh_floatP)org.z;
    const bvh_floatP xs = BVH_MIN((bvh_floatP)x0 + lane, (bvh_floatP)(HC_RES - 1));
    r.dx = base.x + xs * step.x;
    r.dy = base.y + xs * step.y;
    r.dz = base.z + xs * step.z;
    HitPacket hp = bvh_closest_packet(nodes, tris, order, &r, 0.0f, (bvh_floatP)INFINITY);
    bvh_vstoreP(hp.patch, 0, ids);
    bvh_vstoreP(hp.front, 0, fronts);
}

#endif
