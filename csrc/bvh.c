/*
 * Binned-SAH bounding volume hierarchy builder for triangle patches.
 *
 * Host-side by design: building is branchy, sequential and memory-allocating, which suits a
 * CPU and not an OpenCL device. The result is flattened to plain arrays that the traversal
 * in kernels/bvh.cl walks:
 *
 *   node k: float bmin[3]; int32 offset; float bmax[3]; int32 count   (32 bytes, two float4)
 *     count == 0: interior, children at offset and offset + 1
 *     count  > 0: leaf, primitives order[offset .. offset + count)
 *
 * Python signature:  _bvh.build(tris, nodes, order) -> n_nodes
 *   tris  : C-contiguous float32 buffer of N*9 values (three corners per triangle)
 *   nodes : writable float32 buffer of at least max(1, 2N-1)*8 values (int fields bit-cast)
 *   order : writable int32 buffer of N values, filled with the triangle permutation
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <float.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define N_BINS 16
#define MAX_LEAF 4
#define TRAVERSAL_COST 1.0f

typedef struct {
    float bmin[3];
    int32_t offset;
    float bmax[3];
    int32_t count;
} Node;

typedef struct {
    float bmin[3], bmax[3];
} Box;

static void box_empty(Box *b)
{
    for (int a = 0; a < 3; ++a) {
        b->bmin[a] = FLT_MAX;
        b->bmax[a] = -FLT_MAX;
    }
}

static void box_grow_box(Box *b, const Box *o)
{
    for (int a = 0; a < 3; ++a) {
        if (o->bmin[a] < b->bmin[a]) b->bmin[a] = o->bmin[a];
        if (o->bmax[a] > b->bmax[a]) b->bmax[a] = o->bmax[a];
    }
}

static void box_grow_point(Box *b, const float *p)
{
    for (int a = 0; a < 3; ++a) {
        if (p[a] < b->bmin[a]) b->bmin[a] = p[a];
        if (p[a] > b->bmax[a]) b->bmax[a] = p[a];
    }
}

static float box_half_area(const Box *b)
{
    float dx = b->bmax[0] - b->bmin[0], dy = b->bmax[1] - b->bmin[1], dz = b->bmax[2] - b->bmin[2];
    if (dx < 0.0f) return 0.0f;
    return dx * dy + dy * dz + dz * dx;
}

typedef struct {
    int32_t node, start, end;
} Task;

/* Returns the node count, or -1 when memory runs out. */
static int32_t build_bvh(const float *tris, int32_t n, Node *nodes, int32_t *order)
{
    Box *pbox = malloc(sizeof(Box) * (size_t)(n > 0 ? n : 1));
    float *cent = malloc(sizeof(float) * 3 * (size_t)(n > 0 ? n : 1));
    Task *stack = malloc(sizeof(Task) * 128);
    if (!pbox || !cent || !stack) {
        free(pbox); free(cent); free(stack);
        return -1;
    }
    for (int32_t i = 0; i < n; ++i) {
        box_empty(&pbox[i]);
        for (int c = 0; c < 3; ++c) box_grow_point(&pbox[i], tris + 9 * (size_t)i + 3 * c);
        for (int a = 0; a < 3; ++a) cent[3 * i + a] = 0.5f * (pbox[i].bmin[a] + pbox[i].bmax[a]);
        order[i] = i;
    }

    int32_t n_nodes = 1, sp = 0;
    stack[sp++] = (Task){0, 0, n};
    while (sp > 0) {
        Task t = stack[--sp];
        Node *node = &nodes[t.node];
        Box bounds, cbounds;
        box_empty(&bounds);
        box_empty(&cbounds);
        for (int32_t i = t.start; i < t.end; ++i) {
            box_grow_box(&bounds, &pbox[order[i]]);
            box_grow_point(&cbounds, &cent[3 * order[i]]);
        }
        memcpy(node->bmin, bounds.bmin, sizeof bounds.bmin);
        memcpy(node->bmax, bounds.bmax, sizeof bounds.bmax);
        int32_t count = t.end - t.start;

        int best_axis = -1, best_split = 0;
        float best_cost = FLT_MAX;
        for (int a = 0; a < 3; ++a) {
            float lo = cbounds.bmin[a], extent = cbounds.bmax[a] - lo;
            if (!(extent > 0.0f)) continue;
            float scale = N_BINS / extent;
            int32_t bin_count[N_BINS] = {0};
            Box bin_box[N_BINS];
            for (int b = 0; b < N_BINS; ++b) box_empty(&bin_box[b]);
            for (int32_t i = t.start; i < t.end; ++i) {
                int b = (int)((cent[3 * order[i] + a] - lo) * scale);
                b = b < 0 ? 0 : (b >= N_BINS ? N_BINS - 1 : b);
                bin_count[b]++;
                box_grow_box(&bin_box[b], &pbox[order[i]]);
            }
            /* Sweep from the right to get the cost of every right part, then from the left. */
            float right_area[N_BINS];
            int32_t right_count[N_BINS];
            Box acc;
            box_empty(&acc);
            int32_t cnt = 0;
            for (int b = N_BINS - 1; b > 0; --b) {
                box_grow_box(&acc, &bin_box[b]);
                cnt += bin_count[b];
                right_area[b] = box_half_area(&acc);
                right_count[b] = cnt;
            }
            box_empty(&acc);
            cnt = 0;
            for (int b = 0; b < N_BINS - 1; ++b) {
                box_grow_box(&acc, &bin_box[b]);
                cnt += bin_count[b];
                if (cnt == 0 || right_count[b + 1] == 0) continue;
                float cost = box_half_area(&acc) * cnt + right_area[b + 1] * right_count[b + 1];
                if (cost < best_cost) {
                    best_cost = cost;
                    best_axis = a;
                    best_split = b + 1;
                }
            }
        }

        float parent_area = box_half_area(&bounds);
        float sah = parent_area > 0.0f ? TRAVERSAL_COST + best_cost / parent_area : FLT_MAX;
        int32_t mid;
        if (count <= 1 || (count <= MAX_LEAF && sah >= (float)count)) {
            node->offset = t.start;
            node->count = count;
            continue;
        }
        if (best_axis < 0) {
            /* All centroids coincide: no spatial split exists, so split the index range. */
            if (count <= MAX_LEAF) {
                node->offset = t.start;
                node->count = count;
                continue;
            }
            mid = t.start + count / 2;
        } else {
            float lo = cbounds.bmin[best_axis];
            float scale = N_BINS / (cbounds.bmax[best_axis] - lo);
            int32_t i = t.start, j = t.end - 1;
            while (i <= j) {
                int b = (int)((cent[3 * order[i] + best_axis] - lo) * scale);
                b = b < 0 ? 0 : (b >= N_BINS ? N_BINS - 1 : b);
                if (b < best_split) {
                    ++i;
                } else {
                    int32_t tmp = order[i];
                    order[i] = order[j];
                    order[j--] = tmp;
                }
            }
            mid = i;
            if (mid == t.start || mid == t.end) mid = t.start + count / 2;
        }
        int32_t left = n_nodes;
        n_nodes += 2;
        node->offset = left;
        node->count = 0;
        if (sp + 2 > 128) { /* depth beyond 64 is impossible with halving splits; guard anyway */
            free(pbox); free(cent); free(stack);
            return -1;
        }
        /* Larger half first onto the stack so the smaller one is processed next: bounded depth. */
        if (mid - t.start > t.end - mid) {
            stack[sp++] = (Task){left, t.start, mid};
            stack[sp++] = (Task){left + 1, mid, t.end};
        } else {
            stack[sp++] = (Task){left + 1, mid, t.end};
            stack[sp++] = (Task){left, t.start, mid};
        }
    }
    free(pbox);
    free(cent);
    free(stack);
    return n_nodes;
}

