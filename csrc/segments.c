/*
 * Segments between points that pass near a sphere: the pre-test of a move's occlusion rows
 * (pydynrad/dynamic/moves.py, hidden_between; docs/design.md, 'Moving objects').
 *
 * Host-side by design: a move tests every entry of the ~900 rows that may see the object
 * (~400k segments between patch centres on the bench's Cornell box) and traces only the few
 * that pass within the object's bounding sphere. numpy did the test in ~15 passes over
 * float64 temporaries and gathers (the largest single cost of a corrected move;
 * docs/decisions/0033-native-host-passes.md); here it is one pass:
 *
 *   u = p - c per point; g = u_a . u_b; uv = g - |u_a|^2; vv = |u_a|^2 + |u_b|^2 - 2 g;
 *   the segment's closest point to c is at t = -uv / vv clipped to [0, 1], near when its
 *   squared distance q (|u_a|^2 at t = 0, |u_b|^2 at t = 1, else |u_a|^2 - uv^2 / vv) is at
 *   most reach^2.
 *
 * With a box (the object's bounds in its own space and the world-to-object map), a segment
 * near the sphere must also cross the box, by the slab test on the segment moved into object
 * space: the sphere of a box holds 2.7 times its volume (a cube's), so about half of the
 * segments near the sphere miss the box, and each of them would be a ray traced for nothing.
 *
 * Each segment kept is written out as the ray that the object's tree traces (origin a and
 * direction b - a in object space, t in (0, 1)): moving ~30k of them into object space took
 * numpy passes of gathers and small matrix products, here they are a copy of what the slab
 * test computed anyway.
 *
 * With planes (an object that is one convex solid, pydynrad/geometry/convex.py), a segment that crosses
 * the box is kept only if it crosses the solid's boundary, which clipping it by the planes
 * decides exactly: nothing is left to trace. On the bench's block, 99.9% of the segments that
 * crossed its box were hidden (the box is the block), and tracing them waited for the block's
 * own hemicubes queued ahead of them on the device.
 *
 * Rows are read where they lie: row k is the span starts[k] <= j < ends[k] of the indices (the
 * rows of F that a move tests, picked out of the whole F by their patches without a copy: the
 * copy and an int64 version of the indices were almost half of the pre-test).
 *
 * Python signature:  _segments.near_sphere(points, starts, ends, indices, owners, center, reach, box[, planes]) -> (segments, rays)
 *   points  : C-contiguous float64 buffer of n*3 values
 *   starts, ends : int64 buffers of r values: row k's segments are the j in [starts[k], ends[k])
 *   indices : int32 buffer of m point indices (scipy's CSR indices): segment j of row k goes
 *             from point owners[k] to point indices[j]
 *   owners  : int64 buffer of r values, a point index per row, or -1 to skip the row
 *   center  : (cx, cy, cz) floats; reach : float, the sphere's radius with any margin
 *   box     : None, or 18 floats: the world-to-object map x -> A x + t (A row-major, then t),
 *             then the box's low and high corners in object space (any margin included);
 *             None: no box test, and the rays are in world space
 *   planes  : None (the default), or 4 k floats (1 <= k <= MAX_PLANES; a box is needed): rows
 *             (n, d) of the convex solid n . x <= d in object space
 *   segments: bytes of int64, row by row in the order given: the segments j with q <= reach^2
 *             (and crossing the box; with planes, crossing the solid's boundary)
 *   rays    : bytes of float64, 6 per segment kept: its ray's origin and direction (empty with
 *             planes: nothing is left to trace)
 *   Indices are checked (0 <= i < n, 0 <= starts[k] <= ends[k] <= m): ValueError if not.
 * A list of segments a[i] -> b[i] is one entry per row (starts = 0..m-1, ends = 1..m, owners = a).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Whether the segment a -> b (object space) meets the box [lo, hi]: the slab test over t in [0, 1].
   Half the segments it sees miss the box, at an axis that varies, so it is written without
   branches (the three divisions independent, the picks as selects) and decides as an early
   exit at the first axis would: t0 only grows and t1 only shrinks. An axis parallel to the
   segment (d = 0) puts it outside or leaves it. */
static int crosses_box(const double *a, const double *b, const double *lo, const double *hi)
{
    double t0 = 0.0, t1 = 1.0;
    for (int k = 0; k < 3; ++k) {
        const double d = b[k] - a[k], inv = 1.0 / d;
        const double ta = (lo[k] - a[k]) * inv, tb = (hi[k] - a[k]) * inv;
        const int parallel = d == 0.0, outside = a[k] < lo[k] || a[k] > hi[k];
        double enter = ta > tb ? tb : ta, leave = ta > tb ? ta : tb;
        enter = parallel ? (outside ? INFINITY : -INFINITY) : enter;
        leave = parallel ? INFINITY : leave;
        t0 = enter > t0 ? enter : t0;
        t1 = leave < t1 ? leave : t1;
    }
    return !(t0 > t1);
}

