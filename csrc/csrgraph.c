/*
 * Passes over a CSR matrix's structure that the far field's precompute makes of the full F
 * (pydynrad/host/csrgraph.py): its weakly connected components (patches that exchange no light
 * with each other, which no cluster may join) and its copy by column in float32 (the first
 * bounce's product over lit columns).
 *
 * scipy did both through a transpose of F: connected_components(connection="weak") adds F's
 * transpose to F, and csc_matrix(F, dtype=float32) transposes and then converts. On a large
 * scene the two transposes were most of the far field's build
 * (docs/decisions/0033-native-host-passes.md). Here the components come from a union-find over the entries (no
 * transpose), and the by-column copy is one counting pass and one scatter that writes float32.
 *
 * The far field's G = F Pr (Pr one entry per row: the patch's cluster and its weight) was
 * scipy's general sparse product, seconds on a large scene,
 * most of it converting F's float32 values and a symbolic pass; here it is one counting pass
 * and one summing pass that read F as it is, with scipy's order of sums and of entries.
 *
 * Python signatures:
 *   _csrgraph.weak_components(indptr, indices, labels) -> count
 *       indptr int64 (n + 1), indices int32 or int64 (n columns: the matrix is square);
 *       labels writable int64 (n): each node's component, numbered in the order of the
 *       components' smallest node (as scipy's connected_components numbers them).
 *   _csrgraph.to_columns(indptr, indices, data, n_cols, out_indptr, out_indices, out_data) -> None
 *       data float32 or float64; out_indptr writable int64 (n_cols + 1); out_indices writable int32
 *       (rows < 2^31); out_data writable float32, both of nnz. Row indices come out ascending
 *       within each column.
 *   _csrgraph.label_counts(indptr, indices, labels, n_labels, out_counts) -> None
 *       labels int64 (one per column, in [0, n_labels)); out_counts writable int64 (n rows):
 *       the distinct labels of each row's columns.
 *   _csrgraph.sum_by_label(indptr, indices, data, labels, weights, n_labels, out_indptr,
 *                          out_indices, out_data) -> nnz
 *       data float32 or float64; weights float64 (one per column); out_indptr writable int64
 *       (n + 1); out_indices writable int32, out_data writable float64, each of at least the
 *       counts' sum. Row i of the result holds, per label k of its columns, the sum over its
 *       entries (i, j) with labels[j] == k of data * weights[j], in float64 and in the row's
 *       order: scipy's csr_matmat with a right factor of one entry per row, entries in its
 *       order (the last label first met comes first) and exact zeros dropped. Returns the
 *       result's non-zeros.
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

#define SCATTER(NAME, ITYPE, VTYPE)                                                                                    \
    static int NAME(const int64_t *ip, const ITYPE *ix, const VTYPE *v, Py_ssize_t n_rows, Py_ssize_t n_cols,         \
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
                int64_t c = (int64_t)ix[j];                                                                            \
                if (c < 0 || c >= n_cols) return -1; /* read again unlocked: checked where it is used */              \
                int64_t at = op[c]++;                                                                                  \
                ox[at] = (int32_t)r;                                                                                   \
                ov[at] = (float)v[j];                                                                                  \
            }                                                                                                          \
        }                                                                                                              \
        for (Py_ssize_t c = n_cols; c > 0; --c) op[c] = op[c - 1];                                                     \
        op[0] = 0;                                                                                                     \
        return 0;                                                                                                      \
    }

SCATTER(scatter_i32_f32, int32_t, float)
SCATTER(scatter_i32_f64, int32_t, double)
SCATTER(scatter_i64_f32, int64_t, float)
SCATTER(scatter_i64_f64, int64_t, double)

