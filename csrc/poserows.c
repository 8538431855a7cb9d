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
 * copy and a second eliminate_zeros); here it is one read and one
 * write of each entry.
 *
 * The second pass, difference(), is D = current - kept for the rows a move leaves stale in K
 * (pydynrad/dynamic/stale.py): a merge of each current row with its kept row, read in place
 * (scipy sliced the kept rows out first, then subtracted: a copy more, and slower;
 * docs/decisions/0033-native-host-passes.md). The merge's branches bound it, not memory: so each step writes its entry
 * and advances the output only where it is non-zero (most are zero: a stale row equals its
 * kept row but where an object hides or shows), and the order checks run without an early
 * exit, which vectorizes.
 *
 * The third, moved_difference(), is the two at once where only D is wanted (a move at budget 0:
 * pydynrad/dynamic/moves.py, WorldRows.differences): each row at the pose is made as assemble()
 * makes it, value for value, and merged with its kept row as it is made, so the rows at the pose
 * are never written (assemble wrote a move's entries into fresh pages, which a merge then read
 * back from memory, each a visible share of a moving frame).
 *
 * A move after a move mostly changes little of a row at the pose: of its static entries only
 * those whose segment the objects hide now and did not then, or the reverse (3-8% on the bench's
 * box). Where a row's D at the last pose was made here from the same static row, is held
 * against the same kept row, and neither row at the pose is capped, moved_difference() starts
 * from that D (since_row): it reads two flags per entry, and the static and kept rows only where
 * a presence changed, where the whole merge read ~25 bytes per entry, out of the cache in a
 * frame (docs/decisions/0033-native-host-passes.md).
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
 *   _poserows.moved_difference(starts, ends, indices, data, hidden, r_indptr, r_indices, r_data,
 *                              k_indptr, k_indices, k_data, slots, since, hidden_prev, row_sums,
 *                              p_starts, p_ends, p_indices, p_data, first_object,
 *                              out_indptr, out_indices, out_data, out_capped) -> nnz
 *   the first eight as for assemble, the next four as for difference; then per row: since
 *   (uint8: its row at the last pose was made from the same static row with the mask
 *   hidden_prev, uint8 per entry like hidden, and not capped, and p's row is its D then,
 *   against the same kept row), row_sums (float64: the sum of its static row) and its last D
 *   (spans p_starts, p_ends of int64 into p_indices and p_data, as the static rows are read; an
 *   empty span where not since); first_object: the first object column; out_* of at least the
 *   rows' entries + len(r_indices) + the entries of the kept rows named + those of the spans;
 *   out_capped: uint8 per row, set where the row at the pose is scaled or capped. Row i of the
 *   output is assemble's row i minus kept row slots[i], exact zeros dropped; -1 - i where row
 *   i's static columns or its kept row's columns are out of order. Where since, the caller
 *   vouches that the static rows and kept rows are in increasing column order (they are then
 *   read only where a presence changed): scipy's has_canonical_format, which it caches.
 *
 * Array lengths, spans, indptr ranges and slots are checked: ValueError.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* How far below 1, relative to the row's sum, a row at the pose must sum, by since_row's
   estimate, to take moved_difference's "since" path: that estimate differs from assemble_row's
   own sum by rounding alone, ~1e-13 for rows of a few thousand entries. */
#define SINCE_MARGIN 1e-9

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

/* The entries of the kept rows slots[k] (of kr rows with row pointers kp), k < rows; -1 with
   a ValueError set where a slot names no kept row. */
static Py_ssize_t kept_entries(const char *pass, const int64_t *slots, const int64_t *kp, Py_ssize_t rows, Py_ssize_t kr)
{
    Py_ssize_t n = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) {
        if (slots[k] < 0 || slots[k] >= kr) {
            PyErr_Format(PyExc_ValueError, "%s: slot %lld of row %zd is outside the %zd kept rows", pass,
                         (long long)slots[k], k, kr);
            return -1;
        }
        n += kp[slots[k] + 1] - kp[slots[k]];
    }
    return n;
}

static Py_ssize_t span_entries(const int64_t *starts, const int64_t *ends, Py_ssize_t rows)
{
    Py_ssize_t n = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) n += ends[k] - starts[k];
    return n;
}

