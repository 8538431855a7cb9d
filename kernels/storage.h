// Storage types for device-resident matrices (the multibounce matrix K and its updates).
//
// Select one with a build define: STORAGE_FP16, STORAGE_FP32 (default) or STORAGE_FP64.
//   STORE_T       element type in memory (half is only a storage type: no cl_khr_fp16 needed)
//   REAL          compute type: float for fp16/fp32 storage, double for fp64 storage
//   REALV(n)      REAL vector type of width n (n = 2, 4, 8, 16)
//   LOAD(p, i)    element i of p as REAL;           STORE(v, p, i)   p[i] = v (fp16: round to nearest even)
//   LOADV(n, p, i) n elements p[i..i+n) as REALV(n); STOREV(n, v, p, i) the inverse
//   VLOADR(n, p, i) n elements of a REAL array (vectors x, y live in REAL, not in STORE_T)
// Vector forms need only element alignment (vload_half*/vload* semantics), so i need not be
// a multiple of n.
#ifndef PYDYNRAD_STORAGE_H
#define PYDYNRAD_STORAGE_H

#define PDR_CAT(a, b) a##b
#define PDR_XCAT(a, b) PDR_CAT(a, b)

#if defined(STORAGE_FP64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double STORE_T;
typedef double REAL;
#define REAL_BASE double
#define LOAD(p, i) ((p)[i])
#define STORE(v, p, i) ((p)[i] = (v))
#define LOADV(n, p, i) PDR_XCAT(vload, n)(0, (p) + (i))
#define STOREV(n, v, p, i) PDR_XCAT(vstore, n)((v), 0, (p) + (i))
#elif defined(STORAGE_FP16)
typedef half STORE_T;
typedef float REAL;
#define REAL_BASE float
#define LOAD(p, i) vload_half(0, (p) + (i))
#define STORE(v, p, i) vstore_half_rte((v), 0, (p) + (i))
#define LOADV(n, p, i) PDR_XCAT(vload_half, n)(0, (p) + (i))
#define STOREV(n, v, p, i) PDR_XCAT(PDR_XCAT(vstore_half, n), _rte)((v), 0, (p) + (i))
#else
#ifndef STORAGE_FP32
#define STORAGE_FP32
#endif
typedef float STORE_T;
typedef float REAL;
#define REAL_BASE float
#define LOAD(p, i) ((p)[i])
#define STORE(v, p, i) ((p)[i] = (v))
#define LOADV(n, p, i) PDR_XCAT(vload, n)(0, (p) + (i))
#define STOREV(n, v, p, i) PDR_XCAT(vstore, n)((v), 0, (p) + (i))
#endif

#define REALV(n) PDR_XCAT(REAL_BASE, n)
#define VLOADR(n, p, i) PDR_XCAT(vload, n)(0, (p) + (i))

// n-wide access for the kernels' inner loops (n = 4, 8 or 16). With PDR_CLANG_VECTORS (set by
// the host on clang-based CPU compilers such as PoCL, whose buffers are aligned to >= 128 bytes)
// loads and stores are aligned vector dereferences and fp16 converts with
// __builtin_convertvector (F16C instructions): PoCL does not inline its vload*/vstore*
// builtins, and a call inside an inner loop spills every vector register. The pointer must be
// aligned to the vector's size.
//   KVN(n, p) / KVN_STORE(n, v, p): n elements of K at p as REALV(n); RVN(n, p) / RVN_STORE:
//   the same for REAL arrays; KV, RV, ...: the same at the kernel's width VW (from the host);
//   K1(p, i): one element of K as REAL (a plain load, without the vload_half call, where the
//   compiler allows; p 4-byte aligned).
#ifdef PDR_CLANG_VECTORS
#define RVN(n, p) (*(__global const REALV(n) *)(p))
#define RVN_STORE(n, v, p) (*(__global REALV(n) *)(p) = (v))
#if defined(STORAGE_FP16)
typedef __fp16 pdr_half4 __attribute__((ext_vector_type(4)));
typedef __fp16 pdr_half8 __attribute__((ext_vector_type(8)));
typedef __fp16 pdr_half16 __attribute__((ext_vector_type(16)));
#define KVN(n, p) __builtin_convertvector(*(__global const PDR_XCAT(pdr_half, n) *)(p), REALV(n))
#define KVN_STORE(n, v, p) (*(__global PDR_XCAT(pdr_half, n) *)(p) = __builtin_convertvector((v), PDR_XCAT(pdr_half, n)))
#else
#define KVN(n, p) RVN(n, p)
#define KVN_STORE(n, v, p) RVN_STORE(n, v, p)
#endif
#else
#define RVN(n, p) PDR_XCAT(vload, n)(0, (p))
#define RVN_STORE(n, v, p) PDR_XCAT(vstore, n)((v), 0, (p))
#define KVN(n, p) LOADV(n, (p), 0)
#define KVN_STORE(n, v, p) STOREV(n, (v), (p), 0)
#endif
#ifdef VW
typedef REALV(VW) realv;
#define RV(p) RVN(VW, p)
#define RV_STORE(v, p) RVN_STORE(VW, v, p)
#define KV(p) KVN(VW, p)
#define KV_STORE(v, p) KVN_STORE(VW, v, p)
#endif

#if defined(PDR_CLANG_VECTORS) && defined(STORAGE_FP16)
typedef __fp16 pdr_half2 __attribute__((ext_vector_type(2)));
// Scalar half loads need cl_khr_fp16; an aligned pair of halves does not (p 4-byte aligned).
inline REAL pdr_half_at(__global const STORE_T *p, int i)
{
    const float2 f = __builtin_convertvector(*(__global const pdr_half2 *)(p + (i & ~1)), float2);
    return (i & 1) ? f.y : f.x;
}
#define K1(p, i) pdr_half_at((p), (i))
#else
#define K1(p, i) LOAD(p, i)
#endif

// Full unrolling of a short constant-count loop whose arrays must stay in registers (clang's
// pragma; other compilers decide for themselves).
#ifdef __clang__
#define PDR_UNROLL _Pragma("unroll")
#else
#define PDR_UNROLL
#endif

// Horizontal sums, pairwise so rounding grows like log(n).
inline REAL pdr_hsum4(REALV(4) a) { return (a.x + a.y) + (a.z + a.w); }
#define PDR_HSUM_4(a) pdr_hsum4(a)
#define PDR_HSUM_8(a) pdr_hsum4((a).lo + (a).hi)
#define PDR_HSUM_16(a) pdr_hsum4(((a).lo.lo + (a).lo.hi) + ((a).hi.lo + (a).hi.hi))
#define HSUM(n, a) PDR_XCAT(PDR_HSUM_, n)(a)

#endif