/* Whether the segment a -> b (object space) crosses the boundary of the convex solid
   n_k . x <= d_k, k < count (rows of 4 in planes): clipped by the planes (Cyrus-Beck) it keeps
   a part of positive length in the open solid, and not both of its ends lie in the closed one
   (a segment wholly inside crosses no face, as a ray started inside a closed mesh with t in
   (0, 1) meets no triangle). A segment on the outer side of a plane or in it, touching the
   solid at an end, an edge or a face only, does not cross: a ray along a triangle's plane
   meets none of it. Only segments near the object get here (a few percent), so branches. */
static int crosses_solid(const double *a, const double *b, const double *planes, int count)
{
    double t0 = 0.0, t1 = 1.0;
    int inside = 1;
    for (int k = 0; k < count; ++k) {
        const double *p = planes + 4 * k;
        const double sa = p[0] * a[0] + p[1] * a[1] + p[2] * a[2] - p[3];
        const double sb = p[0] * b[0] + p[1] * b[1] + p[2] * b[2] - p[3];
        if (sa >= 0.0 && sb >= 0.0) return 0;
        if (sa > 0.0) {
            const double t = sa / (sa - sb);
            t0 = t > t0 ? t : t0;
        } else if (sb > 0.0) {
            const double t = sa / (sa - sb);
            t1 = t < t1 ? t : t1;
        }
        inside &= sa <= 0.0 && sb <= 0.0;
    }
    return t0 < t1 && !inside;
}

/* The most planes a solid may give (pydynrad/geometry/convex.py's MAX_PLANES is at most this). */
#define MAX_PLANES 64

/* Per point: u = p - c and |u|^2 (what the sphere test reads, 32 bytes: the village's and the
   Cornell box's points stay in L1/L2), and apart from them the point in object space (read only
   for the few segments near the sphere). */
#define TEST 4
/* Segments whose sphere test runs before the few near ones are looked at: a pass of compares
   without branches, then a scan of its flags. The outcome is data dependent (5-15% near), and
   branching on it per segment mispredicted often enough to cost more than the flags' second
   pass (docs/decisions/0033-native-host-passes.md). */
#define BLOCK 512

/* Output that grows as segments are kept: a move keeps ~30k of ~500k, so sizing it for every
   segment would fault in ~27 MB per call for nothing. Rays only where something traces them
   (not with planes: the pass decided). */
typedef struct {
    int64_t *seg;
    double *ray;
    Py_ssize_t count, cap;
    int rays;
} kept_t;

static int keep(kept_t *k, int64_t j, const double *a, const double *b)
{
    if (k->count == k->cap) {
        Py_ssize_t cap = k->cap ? 2 * k->cap : 4096;
        int64_t *seg = realloc(k->seg, (size_t)cap * sizeof(int64_t));
        if (!seg) return -1;
        k->seg = seg;
        if (k->rays) {
            double *ray = realloc(k->ray, (size_t)cap * 6 * sizeof(double));
            if (!ray) return -1;
            k->ray = ray;
        }
        k->cap = cap;
    }
    if (k->rays) {
        double *r = k->ray + 6 * k->count;
        for (int q = 0; q < 3; ++q) r[q] = a[q], r[3 + q] = b[q] - a[q];
    }
    k->seg[k->count++] = j;
    return 0;
}

/* Clones of a loop for the SIMD widths of x86 CPUs, picked when the module loads (GCC's
   ifunc, which glibc has and musl has not): the wheel's baseline is SSE2, whatever CPU runs it. */
#if defined(__GNUC__) && defined(__x86_64__) && defined(__linux__) && defined(__GLIBC__)
#define SIMD_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define SIMD_CLONES
#endif

/* The far ends of a block's segments gathered side by side (one array per coordinate), so that
   the test below runs on whole SIMD registers: GCC does not vectorise gathers for generic x86
   tuning, and a gather per lane cost as much as the scalar loop. */
typedef struct {
    double x[BLOCK], y[BLOCK], z[BLOCK], n[BLOCK];
} ends_t;

/* The flags of the segments from ua to the far ends e (q < len): whether each passes within
   reach. Identical in every clone: -ffp-contract=off keeps FMA out (setup.py). */
