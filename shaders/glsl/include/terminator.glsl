// The shadow terminator fix of Hanika 2021 ("Hacking the shadow terminator", Ray Tracing Gems II ch. 4): a ray
// that leaves a flat triangle of a smooth (vertex-normal) mesh starts from a point moved towards where the curved
// surface the normals describe would be. Each vertex's tangent plane (its normal) gets the point projected onto it
// where the point lies below that plane; the barycentric mean of the three is the new origin. Flat-shaded triangles
// (vertex normals = the facet's) keep their point; the offset is at most the triangle's deviation from the
// smooth surface, so it vanishes as meshes are refined.
#ifndef TERMINATOR_GLSL
#define TERMINATOR_GLSL

// p: the hit point, b: its barycentrics (b.x for p0, ...), p0..p2: the triangle's vertices, n0..n2: their unit
// normals, turned to the side the ray leaves from. Returns the shadow ray's origin (before offset_ray).
vec3 terminator_offset(vec3 p, vec3 b, vec3 p0, vec3 p1, vec3 p2, vec3 n0, vec3 n1, vec3 n2) {
    vec3 t0 = p - p0, t1 = p - p1, t2 = p - p2;
    t0 -= min(0.0, dot(t0, n0)) * n0;
    t1 -= min(0.0, dot(t1, n1)) * n1;
    t2 -= min(0.0, dot(t2, n2)) * n2;
    return b.x * (p0 + t0) + b.y * (p1 + t1) + b.z * (p2 + t2);
}

#endif
