/*
 * Run-length hemicube scanlines summed into CSR rows (docs/design.md, 'Hemicube form factors').
 *
 * Host-side by design: each row's runs (patch, weight) come back from the device scanline by
 * scanline, a patch seen on several scanlines once per run; the row's entry for it is the sum
 * of those weights. numpy did this with one sort of every run's (row, column) key per block
 * (np.unique + bincount: a sizeable share of the CPU time of tracing them, on the one core
 * PoCL's two threads also need); here each row's runs are
 * sorted by column alone, by a stable radix sort of 11-bit digits (two passes below 2^22
 * columns), and runs of one column summed where they meet, a few times faster
 * (docs/decisions/0011-ray-tracing.md).
 *
 * The sums are those of np.bincount bit for bit: float64, each column's weights added in the
 * order the runs appear (scanline by scanline, run by run: the sort is stable), from 0.0.
 *
 * Up to DENSE_COLUMNS columns the runs are summed into a dense row instead, its columns marked
 * in a bitmap read in order after: the same sums in the same order, with no sort. A radix
 * pass over 2^11 digits cleared and summed those digits for every row, however few its runs:
 * for rows of about a thousand runs over a small scene's columns (a moving block's rows) that
 * was most of the call (docs/decisions/0033-native-host-passes.md).
 *
 * Python signature:  _runs.to_csr(patch, weight, count, runs_per_line, n_cols, indptr, indices, data) -> nnz
 *   patch   : int32 buffer of B*S*L values: line k's j-th run's column at [k*L + j] (< 0: none)
 *   weight  : float32 buffer of B*S*L values, the runs' weights
 *   count   : int32 buffer of B*S values, the runs of each line (0..L); S = lines per row,
 *             given by the buffers' sizes and indptr's (B + 1 entries)
 *   runs_per_line : L
 *   n_cols  : columns; a run's column must be < n_cols
 *   indptr  : writable int64 buffer of B + 1 values
 *   indices : writable int32 buffer, data : writable float64 buffer, each of at least
 *             sum(count) values (the most entries there can be)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>

typedef struct {
    int32_t col;
    float weight;
} Run;

#define DIGIT_BITS 11
#define DIGITS (1 << DIGIT_BITS)
/* The most columns summed densely: the bitmap read per row is at most 1,024 words. */
#define DENSE_COLUMNS (1 << 16)

/* Sort runs[0..n) by column, stably (LSD radix), for columns below 2^bits; scratch holds n
 * runs. Returns where the sorted runs are (runs or scratch). */
static Run *sort_runs(Run *runs, Run *scratch, Py_ssize_t n, int bits)
{
    Py_ssize_t start[DIGITS];
    for (int shift = 0; shift < bits; shift += DIGIT_BITS) {
        for (int d = 0; d < DIGITS; ++d) start[d] = 0;
        for (Py_ssize_t i = 0; i < n; ++i) ++start[((uint32_t)runs[i].col >> shift) & (DIGITS - 1)];
        Py_ssize_t at = 0;
        for (int d = 0; d < DIGITS; ++d) {
            Py_ssize_t c = start[d];
            start[d] = at;
            at += c;
        }
        for (Py_ssize_t i = 0; i < n; ++i) scratch[start[((uint32_t)runs[i].col >> shift) & (DIGITS - 1)]++] = runs[i];
        Run *t = runs;
        runs = scratch;
        scratch = t;
    }
    return runs;
}

