/*
 * Rays checked and moved into a scene's device frame, in one pass (pydynrad/geometry/bvh.py, _rays).
 *
 * Host-side by design: the rays come from the user as (n, 3) float32 or float64 arrays, and the
 * kernels read float32 in the scene's DeviceFrame, x_device = (x - origin) / unit. numpy did this
 * in a dozen passes over float64 temporaries (as long as tracing the rays; here a fraction of
 * it); each ray is converted and checked once, with the same arithmetic:
 * positions (double)x - origin, then / unit, then rounded to float; directions (double)x / unit,
 * rounded; without a frame, only rounded. The result is numpy's bit for bit (the unit is a power
 * of two, so dividing by it is multiplying by its exact reciprocal).
 *
 * Python signature:  _raybatch.prepare(origins, directions, tmax, frame, out_o, out_d, out_t) -> (code, ray)
 *   origins, directions : C-contiguous buffers of n*3 float32 or float64 values (format "f"/"d")
 *   tmax   : C-contiguous float32 buffer of n values, or of 1 value for every ray
 *   frame  : None, or (origin_x, origin_y, origin_z, unit), unit a power of two (DeviceFrame's)
 *   out_o, out_d : writable float32 buffers of n*3 values; out_t: of n values
 *   returns (code, ray): (0, -1) when every ray is fine; else the first of the problems found, in
 *   this order, and the first ray that has it: 1 a non-finite origin or direction (as device
 *   floats), 2 a zero direction, 3 tmax not > 0 (the order numpy's checks took).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <string.h>

#define PREPARE(NAME, T)                                                                                      \
    static void NAME(const T *o, const T *d, const float *tmax, Py_ssize_t tmax_step, Py_ssize_t n,         \
                     const double *frame, float *oo, float *od, float *ot, Py_ssize_t *first)                \
    {                                                                                                       \
        for (Py_ssize_t i = 0; i < n; ++i) {                                                                \
            float p[3], q[3];                                                                               \
            for (int a = 0; a < 3; ++a) {                                                                   \
                if (frame) {                                                                                \
                    p[a] = (float)(((double)o[3 * i + a] - frame[a]) * frame[3]);                           \
                    q[a] = (float)((double)d[3 * i + a] * frame[3]);                                        \
                } else {                                                                                    \
                    p[a] = (float)o[3 * i + a];                                                             \
                    q[a] = (float)d[3 * i + a];                                                             \
                }                                                                                           \
                oo[3 * i + a] = p[a];                                                                       \
                od[3 * i + a] = q[a];                                                                       \
            }                                                                                               \
            float t = tmax[i * tmax_step];                                                                  \
            ot[i] = t;                                                                                      \
            int bad = 0;                                                                                    \
            for (int a = 0; a < 3; ++a) bad |= !isfinite(p[a]) || !isfinite(q[a]);                         \
            if (bad && first[0] < 0) first[0] = i;                                                          \
            if (q[0] == 0.0f && q[1] == 0.0f && q[2] == 0.0f && first[1] < 0) first[1] = i;                 \
            if (!(t > 0.0f) && first[2] < 0) first[2] = i;                                                  \
        }                                                                                                   \
    }

PREPARE(prepare_f, float)
PREPARE(prepare_d, double)

static PyObject *py_prepare(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer o, d, t, oo, od, ot;
    PyObject *frame_obj;
    if (!PyArg_ParseTuple(args, "y*y*y*Ow*w*w*", &o, &d, &t, &frame_obj, &oo, &od, &ot)) return NULL;
    PyObject *result = NULL;
    double frame[4];
    int have_frame = frame_obj != Py_None;
    if (have_frame && !PyArg_ParseTuple(frame_obj, "dddd", &frame[0], &frame[1], &frame[2], &frame[3])) goto done;
    int exponent;
    if (have_frame && !(frexp(frame[3], &exponent) == 0.5 && exponent > -1020 && exponent < 1020)) {
        PyErr_SetString(PyExc_ValueError, "the frame's unit must be a power of two");
        goto done;
    }
    /* x / 2^k and x * 2^-k are the same number rounded the same way: one multiply, no divide. */
    if (have_frame) frame[3] = 1.0 / frame[3];
    /* y* gives bytes without a format: the element size comes from the output size. */
    Py_ssize_t n = ot.len / (Py_ssize_t)sizeof(float);
    Py_ssize_t item = n > 0 ? o.len / (3 * n) : 4;
    if ((item != 4 && item != 8) || o.len != 3 * n * item || d.len != o.len || oo.len != 3 * n * (Py_ssize_t)sizeof(float) ||
        od.len != oo.len || (t.len != ot.len && t.len != (Py_ssize_t)sizeof(float))) {
        PyErr_SetString(PyExc_ValueError, "prepare needs n*3 float32 or float64 origins and directions, n or 1 float32 "
                                          "tmax, and float32 outputs of n*3, n*3 and n values");
        goto done;
    }
    Py_ssize_t first[3] = {-1, -1, -1}, step = t.len == ot.len ? 1 : 0;
    Py_BEGIN_ALLOW_THREADS
    if (item == 4)
        prepare_f((const float *)o.buf, (const float *)d.buf, (const float *)t.buf, step, n, have_frame ? frame : NULL,
                  (float *)oo.buf, (float *)od.buf, (float *)ot.buf, first);
    else
        prepare_d((const double *)o.buf, (const double *)d.buf, (const float *)t.buf, step, n, have_frame ? frame : NULL,
                  (float *)oo.buf, (float *)od.buf, (float *)ot.buf, first);
    Py_END_ALLOW_THREADS
    int code = 0;
    while (code < 3 && first[code] < 0) ++code;
    result = code < 3 ? Py_BuildValue("in", code + 1, first[code]) : Py_BuildValue("in", 0, (Py_ssize_t)-1);
done:
    PyBuffer_Release(&o);
    PyBuffer_Release(&d);
    PyBuffer_Release(&t);
    PyBuffer_Release(&oo);
    PyBuffer_Release(&od);
    PyBuffer_Release(&ot);
    return result;
}

static PyMethodDef methods[] = {
    {"prepare", py_prepare, METH_VARARGS,
     "prepare(origins, directions, tmax, frame, out_o, out_d, out_t) -> (code, ray): rays checked and moved into the device frame"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_raybatch", "Ray batches checked and moved into the device frame (native).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__raybatch(void) { return PyModule_Create(&module); }
