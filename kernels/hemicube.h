// Hemicube ray generation shared by the form-factor rows (hemicube.cl) and the gathers at
// arbitrary points (gather.cl): the frame at a point and the direction of every pixel.
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

#endif
