/*
 * Products of a sparse matrix with a few dense columns (k <= 4, the colour channels), on the
 * host's cores.
 *
 * columns_times: y += A[:, cols] x for a matrix held by column (CSC), over the chosen columns
 * only: the far field's first bounce D1 = P F L over the lit columns of F
 * (pydynrad/farfield/level.py, FarField._first_bounce).
 *
 * scipy first copied the chosen columns out (F[:, cols]) and then multiplied: two passes over
 * their entries, the first writing them all (millions of entries when a lamp lights part of a
 * large scene). Here each entry is read once and added into y; the
 * caller splits the columns over threads, each with its own y (the GIL is released).
 *
 * Python signature:
 *   _colproduct.columns_times(indptr, indices, data, cols, x, out, k) -> None
 *   indptr  : int64 (n_cols + 1); indices : int32 or int64 row indices (the itemsize says
 *             which); data : float32 or float64 values (likewise), one per index
 *   cols    : int64 column numbers; x : float64 (len(cols), k), row t multiplying column cols[t]
 *   out     : writable float64 (n_rows, k), added into (n_rows from its length)
 *   Lengths, column numbers and row indices are checked: ValueError.
 *
 * rows_times: y[first:last] = A[first:last] x for a matrix held by row (CSR), each row summed
 * in float64 in its entries' order (scipy's with one vector). scipy's CSR times an
 * (n, 3) array took several times one column's time, and ran on one core; the caller splits the rows over threads.
 *
 *   _colproduct.rows_times(indptr, indices, data, first, last, x, out, k) -> None
 *   indptr  : int64 (n_rows + 1); indices, data : as for columns_times
 *   first, last : the rows to compute, 0 <= first <= last <= n_rows
 *   x       : float64 (n_cols, k) (n_cols from its length); out : writable float64 (n_rows, k)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>

#define PRODUCT(NAME, ITYPE, DTYPE)                                                                                    \
    static int NAME(const int64_t *ip, const ITYPE *ix, const DTYPE *v, Py_ssize_t n_cols, Py_ssize_t n_rows,         \
                    const int64_t *cols, Py_ssize_t m, const double *x, double *y, int k)                              \
    {                                                                                                                  \
        for (Py_ssize_t t = 0; t < m; ++t) {                                                                           \
            int64_t c = cols[t];                                                                                       \
            if (c < 0 || c >= n_cols) return -1;                                                                       \
            const double *xt = x + (size_t)t * k;                                                                      \
            for (int64_t j = ip[c]; j < ip[c + 1]; ++j) {                                                              \
                int64_t r = (int64_t)ix[j];                                                                            \
                if (r < 0 || r >= n_rows) return -1;                                                                   \
                double a = (double)v[j];                                                                               \
                double *yr = y + (size_t)r * k;                                                                        \
                for (int q = 0; q < k; ++q) yr[q] += a * xt[q];                                                        \
            }                                                                                                          \
        }                                                                                                              \
        return 0;                                                                                                      \
    }

/* One row product per k, so that the k sums live in registers (with k a run-time bound they
   went through memory, slower than scipy even at k = 1). Indices are checked in the same pass. */
#define ROWS_K(NAME, ITYPE, DTYPE, K)                                                                                  \
    static int NAME##_##K(const int64_t *ip, const ITYPE *ix, const DTYPE *v, Py_ssize_t first, Py_ssize_t last,      \
                          Py_ssize_t n_cols, const double *x, double *y)                                              \
    {                                                                                                                  \
        int bad = 0;                                                                                                   \
        for (Py_ssize_t r = first; r < last; ++r) {                                                                    \
            double acc[K] = {0.0};                                                                                     \
            for (int64_t j = ip[r]; j < ip[r + 1]; ++j) {                                                              \
                int64_t c = (int64_t)ix[j];                                                                            \
                bad |= (uint64_t)c >= (uint64_t)n_cols;                                                                \
                c = bad ? 0 : c;                                                                                       \
                const double a = (double)v[j], *xc = x + (size_t)c * K;                                                \
                for (int q = 0; q < K; ++q) acc[q] += a * xc[q];                                                       \
            }                                                                                                          \
            for (int q = 0; q < K; ++q) y[(size_t)r * K + q] = acc[q];                                                 \
        }                                                                                                              \
        return -bad;                                                                                                   \
    }
