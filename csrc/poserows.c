/*
 * A static patch's row of F at the objects' current poses, from its row of the static F, in one
 * pass (pydynrad/dynamic/moves.py, at_pose; docs/design.md, 'Moving objects').
 *
 * Per row: the entries the objects hide are dropped, the objects' columns (by reciprocity,
 * computed by the caller) are appended, and where the row then sums above 1 its static entries
 * are scaled so that it sums to 1 (the object columns kept as they are, the scale clipped at 0);
 * where the object columns alone sum above 1 (reciprocity from large object patches on small
 * static ones, hemicube error included: 1.8 and more were seen), the static entries go and the
 * object columns are scaled to sum to 1, so no row ever sums above 1.
 * scipy did this in five passes that each copied the ~500k entries of a move's rows on the
 * bench's Cornell box (a mask copy, eliminate_zeros, a sum of two CSR matrices, the capping's
 * copy and a second eliminate_zeros: ~15 ms on the 2-core EPYC); here it is one read and one
 * write of each entry.
 *
 * The second pass, difference(), is D = current - kept for the rows a move leaves stale in K
 * (pydynrad/dynamic/stale.py): a merge of each current row with its kept row, read in place
 * (scipy sliced the kept rows out first, then subtracted: 5.8-6.8 ms for the ~850k entries of a
 * move's 958 stale rows on the bench's Cornell box, against 4.4-4.7 ms here; PoCL host, 2-core
 * Xeon, 2026-12-02). The merge's branches bound it, not memory: so each step writes its entry
 * and advances the output only where it is non-zero (most are zero: a stale row equals its
 * kept row but where an object hides or shows), and the order checks run without an early
 * exit, which vectorizes (medians 1.80-1.92 -> 1.58-1.73 ms for the ~850k entries of a move
 * there, one thread, 2026-12-03).
 *
 * Column indices are int32 (scipy's own for fewer than 2^31 columns), row pointers int64. The
 * rows read are spans of a CSR matrix's entries, starts[k] <= j < ends[k] for row k, so that
 * rows picked out of a larger matrix (a move's candidates out of the whole static F) are read
 * where they lie, with no copy; the rows written are a CSR matrix of their own.
 *
 * Python signatures:
 *   _poserows.assemble(starts, ends, indices, data, hidden, r_indptr, r_indices, r_data,
 *                      out_indptr, out_indices, out_data) -> nnz
 *   starts, ends : int64 of r: the static rows' spans of indices (int32) and data (float64), of
 *             m entries each; every column below every object column, entries in increasing
 *             column order
 *   hidden  : uint8 of m: non-zero where the entry is hidden
 *   r_indptr, r_indices, r_data : the object columns of the same r rows (CSR, final column
 *             numbers, increasing within a row)
 *   out_indptr : writable int64 of r + 1; out_indices, out_data : writable int32 and float64
 *             of at least the rows' entries + len(r_indices) values; receive the rows, zeros
 *             dropped
 *   Returns the entries written.
 *
 *   _poserows.difference(starts, ends, indices, data, k_indptr, k_indices, k_data, slots,
 *                        out_indptr, out_indices, out_data) -> nnz
 *   starts, ends, indices, data : r rows as spans (as for assemble), each with increasing columns
 *   k_indptr, k_indices, k_data : M rows (CSR), likewise; slots : int64 of r, each in [0, M)
 *   out_* : as for assemble, of at least the rows' entries + the entries of the kept rows named
 *   Row i of the output is row i minus kept row slots[i], exact zeros dropped. Returns the
 *   entries written, or -1 - i where row i (of either input) has columns out of order.
 *
 * Array lengths, spans, indptr ranges and slots are checked: ValueError.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>

static int bad_indptr(const int64_t *p, Py_ssize_t rows, Py_ssize_t m)
{
    if (p[0] != 0 || p[rows] != m) return 1;
    for (Py_ssize_t k = 0; k < rows; ++k)
        if (p[k + 1] < p[k]) return 1;
    return 0;
}

/* Whether every span lies in [0, m). */
static int bad_spans(const int64_t *starts, const int64_t *ends, Py_ssize_t rows, Py_ssize_t m)
{
    for (Py_ssize_t k = 0; k < rows; ++k)
        if (starts[k] < 0 || ends[k] < starts[k] || ends[k] > m) return 1;
    return 0;
}