SIMD_CLONES
static void flags_test(const ends_t *e, int len, const double *ua, double reach2, unsigned char *flag)
{
    const double ax = ua[0], ay = ua[1], az = ua[2], na = ua[3], slack = na - reach2;
    const int na_in = na <= reach2;
    for (int q = 0; q < len; ++q) {
        const double g = ax * e->x[q] + ay * e->y[q] + az * e->z[q], nb = e->n[q];
        const double uv = g - na, vv = na + nb - 2.0 * g;
        /* Closest point at t = -uv / vv clipped to [0, 1]: at a (t = 0), q = |u_a|^2; at b
           (t = 1), q = |u_b|^2; inside, q = |u_a|^2 - uv^2 / vv, compared as
           (|u_a|^2 - reach^2) vv <= uv^2 (no division). Each case's compare is made
           and the right one picked by masks, not branches. */
        const int at_a = -uv <= 0.0, at_b = -uv >= vv;
        const int inside = !(at_a | at_b);
        flag[q] = (unsigned char)((at_a & na_in) | ((!at_a) & at_b & (nb <= reach2)) |
                                  (inside & (slack * vv <= uv * uv)));
    }
}

/* The flags of segments ua -> u[ix[q]], q < len (flags_test, their far ends gathered into e);
   nonzero if an index is out of range. */
static int flags_near(const double *u, Py_ssize_t n, const int32_t *ix, int len, const double *ua, double reach2,
                      ends_t *e, unsigned char *flag)
{
    int bad = 0;
    for (int q = 0; q < len; ++q) {
        const int32_t ib = ix[q];
        const int ok = ib >= 0 && ib < n;
        bad |= !ok;
        const double *ub = u + TEST * (ok ? ib : 0);
        e->x[q] = ub[0], e->y[q] = ub[1], e->z[q] = ub[2], e->n[q] = ub[3];
    }
    flags_test(e, len, ua, reach2, flag);
    return bad;
}

/* The places q < len of the set flags (each 0 or 1), in order, into near; returns their count.
   Eight flags a word, a set one found from its lowest bit on a little-endian machine (a byte
   loop elsewhere): a branch per flag on 5-15% set mispredicted, and was a fifth of the pass. */
static int near_list(const unsigned char *flag, int len, int *near)
{
    int count = 0, q = 0;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    for (; q + 8 <= len; q += 8) {
        uint64_t w;
        memcpy(&w, flag + q, 8);
        for (; w; w &= w - 1) near[count++] = q + (__builtin_ctzll(w) >> 3);
    }
#endif
    for (; q < len; ++q)
        if (flag[q]) near[count++] = q;
    return count;
}

/* 0, -1 for an index out of range, -2 out of memory. */
static int near_sphere(const double *P, Py_ssize_t n, const int64_t *starts, const int64_t *ends, const int32_t *indices,
                       const int64_t *owners, Py_ssize_t rows, Py_ssize_t m, const double c[3], double reach2,
                       const double *box, const double *planes, int n_planes, kept_t *out)
{
    /* Once per point, not per segment. */
    size_t np = (size_t)(n > 0 ? n : 1);
    double *u = malloc(np * TEST * sizeof(double)), *obj = malloc(np * 3 * sizeof(double));
    if (!u || !obj) {
        free(u), free(obj);
        return -2;
    }
    int status = 0;
    for (Py_ssize_t i = 0; i < n; ++i) {
        const double *p = P + 3 * i;
        double *w = u + TEST * i;
        double x = p[0] - c[0], y = p[1] - c[1], z = p[2] - c[2];
        w[0] = x, w[1] = y, w[2] = z, w[3] = x * x + y * y + z * z;
        for (int k = 0; k < 3; ++k)
            obj[3 * i + k] = box ? box[3 * k] * p[0] + box[3 * k + 1] * p[1] + box[3 * k + 2] * p[2] + box[9 + k] : p[k];
    }
    unsigned char flag[BLOCK];
    int near[BLOCK];
    ends_t far_ends;
    for (Py_ssize_t k = 0; k < rows && !status; ++k) {
        int64_t ia = owners[k], lo = starts[k], hi = ends[k];
        if (lo < 0 || hi < lo || hi > m || ia >= n) { status = -1; break; }
        if (ia < 0) continue;
        const double *ua = u + TEST * ia;
        for (int64_t j0 = lo; j0 < hi && !status; j0 += BLOCK) {
            const int len = (int)(hi - j0 < BLOCK ? hi - j0 : BLOCK);
            const int32_t *ix = indices + j0;
            if (flags_near(u, n, ix, len, ua, reach2, &far_ends, flag)) { status = -1; break; }
            const int n_near = near_list(flag, len, near);
            for (int t = 0; t < n_near; ++t) {
                const int q = near[t];
                const double *oa = obj + 3 * ia, *ob = obj + 3 * ix[q];
                if (box && !crosses_box(oa, ob, box + 12, box + 15)) continue;
                if (n_planes && !crosses_solid(oa, ob, planes, n_planes)) continue;
                if (keep(out, j0 + q, oa, ob)) {
                    status = -2;
                    break;
                }
            }
        }
    }
    free(u);
    free(obj);
    return status;
}

