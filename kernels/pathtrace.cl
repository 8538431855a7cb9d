// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): a pass is n items x spp paths,
// each bounce 2 + n_lights rays; pydynrad/pathtracer.py doubles spp per pass from 1 up to
// _MAX_PASS (16) and splits each pass into launches over ranges of items (a global offset;
// n_pixels / n_items is the range's end) of at most PATH_RAYS_PER_LAUNCH (2^22) rays counting
// 6 bounces a path (~84 ms; Russian roulette ends most paths sooner): a 640 x 480 pass of 16 spp
// without lights is 15 launches of 21,845 pixels.
// Reference path tracer: the ground truth that radiosity results are compared against.
//
// Every surface is a one-sided Lambertian patch (the side its normal faces), like the
// hemicubes of the radiosity solver: a ray that reaches a patch's back is absorbed.
// Radiometry: a patch's emission E (W/unit^2, radiant exitance) emits radiance E / pi; a
// surface of albedo rho reflects radiance (rho / pi) * H, H = irradiance (W/unit^2).
//
// Estimator: direct light from emitting patches is sampled two ways at each diffuse vertex,
// next-event estimation (an emitter picked with probability proportional to its power, a
// uniform point on it) and the cosine-sampled bounce ray hitting an emitter, combined with
// multiple importance sampling (balance heuristic), so neither double counts and neither
// has the 1/d^2 spikes of NEE alone next to an emitter. A camera ray's first hit adds its
// emission in full. The analytic lights (points, spots, directional) are deltas: NEE only.
// A bounce ray that leaves the scene sees the sky (sky.h; none when its mode is 0), which is
// smooth enough for the cosine-sampled bounce alone.
// Russian roulette after RR_DEPTH bounces, at most MAX_DEPTH bounces.
//
// Random numbers come from rng.cl keyed by (seed, pixel or patch, sample index), so an image
// is the same whatever the pass size.
#include "bvh.cl"
#include "lights.h"
#include "rng.cl"
#include "sky.h"

#ifndef MAX_DEPTH
#error "MAX_DEPTH (the bounce limit) must come from the host (pydynrad/pathtracer.py)"
#endif
#ifndef RR_DEPTH
#define RR_DEPTH 3
#endif

// Scene arguments shared by both entry points, in this order. em_tri: 4 float4 per emitting
// patch (v0, e1 = v1 - v0, e2 = v2 - v0, normal); em_cdf: cumulative power shares.
#define SCENE_ARGS                                                                              \
    __global const float4 *nodes, __global const float4 *tris, __global const int *order,       \
    __global const float4 *normals, __global const float4 *albedo,                            \
    __global const float4 *emission,                                                          \
    const int n_emitters, __global const float4 *em_tri, __global const float4 *em_emission,  \
    __global const float *em_cdf, const float inv_power,                                      \
    const int n_lights, __global const float4 *lights, __global const float *light_tables,    \
    __global const float4 *sky,                                                               \
    const float eps, const float far
#define SCENE_PASS                                                                              \
    nodes, tris, order, normals, albedo, emission, n_emitters, em_tri, em_emission, em_cdf,   \
    inv_power, n_lights, lights, light_tables, sky, eps, far

// Area pdf with which emitter_irradiance picks a point on emitting patch j: its pick
// probability (power share, power = mean emission * area) over its area.
inline float emitter_area_pdf(float3 e, const float inv_power)
{
    return (e.x + e.y + e.z) * (1.0f / 3.0f) * inv_power;
}

// Balance-heuristic weight of a technique with pdf a against one with pdf b (solid angle).
inline float mis_weight(float a, float b)
{
    return a / (a + b);
}

// One-sample NEE estimate of the irradiance at x from the emitting patches, MIS-weighted
// against the cosine-sampled bounce (whose pdf is cos / pi).
inline float3 emitter_irradiance(float3 x, float3 n, uint *rng, SCENE_ARGS)
{
    if (n_emitters == 0) return (float3)(0.0f);
    float u = rng_next(rng);
    int lo = 0, hi = n_emitters - 1;
    while (lo < hi) {  // first k with cdf[k] > u
        int mid = (lo + hi) / 2;
        if (em_cdf[mid] > u) hi = mid; else lo = mid + 1;
    }
    float3 v0 = em_tri[4 * lo].xyz, e1 = em_tri[4 * lo + 1].xyz, e2 = em_tri[4 * lo + 2].xyz;
    float3 ny = em_tri[4 * lo + 3].xyz;
    float s = sqrt(rng_next(rng)), t = rng_next(rng);
    float3 y = v0 + e1 * (s * (1.0f - t)) + e2 * (s * t);
    float3 d = y - x;
    float dist2 = BVH_DOT(d, d);
    float dist = sqrt(dist2);
    float3 w = d / dist;
    float cx = BVH_DOT(n, w), cy = -BVH_DOT(ny, w);
    if (cx <= 0.0f || cy <= 0.0f) return (float3)(0.0f);
    if (bvh_occluded(nodes, tris, x, w, 0.0f, dist - eps)) return (float3)(0.0f);
    float3 e = em_emission[lo].xyz;
    float pdf_light = emitter_area_pdf(e, inv_power) * dist2 / cy;  // solid angle
    // radiance E/pi times cos_x over the solid-angle pdf, weighted.
    return e * (M_1_PI_F * cx / pdf_light * mis_weight(pdf_light, cx * M_1_PI_F));
}

