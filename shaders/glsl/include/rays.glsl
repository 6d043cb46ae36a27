// Ray and hit records of the batch query API (engine/rt/tracer.py packs and unpacks these).
#ifndef RAYS_GLSL
#define RAYS_GLSL
struct Ray {
    vec4 origin;      // xyz origin, w: tmin
    vec4 direction;   // xyz direction (not normalized: hit = origin + t * direction), w: tmax
};
struct HitRecord {
    float t;          // +inf on a miss
    int prim;         // original triangle index, -1 on a miss
    float u, v;       // barycentrics of vertices 1 and 2
};
#endif