/* None where a pass returned 0, else NULL with ValueError(message). */
static PyObject *none_unless(int status, const char *message)
{
    if (status) {
        PyErr_SetString(PyExc_ValueError, message);
        return NULL;
    }
    Py_RETURN_NONE;
}

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
             n_rows < INT32_MAX && op.len == (n_cols + 1) * I && ox.len == nnz * (Py_ssize_t)sizeof(int32_t) &&
             ov.len == nnz * (Py_ssize_t)sizeof(float);
    Py_ssize_t vsz = nnz > 0 ? v.len / nnz : 4;
    if (!ok || !(vsz == 4 || vsz == 8) || v.len != nnz * vsz) {
        PyErr_SetString(PyExc_ValueError, "to_columns needs a CSR matrix (int64 indptr from 0, non-decreasing, "
                                          "ending at nnz; int32/int64 indices; float32/float64 data) of fewer than "
                                          "2^31 rows, and int64 (n_cols + 1), int32 (nnz) and float32 (nnz) outputs");
        goto done;
    }
    int status;
    Py_BEGIN_ALLOW_THREADS
    if (isz == 4)
        status = vsz == 4 ? scatter_i32_f32(ip.buf, ix.buf, v.buf, n_rows, n_cols, op.buf, ox.buf, ov.buf)
                          : scatter_i32_f64(ip.buf, ix.buf, v.buf, n_rows, n_cols, op.buf, ox.buf, ov.buf);
    else
        status = vsz == 4 ? scatter_i64_f32(ip.buf, ix.buf, v.buf, n_rows, n_cols, op.buf, ox.buf, ov.buf)
                          : scatter_i64_f64(ip.buf, ix.buf, v.buf, n_rows, n_cols, op.buf, ox.buf, ov.buf);
    Py_END_ALLOW_THREADS
    result = none_unless(status, "to_columns: a column index is out of range");
done:
    PyBuffer_Release(&ip);
    PyBuffer_Release(&ix);
    PyBuffer_Release(&v);
    PyBuffer_Release(&op);
    PyBuffer_Release(&ox);
    PyBuffer_Release(&ov);
    return result;
}

/* The labels of a row's columns, each met once: next[k] is -1 for a label not yet met in the
 * row, else the label met before it (a chain from head, scipy's csr_matmat bookkeeping). */
#define COUNT_LABELS(NAME, ITYPE)                                                                                      \
    static int NAME(const int64_t *ip, const ITYPE *ix, Py_ssize_t n_rows, Py_ssize_t n_cols, const int64_t *label,   \
                    int64_t n_labels, int64_t *next, int64_t *counts)                                                  \
    {                                                                                                                  \
        for (Py_ssize_t r = 0; r < n_rows; ++r) {                                                                      \
            int64_t head = -2, length = 0;                                                                             \
            for (int64_t j = ip[r]; j < ip[r + 1]; ++j) {                                                              \
                int64_t c = (int64_t)ix[j];                                                                            \
                if (c < 0 || c >= n_cols) return -1;                                                                   \
                int64_t k = label[c];                                                                                  \
                if (k < 0 || k >= n_labels) return -1; /* checked up front; read again here, unlocked */             \
                if (next[k] == -1) next[k] = head, head = k, ++length;                                                 \
            }                                                                                                          \
            counts[r] = length;                                                                                        \
            while (head != -2) {                                                                                       \
                int64_t t = head;                                                                                      \
                head = next[t], next[t] = -1;                                                                          \
            }                                                                                                          \
        }                                                                                                              \
        return 0;                                                                                                      \
    }

COUNT_LABELS(count_labels_i32, int32_t)
COUNT_LABELS(count_labels_i64, int64_t)