// Cosine-weighted direction about n (pdf cos / pi); branchless basis of Duff et al. 2017.
inline float3 sample_cosine(float3 n, uint *rng)
{
    float sign = as_float((as_uint(n.z) & 0x80000000u) | 0x3f800000u);  // copysign(1, n.z), -0 included (bvh_ray_frame)
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    float3 t = (float3)(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    float3 bt = (float3)(b, sign + n.y * n.y * a, -n.y);
    float r = sqrt(rng_next(rng)), phi = 2.0f * M_PI_F * rng_next(rng);
    float z = sqrt(BVH_MAX(1.0f - r * r, 0.0f));
    return normalize(t * (r * cos(phi)) + bt * (r * sin(phi)) + n * z);
}

// Radiance reflected at surface point p (normal n, albedo rho) towards any direction,
// excluding p's own emission: (rho / pi) * H(p), H estimated by NEE plus one path.
inline float3 reflected_radiance(float3 p, float3 n, float3 rho, uint *rng, SCENE_ARGS)
{
    float3 acc = (float3)(0.0f);
    float3 thr = rho;  // product of albedos along the path
    for (int depth = 0; depth < MAX_DEPTH; ++depth) {
        float3 x = p + n * eps;
        float3 h = analytic_irradiance(p, x, n, n_lights, lights, light_tables, nodes, tris, eps, far)
                   + emitter_irradiance(x, n, rng, SCENE_PASS);
        acc += thr * h * M_1_PI_F;
        // The cosine pdf cancels the cosine and 1/pi: radiance arriving along the bounce ray
        // enters with weight thr (rho of this vertex included).
        float3 w = sample_cosine(n, rng);
        Hit hit = bvh_closest(nodes, tris, order, x, w, 0.0f, INFINITY);
        if (hit.patch < 0) {  // radiance L of the sky enters with weight thr, as an emitter's does
            acc += thr * sky_luminance(sky, w);
            break;
        }
        if (!hit.front) break;
        float3 e = emission[hit.patch].xyz;
        float3 ny = normals[hit.patch].xyz;
        if (n_emitters > 0 && (e.x > 0.0f || e.y > 0.0f || e.z > 0.0f)) {
            // The bounce ray found an emitter: its radiance E/pi enters with weight thr,
            // MIS-weighted against NEE having picked the same point.
            float pdf_light = emitter_area_pdf(e, inv_power) * hit.t * hit.t / BVH_MAX(-BVH_DOT(ny, w), 1e-12f);
            acc += thr * e * (M_1_PI_F * mis_weight(BVH_DOT(n, w) * M_1_PI_F, pdf_light));
        }
        p = x + w * hit.t;
        n = ny;
        thr *= albedo[hit.patch].xyz;
        if (depth + 1 >= RR_DEPTH) {
            float q = BVH_MIN(BVH_MAX(thr.x, BVH_MAX(thr.y, thr.z)), 0.95f);
            if (rng_next(rng) >= q) break;
            thr /= q;
        }
    }
    return acc;
}

// Radiance along one camera ray per pixel (from the camera at origin through the pixel centre,
// the ray `render` casts),
// summed over samples [sample_start, sample_start + n_samples) into accum[pixel].xyz.
__kernel void trace_pixels(const float4 origin, __global const float4 *ray_dir, const int n_pixels,
                           __global float4 *accum, const uint seed, const uint sample_start, const int n_samples,
                           SCENE_ARGS)
{
    int i = get_global_id(0);
    if (i >= n_pixels) return;
    float3 o = origin.xyz, d = ray_dir[i].xyz;
    Hit hit = bvh_closest(nodes, tris, order, o, d, 0.0f, INFINITY);
    if (hit.patch < 0 || !hit.front) return;
    float3 p = o + d * hit.t;
    float3 n = normals[hit.patch].xyz;
    float3 rho = albedo[hit.patch].xyz;
    float3 sum = emission[hit.patch].xyz * (M_1_PI_F * (float)n_samples);
    for (int s = 0; s < n_samples; ++s) {
        uint rng = rng_stream(seed, (uint)i, sample_start + (uint)s);
        sum += reflected_radiance(p, n, rho, &rng, SCENE_PASS);
    }
    accum[i].xyz += sum;
}

// Radiosity gathered at the centres of the patches `patch_ids`, minus their own emission:
// pi * reflected radiance = rho * H, summed over the samples into accum[k].xyz.
__kernel void gather_patches(__global const int *patch_ids, __global const float4 *centers, const int n_items,
                             __global float4 *accum, const uint seed, const uint sample_start, const int n_samples,
                             SCENE_ARGS)
{
    int k = get_global_id(0);
    if (k >= n_items) return;
    int i = patch_ids[k];
    float3 p = centers[i].xyz, n = normals[i].xyz, rho = albedo[i].xyz;
    float3 sum = (float3)(0.0f);
    for (int s = 0; s < n_samples; ++s) {
        uint rng = rng_stream(seed, (uint)i, sample_start + (uint)s);
        sum += reflected_radiance(p, n, rho, &rng, SCENE_PASS);
    }
    accum[k].xyz += sum * M_PI_F;
}