#define ROWS(NAME, ITYPE, DTYPE)                                                                                       \
    ROWS_K(NAME, ITYPE, DTYPE, 1)                                                                                      \
    ROWS_K(NAME, ITYPE, DTYPE, 2)                                                                                      \
    ROWS_K(NAME, ITYPE, DTYPE, 3)                                                                                      \
    ROWS_K(NAME, ITYPE, DTYPE, 4)                                                                                      \
    static int NAME(const int64_t *ip, const ITYPE *ix, const DTYPE *v, Py_ssize_t first, Py_ssize_t last,            \
                    Py_ssize_t n_cols, const double *x, double *y, int k)                                              \
    {                                                                                                                  \
        switch (k) {                                                                                                   \
        case 1: return NAME##_1(ip, ix, v, first, last, n_cols, x, y);                                                 \
        case 2: return NAME##_2(ip, ix, v, first, last, n_cols, x, y);                                                 \
        case 3: return NAME##_3(ip, ix, v, first, last, n_cols, x, y);                                                 \
        default: return NAME##_4(ip, ix, v, first, last, n_cols, x, y);                                                \
        }                                                                                                              \
    }

ROWS(rows_i32_f32, int32_t, float)
ROWS(rows_i32_f64, int32_t, double)
ROWS(rows_i64_f32, int64_t, float)
ROWS(rows_i64_f64, int64_t, double)

PRODUCT(product_i32_f32, int32_t, float)
PRODUCT(product_i32_f64, int32_t, double)
PRODUCT(product_i64_f32, int64_t, float)
PRODUCT(product_i64_f64, int64_t, double)