/* Row k at the pose into ox, ov: its static entries left, then its object columns, capped (the
   file's head); *capped: whether it was scaled or capped. Returns the entries written. */
static Py_ssize_t assemble_row(Py_ssize_t k, const int64_t *is, const int64_t *ie, const int32_t *ix, const double *x,
                               const uint8_t *hidden, const int64_t *rp, const int32_t *rx, const double *rv,
                               int32_t *ox, double *ov, int *capped)
{
    Py_ssize_t n = 0;
    double kept = 0.0, objects = 0.0;
    for (int64_t j = is[k]; j < ie[k]; ++j)
        if (!hidden[j] && x[j] != 0.0) {
            kept += x[j];
            ox[n] = ix[j], ov[n++] = x[j];
        }
    for (int64_t j = rp[k]; j < rp[k + 1]; ++j) objects += rv[j];
    const double g = objects > 1.0 ? 1.0 / objects : 1.0;
    *capped = objects > 1.0 || (kept > 0.0 && kept + objects > 1.0);
    if (kept > 0.0 && kept + objects > 1.0) {
        double f = objects < 1.0 ? (1.0 - objects) / kept : 0.0;
        Py_ssize_t w = 0;
        for (Py_ssize_t j = 0; j < n; ++j) {
            double v = ov[j] * f;
            if (v != 0.0) ox[w] = ox[j], ov[w++] = v;
        }
        n = w;
    }
    for (int64_t j = rp[k]; j < rp[k + 1]; ++j)
        if (rv[j] != 0.0) ox[n] = rx[j], ov[n++] = rv[j] * g;
    return n;
}

static Py_ssize_t assemble(Py_ssize_t rows, const int64_t *is, const int64_t *ie, const int32_t *ix, const double *x,
                           const uint8_t *hidden, const int64_t *rp, const int32_t *rx, const double *rv, int64_t *op,
                           int32_t *ox, double *ov)
{
    int capped;
    op[0] = 0;
    for (Py_ssize_t k = 0; k < rows; ++k)
        op[k + 1] = op[k] + assemble_row(k, is, ie, ix, x, hidden, rp, rx, rv, ox + op[k], ov + op[k], &capped);
    return op[rows];
}

static int increasing(const int32_t *x, int64_t start, int64_t end)
{
    int ok = 1;  /* no early exit: the loop vectorizes, and rows in order are the rule */
    for (int64_t t = start + 1; t < end; ++t) ok &= x[t] > x[t - 1];
    return ok;
}

/* Entries [i, ie) of (ax, av) minus entries [j, je) of (bx, bv), both in increasing column order,
   into ox, ov, exact zeros dropped. Returns the entries written. */
static Py_ssize_t merge_row(int64_t i, int64_t ie, const int32_t *ax, const double *av, int64_t j, int64_t je,
                            const int32_t *bx, const double *bv, int32_t *ox, double *ov)
{
    Py_ssize_t n = 0;
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
    return n;
}

static Py_ssize_t difference(Py_ssize_t rows, const int64_t *as, const int64_t *ae, const int32_t *ax, const double *av,
                             const int64_t *bp, const int32_t *bx, const double *bv, const int64_t *slots, int64_t *op,
                             int32_t *ox, double *ov)
{
    op[0] = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) {
        const int64_t j = bp[slots[k]], je = bp[slots[k] + 1];
        if (!increasing(ax, as[k], ae[k]) || !increasing(bx, j, je)) return -1 - k;
        op[k + 1] = op[k] + merge_row(as[k], ae[k], ax, av, j, je, bx, bv, ox + op[k], ov + op[k]);
    }
    return op[rows];
}

/* The first entry of columns [j, je) (increasing) at or above c, searched from j in steps that
   double (the columns asked for come in increasing order and close together), then halve. */
static int64_t gallop(const int32_t *x, int64_t j, int64_t je, int32_t c)
{
    int64_t step = 1, hi = j;
    while (hi < je && x[hi] < c) {
        j = hi + 1;
        hi += step;
        step <<= 1;
    }
    hi = hi < je ? hi : je;
    while (j < hi) {
        const int64_t mid = j + (int64_t)((uint64_t)(hi - j) >> 1);
        if (x[mid] < c)
            j = mid + 1;
        else
            hi = mid;
    }
    return j;
}

