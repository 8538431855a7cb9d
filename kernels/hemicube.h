// Hemicube ray generation shared by the form-factor rows (hemicube.cl) and the gathers at
// arbitrary points (gather.cl): the frame at a point, the direction of every pixel, and
// packets of rays traced (a run of one scanline's pixels, or a tile of a few scanlines).
// Includes bvh.cl itself, built for packets from one origin.
//
// A hemicube of resolution R (HC_RES) has a top face of R x R pixels and four side faces of
// R x R/2, i.e. 3R scanlines of R pixels each:
//   s <  R : top face z = 1, pixel (x, s) centred at (u, v) = (-1 + (x + .5) 2/R, -1 + (s + .5) 2/R)
//   s >= R : side f = (s - R) / (R/2), row r = (s - R) % (R/2), height h = (r + .5) 2/R,
//            across a = -1 + (x + .5) 2/R; f = 0: (1, a, h), 1: (-1, -a, h), 2: (-a, 1, h), 3: (a, -1, h)
// in the frame (T, B, N), T rotated about N by a pseudo-random angle keyed by an integer (the
// patch index for a patch's row), so regular structures do not alias the same way at every
// point. pydynrad/formfactors.py computes the pixels' delta form factors in the same layout.
//
// Tiles (hemicube.cl): HC_TILE_Y consecutive scanlines of one face make a band, and
// HC_TILE_X = BVH_PACKET / HC_TILE_Y pixels of each a tile, traced as one packet. A tile's rays
// lie closer together than a run of BVH_PACKET pixels of one scanline, so the packet visits
// fewer nodes (bench/formfactors.py). Each face is cut into bands from its first scanline; a
// face's last band may hold fewer scanlines.
#ifndef PYDYNRAD_HEMICUBE_H
#define PYDYNRAD_HEMICUBE_H

#ifndef HC_RES
#error "HC_RES (the hemicube resolution) must be defined"
#endif
// The lane offsets (HC_LANES) are written out for these widths.
#if BVH_PACKET != 4 && BVH_PACKET != 8 && BVH_PACKET != 16
#error "hemicube.h needs BVH_PACKET of 4, 8 or 16 from the host (pydynrad.device.launch.bvh_packet)"
#endif

// Every ray of a packet leaves the hemicube's centre.
#if defined(PYDYNRAD_BVH_CL) && !defined(BVH_SHARED_ORIGIN)
#error "include hemicube.h before bvh.cl: it builds bvh.cl's packets for one shared origin"
#endif
#define BVH_SHARED_ORIGIN
#include "bvh.cl"

#if BVH_PACKET == 16
#define HC_LANES (bvh_floatP)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15)
#elif BVH_PACKET == 8
#define HC_LANES (bvh_floatP)(0, 1, 2, 3, 4, 5, 6, 7)
#else
#define HC_LANES (bvh_floatP)(0, 1, 2, 3)
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

// The hemicube's frame about unit normal n with rotation key: tangent *T and bitangent *B.
inline void hc_frame(float3 n, uint key, float3 *T, float3 *B)
{
    // Orthonormal basis around n without a branch on its direction (Duff et al. 2017),
    // then rotated about n by the key's angle.
    float sg = copysign(1.0f, n.z);
    float a = -1.0f / (sg + n.z);
    float b = n.x * n.y * a;
    float3 t0 = (float3)(1.0f + sg * n.x * n.x * a, sg * b, -sg * n.x);
    float3 b0 = (float3)(b, sg + n.y * n.y * a, -n.y);
    float ang = (float)hc_hash(key) * (6.283185307179586f / 4294967296.0f);
    float cs = cos(ang), sn = sin(ang);
    *T = cs * t0 + sn * b0;
    *B = cs * b0 - sn * t0;
}

// Scanline s in the frame (T, B, n): pixel x's (unnormalised) world direction is
// *base + x * *step, and the next scanline of the same face lies *row further.
inline void hc_face_scanline(float3 T, float3 B, float3 n, int s, float3 *base, float3 *step, float3 *row)
{
    const int R = HC_RES, H = HC_RES / 2;
    float px = 2.0f / R;
    float3 b_, d_;
    if (s < R) {
        float v = -1.0f + (s + 0.5f) * px;
        b_ = -T + v * B + n;
        d_ = T;
        *row = px * B;
    } else {
        int f = (s - R) / H, r = (s - R) % H;
        float h = (r + 0.5f) * px;
        float3 out = f == 0 ? T : (f == 1 ? -T : (f == 2 ? B : -B));
        float3 across = f == 0 ? B : (f == 1 ? -B : (f == 2 ? -T : T));
        b_ = out - across + h * n;
        d_ = across;
        *row = px * n;
    }
    *base = b_ + 0.5f * px * d_;
    *step = d_ * px;
}

