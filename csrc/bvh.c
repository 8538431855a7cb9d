/*
 * Binned-SAH bounding volume hierarchy builder for triangle patches.
 *
 * Host-side by design: building is branchy, sequential and memory-allocating, which suits a
 * CPU and not an OpenCL device. A binary tree is built with binned SAH, then collapsed to a
 * 4-wide tree (each wide node adopts the children of its largest-area interior children
 * until it has four), flattened to plain arrays that the traversal in kernels/bvh.cl walks:
 *
 *   wide node k: 8 float4 = 32 floats at nodes[32 k]:
 *     minx[4], maxx[4], miny[4], maxy[4], minz[4], maxz[4]   the four children's boxes (SoA)
 *     int32 child[4]                                          bit-cast into the float slots
 *     4 floats of padding (a node spans exactly two 64-byte cache lines)
 *   child c: > 0 the wide node of that index; 0 an empty slot (its box is inverted: +inf..-inf,
 *   which no ray enters); < 0 a leaf ~(first << 3 | (count - 1)): triangles first .. first + count
 *   in BVH order. Node 0 is the root; the root's own box is not stored (its children's are).
 *
 * Python signature:  _bvh.build(tris, nodes, order, packed) -> n_nodes (wide nodes written)
 *   tris   : C-contiguous float32 buffer of N*9 values (three corners per triangle), N < 2^28
 *   nodes  : writable float32 buffer of at least max(1, N)*32 values
 *   order  : writable int32 buffer of N values, filled with the triangle permutation
 *   packed : writable float32 buffer of N*12 values, filled in BVH order with
 *            v0, 0, v1, 0, v2, 0 (the corners, so shared corners stay bit-identical)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define N_BINS 16
#define MAX_LEAF 4
#define TRAVERSAL_COST 1.0f
#define WIDTH 4
#define NODE_FLOATS 32
#define MAX_TRIANGLES (1 << 28) /* the leaf encoding keeps 28 bits for the first triangle */

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

/* A node still to build. Its bounds (of the boxes and of the centroids) come from the
 * parent's bins, which saves a pass over the range at every level; known == 0 asks for a pass. */
typedef struct {
    int32_t node, start, end, known;
    Box bounds, cbounds;
} Task;

/* One primitive as the builder sees it; the array of these is permuted in place while
 * partitioning, so every pass over a node's range reads memory sequentially (an index
 * indirection into 1M boxes would miss the cache on nearly every access). */
typedef struct {
    Box box;
    float cent[3];
    int32_t index;
} Prim;

static int bin_of(float c, float lo, float scale)
{
    int b = (int)((c - lo) * scale);
    return b < 0 ? 0 : (b >= N_BINS ? N_BINS - 1 : b);
}