static PyObject *py_near_sphere(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer P, st, en, ix, ow;
    double c[3], reach, box[18], planes[4 * MAX_PLANES];
    PyObject *box_obj, *planes_obj = Py_None;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*(ddd)dO|O", &P, &st, &en, &ix, &ow, &c[0], &c[1], &c[2], &reach, &box_obj,
                          &planes_obj))
        return NULL;
    PyObject *result = NULL;
    kept_t out = {NULL, NULL, 0, 0, 1};
    int have_box = box_obj != Py_None, n_planes = 0;
    if (planes_obj != Py_None) {
        PyObject *seq = PySequence_Fast(planes_obj, "near_sphere: planes must be None or 4 k floats");
        if (!seq) goto done;
        Py_ssize_t len = PySequence_Fast_GET_SIZE(seq);
        int bad = !have_box || len < 4 || len % 4 || len > 4 * MAX_PLANES;
        for (Py_ssize_t k = 0; k < len && !bad; ++k) {
            planes[k] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, k));
            bad = (planes[k] == -1.0 && PyErr_Occurred()) || !isfinite(planes[k]);
        }
        Py_DECREF(seq);
        if (bad) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "near_sphere: planes must be 4 k finite floats (1 <= k <= 64), "
                                                  "with a box");
            goto done;
        }
        n_planes = (int)(len / 4);
        out.rays = 0;
    }
    if (have_box) {
        PyObject *seq = PySequence_Fast(box_obj, "near_sphere: box must be None or 18 floats");
        if (!seq) goto done;
        int bad = PySequence_Fast_GET_SIZE(seq) != 18;
        for (int k = 0; k < 18 && !bad; ++k) {
            box[k] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, k));
            bad = box[k] == -1.0 && PyErr_Occurred();
        }
        Py_DECREF(seq);
        if (bad) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "near_sphere: box must be None or 18 floats");
            goto done;
        }
    }
    Py_ssize_t n = P.len / (Py_ssize_t)(3 * sizeof(double)), m = ix.len / (Py_ssize_t)sizeof(int32_t);
    Py_ssize_t rows = ow.len / (Py_ssize_t)sizeof(int64_t);
    if (P.len != n * 3 * (Py_ssize_t)sizeof(double) || ix.len != m * (Py_ssize_t)sizeof(int32_t) ||
        ow.len != rows * (Py_ssize_t)sizeof(int64_t) || st.len != rows * (Py_ssize_t)sizeof(int64_t) ||
        en.len != rows * (Py_ssize_t)sizeof(int64_t)) {
        PyErr_SetString(PyExc_ValueError, "near_sphere needs n*3 float64 points, int64 starts, ends and owners (r each) "
                                          "and int32 indices");
        goto done;
    }
    int status;
    Py_BEGIN_ALLOW_THREADS
    status = near_sphere((const double *)P.buf, n, (const int64_t *)st.buf, (const int64_t *)en.buf, (const int32_t *)ix.buf,
                         (const int64_t *)ow.buf, rows, m, c, reach * reach, have_box ? box : NULL, planes, n_planes,
                         &out);
    Py_END_ALLOW_THREADS
    if (status == -2)
        PyErr_NoMemory();
    else if (status < 0)
        PyErr_SetString(PyExc_ValueError, "near_sphere: a point index or a row's span is out of range");
    else
        result = Py_BuildValue("(y#y#)", out.count ? (const char *)out.seg : "", out.count * (Py_ssize_t)sizeof(int64_t),
                               out.rays && out.count ? (const char *)out.ray : "",
                               (out.rays ? out.count : 0) * 6 * (Py_ssize_t)sizeof(double));
done:
    free(out.seg);
    free(out.ray);
    PyBuffer_Release(&P);
    PyBuffer_Release(&st);
    PyBuffer_Release(&en);
    PyBuffer_Release(&ix);
    PyBuffer_Release(&ow);
    return result;
}

static PyMethodDef methods[] = {
    {"near_sphere", py_near_sphere, METH_VARARGS,
     "near_sphere(points, starts, ends, indices, owners, center, reach, box[, planes]) -> (segments, rays): row spans' segments passing within reach of center (and crossing box, and the solid of planes), and their rays"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_segments",
                                    "Segments between points passing near a sphere (native).", -1, methods};

PyMODINIT_FUNC PyInit__segments(void) { return PyModule_Create(&module); }