#define SUM_LABELS(NAME, ITYPE, VTYPE)                                                                                 \
    static int64_t NAME(const int64_t *ip, const ITYPE *ix, const VTYPE *v, Py_ssize_t n_rows, Py_ssize_t n_cols,     \
                        const int64_t *label, int64_t n_labels, const double *w, int64_t *next, double *sums,          \
                        int64_t capacity,                                                                              \
                        int64_t *op, int32_t *ox, double *ov)                                                          \
    {                                                                                                                  \
        int64_t nnz = 0;                                                                                               \
        op[0] = 0;                                                                                                     \
        for (Py_ssize_t r = 0; r < n_rows; ++r) {                                                                      \
            int64_t head = -2;                                                                                         \
            for (int64_t j = ip[r]; j < ip[r + 1]; ++j) {                                                              \
                int64_t c = (int64_t)ix[j];                                                                            \
                if (c < 0 || c >= n_cols) return -1;                                                                   \
                int64_t k = label[c];                                                                                  \
                if (k < 0 || k >= n_labels) return -1;                                                                 \
                sums[k] += (double)v[j] * w[c];                                                                        \
                if (next[k] == -1) next[k] = head, head = k;                                                           \
            }                                                                                                          \
            while (head != -2) {                                                                                       \
                int64_t t = head;                                                                                      \
                if (sums[t] != 0) {                                                                                    \
                    if (nnz == capacity) return -2;                                                                    \
                    ox[nnz] = (int32_t)t, ov[nnz] = sums[t], ++nnz;                                                    \
                }                                                                                                      \
                head = next[t], next[t] = -1, sums[t] = 0;                                                             \
            }                                                                                                          \
            op[r + 1] = nnz;                                                                                           \
        }                                                                                                              \
        return nnz;                                                                                                    \
    }

SUM_LABELS(sum_labels_i32_f32, int32_t, float)
SUM_LABELS(sum_labels_i32_f64, int32_t, double)
SUM_LABELS(sum_labels_i64_f32, int64_t, float)
SUM_LABELS(sum_labels_i64_f64, int64_t, double)

/* 1 where labels holds n_cols int64 values in [0, n_labels) and n_labels fits int32. */
static int labels_ok(const Py_buffer *lb, Py_ssize_t n_cols, Py_ssize_t n_labels)
{
    if (n_labels < 1 || n_labels > INT32_MAX || lb->len != n_cols * (Py_ssize_t)sizeof(int64_t)) return 0;
    const int64_t *l = lb->buf;
    int bad = 0;
    for (Py_ssize_t c = 0; c < n_cols; ++c) bad |= l[c] < 0 || l[c] >= n_labels;
    return !bad;
}

static PyObject *py_label_counts(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer ip, ix, lb, out;
    Py_ssize_t n_labels;
    if (!PyArg_ParseTuple(args, "y*y*y*nw*", &ip, &ix, &lb, &n_labels, &out)) return NULL;
    PyObject *result = NULL;
    int64_t *next = NULL;
    Py_ssize_t n_rows = 0, isz = 0, n_cols = lb.len / (Py_ssize_t)sizeof(int64_t);
    int64_t nnz = 0;
    if (!(csr_structure(&ip, &ix, &n_rows, &nnz, &isz) && labels_ok(&lb, n_cols, n_labels) &&
          out.len == n_rows * (Py_ssize_t)sizeof(int64_t))) {
        PyErr_SetString(PyExc_ValueError, "label_counts needs a CSR structure (int64 indptr from 0, non-decreasing, "
                                          "ending at nnz; int32/int64 indices), int64 labels in [0, n_labels) of "
                                          "its columns and int64 counts of its rows");
        goto done;
    }
    if (!(next = malloc((size_t)n_labels * sizeof(int64_t)))) {
        PyErr_NoMemory();
        goto done;
    }
    int status;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = 0; k < n_labels; ++k) next[k] = -1;
    status = isz == 4 ? count_labels_i32(ip.buf, ix.buf, n_rows, n_cols, lb.buf, n_labels, next, out.buf)
                      : count_labels_i64(ip.buf, ix.buf, n_rows, n_cols, lb.buf, n_labels, next, out.buf);
    Py_END_ALLOW_THREADS
    result = none_unless(status, "label_counts: a column index or a label is out of range");
done:
    free(next);
    PyBuffer_Release(&ip);
    PyBuffer_Release(&ix);
    PyBuffer_Release(&lb);
    PyBuffer_Release(&out);
    return result;
}

