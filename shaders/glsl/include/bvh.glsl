// BVH traversal: the one include every tracing kernel shares (layout: engine/bvh/layout.py).
//
//   #define BVH_SET 1         // descriptor set of the two buffers (default 0)
//   #define BVH_BINDING 0     // nodes at BVH_BINDING, triangles at BVH_BINDING + 1 (default 0)
//   #include "bvh.glsl"
//   bool   bvh_occluded(vec3 o, vec3 d, float tmin, float tmax);   // any hit: stops at the first
//   BvhHit bvh_intersect(vec3 o, vec3 d, float tmin, float tmax);  // closest hit: t, prim (-1: miss), u, v
//
// Directions are used as given: the hit point is o + t * d. Triangles are tested with the watertight
// algorithm of Woop, Benthin and Wald (JCGT 2013), so rays do not slip through edges shared by two
// triangles; `precise` keeps the compiler from fusing the edge functions' products into FMAs, which
// would break the exact sign symmetry between neighbours.
#ifndef BVH_GLSL
#define BVH_GLSL

#ifndef BVH_SET
#define BVH_SET 0
#endif
#ifndef BVH_BINDING
#define BVH_BINDING 0
#endif
#ifndef BVH_STACK_SIZE
#define BVH_STACK_SIZE 32   // the builder caps the depth so that the stack cannot overflow
#endif
#define BVH_LEAF 0x80000000u
#define BVH_INF uintBitsToFloat(0x7f800000u)

struct BvhNode { vec4 a, b, c, d; };   // (lmin, left) (lmax, right) (rmin, lcount) (rmax, rcount)
struct BvhTri { vec4 v0, v1, v2; };    // v0.w = original triangle index (int bits)
struct BvhHit { float t; int prim; float u; float v; };

layout(std430, set = BVH_SET, binding = BVH_BINDING) readonly buffer BvhNodes { BvhNode bvh_nodes[]; };
layout(std430, set = BVH_SET, binding = BVH_BINDING + 1) readonly buffer BvhTris { BvhTri bvh_tris[]; };

// Per-ray constants of the watertight test: rows that permute + shear a vertex into ray space.
struct BvhRay {
    vec3 o, inv_d, o_inv_d;
    vec3 rx, ry, rz;
};

BvhRay bvh_ray(vec3 o, vec3 d) {
    BvhRay r;
    r.o = o;
    // Zero direction components would give 0 * inf = NaN in the slab test: nudge them to a tiny value.
    vec3 dd = mix(d, mix(vec3(1e-30), vec3(-1e-30), lessThan(d, vec3(0.0))), lessThan(abs(d), vec3(1e-30)));
    r.inv_d = 1.0 / dd;
    r.o_inv_d = o * r.inv_d;
    vec3 ad = abs(d);
    int kz = ad.x > ad.y ? (ad.x > ad.z ? 0 : 2) : (ad.y > ad.z ? 1 : 2);
    int kx = kz == 2 ? 0 : kz + 1;
    int ky = kx == 2 ? 0 : kx + 1;
    if (d[kz] < 0.0) { int t = kx; kx = ky; ky = t; }   // keep the winding
    vec3 ex = vec3(0.0), ey = vec3(0.0), ez = vec3(0.0);
    ex[kx] = 1.0; ey[ky] = 1.0; ez[kz] = 1.0;
    float sz = 1.0 / d[kz];
    r.rx = ex - (d[kx] * sz) * ez;
    r.ry = ey - (d[ky] * sz) * ez;
    r.rz = sz * ez;
    return r;
}

// Entry distance of the ray into the box, or +inf when it misses [tmin, tmax].
float bvh_box(vec3 bmin, vec3 bmax, BvhRay r, float tmin, float tmax) {
    vec3 t0 = bmin * r.inv_d - r.o_inv_d;
    vec3 t1 = bmax * r.inv_d - r.o_inv_d;
    vec3 lo = min(t0, t1), hi = max(t0, t1);
    float tn = max(max(lo.x, lo.y), max(lo.z, tmin));
    float tf = min(min(hi.x, hi.y), min(hi.z, tmax)) * 1.0000004;   // conservative: 2 ulp-ish (Ize 2013)
    return tn <= tf ? tn : BVH_INF;
}

// Watertight ray/triangle test; on a hit in [tmin, tmax] returns true with t and barycentrics of v1, v2.
bool bvh_triangle(BvhRay r, BvhTri tri, float tmin, float tmax, out float t, out float u, out float v) {
    vec3 A = tri.v0.xyz - r.o, B = tri.v1.xyz - r.o, C = tri.v2.xyz - r.o;
    float ax = dot(r.rx, A), ay = dot(r.ry, A);
    float bx = dot(r.rx, B), by = dot(r.ry, B);
    float cx = dot(r.rx, C), cy = dot(r.ry, C);
    precise float U = cx * by - cy * bx;
    precise float V = ax * cy - ay * cx;
    precise float W = bx * ay - by * ax;
    if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
    float det = U + V + W;
    if (det == 0.0) return false;
    float T = U * dot(r.rz, A) + V * dot(r.rz, B) + W * dot(r.rz, C);
    float inv_det = 1.0 / det;
    t = T * inv_det;
    if (!(t >= tmin && t <= tmax)) return false;
    u = V * inv_det;
    v = W * inv_det;
    return true;
}

