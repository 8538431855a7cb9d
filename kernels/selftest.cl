// Launch bound: one multiply per item (a test kernel).
// A minimal program: lets the device layer and the tests check building, caching, defines
// and build-log reporting without depending on any real kernel.
#ifndef SELFTEST_SCALE
#define SELFTEST_SCALE 2
#endif

#ifdef SELFTEST_BREAK
this line is not OpenCL C;
#endif

#ifdef SELFTEST_WARN
#warning "selftest: a build that succeeds with a non-empty log"
#endif

__kernel void scale(__global float *x)
{
    const size_t i = get_global_id(0);
    x[i] *= SELFTEST_SCALE;
}
