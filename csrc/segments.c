/*
 * Segments between points that pass near a sphere: the pre-test of a move's occlusion rows
 * (pydynrad/dynamic/moves.py, hidden_between; docs/design.md, 'Moving objects').
 *
 * Host-side by design: a move tests every entry of the ~900 rows that may see the object
 * (~400k segments between patch centres on the bench's Cornell box) and traces only the few
 * that pass within the object's bounding sphere. numpy did the test in ~15 passes over
 * float64 temporaries and gathers (~8 ms on the loaded 2-core EPYC, the largest single cost of
 * a corrected move); here it is one pass:
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
 * numpy ~3 ms of gathers and small matrix products, here they are a copy of what the slab
 * test computed anyway.
 *
 * Rows are read where they lie: row k is the span starts[k] <= j < ends[k] of the indices (the
 * rows of F that a move tests, picked out of the whole F by their patches without a copy: the
 * copy and an int64 version of the indices were 1.7 ms of a 3.8 ms pre-test at 426k entries).
 *
 * Python signature:  _segments.near_sphere(points, starts, ends, indices, owners, center, reach, box) -> (segments, rays)
 *   points  : C-contiguous float64 buffer of n*3 values
 *   starts, ends : int64 buffers of r values: row k's segments are the j in [starts[k], ends[k])
 *   indices : int32 buffer of m point indices (scipy's CSR indices): segment j of row k goes
 *             from point owners[k] to point indices[j]
 *   owners  : int64 buffer of r values, a point index per row, or -1 to skip the row
 *   center  : (cx, cy, cz) floats; reach : float, the sphere's radius with any margin
 *   box     : None, or 18 floats: the world-to-object map x -> A x + t (A row-major, then t),
 *             then the box's low and high corners in object space (any margin included);
 *             None: no box test, and the rays are in world space
 *   segments: bytes of int64, row by row in the order given: the segments j with q <= reach^2
 *             (and crossing the box)
 *   rays    : bytes of float64, 6 per segment kept: its ray's origin and direction
 *   Indices are checked (0 <= i < n, 0 <= starts[k] <= ends[k] <= m): ValueError if not.
 * A list of segments a[i] -> b[i] is one entry per row (starts = 0..m-1, ends = 1..m, owners = a).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>

/* Whether the segment a -> b (object space) meets the box [lo, hi]: the slab test over t in [0, 1]. */
static int crosses_box(const double *a, const double *b, const double *lo, const double *hi)
{
    double t0 = 0.0, t1 = 1.0;
    for (int k = 0; k < 3; ++k) {
        double d = b[k] - a[k];
        if (d == 0.0) {
            if (a[k] < lo[k] || a[k] > hi[k]) return 0;
            continue;
        }
        const double inv = 1.0 / d; /* one division per axis, not two */
        double ta = (lo[k] - a[k]) * inv, tb = (hi[k] - a[k]) * inv;
        if (ta > tb) { double s = ta; ta = tb; tb = s; }
        if (ta > t0) t0 = ta;
        if (tb < t1) t1 = tb;
        if (t0 > t1) return 0;
    }
    return 1;
}

#define STRIDE 7 /* per point: u = p - c, |u|^2, and the point in object space */

/* Output that grows as segments are kept: a move keeps ~30k of ~500k, so sizing it for every
   segment would fault in ~27 MB per call for nothing. */
typedef struct {
    int64_t *seg;
    double *ray;
    Py_ssize_t count, cap;
} kept_t;

static int keep(kept_t *k, int64_t j, const double *a, const double *b)
{
    if (k->count == k->cap) {
        Py_ssize_t cap = k->cap ? 2 * k->cap : 4096;
        int64_t *seg = realloc(k->seg, (size_t)cap * sizeof(int64_t));
        if (seg) k->seg = seg;
        double *ray = seg ? realloc(k->ray, (size_t)cap * 6 * sizeof(double)) : NULL;
        if (!ray) return -1;
        k->ray = ray, k->cap = cap;
    }
    double *r = k->ray + 6 * k->count;
    for (int q = 0; q < 3; ++q) r[q] = a[q], r[3 + q] = b[q] - a[q];
    k->seg[k->count++] = j;
    return 0;
}