// Scanline s of the hemicube about unit normal n with rotation key: pixel x's world
// direction is *base + x * *step.
inline void hc_scanline(float3 n, uint key, int s, float3 *base, float3 *step)
{
    float3 T, B, row;
    hc_frame(n, key, &T, &B);
    hc_face_scanline(T, B, n, s, base, step, &row);
}

// The packet org + t (dx, dy, dz) traced: each lane's nearest patch (-1: none) and whether it
// met that patch's front; instance `skip` (-1: none) not looked at (bvh_closest_packet).
inline void hc_trace(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                     float3 org, bvh_floatP dx, bvh_floatP dy, bvh_floatP dz, int skip, int *ids, int *fronts)
{
    RayPacket r = {org.x, org.y, org.z, dx, dy, dz};
    HitPacket hp = bvh_closest_packet(nodes, tris, order, &r, 0.0f, (bvh_floatP)INFINITY, skip);
    bvh_vstoreP(hp.patch, 0, ids);
    bvh_vstoreP(hp.front, 0, fronts);
}

// Pixels x0 .. x0 + BVH_PACKET - 1 of a scanline (base, step from hc_scanline; lanes past the
// scanline's end repeat its last pixel) traced from org as one packet (hc_trace).
inline void hc_trace_packet(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                            float3 org, float3 base, float3 step, int x0, int *ids, int *fronts)
{
    const bvh_floatP xs = BVH_MIN((bvh_floatP)x0 + HC_LANES, (bvh_floatP)(HC_RES - 1));
    hc_trace(nodes, tris, order, org, base.x + xs * step.x, base.y + xs * step.y, base.z + xs * step.z, -1, ids, fronts);
}

#ifdef HC_TILE_Y
#define HC_TILE_X (BVH_PACKET / HC_TILE_Y)
#define HC_TOP_BANDS ((HC_RES + HC_TILE_Y - 1) / HC_TILE_Y)
#define HC_SIDE_BANDS ((HC_RES / 2 + HC_TILE_Y - 1) / HC_TILE_Y)
// Bands per hemicube (pydynrad.device.launch.HemicubeTiles.bands computes the same for the host).
#define HC_BANDS (HC_TOP_BANDS + 4 * HC_SIDE_BANDS)

// Band b (0 .. HC_BANDS - 1): its first scanline, and in *rows how many it holds.
inline int hc_band(int b, int *rows)
{
    const int R = HC_RES, H = HC_RES / 2;
    int s0, end;
    if (b < HC_TOP_BANDS) {
        s0 = b * HC_TILE_Y;
        end = R;
    } else {
        int f = (b - HC_TOP_BANDS) / HC_SIDE_BANDS, j = (b - HC_TOP_BANDS) % HC_SIDE_BANDS;
        s0 = R + f * H + j * HC_TILE_Y;
        end = R + (f + 1) * H;
    }
    *rows = min(HC_TILE_Y, end - s0);
    return s0;
}

// The tile of pixels x0 .. x0 + HC_TILE_X - 1 of `rows` consecutive scanlines of one face, the
// first of them given by hc_face_scanline (base, step, row), traced from org as one packet
// (hc_trace, instance `skip` not looked at). Lane l is pixel x0 + l % HC_TILE_X of the tile's
// scanline l / HC_TILE_X; lanes past the face's last pixel or the band's last scanline repeat it.
inline void hc_trace_tile(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                          float3 org, float3 base, float3 step, float3 row, int x0, int rows, int skip, int *ids,
                          int *fronts)
{
    const bvh_floatP lane = HC_LANES;
    const bvh_floatP ly = floor(lane * (1.0f / HC_TILE_X));
    const bvh_floatP xs = BVH_MIN((bvh_floatP)x0 + (lane - ly * HC_TILE_X), (bvh_floatP)(HC_RES - 1));
    const bvh_floatP ys = BVH_MIN(ly, (bvh_floatP)(rows - 1));
    hc_trace(nodes, tris, order, org, base.x + xs * step.x + ys * row.x, base.y + xs * step.y + ys * row.y,
             base.z + xs * step.z + ys * row.z, skip, ids, fronts);
}
#endif  // HC_TILE_Y

#endif