static Py_ssize_t span_entries(const int64_t *starts, const int64_t *ends, Py_ssize_t rows)
{
    Py_ssize_t n = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) n += ends[k] - starts[k];
    return n;
}

static Py_ssize_t assemble(Py_ssize_t rows, const int64_t *is, const int64_t *ie, const int32_t *ix, const double *x,
                           const uint8_t *hidden, const int64_t *rp, const int32_t *rx, const double *rv, int64_t *op,
                           int32_t *ox, double *ov)
{
    Py_ssize_t n = 0;
    op[0] = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) {
        Py_ssize_t start = n;
        double kept = 0.0, objects = 0.0;
        for (int64_t j = is[k]; j < ie[k]; ++j)
            if (!hidden[j] && x[j] != 0.0) {
                kept += x[j];
                ox[n] = ix[j], ov[n++] = x[j];
            }
        for (int64_t j = rp[k]; j < rp[k + 1]; ++j) objects += rv[j];
        const double g = objects > 1.0 ? 1.0 / objects : 1.0;
        if (kept > 0.0 && kept + objects > 1.0) {
            double f = objects < 1.0 ? (1.0 - objects) / kept : 0.0;
            Py_ssize_t w = start;
            for (Py_ssize_t j = start; j < n; ++j) {
                double v = ov[j] * f;
                if (v != 0.0) ox[w] = ox[j], ov[w++] = v;
            }
            n = w;
        }
        for (int64_t j = rp[k]; j < rp[k + 1]; ++j)
            if (rv[j] != 0.0) ox[n] = rx[j], ov[n++] = rv[j] * g;
        op[k + 1] = n;
    }
    return n;
}

static int increasing(const int32_t *x, int64_t start, int64_t end)
{
    int ok = 1;  /* no early exit: the loop vectorizes, and rows in order are the rule */
    for (int64_t t = start + 1; t < end; ++t) ok &= x[t] > x[t - 1];
    return ok;
}

static Py_ssize_t difference(Py_ssize_t rows, const int64_t *as, const int64_t *ae, const int32_t *ax, const double *av,
                             const int64_t *bp, const int32_t *bx, const double *bv, const int64_t *slots, int64_t *op,
                             int32_t *ox, double *ov)
{
    Py_ssize_t n = 0;
    op[0] = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) {
        int64_t i = as[k], ie = ae[k], j = bp[slots[k]], je = bp[slots[k] + 1];
        if (!increasing(ax, i, ie) || !increasing(bx, j, je)) return -1 - k;
        while (i < ie && j < je) {
            const int32_t a = ax[i], c = bx[j];
            double v;
            if (a == c)
                v = av[i++] - bv[j++];
            else if (a < c)
                v = av[i++];
            else
                v = -bv[j++];
            ox[n] = a < c ? a : c, ov[n] = v;
            n += v != 0.0;
        }
        for (; i < ie; ++i) ox[n] = ax[i], ov[n] = av[i], n += av[i] != 0.0;
        for (; j < je; ++j) ox[n] = bx[j], ov[n] = -bv[j], n += bv[j] != 0.0;
        op[k + 1] = n;
    }
    return n;
}

/* Both passes take eleven buffers: eight read, three written. */
#define BUFFERS 11
enum { P = sizeof(int64_t), I = sizeof(int32_t), D = sizeof(double) };

static PyObject *with_buffers(PyObject *args, PyObject *(*pass)(Py_buffer *b))
{
    Py_buffer b[BUFFERS];
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*w*w*w*", &b[0], &b[1], &b[2], &b[3], &b[4], &b[5], &b[6], &b[7], &b[8],
                          &b[9], &b[10]))
        return NULL;
    PyObject *result = pass(b);
    for (int k = 0; k < BUFFERS; ++k) PyBuffer_Release(&b[k]);
    return result;
}

