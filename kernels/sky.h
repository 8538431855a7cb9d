// Sky luminance for rays that leave the scene: the uniform sky, the traditional CIE overcast
// sky and the CIE standard general skies (CIE S 011 / ISO 15469), over a uniform ground.
// Shared by the hemicube gathers (gather.cl) and the path tracer (pathtrace.cl).
//
// sky: 4 float4 (packed by pydynrad.lights.sky.pack_sky):
//   [0] up.xyz (unit zenith), mode (0 no sky, 1 CIE general sky, 2 traditional overcast)
//   [1] sun.xyz (unit, towards the sun), zenith luminance Lz (cd/m2)
//   [2] a, b, c, d of the gradation phi(Z) = 1 + a exp(b / cos Z) and the indicatrix
//       f(chi) = 1 + c (exp(d chi) - exp(d pi / 2)) + e cos^2 chi
//   [3] e, 1 / (f(Z_sun) phi(0)), ground luminance (cd/m2), unused
// The uniform sky is the general sky with a = c = e = 0.
#ifndef PYDYNRAD_SKY_H
#define PYDYNRAD_SKY_H

// Luminance seen along unit direction w (0 without a sky). Below the horizon: the ground's.
inline float sky_luminance(__global const float4 *sky, float3 w)
{
    const float4 s0 = sky[0];
    const int mode = (int)s0.w;
    if (mode == 0) return 0.0f;
    const float cz = w.x * s0.x + w.y * s0.y + w.z * s0.z;
    if (cz <= 0.0f) return sky[3].z;
    const float4 s1 = sky[1];
    if (mode == 2) return s1.w * (1.0f + 2.0f * cz) * (1.0f / 3.0f);
    const float4 p = sky[2], q = sky[3];
    const float cchi = clamp(w.x * s1.x + w.y * s1.y + w.z * s1.z, -1.0f, 1.0f);
    const float chi = acos(cchi);
    const float f = 1.0f + p.z * (exp(p.w * chi) - exp(p.w * 1.5707963267948966f)) + q.x * cchi * cchi;
    const float phi = 1.0f + p.x * exp(p.y / cz);
    return s1.w * f * phi * q.y;
}

#endif