/* A word of eight flags with each non-zero byte made 1 (a flag may be any non-zero byte). */
static uint64_t ones(uint64_t w)
{
    w |= w >> 4;
    w |= w >> 2;
    w |= w >> 1;
    return w & 0x0101010101010101ULL;
}

/* Entries [t, te)'s flags whose presence changed since the last pose (hidden then and not now, or
   the reverse; explicit zeros have none), into changed (their positions); and the sum of the
   hidden entries. Eight flags at a time, visiting only the set bits of each word (a byte's
   bit, at 8 times its place in the word, on a little-endian machine; a byte loop elsewhere):
   most words of both masks are zero, and a byte loop over the rest was most of the pass.
   Returns the count. */
static Py_ssize_t changed_entries(int64_t t, int64_t te, const double *x, const uint8_t *hidden,
                                  const uint8_t *hidden_prev, int64_t *changed, double *hidden_sum)
{
    Py_ssize_t n = 0;
    double sum = 0.0;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    for (; t + 8 <= te; t += 8) {
        uint64_t h, p;
        memcpy(&h, hidden + t, 8);
        memcpy(&p, hidden_prev + t, 8);
        h = ones(h), p = ones(p);
        for (uint64_t w = h; w; w &= w - 1) sum += x[t + (__builtin_ctzll(w) >> 3)];
        for (uint64_t w = h ^ p; w; w &= w - 1) {
            const int64_t u = t + (__builtin_ctzll(w) >> 3);
            if (x[u] != 0.0) changed[n++] = u;
        }
    }
#endif
    for (; t < te; ++t) {
        if (hidden[t]) sum += x[t];
        if (!hidden[t] != !hidden_prev[t] && x[t] != 0.0) changed[n++] = t;
    }
    *hidden_sum = sum;
    return n;
}

/* Row k's D from the row's D at the last pose (moved_difference's "since" path: the file's
   head), or -1 where the row at the pose may be capped (it is then made whole). Whether it is:
   its static sum, the row's whole sum less its hidden entries (not summed in assemble_row's
   order, hence SINCE_MARGIN), plus its object columns. The static entries whose presence
   changed since take their value at the pose (x or nothing) minus their kept value k; the
   others keep their last D; the object columns are merged with the kept row's afresh. k needs
   no look into the kept row (cold in a frame: a look per change cost more than the merge it
   saves) but for an entry hidden now that has a last D: one shown now had none then, so its
   last D is exactly -k (or none where k = 0), and one hidden now without a last D had
   x - k = 0 then, so k = x. The same values, bit for bit, as merging assemble_row's row with
   the kept row, where neither row at the pose is capped. Returns the entries written. */
static Py_ssize_t since_row(Py_ssize_t k, const int64_t *is, const int64_t *ie, const int32_t *ix, const double *x,
                            const uint8_t *hidden, const uint8_t *hidden_prev, const double *row_sums,
                            const int64_t *rp, const int32_t *rx, const double *rv, int64_t j, int64_t je,
                            const int32_t *bx, const double *bv, int64_t d, int64_t de, const int32_t *px,
                            const double *pv, int32_t first_object, int64_t *changed, int32_t *ox, double *ov)
{
    double hid, objects = 0.0;
    const Py_ssize_t nc = changed_entries(is[k], ie[k], x, hidden, hidden_prev, changed, &hid);
    for (int64_t r = rp[k]; r < rp[k + 1]; ++r) objects += rv[r];
    if (!(objects <= 1.0 && row_sums[k] - hid + objects <= 1.0 - SINCE_MARGIN * (1.0 + row_sums[k]))) return -1;
    const int64_t d_objects = gallop(px, d, de, first_object);
    Py_ssize_t n = 0;
    for (Py_ssize_t q = 0; q < nc; ++q) {
        const int64_t t = changed[q];
        const int32_t c = ix[t];
        for (; d < d_objects && px[d] < c; ++d)  /* the last D where nothing changed */
            ox[n] = px[d], ov[n] = pv[d], ++n;
        const int last = d < d_objects && px[d] == c;
        double v;
        if (!hidden[t]) {
            v = last ? x[t] - (-pv[d]) : x[t];
        } else if (!last) {
            v = -x[t];
        } else {
            j = gallop(bx, j, je, c);
            v = j < je && bx[j] == c ? -bv[j] : 0.0;
        }
        d += last;
        ox[n] = c, ov[n] = v;
        n += v != 0.0;
    }
    for (; d < d_objects; ++d) ox[n] = px[d], ov[n] = pv[d], ++n;
    const int64_t b_objects = gallop(bx, j, je, first_object);
    return n + merge_row(rp[k], rp[k + 1], rx, rv, b_objects, je, bx, bv, ox + n, ov + n);
}

