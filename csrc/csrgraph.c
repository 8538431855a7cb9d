/*
 * Passes over a CSR matrix's structure that the far field's precompute makes of the full F
 * (pydynrad/csrgraph.py): its weakly connected components (patches that exchange no light
 * with each other, which no cluster may join) and its copy by column in float32 (the first
 * bounce's product over lit columns).
 *
 * scipy did both through a transpose of F: connected_components(connection="weak") adds F's
 * transpose to F, and csc_matrix(F, dtype=float32) transposes and then converts. On the 66k
 * village (35M entries) the two transposes took 1.7 of the far field's 2.6 s build (Intel Xeon,
 * PoCL host, 2026-12-03). Here the components come from a union-find over the entries (no
 * transpose), and the by-column copy is one counting pass and one scatter that writes float32.
 *
 * Python signatures:
 *   _csrgraph.weak_components(indptr, indices, labels) -> count
 *       indptr int64 (n + 1), indices int32 or int64 (n columns: the matrix is square);
 *       labels writable int64 (n): each node's component, numbered in the order of the
 *       components' smallest node (as scipy's connected_components numbers them).
 *   _csrgraph.to_columns(indptr, indices, data, n_cols, out_indptr, out_indices, out_data) -> None
 *       data float64; out_indptr writable int64 (n_cols + 1); out_indices writable int32
 *       (rows < 2^31); out_data writable float32, both of nnz. Row indices come out ascending
 *       within each column.
 *   Lengths and indices are checked: ValueError.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>

static int64_t find(int64_t *parent, int64_t a)
{
    while (parent[a] != a) {
        parent[a] = parent[parent[a]]; /* path halving */
        a = parent[a];
    }
    return a;
}

/* A CSR structure's rows, entries and index size from its int64 indptr and its indices:
 * 1 where indptr starts at 0, does not decrease and ends at nnz, and the indices are nnz
 * int32 or int64 values; else 0. */
static int csr_structure(const Py_buffer *ip, const Py_buffer *ix, Py_ssize_t *n_rows, int64_t *nnz, Py_ssize_t *isz)
{
    const Py_ssize_t I = (Py_ssize_t)sizeof(int64_t);
    const int64_t *p = ip->buf;
    Py_ssize_t n = ip->len / I - 1;
    if (n < 0 || ip->len != (n + 1) * I || p[0] != 0) return 0;
    for (Py_ssize_t i = 0; i < n; ++i)
        if (p[i + 1] < p[i]) return 0;
    *n_rows = n, *nnz = p[n], *isz = p[n] > 0 ? ix->len / p[n] : 4;
    return (*isz == 4 || *isz == 8) && ix->len == *nnz * *isz;
}

#define UNITE(NAME, ITYPE)                                                                                             \
    static int NAME(const int64_t *ip, const ITYPE *ix, Py_ssize_t n, int64_t *parent)                                \
    {                                                                                                                  \
        for (Py_ssize_t i = 0; i < n; ++i) {                                                                           \
            for (int64_t j = ip[i]; j < ip[i + 1]; ++j) {                                                              \
                int64_t c = (int64_t)ix[j];                                                                            \
                if (c < 0 || c >= n) return -1;                                                                        \
                int64_t a = find(parent, (int64_t)i), b = find(parent, c);                                             \
                if (a != b) parent[a > b ? a : b] = a < b ? a : b; /* the smaller node is the root */                  \
            }                                                                                                          \
        }                                                                                                              \
        return 0;                                                                                                      \
    }

UNITE(unite_i32, int32_t)
UNITE(unite_i64, int64_t)

static PyObject *py_weak_components(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer ip, ix, out;
    if (!PyArg_ParseTuple(args, "y*y*w*", &ip, &ix, &out)) return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = 0, isz = 0;
    int64_t nnz = 0;
    int ok = csr_structure(&ip, &ix, &n, &nnz, &isz) && out.len == n * (Py_ssize_t)sizeof(int64_t);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "weak_components needs a square CSR structure (int64 indptr from 0, "
                                          "non-decreasing, ending at nnz; int32/int64 indices) and int64 labels of "
                                          "its rows");
        goto done;
    }
    int64_t *parent = out.buf, count = 0;
    int status = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; ++i) parent[i] = i;
    status = isz == 4 ? unite_i32(ip.buf, ix.buf, n, parent) : unite_i64(ip.buf, ix.buf, n, parent);
    if (!status) {
        /* Every parent is at most its node (a union hangs the larger root under the smaller,
         * path halving only shortens chains), so the roots are each component's smallest
         * node and one pass in node order resolves every node to its root. A second pass
         * numbers the roots in that order, as scipy numbers components; a later node reads
         * its label from its root's entry, which by then holds it. */
        for (Py_ssize_t i = 0; i < n; ++i) parent[i] = parent[parent[i]];
        for (Py_ssize_t i = 0; i < n; ++i) parent[i] = parent[i] == (int64_t)i ? count++ : parent[parent[i]];
    }
    Py_END_ALLOW_THREADS
    if (status) {
        PyErr_SetString(PyExc_ValueError, "weak_components: a column index is out of range");
        goto done;
    }
    result = PyLong_FromLongLong((long long)count);