bool bvh_occluded(vec3 o, vec3 d, float tmin, float tmax) {
    BvhRay r = bvh_ray(o, d);
    uint stack[BVH_STACK_SIZE];
    int sp = 0;
    uint node = 0u;
    while (true) {
        BvhNode n = bvh_nodes[node];
        uint lw = floatBitsToUint(n.a.w), rw = floatBitsToUint(n.b.w);
        bool gl = bvh_box(n.a.xyz, n.b.xyz, r, tmin, tmax) < BVH_INF;
        bool gr = bvh_box(n.c.xyz, n.d.xyz, r, tmin, tmax) < BVH_INF;
        float t, u, v;
        if (gl && (lw & BVH_LEAF) != 0u) {
            uint first = lw & ~BVH_LEAF, count = floatBitsToUint(n.c.w);
            for (uint i = first; i < first + count; ++i)
                if (bvh_triangle(r, bvh_tris[i], tmin, tmax, t, u, v)) return true;
            gl = false;
        }
        if (gr && (rw & BVH_LEAF) != 0u) {
            uint first = rw & ~BVH_LEAF, count = floatBitsToUint(n.d.w);
            for (uint i = first; i < first + count; ++i)
                if (bvh_triangle(r, bvh_tris[i], tmin, tmax, t, u, v)) return true;
            gr = false;
        }
        if (gl && gr) {
            stack[sp++] = rw;
            node = lw;
        } else if (gl || gr) {
            node = gl ? lw : rw;
        } else {
            if (sp == 0) break;
            node = stack[--sp];
        }
    }
    return false;
}

BvhHit bvh_intersect(vec3 o, vec3 d, float tmin, float tmax) {
    BvhRay r = bvh_ray(o, d);
    BvhHit best = BvhHit(BVH_INF, -1, 0.0, 0.0);
    float tbest = tmax;
    uint stack[BVH_STACK_SIZE];
    float stack_t[BVH_STACK_SIZE];
    int sp = 0;
    uint node = 0u;
    while (true) {
        BvhNode n = bvh_nodes[node];
        uint lw = floatBitsToUint(n.a.w), rw = floatBitsToUint(n.b.w);
        float tl = bvh_box(n.a.xyz, n.b.xyz, r, tmin, tbest);
        float tr = bvh_box(n.c.xyz, n.d.xyz, r, tmin, tbest);
        float t, u, v;
        if (tl < BVH_INF && (lw & BVH_LEAF) != 0u) {
            uint first = lw & ~BVH_LEAF, count = floatBitsToUint(n.c.w);
            for (uint i = first; i < first + count; ++i) {
                BvhTri tri = bvh_tris[i];
                if (bvh_triangle(r, tri, tmin, tbest, t, u, v) && t < tbest) {
                    tbest = t;
                    best = BvhHit(t, floatBitsToInt(tri.v0.w), u, v);
                }
            }
            tl = BVH_INF;
        }
        if (tr < BVH_INF && (rw & BVH_LEAF) != 0u) {
            uint first = rw & ~BVH_LEAF, count = floatBitsToUint(n.d.w);
            for (uint i = first; i < first + count; ++i) {
                BvhTri tri = bvh_tris[i];
                if (bvh_triangle(r, tri, tmin, tbest, t, u, v) && t < tbest) {
                    tbest = t;
                    best = BvhHit(t, floatBitsToInt(tri.v0.w), u, v);
                }
            }
            tr = BVH_INF;
        }
        tl = tl <= tbest ? tl : BVH_INF;
        tr = tr <= tbest ? tr : BVH_INF;
        if (tl < BVH_INF && tr < BVH_INF) {           // both: visit the nearer, keep the farther
            bool left_first = tl <= tr;
            stack[sp] = left_first ? rw : lw;
            stack_t[sp++] = left_first ? tr : tl;
            node = left_first ? lw : rw;
        } else if (tl < BVH_INF || tr < BVH_INF) {
            node = tl < BVH_INF ? lw : rw;
        } else {
            bool found = false;
            while (sp > 0) {                           // skip entries now farther than the best hit
                --sp;
                if (stack_t[sp] <= tbest) { node = stack[sp]; found = true; break; }
            }
            if (!found) break;
        }
    }
    return best;
}

#endif