/* The binary tree; returns its node count, or -1 when memory runs out. */
static int32_t build_binary(const float *tris, int32_t n, Node *nodes, int32_t *order, float *packed)
{
    Prim *prims = malloc(sizeof(Prim) * (size_t)(n > 0 ? n : 1));
    Task *stack = malloc(sizeof(Task) * 128);
    if (!prims || !stack) {
        free(prims); free(stack);
        return -1;
    }
    for (int32_t i = 0; i < n; ++i) {
        Prim *p = &prims[i];
        box_empty(&p->box);
        for (int c = 0; c < 3; ++c) box_grow_point(&p->box, tris + 9 * (size_t)i + 3 * c);
        for (int a = 0; a < 3; ++a) p->cent[a] = 0.5f * (p->box.bmin[a] + p->box.bmax[a]);
        p->index = i;
    }

    int32_t n_nodes = 1, sp = 0;
    stack[sp++] = (Task){0, 0, n, 0};
    while (sp > 0) {
        Task t = stack[--sp];
        Node *node = &nodes[t.node];
        Box bounds = t.bounds, cbounds = t.cbounds;
        if (!t.known) {
            box_empty(&bounds);
            box_empty(&cbounds);
            for (int32_t i = t.start; i < t.end; ++i) {
                box_grow_box(&bounds, &prims[i].box);
                box_grow_point(&cbounds, prims[i].cent);
            }
        }
        memcpy(node->bmin, bounds.bmin, sizeof bounds.bmin);
        memcpy(node->bmax, bounds.bmax, sizeof bounds.bmax);
        int32_t count = t.end - t.start;
        if (count <= 1) {
            node->offset = t.start;
            node->count = count;
            continue;
        }

        /* Bin all three axes in one sequential pass. */
        float lo[3], scale[3];
        int32_t bin_count[3][N_BINS];
        Box bin_box[3][N_BINS], bin_cbox[3][N_BINS];
        for (int a = 0; a < 3; ++a) {
            float extent = cbounds.bmax[a] - cbounds.bmin[a];
            lo[a] = cbounds.bmin[a];
            scale[a] = extent > 0.0f ? N_BINS / extent : 0.0f;
            for (int b = 0; b < N_BINS; ++b) {
                bin_count[a][b] = 0;
                box_empty(&bin_box[a][b]);
                box_empty(&bin_cbox[a][b]);
            }
        }
        for (int32_t i = t.start; i < t.end; ++i) {
            const Prim *p = &prims[i];
            for (int a = 0; a < 3; ++a) {
                int b = bin_of(p->cent[a], lo[a], scale[a]);
                bin_count[a][b]++;
                box_grow_box(&bin_box[a][b], &p->box);
                box_grow_point(&bin_cbox[a][b], p->cent);
            }
        }

        int best_axis = -1, best_split = 0;
        float best_cost = FLT_MAX;
        for (int a = 0; a < 3; ++a) {
            if (scale[a] == 0.0f) continue;
            /* Sweep from the right to get the cost of every right part, then from the left. */
            float right_area[N_BINS];
            int32_t right_count[N_BINS];
            Box acc;
            box_empty(&acc);
            int32_t cnt = 0;
            for (int b = N_BINS - 1; b > 0; --b) {
                box_grow_box(&acc, &bin_box[a][b]);
                cnt += bin_count[a][b];
                right_area[b] = box_half_area(&acc);
                right_count[b] = cnt;
            }
            box_empty(&acc);
            cnt = 0;
            for (int b = 0; b < N_BINS - 1; ++b) {
                box_grow_box(&acc, &bin_box[a][b]);
                cnt += bin_count[a][b];
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
        int32_t mid, known = 0;
        if (count <= MAX_LEAF && (sah >= (float)count || best_axis < 0)) {
            node->offset = t.start;
            node->count = count;
            continue;
        }
        if (best_axis < 0) {
            /* All centroids coincide: no spatial split exists, so split the index range. */
            mid = t.start + count / 2;
        } else {
            int32_t i = t.start, j = t.end - 1;
            while (i <= j) {
                if (bin_of(prims[i].cent[best_axis], lo[best_axis], scale[best_axis]) < best_split) {
                    ++i;
                } else {
                    Prim tmp = prims[i];
                    prims[i] = prims[j];
                    prims[j--] = tmp;
                }
            }
            mid = i;
            if (mid == t.start || mid == t.end)
                mid = t.start + count / 2;
            else
                known = 1;
        }

        int32_t left = n_nodes;
        n_nodes += 2;
        node->offset = left;
        node->count = 0;
        if (sp + 2 > 128) { /* depth beyond 64 is impossible with halving splits; guard anyway */
            free(prims); free(stack);
            return -1;
        }
        Task lt = {left, t.start, mid, known}, rt = {left + 1, mid, t.end, known};
        if (known) {
            box_empty(&lt.bounds); box_empty(&lt.cbounds);
            box_empty(&rt.bounds); box_empty(&rt.cbounds);
            for (int b = 0; b < N_BINS; ++b) {
                Task *side = b < best_split ? &lt : &rt;
                box_grow_box(&side->bounds, &bin_box[best_axis][b]);
                box_grow_box(&side->cbounds, &bin_cbox[best_axis][b]);
            }
        }
        /* Larger half first onto the stack so the smaller one is processed next: bounded depth. */
        if (mid - t.start > t.end - mid) {
            stack[sp++] = lt;
            stack[sp++] = rt;
        } else {
            stack[sp++] = rt;
            stack[sp++] = lt;
        }
    }
    for (int32_t i = 0; i < n; ++i) {
        int32_t k = prims[i].index;
        const float *v = tris + 9 * (size_t)k;
        float *out = packed + 12 * (size_t)i;
        order[i] = k;
        for (int c = 0; c < 3; ++c)
            for (int a = 0; a < 3; ++a) out[4 * c + a] = v[3 * c + a];
        out[3] = out[7] = out[11] = 0.0f;
    }
    free(prims);
    free(stack);
    return n_nodes;
}

static float node_half_area(const Node *b)
{
    Box box;
    memcpy(box.bmin, b->bmin, sizeof box.bmin);
    memcpy(box.bmax, b->bmax, sizeof box.bmax);
    return box_half_area(&box);
}

/* Collapse the binary tree into 4-wide nodes (layout at the top of this file). Returns the
 * wide node count, or -1 when memory runs out. */
static int32_t collapse(const Node *bin, float *out)
{
    /* Pending wide nodes as (binary node, wide index) pairs; grown on demand. */
    int32_t cap = 256, sp = 0, n_wide = 1;
    int32_t *stack = malloc(sizeof(int32_t) * 2 * (size_t)cap);
    if (!stack) return -1;
    stack[sp++] = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        int32_t w = stack[--sp], b = stack[--sp];
        int32_t kids[WIDTH], nk = 0;
        if (bin[b].count > 0) {
            kids[nk++] = b; /* the whole tree is one leaf: the root holds it as its only child */
        } else {
            kids[nk++] = bin[b].offset;
            kids[nk++] = bin[b].offset + 1;
        }
        while (nk < WIDTH) {
            int best = -1;
            float best_area = -1.0f;
            for (int c = 0; c < nk; ++c) {
                float area = node_half_area(&bin[kids[c]]);
                if (bin[kids[c]].count == 0 && area > best_area) {
                    best = c;
                    best_area = area;
                }
            }
            if (best < 0) break;
            int32_t first = bin[kids[best]].offset;
            kids[best] = first;
            kids[nk++] = first + 1;
        }
        float *node = out + (size_t)w * NODE_FLOATS;
        int32_t *child = (int32_t *)(node + 6 * WIDTH);
        for (int c = 0; c < WIDTH; ++c) {
            if (c >= nk) {
                for (int a = 0; a < 3; ++a) {
                    node[(2 * a) * WIDTH + c] = INFINITY;
                    node[(2 * a + 1) * WIDTH + c] = -INFINITY;
                }
                child[c] = 0;
                continue;
            }
            const Node *k = &bin[kids[c]];
            for (int a = 0; a < 3; ++a) {
                node[(2 * a) * WIDTH + c] = k->bmin[a];
                node[(2 * a + 1) * WIDTH + c] = k->bmax[a];
            }
            if (k->count > 0) {
                child[c] = ~((k->offset << 3) | (k->count - 1));
                continue;
            }
            if (sp + 2 > 2 * cap) {
                int32_t *grown = realloc(stack, sizeof(int32_t) * 4 * (size_t)cap);
                if (!grown) {
                    free(stack);
                    return -1;
                }
                stack = grown;
                cap *= 2;
            }
            child[c] = n_wide;
            stack[sp++] = kids[c];
            stack[sp++] = n_wide++;
        }
        for (int c = 0; c < WIDTH; ++c) node[7 * WIDTH + c] = 0.0f;
    }
    free(stack);
    return n_wide;
}

/* Binary build, then the wide collapse into nodes; returns the wide node count or -1. */
static int32_t build_bvh(const float *tris, int32_t n, float *nodes, int32_t *order, float *packed)
{
    Node *bin = malloc(sizeof(Node) * (size_t)(2 * n - 1));
    if (!bin) return -1;
    int32_t n_wide = build_binary(tris, n, bin, order, packed) < 0 ? -1 : collapse(bin, nodes);
    free(bin);
    return n_wide;
}

static PyObject *py_build(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer tris, nodes, order, packed;
    if (!PyArg_ParseTuple(args, "y*w*w*w*", &tris, &nodes, &order, &packed)) return NULL;
    PyObject *result = NULL;
    Py_ssize_t n = tris.len / (Py_ssize_t)(9 * sizeof(float));
    if (tris.len != n * (Py_ssize_t)(9 * sizeof(float)) || n >= MAX_TRIANGLES) {
        PyErr_SetString(PyExc_ValueError, "tris must hold N*9 float32 values with N < 2^28");
    } else if (nodes.len < (Py_ssize_t)sizeof(float) * NODE_FLOATS * (n > 0 ? n : 1)) {
        PyErr_SetString(PyExc_ValueError, "nodes buffer too small: need max(1, N)*128 bytes");
    } else if (order.len < (Py_ssize_t)sizeof(int32_t) * n) {
        PyErr_SetString(PyExc_ValueError, "order buffer too small: need N int32 values");
    } else if (packed.len < (Py_ssize_t)sizeof(float) * 12 * n) {
        PyErr_SetString(PyExc_ValueError, "packed buffer too small: need N*12 float32 values");
    } else if (n == 0) {
        PyErr_SetString(PyExc_ValueError, "cannot build a BVH over zero triangles");
    } else {
        int32_t n_nodes;
        Py_BEGIN_ALLOW_THREADS
        n_nodes = build_bvh((const float *)tris.buf, (int32_t)n, (float *)nodes.buf, (int32_t *)order.buf,
                            (float *)packed.buf);
        Py_END_ALLOW_THREADS
        if (n_nodes < 0)
            PyErr_NoMemory();
        else
            result = PyLong_FromLong(n_nodes);
    }
    PyBuffer_Release(&tris);
    PyBuffer_Release(&nodes);
    PyBuffer_Release(&order);
    PyBuffer_Release(&packed);
    return result;
}

static PyMethodDef methods[] = {
    {"build", py_build, METH_VARARGS, "build(tris, nodes, order, packed) -> n_nodes: binned-SAH 4-wide BVH over triangles"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_bvh", "Binned-SAH BVH builder (native).", -1, methods};

PyMODINIT_FUNC PyInit__bvh(void) { return PyModule_Create(&module); }