/* Each row at the pose is made into a scratch row (one row long, so it stays in the core's
   cache) and merged from there: making it in the merge, entry by entry, was slower than
   writing all the rows out and merging them after. Rows with since[k] take since_row instead where
   they are surely uncapped. capped[k]: 1 where row k at the pose was scaled or capped. -2 -
   rows: no memory for the scratch row. */
static Py_ssize_t moved_difference(Py_ssize_t rows, const int64_t *is, const int64_t *ie, const int32_t *ix,
                                   const double *x, const uint8_t *hidden, const int64_t *rp, const int32_t *rx,
                                   const double *rv, const int64_t *bp, const int32_t *bx, const double *bv,
                                   const int64_t *slots, const uint8_t *since, const uint8_t *hidden_prev,
                                   const double *row_sums, const int64_t *ps, const int64_t *pe, const int32_t *px,
                                   const double *pv, int32_t first_object, int64_t *op, int32_t *ox, double *ov,
                                   uint8_t *capped)
{
    int64_t longest = 1;
    for (Py_ssize_t k = 0; k < rows; ++k) {
        const int64_t len = ie[k] - is[k] + rp[k + 1] - rp[k];
        longest = len > longest ? len : longest;
    }
    int32_t *sx = malloc((size_t)longest * sizeof(int32_t));
    double *sv = malloc((size_t)longest * sizeof(double));
    int64_t *changed = malloc((size_t)longest * sizeof(int64_t));
    Py_ssize_t status = 0;
    op[0] = 0;
    if (!sx || !sv || !changed) status = -2 - rows;
    for (Py_ssize_t k = 0; k < rows && !status; ++k) {
        const int64_t j = bp[slots[k]], je = bp[slots[k] + 1];
        if (since[k] && increasing(px, ps[k], pe[k])) {
            const Py_ssize_t n = since_row(k, is, ie, ix, x, hidden, hidden_prev, row_sums, rp, rx, rv, j, je, bx, bv,
                                           ps[k], pe[k], px, pv, first_object, changed, ox + op[k], ov + op[k]);
            if (n >= 0) {
                capped[k] = 0;
                op[k + 1] = op[k] + n;
                continue;
            }
        }
        if (!increasing(ix, is[k], ie[k]) || !increasing(bx, j, je)) {
            status = -1 - k;
            break;
        }
        int cap;
        const Py_ssize_t n = assemble_row(k, is, ie, ix, x, hidden, rp, rx, rv, sx, sv, &cap);
        capped[k] = (uint8_t)cap;
        op[k + 1] = op[k] + merge_row(0, n, sx, sv, j, je, bx, bv, ox + op[k], ov + op[k]);
    }
    free(sx), free(sv), free(changed);
    return status ? status : op[rows];
}

/* assemble and difference take eleven buffers: eight read, three written. */
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
    const Py_ssize_t kept = kept_entries("difference", slots, kp, rows, kr);
    if (kept < 0) return NULL;
    const Py_ssize_t most = span_entries(b[0].buf, b[1].buf, rows) + kept;
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

/* moved_difference's buffers: assemble's eight, difference's four kept-row buffers, the seven
   of the "since" path, then four written. */
#define MOVED_BUFFERS 23