/* F's product for the matrix's index and value sizes (bytes: 4 or 8 each). */
#define BY_TYPES(F, isz, vsz, ...)                                                                                     \
    ((isz) == 4 ? ((vsz) == 4 ? F##_i32_f32(__VA_ARGS__) : F##_i32_f64(__VA_ARGS__))                                   \
                : ((vsz) == 4 ? F##_i64_f32(__VA_ARGS__) : F##_i64_f64(__VA_ARGS__)))

/* Whether indptr p of n rows (or columns) starts at 0 and never decreases. */
static int good_indptr(const int64_t *p, Py_ssize_t n)
{
    int ok = p[0] == 0;
    for (Py_ssize_t c = 0; c < n && ok; ++c) ok = p[c + 1] >= p[c];
    return ok;
}

/* Bytes per index and per value of a matrix's nnz entries (4 or 8 each), or 0 if they are neither. */
static int entry_sizes(Py_ssize_t nnz, const Py_buffer *ix, const Py_buffer *v, Py_ssize_t *isz, Py_ssize_t *vsz)
{
    if (nnz == 0) return ix->len == 0 && v->len == 0;
    *isz = ix->len / nnz, *vsz = v->len / nnz;
    return (*isz == 4 || *isz == 8) && (*vsz == 4 || *vsz == 8) && ix->len == nnz * *isz && v->len == nnz * *vsz;
}

/* None, or the ValueError ``error`` where status != 0; the n buffers released either way. */
static PyObject *finished(int status, const char *error, Py_buffer *b, int n)
{
    for (int q = 0; q < n; ++q) PyBuffer_Release(&b[q]);
    if (status) {
        PyErr_SetString(PyExc_ValueError, error);
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyObject *py_columns_times(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer b[6], *ip = &b[0], *ix = &b[1], *v = &b[2], *cols = &b[3], *x = &b[4], *out = &b[5];
    int k;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*i", ip, ix, v, cols, x, out, &k)) return NULL;
    const Py_ssize_t I = (Py_ssize_t)sizeof(int64_t), D = (Py_ssize_t)sizeof(double);
    Py_ssize_t n_cols = ip->len / I - 1, m = cols->len / I;
    Py_ssize_t nnz = -1, isz = 0, vsz = 0;
    if (n_cols >= 0 && ip->len == (n_cols + 1) * I) nnz = ((const int64_t *)ip->buf)[n_cols];
    const int ok = k >= 1 && k <= 4 && nnz >= 0 && cols->len == m * I && x->len == m * k * D &&
                   out->len % (k * D) == 0 && entry_sizes(nnz, ix, v, &isz, &vsz) && good_indptr(ip->buf, n_cols);
    if (!ok)
        return finished(1, "columns_times needs a CSC matrix (int64 indptr from 0, non-decreasing; int32/int64 "
                           "indices and float32/float64 data of its entries), int64 columns, float64 x (columns, k) "
                           "and out (rows, k), 1 <= k <= 4", b, 6);
    Py_ssize_t n_rows = out->len / (k * D);
    int status = 0;
    if (nnz > 0) {
        Py_BEGIN_ALLOW_THREADS
        status = BY_TYPES(product, isz, vsz, ip->buf, ix->buf, v->buf, n_cols, n_rows, cols->buf, m, x->buf, out->buf, k);
        Py_END_ALLOW_THREADS
    }
    return finished(status, "columns_times: a column number or row index is out of range", b, 6);
}

static PyObject *py_rows_times(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer b[5], *ip = &b[0], *ix = &b[1], *v = &b[2], *x = &b[3], *out = &b[4];
    Py_ssize_t first, last;
    int k;
    if (!PyArg_ParseTuple(args, "y*y*y*nny*w*i", ip, ix, v, &first, &last, x, out, &k)) return NULL;
    const Py_ssize_t I = (Py_ssize_t)sizeof(int64_t), D = (Py_ssize_t)sizeof(double);
    Py_ssize_t n_rows = ip->len / I - 1, nnz = -1, isz = 0, vsz = 0;
    int ok = k >= 1 && k <= 4 && n_rows >= 0 && ip->len == (n_rows + 1) * I && out->len == n_rows * k * D &&
             x->len % (k * D) == 0 && 0 <= first && first <= last && last <= n_rows;
    if (ok) {
        nnz = ((const int64_t *)ip->buf)[n_rows];
        ok = nnz >= 0 && entry_sizes(nnz, ix, v, &isz, &vsz) && good_indptr(ip->buf, n_rows);
    }
    if (!ok)
        return finished(1, "rows_times needs a CSR matrix (int64 indptr from 0, non-decreasing; int32/int64 indices "
                           "and float32/float64 data of its entries), rows 0 <= first <= last <= n_rows, float64 x "
                           "(columns, k) and out (rows, k), 1 <= k <= 4", b, 5);
    Py_ssize_t n_cols = x->len / (k * D);
    if (nnz > 0 && n_cols == 0)  /* every index out of range; the loop would read x[0] */
        return finished(1, "rows_times: a column index is out of range", b, 5);
    int status = 0;
    if (nnz > 0) {
        Py_BEGIN_ALLOW_THREADS
        status = BY_TYPES(rows, isz, vsz, ip->buf, ix->buf, v->buf, first, last, n_cols, x->buf, out->buf, k);
        Py_END_ALLOW_THREADS
    } else {
        for (Py_ssize_t q = first * k; q < last * k; ++q) ((double *)out->buf)[q] = 0.0;
    }
    return finished(status, "rows_times: a column index is out of range", b, 5);
}

static PyMethodDef methods[] = {
    {"columns_times", py_columns_times, METH_VARARGS,
     "columns_times(indptr, indices, data, cols, x, out, k): out += A[:, cols] x for CSC A, the chosen columns only"},
    {"rows_times", py_rows_times, METH_VARARGS,
     "rows_times(indptr, indices, data, first, last, x, out, k): out[first:last] = A[first:last] x for CSR A"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_colproduct",
                                    "Products of a sparse matrix with a few dense columns (native).", -1, methods};

PyMODINIT_FUNC PyInit__colproduct(void) { return PyModule_Create(&module); }