static PyObject *assemble_buffers(Py_buffer *b)
{
    Py_ssize_t rows = b[0].len / P, m = b[2].len / I, mr = b[6].len / I;
    if (b[0].len != rows * P || b[1].len != rows * P || b[2].len != m * I || b[3].len != m * D || b[4].len != m ||
        b[5].len != (rows + 1) * P || b[6].len != mr * I || b[7].len != mr * D || b[8].len != (rows + 1) * P) {
        PyErr_SetString(PyExc_ValueError, "assemble needs row spans (int64 starts and ends of r) of int32 indices and "
                                          "float64 data, a uint8 mask per entry, CSR object columns of the same r rows, "
                                          "and an output indptr of r + 1");
        return NULL;
    }
    if (bad_spans(b[0].buf, b[1].buf, rows, m) || bad_indptr(b[5].buf, rows, mr)) {
        PyErr_SetString(PyExc_ValueError, "assemble: a row's span lies outside the entries, or an indptr does not run "
                                          "from 0 to its entries without decreasing");
        return NULL;
    }
    const Py_ssize_t most = span_entries(b[0].buf, b[1].buf, rows) + mr;
    if (b[9].len < most * I || b[10].len < most * D) {
        PyErr_Format(PyExc_ValueError, "assemble: the outputs hold fewer than the %zd entries the rows may have", most);
        return NULL;
    }
    Py_ssize_t n;
    Py_BEGIN_ALLOW_THREADS
    n = assemble(rows, b[0].buf, b[1].buf, b[2].buf, b[3].buf, b[4].buf, b[5].buf, b[6].buf, b[7].buf, b[8].buf,
                 b[9].buf, b[10].buf);
    Py_END_ALLOW_THREADS
    return PyLong_FromSsize_t(n);
}

static PyObject *difference_buffers(Py_buffer *b)
{
    Py_ssize_t rows = b[0].len / P, m = b[2].len / I, kr = b[4].len / P - 1, km = b[5].len / I;
    if (kr < 0 || b[0].len != rows * P || b[1].len != rows * P || b[2].len != m * I || b[3].len != m * D ||
        b[4].len != (kr + 1) * P || b[5].len != km * I || b[6].len != km * D || b[7].len != rows * P ||
        b[8].len != (rows + 1) * P) {
        PyErr_SetString(PyExc_ValueError, "difference needs row spans (int64 starts and ends of r) of int32 indices and "
                                          "float64 data, a CSR matrix (int64 indptr, int32 indices, float64 data), an "
                                          "int64 slot per row and an output indptr of r + 1");
        return NULL;
    }
    const int64_t *slots = b[7].buf, *kp = b[4].buf;
    if (bad_spans(b[0].buf, b[1].buf, rows, m) || bad_indptr(kp, kr, km)) {
        PyErr_SetString(PyExc_ValueError, "difference: a row's span lies outside the entries, or an indptr does not run "
                                          "from 0 to its entries without decreasing");
        return NULL;
    }
    Py_ssize_t most = span_entries(b[0].buf, b[1].buf, rows);
    for (Py_ssize_t k = 0; k < rows; ++k) {
        if (slots[k] < 0 || slots[k] >= kr) {
            PyErr_Format(PyExc_ValueError, "difference: slot %lld of row %zd is outside the %zd kept rows",
                         (long long)slots[k], k, kr);
            return NULL;
        }
        most += kp[slots[k] + 1] - kp[slots[k]];
    }
    if (b[9].len < most * I || b[10].len < most * D) {
        PyErr_Format(PyExc_ValueError, "difference: the outputs hold fewer than the %zd entries the rows may have", most);
        return NULL;
    }
    Py_ssize_t n;
    Py_BEGIN_ALLOW_THREADS
    n = difference(rows, b[0].buf, b[1].buf, b[2].buf, b[3].buf, kp, b[5].buf, b[6].buf, slots, b[8].buf, b[9].buf,
                   b[10].buf);
    Py_END_ALLOW_THREADS
    return PyLong_FromSsize_t(n);
}

static PyObject *py_assemble(PyObject *self, PyObject *args)
{
    (void)self;
    return with_buffers(args, assemble_buffers);
}

static PyObject *py_difference(PyObject *self, PyObject *args)
{
    (void)self;
    return with_buffers(args, difference_buffers);
}

static PyMethodDef methods[] = {
    {"assemble", py_assemble, METH_VARARGS,
     "assemble(starts, ends, indices, data, hidden, r_indptr, r_indices, r_data, out_indptr, out_indices, out_data) -> nnz: "
     "static rows without their hidden entries, with their object columns, capped to a sum of 1"},
    {"difference", py_difference, METH_VARARGS,
     "difference(starts, ends, indices, data, k_indptr, k_indices, k_data, slots, out_indptr, out_indices, out_data) -> nnz: "
     "each row minus kept row slots[i], zeros dropped (-1 - i: row i's columns out of order)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_poserows",
                                    "Rows of F at the objects' poses, and their change from the rows kept (native).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__poserows(void) { return PyModule_Create(&module); }