/* 0, -1 for an index out of range, -2 out of memory. */
static int near_sphere(const double *P, Py_ssize_t n, const int64_t *starts, const int64_t *ends, const int32_t *indices,
                       const int64_t *owners, Py_ssize_t rows, Py_ssize_t m, const double c[3], double reach2,
                       const double *box, kept_t *out)
{
    /* Once per point, not per segment. */
    double *u = malloc((size_t)(n > 0 ? n : 1) * STRIDE * sizeof(double));
    if (!u) return -2;
    int status = 0;
    for (Py_ssize_t i = 0; i < n; ++i) {
        const double *p = P + 3 * i;
        double *w = u + STRIDE * i;
        double x = p[0] - c[0], y = p[1] - c[1], z = p[2] - c[2];
        w[0] = x, w[1] = y, w[2] = z, w[3] = x * x + y * y + z * z;
        for (int k = 0; k < 3; ++k)
            w[4 + k] = box ? box[3 * k] * p[0] + box[3 * k + 1] * p[1] + box[3 * k + 2] * p[2] + box[9 + k] : p[k];
    }
    for (Py_ssize_t k = 0; k < rows && !status; ++k) {
        int64_t ia = owners[k], lo = starts[k], hi = ends[k];
        if (lo < 0 || hi < lo || hi > m || ia >= n) { status = -1; break; }
        if (ia < 0) continue;
        const double *ua = u + STRIDE * ia;
        double na = ua[3];
        for (int64_t j = lo; j < hi; ++j) {
            int32_t ib = indices[j];
            if (ib < 0 || ib >= n) { status = -1; break; }
            const double *ub = u + STRIDE * ib;
            double g = ua[0] * ub[0] + ua[1] * ub[1] + ua[2] * ub[2];
            double uv = g - na, vv = na + ub[3] - 2.0 * g;
            /* Closest point at t = -uv / vv clipped to [0, 1]; inside, q = |u_a|^2 - uv^2 / vv,
               compared as (|u_a|^2 - reach^2) vv <= uv^2 (no division, ~2x faster). */
            int near = -uv <= 0.0 ? na <= reach2 : (-uv >= vv ? ub[3] <= reach2 : (na - reach2) * vv <= uv * uv);
            if (near && (!box || crosses_box(ua + 4, ub + 4, box + 12, box + 15)) && keep(out, j, ua + 4, ub + 4)) {
                status = -2;
                break;
            }
        }
    }
    free(u);
    return status;
}

static PyObject *py_near_sphere(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer P, st, en, ix, ow;
    double c[3], reach, box[18];
    PyObject *box_obj;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*(ddd)dO", &P, &st, &en, &ix, &ow, &c[0], &c[1], &c[2], &reach, &box_obj))
        return NULL;
    PyObject *result = NULL;
    kept_t out = {NULL, NULL, 0, 0};
    int have_box = box_obj != Py_None;
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
                         (const int64_t *)ow.buf, rows, m, c, reach * reach, have_box ? box : NULL, &out);
    Py_END_ALLOW_THREADS
    if (status == -2)
        PyErr_NoMemory();
    else if (status < 0)
        PyErr_SetString(PyExc_ValueError, "near_sphere: a point index or a row's span is out of range");
    else
        result = Py_BuildValue("(y#y#)", out.count ? (const char *)out.seg : "", out.count * (Py_ssize_t)sizeof(int64_t),
                               out.count ? (const char *)out.ray : "", out.count * 6 * (Py_ssize_t)sizeof(double));
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
     "near_sphere(points, starts, ends, indices, owners, center, reach, box) -> (segments, rays): row spans' segments passing within reach of center (and crossing box), and their rays"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_segments",
                                    "Segments between points passing near a sphere (native).", -1, methods};

PyMODINIT_FUNC PyInit__segments(void) { return PyModule_Create(&module); }