static PyObject *py_moved_difference(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer b[MOVED_BUFFERS];
    int first_object;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*y*iw*w*w*w*", &b[0], &b[1], &b[2], &b[3], &b[4],
                          &b[5], &b[6], &b[7], &b[8], &b[9], &b[10], &b[11], &b[12], &b[13], &b[14], &b[15], &b[16],
                          &b[17], &b[18], &first_object, &b[19], &b[20], &b[21], &b[22]))
        return NULL;
    PyObject *result = NULL;
    Py_ssize_t rows = b[0].len / P, m = b[2].len / I, mr = b[6].len / I, kr = b[8].len / P - 1, km = b[9].len / I;
    Py_ssize_t pm = b[17].len / I;
    const int64_t *slots = b[11].buf, *kp = b[8].buf, *ps = b[15].buf, *pe = b[16].buf;
    const uint8_t *since = b[12].buf;
    if (kr < 0 || b[0].len != rows * P || b[1].len != rows * P || b[2].len != m * I || b[3].len != m * D ||
        b[4].len != m || b[5].len != (rows + 1) * P || b[6].len != mr * I || b[7].len != mr * D ||
        b[8].len != (kr + 1) * P || b[9].len != km * I || b[10].len != km * D || b[11].len != rows * P ||
        b[12].len != rows || b[14].len != rows * D || b[15].len != rows * P || b[16].len != rows * P ||
        b[17].len != pm * I || b[18].len != pm * D || b[19].len != (rows + 1) * P || b[22].len != rows) {
        PyErr_SetString(PyExc_ValueError, "moved_difference needs assemble's row spans, mask and object columns, a CSR "
                                          "matrix of kept rows, an int64 slot per row, a since flag, a row sum and a "
                                          "span of the last D per row, an output indptr of r + 1 and a flag per row");
        goto done;
    }
    int any_since = 0;
    for (Py_ssize_t k = 0; k < rows; ++k) any_since |= since[k];
    if (any_since && b[13].len != m) {
        PyErr_SetString(PyExc_ValueError, "moved_difference: the rows' last hidden mask must have one flag per entry");
        goto done;
    }
    if (bad_spans(b[0].buf, b[1].buf, rows, m) || bad_indptr(b[5].buf, rows, mr) || bad_indptr(kp, kr, km) ||
        bad_spans(ps, pe, rows, pm)) {
        PyErr_SetString(PyExc_ValueError, "moved_difference: a row's span lies outside the entries, or an indptr does "
                                          "not run from 0 to its entries without decreasing");
        goto done;
    }
    const Py_ssize_t kept = kept_entries("moved_difference", slots, kp, rows, kr);
    if (kept < 0) goto done;
    const Py_ssize_t most = span_entries(b[0].buf, b[1].buf, rows) + mr + kept + span_entries(ps, pe, rows);
    if (b[20].len < most * I || b[21].len < most * D) {
        PyErr_Format(PyExc_ValueError, "moved_difference: the outputs hold fewer than the %zd entries the rows may have",
                     most);
        goto done;
    }
    Py_ssize_t n;
    Py_BEGIN_ALLOW_THREADS
    n = moved_difference(rows, b[0].buf, b[1].buf, b[2].buf, b[3].buf, b[4].buf, b[5].buf, b[6].buf, b[7].buf, kp,
                         b[9].buf, b[10].buf, slots, since, b[13].buf, b[14].buf, ps, pe, b[17].buf, b[18].buf,
                         (int32_t)first_object, b[19].buf, b[20].buf, b[21].buf, b[22].buf);
    Py_END_ALLOW_THREADS
    result = n < -1 - rows ? PyErr_NoMemory() : PyLong_FromSsize_t(n);
done:
    for (int k = 0; k < MOVED_BUFFERS; ++k) PyBuffer_Release(&b[k]);
    return result;
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
    {"moved_difference", py_moved_difference, METH_VARARGS,
     "moved_difference(starts, ends, indices, data, hidden, r_indptr, r_indices, r_data, k_indptr, k_indices, k_data, "
     "slots, since, hidden_prev, row_sums, p_starts, p_ends, p_indices, p_data, first_object, out_indptr, out_indices, "
     "out_data, out_capped) -> nnz: assemble's rows minus kept rows slots[i], the rows themselves never written, from the last "
     "D where since (-1 - i: row i's columns out of order)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_poserows",
                                    "Rows of F at the objects' poses, and their change from the rows kept (native).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__poserows(void) { return PyModule_Create(&module); }
