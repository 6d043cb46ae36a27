// Ray utilities shared by the kernels that start rays on surfaces.
#ifndef RAYUTIL_GLSL
#define RAYUTIL_GLSL

// Move a surface point p off its surface along the unit normal n so that a ray starting there does
// not hit the surface it starts on (the idea of Waechter & Binder, Ray Tracing Gems ch. 6): the step is
// a fixed number of float ulps of p's coordinates, so it scales with the magnitude of p, and a small
// absolute step near the origin where ulps vanish.
vec3 offset_ray(vec3 p, vec3 n) {
    const float near_origin = 1.0 / 32.0;
    const float abs_step = 1.0 / 65536.0;
    const float ulp_step = 256.0;
    ivec3 di = ivec3(ulp_step * n);
    // Adding to the int bits moves away from zero for positive values; flip the step for negative ones.
    ivec3 signed_di = ivec3(mix(vec3(di), -vec3(di), lessThan(p, vec3(0.0))));
    vec3 p_ulp = intBitsToFloat(floatBitsToInt(p) + signed_di);
    vec3 p_abs = p + abs_step * n;
    return mix(p_ulp, p_abs, lessThan(abs(p), vec3(near_origin)));
}

#endif
