// Launch bound (~100 ms on a small GPU tracing ~50 M rays/s): one launch traces a block of rows,
// K * 3R * R rays each; pydynrad/formfactors.py sizes a block so its runs (8 bytes per pixel)
// fit BLOCK_BYTES / 2, i.e. at most BLOCK_BYTES / 16 rays per launch.
// Hemicube form factors by ray casting: one work-item per band of HC_TILE_Y scanlines of a
// hemicube, traced tile by tile (the layout, the ray directions and the tiles are hemicube.h's).
// Each row averages HC_SAMPLES hemicubes (1 unless the host defines it), one per stratum of its
// patch, at origins the host places; sample m of patch i is rotated by key i * HC_SAMPLES + m
// (i alone for one sample).
//
// Each scanline's pixels are run-length encoded: consecutive pixels that see the same patch
// form one run (id, weight), its weight the difference of weights_cum (the prefix sums of the
// scanline's pixel form factors, 3R x (R + 1), summed in float64 on the host) at its ends, so
// nothing N-sized per row ever exists on the device and the host only sums duplicates.
//
// With HC_CLUSTERS defined (the far field's patch-to-cluster form factors G = F Pr) the kernel
// takes labels (int per patch: its cluster, or -1 for none), scale (float per patch: its entry
// of Pr, 1 for the indicator) and pixel_weights (the delta form factors, 3R x R as above)
// instead of weights_cum. It records labels[patch] instead of the patch, so neighbouring pixels
// on different patches of one cluster form one run, and sums each run's pixels' weights times
// their patch's scale.
#if !defined(HC_TILE_Y) || HC_TILE_Y < 1 || BVH_PACKET % HC_TILE_Y != 0
#error "hemicube.cl needs HC_TILE_Y (scanlines per tile, dividing BVH_PACKET) from the host (pydynrad.device.launch.hemicube_tiles)"
#endif
#include "hemicube.h"  // and bvh.cl

#ifdef HC_CLUSTERS
#define HC_WEIGHT_ARGS __global const int *labels, __global const float *scale, __global const float *pixel_weights
#else
#define HC_WEIGHT_ARGS __global const float *weights_cum
#endif

#ifndef HC_SAMPLES
#define HC_SAMPLES 1
#endif

// origins: float4 per (row k, sample m) of this block, at [k * HC_SAMPLES + m]; normals: float4
// per patch. rows: the patches whose hemicubes this block renders, then (at n_rows + k) the
// instance each row's rays need not look at, -1 for none: the patch's own object where it is
// convex (a ray leaving its surface outwards meets nothing of it, so its tree is not walked).
// Outputs per hemicube
// q = k * HC_SAMPLES + m and scanline s: run_patch / run_weight at [(q * 3R + s) * R + j] for
// the j-th run (patch -1: nothing front-facing visible), run_count at [q * 3R + s]. The pixel
// weights (weights_cum, pixel_weights) are the hemicube's, 3R scanlines, divided by HC_SAMPLES.
__kernel void hemicube_runs(__global const float4 *nodes, __global const float4 *tris, __global const int *order,
                            __global const float4 *origins, __global const float4 *normals,
                            __global const int *rows, int n_rows, float eps,
                            __global int *run_patch, __global float *run_weight, __global int *run_count,
                            HC_WEIGHT_ARGS)
{
    const int R = HC_RES;
    int g = get_global_id(0);
    if (g >= n_rows * HC_SAMPLES * HC_BANDS) return;
    int q = g / HC_BANDS, n_lines;
    int s0 = hc_band(g % HC_BANDS, &n_lines);
    int i = rows[q / HC_SAMPLES], skip = rows[n_rows + q / HC_SAMPLES];
    float3 n = normals[i].xyz;
    float3 org = origins[q].xyz + eps * n;

    float3 T, B, base, step_dir, row;
    hc_frame(n, (uint)i * HC_SAMPLES + (uint)(q % HC_SAMPLES), &T, &B);
    hc_face_scanline(T, B, n, s0, &base, &step_dir, &row);

    // Each of the band's scanlines keeps its own runs: the current id (-2: none yet), its
    // first pixel (its weight so far with clusters) and the count.
    int runs[HC_TILE_Y], current[HC_TILE_Y];
#ifdef HC_CLUSTERS
    float acc[HC_TILE_Y];
#else
    int start[HC_TILE_Y];
#endif
    for (int y = 0; y < HC_TILE_Y; ++y) {
        runs[y] = 0;
        current[y] = -2;
#ifdef HC_CLUSTERS
        acc[y] = 0.0f;
#else
        start[y] = 0;
#endif
    }
    for (int x0 = 0; x0 < R; x0 += HC_TILE_X) {
        int ids[BVH_PACKET], fronts[BVH_PACKET];
        hc_trace_tile(nodes, tris, order, org, base, step_dir, row, x0, n_lines, skip, ids, fronts);
        for (int y = 0; y < n_lines; ++y) {
            int s = s0 + y;
            size_t slot = ((size_t)q * 3 * R + s) * R;
            for (int l = y * HC_TILE_X, x = x0; l < (y + 1) * HC_TILE_X && x < R; ++l, ++x) {
                // A back face occludes and receives nothing; a planar patch cannot see itself.
                int hit = (ids[l] >= 0 && fronts[l] && ids[l] != i) ? ids[l] : -1;
#ifdef HC_CLUSTERS
                int id = hit >= 0 ? labels[hit] : -1;
#else
                int id = hit;
#endif
                if (id != current[y]) {
                    if (current[y] != -2) {
                        run_patch[slot + runs[y]] = current[y];
#ifdef HC_CLUSTERS
                        run_weight[slot + runs[y]] = acc[y];
                        acc[y] = 0.0f;
#else
                        run_weight[slot + runs[y]] = weights_cum[s * (R + 1) + x] - weights_cum[s * (R + 1) + start[y]];
                        start[y] = x;
#endif
                        ++runs[y];
                    }
                    current[y] = id;
                }
#ifdef HC_CLUSTERS
                if (id >= 0) acc[y] += pixel_weights[(size_t)s * R + x] * scale[hit];
#endif
            }
        }
    }
    for (int y = 0; y < n_lines; ++y) {
        int s = s0 + y;
        size_t line = (size_t)q * 3 * R + s, slot = line * R;
        run_patch[slot + runs[y]] = current[y];
#ifdef HC_CLUSTERS
        run_weight[slot + runs[y]] = acc[y];
#else
        run_weight[slot + runs[y]] = weights_cum[s * (R + 1) + R] - weights_cum[s * (R + 1) + start[y]];
#endif
        run_count[line] = runs[y] + 1;
    }
}
