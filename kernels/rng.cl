// Counter-based random numbers: a stream is a pure function of (seed, item, sample), so a
// result does not depend on how samples are split into passes or work-items, and any
// sample can be replayed. The hash is PCG's output permutation (Jarzynski and Olano,
// "Hash Functions for GPU Rendering", JCGT 2020); each draw advances the stream by one hash.
#ifndef PYDYNRAD_RNG_CL
#define PYDYNRAD_RNG_CL

inline uint rng_hash(uint v)
{
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// The stream of sample `sample` of item `item` (a pixel or a patch) under `seed`.
inline uint rng_stream(uint seed, uint item, uint sample)
{
    return rng_hash(item ^ rng_hash(sample ^ rng_hash(seed)));
}

// Uniform in [0, 1): the top 24 bits, so the value is exact in float and never 1.
inline float rng_next(uint *state)
{
    *state = rng_hash(*state);
    return (float)(*state >> 8) * (1.0f / 16777216.0f);
}

#endif