static PyObject *py_sum_by_label(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer ip, ix, v, lb, w, op, ox, ov;
    Py_ssize_t n_labels;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*nw*w*w*", &ip, &ix, &v, &lb, &w, &n_labels, &op, &ox, &ov)) return NULL;
    PyObject *result = NULL;
    int64_t *next = NULL;
    double *sums = NULL;
    const Py_ssize_t I = (Py_ssize_t)sizeof(int64_t);
    Py_ssize_t n_rows = 0, isz = 0, n_cols = lb.len / I;
    int64_t nnz = 0;
    int ok = csr_structure(&ip, &ix, &n_rows, &nnz, &isz) && labels_ok(&lb, n_cols, n_labels);
    Py_ssize_t vsz = nnz > 0 ? v.len / nnz : 4;
    int64_t capacity = ox.len / (Py_ssize_t)sizeof(int32_t);
    ok = ok && (vsz == 4 || vsz == 8) && v.len == nnz * vsz && w.len == n_cols * (Py_ssize_t)sizeof(double) &&
         op.len == (n_rows + 1) * I && ov.len == capacity * (Py_ssize_t)sizeof(double);
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "sum_by_label needs a CSR matrix (int64 indptr from 0, non-decreasing, "
                                          "ending at nnz; int32/int64 indices; float32/float64 data), int64 labels "
                                          "in [0, n_labels) and float64 weights of its columns, an int64 (rows + 1) "
                                          "indptr and int32 and float64 outputs of one length");
        goto done;
    }
    if (!(next = malloc((size_t)n_labels * sizeof(int64_t))) || !(sums = calloc((size_t)n_labels, sizeof(double)))) {
        PyErr_NoMemory();
        goto done;
    }
    int64_t got;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = 0; k < n_labels; ++k) next[k] = -1;
    if (isz == 4)
        got = vsz == 4 ? sum_labels_i32_f32(ip.buf, ix.buf, v.buf, n_rows, n_cols, lb.buf, n_labels, w.buf, next, sums, capacity,
                                            op.buf, ox.buf, ov.buf)
                       : sum_labels_i32_f64(ip.buf, ix.buf, v.buf, n_rows, n_cols, lb.buf, n_labels, w.buf, next, sums, capacity,
                                            op.buf, ox.buf, ov.buf);
    else
        got = vsz == 4 ? sum_labels_i64_f32(ip.buf, ix.buf, v.buf, n_rows, n_cols, lb.buf, n_labels, w.buf, next, sums, capacity,
                                            op.buf, ox.buf, ov.buf)
                       : sum_labels_i64_f64(ip.buf, ix.buf, v.buf, n_rows, n_cols, lb.buf, n_labels, w.buf, next, sums, capacity,
                                            op.buf, ox.buf, ov.buf);
    Py_END_ALLOW_THREADS
    if (got < 0) {
        PyErr_SetString(PyExc_ValueError, got == -1 ? "sum_by_label: a column index or a label is out of range"
                                                    : "sum_by_label: the outputs are shorter than the result");
        goto done;
    }
    result = PyLong_FromLongLong((long long)got);
done:
    free(next);
    free(sums);
    PyBuffer_Release(&ip);
    PyBuffer_Release(&ix);
    PyBuffer_Release(&v);
    PyBuffer_Release(&lb);
    PyBuffer_Release(&w);
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
    {"label_counts", py_label_counts, METH_VARARGS,
     "label_counts(indptr, indices, labels, n_labels, out_counts): distinct labels of each row's columns"},
    {"sum_by_label", py_sum_by_label, METH_VARARGS,
     "sum_by_label(indptr, indices, data, labels, weights, n_labels, out_indptr, out_indices, out_data) -> nnz"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_csrgraph",
                                    "Passes over a CSR matrix: weak components, the copy by column, sums by column label (native).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__csrgraph(void) { return PyModule_Create(&module); }