/* Returns nnz, -1 on a bad count or column (*bad set to describe it), -2 when out of memory. */
static Py_ssize_t to_csr(const int32_t *patch, const float *weight, const int32_t *count, Py_ssize_t B, Py_ssize_t S,
                         Py_ssize_t L, int64_t n_cols, int64_t *indptr, int32_t *indices, double *data, const char **bad)
{
    Py_ssize_t most = 0;
    for (Py_ssize_t r = 0; r < B; ++r) {
        Py_ssize_t runs = 0;
        for (Py_ssize_t k = r * S; k < (r + 1) * S; ++k) {
            if (count[k] < 0 || count[k] > L) {
                *bad = "a line's run count lies outside 0..runs_per_line";
                return -1;
            }
            runs += count[k];
        }
        if (runs > most) most = runs;
    }
    int bits = 0;
    while (bits < 31 && ((int64_t)1 << bits) < n_cols) ++bits;
    const int dense = n_cols <= DENSE_COLUMNS;
    const size_t words = (size_t)((n_cols + 63) / 64);
    Run *buf = dense ? NULL : malloc(sizeof(Run) * 2 * (size_t)(most > 0 ? most : 1));
    double *acc = dense ? malloc(sizeof(double) * (size_t)(n_cols > 0 ? n_cols : 1)) : NULL;
    uint64_t *mark = dense ? calloc(words > 0 ? words : 1, sizeof(uint64_t)) : NULL;
    if (dense ? !acc || !mark : !buf) {
        free(buf), free(acc), free(mark);
        return -2;
    }
    Py_ssize_t nnz = 0;
    indptr[0] = 0;
    for (Py_ssize_t r = 0; r < B; ++r) {
        Py_ssize_t n = 0;
        for (Py_ssize_t k = r * S; k < (r + 1) * S; ++k) {
            const int32_t *p = patch + k * L;
            const float *w = weight + k * L;
            for (int32_t j = 0; j < count[k]; ++j) {
                if (p[j] < 0) continue;
                if (p[j] >= n_cols) {
                    *bad = "a run's column is not below n_cols";
                    free(buf), free(acc), free(mark);
                    return -1;
                }
                if (dense) {
                    const uint32_t c = (uint32_t)p[j];
                    const uint64_t bit = (uint64_t)1 << (c & 63);
                    acc[c] = (mark[c >> 6] & bit ? acc[c] : 0.0) + (double)w[j];
                    mark[c >> 6] |= bit;
                } else {
                    buf[n].col = p[j];
                    buf[n].weight = w[j];
                    ++n;
                }
            }
        }
        if (dense) {
            for (size_t q = 0; q < words; ++q) {
                for (uint64_t m = mark[q]; m; m &= m - 1) {
                    const int32_t col = (int32_t)(64 * q + (size_t)__builtin_ctzll(m));
                    indices[nnz] = col;
                    data[nnz++] = acc[col];
                }
                mark[q] = 0;
            }
        } else {
            const Run *sorted = sort_runs(buf, buf + most, n, bits);
            for (Py_ssize_t i = 0; i < n;) {
                int32_t col = sorted[i].col;
                double sum = 0.0;
                for (; i < n && sorted[i].col == col; ++i) sum += (double)sorted[i].weight;
                indices[nnz] = col;
                data[nnz++] = sum;
            }
        }
        indptr[r + 1] = nnz;
    }
    free(buf), free(acc), free(mark);
    return nnz;
}

static PyObject *py_to_csr(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer patch, weight, count, indptr, indices, data;
    Py_ssize_t L;
    long long n_cols;
    if (!PyArg_ParseTuple(args, "y*y*y*nLw*w*w*", &patch, &weight, &count, &L, &n_cols, &indptr, &indices, &data))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t lines = count.len / (Py_ssize_t)sizeof(int32_t);
    Py_ssize_t B = indptr.len / (Py_ssize_t)sizeof(int64_t) - 1;
    Py_ssize_t cap = indices.len / (Py_ssize_t)sizeof(int32_t);
    if (L < 1 || B < 0 || n_cols < 0 || n_cols > INT32_MAX || (B > 0 ? lines % B : lines) != 0) {
        PyErr_SetString(PyExc_ValueError, "to_csr needs runs_per_line >= 1, 0 <= n_cols < 2^31 and lines a multiple of rows");
    } else if (patch.len != lines * L * (Py_ssize_t)sizeof(int32_t) || weight.len != lines * L * (Py_ssize_t)sizeof(float)) {
        PyErr_SetString(PyExc_ValueError, "patch and weight must hold runs_per_line values per line of count");
    } else if (data.len / (Py_ssize_t)sizeof(double) < cap) {
        PyErr_SetString(PyExc_ValueError, "data must hold as many values as indices");
    } else {
        Py_ssize_t S = B > 0 ? lines / B : 0, total = 0, nnz;
        const int32_t *c = (const int32_t *)count.buf;
        for (Py_ssize_t k = 0; k < lines; ++k) total += c[k] > 0 ? c[k] : 0;
        const char *bad = NULL;
        if (cap < total) {
            PyErr_SetString(PyExc_ValueError, "indices and data must hold sum(count) values");
        } else {
            Py_BEGIN_ALLOW_THREADS
            nnz = to_csr((const int32_t *)patch.buf, (const float *)weight.buf, c, B, S, L, (int64_t)n_cols,
                         (int64_t *)indptr.buf, (int32_t *)indices.buf, (double *)data.buf, &bad);
            Py_END_ALLOW_THREADS
            if (nnz == -2)
                PyErr_NoMemory();
            else if (nnz < 0)
                PyErr_SetString(PyExc_ValueError, bad);
            else
                result = PyLong_FromSsize_t(nnz);
        }
    }
    PyBuffer_Release(&patch);
    PyBuffer_Release(&weight);
    PyBuffer_Release(&count);
    PyBuffer_Release(&indptr);
    PyBuffer_Release(&indices);
    PyBuffer_Release(&data);
    return result;
}

static PyMethodDef methods[] = {
    {"to_csr", py_to_csr, METH_VARARGS,
     "to_csr(patch, weight, count, runs_per_line, n_cols, indptr, indices, data) -> nnz: run-length lines summed into CSR rows"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_runs", "Hemicube runs summed into CSR rows (native).", -1, methods};

PyMODINIT_FUNC PyInit__runs(void) { return PyModule_Create(&module); }
