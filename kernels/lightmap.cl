// Launch bound (~100 ms on a small GPU): one item per triangle walks its bounding box of texels
// (grown by one): the launch's work is the sum of the boxes, about the lightmap's texels (a
// 4096^2 map: 17 M texel tests, a few ms).
// Lightmap rasterising (pydynrad/bake/lightmap.py): which triangle fills each texel.
// One work-item per lightmap triangle walks the texels of its bounding box grown by one texel.
// Texel (x, y) covers [x, x+1] x [y, y+1]; its centre is (x + 0.5, y + 0.5).
//
// For a texel centre p, bary[k] is the signed barycentric of corner k (negative outside), and
// reach[k] how much bary[k] can grow across a square of half-size 1 around p, so
//   bary[k] + s * reach[k] >= 0 for all k  <=>  the square of half-size s meets the triangle's
//   three edge half-planes (the separating-axis test; the box axes are tested separately).
// s = 1: a bilinear lookup inside the triangle can read this texel ("near");
// s = 1/2: the texel's own square meets the triangle ("covered", with the box test).
// Among the triangles near a texel the one it lies most inside (largest min_k bary[k]) owns
// it; ties go to the highest triangle index, so the result is the same on every device.
//
// Host guarantees: box[t] = (x0, y0, nx, ny) lies inside the image (nx = 0 for a triangle
// left out); corner[3t + k] is corner k relative to (x0, y0), in texels, with a non-zero
// area; best is filled with INT_MIN and owner with -1 before the first and second kernel.

typedef struct { float b[3]; float r[3]; } Bary;

inline Bary texel_bary(const float2 a, const float2 b, const float2 c, const float2 p)
{
    const float2 e[3][2] = {{b, c}, {c, a}, {a, b}};
    const float area2 = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    const float inv = 1.0f / area2;
    Bary out;
    for (int k = 0; k < 3; ++k) {
        const float2 q0 = e[k][0], d = e[k][1] - e[k][0];
        out.b[k] = (d.x * (p.y - q0.y) - d.y * (p.x - q0.x)) * inv;
        out.r[k] = (fabs(d.x) + fabs(d.y)) * fabs(inv);
    }
    return out;
}

// An int whose order is the float's order, for atomic_max.
inline int ordered_key(const float s)
{
    const int i = as_int(s);
    return i >= 0 ? i : i ^ 0x7fffffff;
}

inline bool reaches(const Bary q, const float s)
{
    return q.b[0] + s * q.r[0] >= 0.0f && q.b[1] + s * q.r[1] >= 0.0f && q.b[2] + s * q.r[2] >= 0.0f;
}

// Pass 1: mark covered texels and raise each near texel's best score.
__kernel void lightmap_best(const int n, __global const int4 *box, __global const float2 *corner,
                            const int width, __global volatile int *best, __global uchar *covered)
{
    const int t = get_global_id(0);
    if (t >= n) return;
    const int4 bx = box[t];
    const float2 a = corner[3 * t], b = corner[3 * t + 1], c = corner[3 * t + 2];
    const float2 lo = fmin(fmin(a, b), c), hi = fmax(fmax(a, b), c);
    for (int j = 0; j < bx.w; ++j) {
        for (int i = 0; i < bx.z; ++i) {
            const float2 p = (float2)(i + 0.5f, j + 0.5f);
            const Bary q = texel_bary(a, b, c, p);
            if (!reaches(q, 1.0f)) continue;
            const int texel = (bx.y + j) * width + bx.x + i;
            const float2 off = fabs(p - clamp(p, lo, hi));
            if (reaches(q, 0.5f) && off.x <= 0.5f && off.y <= 0.5f) covered[texel] = 1;
            atomic_max(&best[texel], ordered_key(fmin(q.b[0], fmin(q.b[1], q.b[2]))));
        }
    }
}

// Pass 2: among the triangles reaching a texel with its best score, the highest index owns it.
__kernel void lightmap_owner(const int n, __global const int4 *box, __global const float2 *corner,
                             const int width, __global const int *best, __global volatile int *owner)
{
    const int t = get_global_id(0);
    if (t >= n) return;
    const int4 bx = box[t];
    const float2 a = corner[3 * t], b = corner[3 * t + 1], c = corner[3 * t + 2];
    for (int j = 0; j < bx.w; ++j) {
        for (int i = 0; i < bx.z; ++i) {
            const Bary q = texel_bary(a, b, c, (float2)(i + 0.5f, j + 0.5f));
            if (!reaches(q, 1.0f)) continue;
            const int texel = (bx.y + j) * width + bx.x + i;
            if (ordered_key(fmin(q.b[0], fmin(q.b[1], q.b[2]))) == best[texel]) atomic_max(&owner[texel], t);
        }
    }
}
