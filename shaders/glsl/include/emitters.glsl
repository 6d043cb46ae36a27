// Emissive triangles as lights, for the path tracer and the real-time frame's ray passes: one triangle picked by
// power (the PathScene's CDF, engine/gpu/pathscene.py: per emissive triangle (flat id bits, cdf, probability), the
// first record's w the count's bits), a uniform point on it, and the solid-angle pdf of that choice. The including
// shader defines EMITTERS_BINDING (set 0) and includes scene_surface.glsl and rayutil.glsl first.
#ifndef EMITTERS_GLSL
#define EMITTERS_GLSL

layout(set = 0, binding = EMITTERS_BINDING) uniform samplerBuffer emitters;

uint emitter_count() { return floatBitsToUint(texelFetch(emitters, 0).w); }

// One emitter point for the shading point p from xi (x picks the triangle, yz the point on it): its radiance towards
// p, the direction, the point moved off its triangle towards p (the shadow ray's end: a ray that ended on the
// triangle would hit it short of its end where it is seen edge-on), and the solid-angle pdf. False: none (its back
// face, which emits nothing, or a degenerate triangle).
bool sample_emitter(vec3 p, vec3 xi, out vec3 wi, out vec3 target, out vec3 li, out float pdf) {
    uint lo = 0u, hi = emitter_count() - 1u;   // the first record whose cdf > xi.x
    while (lo < hi) {
        uint mid = (lo + hi) >> 1;
        if (texelFetch(emitters, int(mid)).y > xi.x) hi = mid; else lo = mid + 1u;
    }
    vec4 rec = texelFetch(emitters, int(lo));
    Tri t = load_tri(floatBitsToUint(rec.x));
    float su = sqrt(xi.y);
    float u = su * (1.0 - xi.z), v = su * xi.z;   // barycentrics of p1, p2
    vec3 q = (1.0 - u - v) * t.p0 + u * t.p1 + v * t.p2;
    vec3 c = cross(t.p1 - t.p0, t.p2 - t.p0);
    float area = 0.5 * length(c);
    vec3 to = q - p;
    float d2 = dot(to, to);
    wi = to * inversesqrt(d2);
    float cos_l = -dot(wi, c) / (2.0 * area);
    if (cos_l <= 0.0 || area <= 0.0) return false;
    target = offset_ray(q, c / (2.0 * area));
    li = tri_emission(t, u, v);
    pdf = rec.z * d2 / (area * cos_l);
    return true;
}

// The solid-angle pdf with which sample_emitter picks the point a ray along d hit on emitter surface s at distance t.
float emitter_pdf(Surface s, vec3 d, float t) {
    float prob = texelFetch(emitters, int(s.emitter) - 1).z;
    return prob * t * t / (s.area * max(dot(s.ng, -d), 1e-8));
}

// The power heuristic's weight (exponent 2) of a sample drawn with pdf a against another strategy's b.
float power_heuristic(float a, float b) {
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0;
}

#endif