static PyObject *py_build(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer tris, nodes, order;
    if (!PyArg_ParseTuple(args, "y*w*w*", &tris, &nodes, &order)) return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = tris.len / (Py_ssize_t)(9 * sizeof(float));
    if (tris.len != n * (Py_ssize_t)(9 * sizeof(float)) || n > INT32_MAX / 2) {
        PyErr_SetString(PyExc_ValueError, "tris must hold N*9 float32 values with N < 2^30");
    } else if (nodes.len < (Py_ssize_t)sizeof(Node) * (n > 0 ? 2 * n - 1 : 1)) {
        PyErr_SetString(PyExc_ValueError, "nodes buffer too small: need (2N-1)*32 bytes");
    } else if (order.len < (Py_ssize_t)sizeof(int32_t) * n) {
        PyErr_SetString(PyExc_ValueError, "order buffer too small: need N int32 values");
    } else if (n == 0) {
        PyErr_SetString(PyExc_ValueError, "cannot build a BVH over zero triangles");
    } else {
        int32_t n_nodes;
        Py_BEGIN_ALLOW_THREADS
        n_nodes = build_bvh((const float *)tris.buf, (int32_t)n, (Node *)nodes.buf, (int32_t *)order.buf);
        Py_END_ALLOW_THREADS
        if (n_nodes < 0)
            PyErr_NoMemory();
        else
            result = PyLong_FromLong(n_nodes);
    }
    PyBuffer_Release(&tris);
    PyBuffer_Release(&nodes);
    PyBuffer_Release(&order);
    return result;
}

static PyMethodDef methods[] = {
    {"build", py_build, METH_VARARGS, "build(tris, nodes, order) -> n_nodes: binned-SAH BVH over triangles"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_bvh", "Binned-SAH BVH builder (native).", -1, methods};

PyMODINIT_FUNC PyInit__bvh(void) { return PyModule_Create(&module); }