done:
    PyBuffer_Release(&ip);
    PyBuffer_Release(&ix);
    PyBuffer_Release(&out);
    return result;
}

#define SCATTER(NAME, ITYPE)                                                                                           \
    static int NAME(const int64_t *ip, const ITYPE *ix, const double *v, Py_ssize_t n_rows, Py_ssize_t n_cols,        \
                    int64_t *op, int32_t *ox, float *ov)                                                               \
    {                                                                                                                  \
        int64_t nnz = ip[n_rows];                                                                                      \
        for (Py_ssize_t c = 0; c <= n_cols; ++c) op[c] = 0;                                                            \
        for (int64_t j = 0; j < nnz; ++j) {                                                                            \
            int64_t c = (int64_t)ix[j];                                                                                \
            if (c < 0 || c >= n_cols) return -1;                                                                       \
            ++op[c + 1];                                                                                               \
        }                                                                                                              \
        for (Py_ssize_t c = 0; c < n_cols; ++c) op[c + 1] += op[c];                                                    \
        /* op[c] is column c's next free place while scattering; shifted back after. */                              \
        for (Py_ssize_t r = 0; r < n_rows; ++r) {                                                                      \
            for (int64_t j = ip[r]; j < ip[r + 1]; ++j) {                                                              \
                int64_t at = op[ix[j]]++;                                                                              \
                ox[at] = (int32_t)r;                                                                                   \
                ov[at] = (float)v[j];                                                                                  \
            }                                                                                                          \
        }                                                                                                              \
        for (Py_ssize_t c = n_cols; c > 0; --c) op[c] = op[c - 1];                                                     \
        op[0] = 0;                                                                                                     \
        return 0;                                                                                                      \
    }

SCATTER(scatter_i32, int32_t)
SCATTER(scatter_i64, int64_t)

static PyObject *py_to_columns(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer ip, ix, v, op, ox, ov;
    Py_ssize_t n_cols;
    if (!PyArg_ParseTuple(args, "y*y*y*nw*w*w*", &ip, &ix, &v, &n_cols, &op, &ox, &ov)) return NULL;
    PyObject *result = NULL;
    const Py_ssize_t I = (Py_ssize_t)sizeof(int64_t);
    Py_ssize_t n_rows = 0, isz = 0;
    int64_t nnz = 0;
    int ok = csr_structure(&ip, &ix, &n_rows, &nnz, &isz) && n_cols >= 0 && n_cols < PY_SSIZE_T_MAX / I - 1 &&
             n_rows < INT32_MAX && v.len == nnz * (Py_ssize_t)sizeof(double) && op.len == (n_cols + 1) * I &&
             ox.len == nnz * (Py_ssize_t)sizeof(int32_t) && ov.len == nnz * (Py_ssize_t)sizeof(float);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "to_columns needs a CSR matrix (int64 indptr from 0, non-decreasing, "
                                          "ending at nnz; int32/int64 indices; float64 data) of fewer than 2^31 "
                                          "rows, and int64 (n_cols + 1), int32 (nnz) and float32 (nnz) outputs");
        goto done;
    }
    int status;
    Py_BEGIN_ALLOW_THREADS
    status = isz == 4 ? scatter_i32(ip.buf, ix.buf, v.buf, n_rows, n_cols, op.buf, ox.buf, ov.buf)
                      : scatter_i64(ip.buf, ix.buf, v.buf, n_rows, n_cols, op.buf, ox.buf, ov.buf);
    Py_END_ALLOW_THREADS
    if (status) {
        PyErr_SetString(PyExc_ValueError, "to_columns: a column index is out of range");
        goto done;
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    PyBuffer_Release(&ip);
    PyBuffer_Release(&ix);
    PyBuffer_Release(&v);
    PyBuffer_Release(&op);
    PyBuffer_Release(&ox);
    PyBuffer_Release(&ov);
    return result;
}

static PyMethodDef methods[] = {
    {"weak_components", py_weak_components, METH_VARARGS,
     "weak_components(indptr, indices, labels) -> count: weakly connected components of a square CSR"},
    {"to_columns", py_to_columns, METH_VARARGS,
     "to_columns(indptr, indices, data, n_cols, out_indptr, out_indices, out_data): CSR -> CSC, float32 values"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_csrgraph",
                                    "Structure passes over a CSR matrix: weak components, the copy by column (native).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__csrgraph(void) { return PyModule_Create(&module); }
