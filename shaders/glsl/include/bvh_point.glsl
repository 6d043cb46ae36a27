// bvh_point.glsl: closest-point queries on the binary BVH that bvh.glsl traces (include bvh.glsl first: the same
// node and triangle buffers, read through its bvh_node_ / bvh_cnode_ / bvh_tri_, BVH_COMPRESSED and
// BVH_IMAGE_FETCH as there). The 8-wide layout is not walked here: engine/rt/closest.py binds a binary tree.
//
// Provides
//     BvhClosest bvh_closest(vec3 p)   the point of the mesh nearest to p
//            BvhClosest { float d2; int prim; float u; float v; }: squared distance, the original triangle index
//            (-1 only for a mesh without triangles), barycentric weights of the triangle's vertices 1 and 2 at the
//            closest point (1 - u - v) * v0 + u * v1 + v * v2. Of triangles at the same distance either may win.
//
// Triangles whose record carries ZERO_AREA_FLAG in v1.w (set by engine/rt/closest.py, which uploads the real
// vertices of zero-area triangles where the ray-tracing records collapse them onto v0) are segments or points:
// their closest point is the nearest of their three edges'.

#ifndef BVH_POINT_GLSL_INCLUDED
#define BVH_POINT_GLSL_INCLUDED

const uint BVH_ZERO_AREA_FLAG = 1u;

struct BvhClosest {
    float d2;  // squared distance, +inf for a mesh without triangles
    int prim;  // original triangle index, -1 for none
    float u;   // barycentric weight of v1
    float v;   // barycentric weight of v2
};

// Squared distance from p to a box (0 inside; +inf for an empty slot's inverted box).
float bvh_box_d2_(vec3 p, vec3 bmin, vec3 bmax) {
    vec3 e = max(max(bmin - p, p - bmax), vec3(0.0));
    return dot(e, e);
}

// The parameter in [0, 1] of the point of segment a b nearest to p (0 for a zero-length segment).
float bvh_segment_t_(vec3 p, vec3 a, vec3 b) {
    vec3 ab = b - a;
    float len2 = dot(ab, ab);
    return len2 > 0.0 ? clamp(dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
}

// The nearest point of a zero-area triangle (a point or a segment): the nearest of its three edges.
vec2 bvh_closest_edges_(vec3 p, vec3 a, vec3 b, vec3 c) {
    float t = bvh_segment_t_(p, a, b);
    vec2 uv = vec2(t, 0.0);
    vec3 q = a + t * (b - a);
    float best = dot(p - q, p - q);
    t = bvh_segment_t_(p, a, c);
    q = a + t * (c - a);
    float d2 = dot(p - q, p - q);
    if (d2 < best) {
        best = d2;
        uv = vec2(0.0, t);
    }
    t = bvh_segment_t_(p, b, c);
    q = b + t * (c - b);
    d2 = dot(p - q, p - q);
    if (d2 < best) {
        uv = vec2(1.0 - t, t);
    }
    return uv;
}

// Ericson, Real-Time Collision Detection, 5.1.5: the barycentrics (weights of b and c) of the point of triangle
// a b c nearest to p, by the Voronoi region of p (vertex, edge or face).
vec2 bvh_closest_triangle_(vec3 p, vec3 a, vec3 b, vec3 c) {
    vec3 ab = b - a;
    vec3 ac = c - a;
    vec3 ap = p - a;
    float d1 = dot(ab, ap);
    float d2 = dot(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) {
        return vec2(0.0, 0.0);  // vertex a
    }
    vec3 bp = p - b;
    float d3 = dot(ab, bp);
    float d4 = dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) {
        return vec2(1.0, 0.0);  // vertex b
    }
    float vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        return vec2(d1 / (d1 - d3), 0.0);  // edge ab
    }
    vec3 cp = p - c;
    float d5 = dot(ab, cp);
    float d6 = dot(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) {
        return vec2(0.0, 1.0);  // vertex c
    }
    float vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        return vec2(0.0, d2 / (d2 - d6));  // edge ac
    }
    float va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return vec2(1.0 - w, w);  // edge bc
    }
    float denom = va + vb + vc;
    vec2 uv = vec2(vb, vc) / denom;  // the face
    // a sliver so thin that rounding put p in its face region with a meaningless denominator: its edges instead
    if (!(denom > 0.0 && uv.x >= 0.0 && uv.y >= 0.0 && uv.x + uv.y <= 1.0)) {
        return bvh_closest_edges_(p, a, b, c);
    }
    return uv;
}

// Triangle slot i of the leaf order against p; keeps it in `best` where it is strictly nearer.
void bvh_point_triangle_(vec3 p, uint i, inout BvhClosest best) {
    BvhTri tri = bvh_tri_(i);
    vec3 a = tri.v0.xyz, b = tri.v1.xyz, c = tri.v2.xyz;
    vec2 uv = (floatBitsToUint(tri.v1.w) & BVH_ZERO_AREA_FLAG) != 0u ? bvh_closest_edges_(p, a, b, c)
                                                                      : bvh_closest_triangle_(p, a, b, c);
    vec3 q = a + uv.x * (b - a) + uv.y * (c - a);
    float d2 = dot(p - q, p - q);
    if (d2 < best.d2) {
        best = BvhClosest(d2, floatBitsToInt(tri.v0.w), uv.x, uv.y);
    }
}

// The leaf child (word w, count n, box distance d2) of a node: its triangles, unless its box is no nearer.
void bvh_point_leaf_(vec3 p, uint w, uint n, float d2, inout BvhClosest best) {
    if ((w & BVH_LEAF_BIT) == 0u || !(d2 < best.d2)) {
        return;
    }
    uint first = w & ~BVH_LEAF_BIT;
    for (uint j = 0u; j < n; ++j) {
        bvh_point_triangle_(p, first + j, best);
    }
}

// Distance-ordered depth-first walk: at each node the nearer child first (leaves tested at once, nodes descended),
// the farther node pushed with its box distance; boxes no nearer than the best so far are skipped, on push and on
// pop. The stack holds at most depth - 1 entries (<= BVH_STACK_SIZE - 1 for the builder's trees).
BvhClosest bvh_closest(vec3 p) {
    BvhClosest best = BvhClosest(BVH_INF, -1, 0.0, 0.0);
    uint stack_node[BVH_STACK_SIZE];
    float stack_d2[BVH_STACK_SIZE];
    uint sp = 0u;
    uint node = 0u;
    for (;;) {
        BvhNode n;
        if (BVH_COMPRESSED) {
            n = bvh_cnode_(node);
        } else {
            n = bvh_node_(node);
        }
        float dl = bvh_box_d2_(p, n.a.xyz, n.b.xyz);
        float dr = bvh_box_d2_(p, n.c.xyz, n.d.xyz);
        uint wl = floatBitsToUint(n.a.w);
        uint wr = floatBitsToUint(n.b.w);
        uint cl = floatBitsToUint(n.c.w);
        uint cr = floatBitsToUint(n.d.w);
        bool left_first = dl <= dr;
        if (left_first) {
            bvh_point_leaf_(p, wl, cl, dl, best);
            bvh_point_leaf_(p, wr, cr, dr, best);
        } else {
            bvh_point_leaf_(p, wr, cr, dr, best);
            bvh_point_leaf_(p, wl, cl, dl, best);
        }
        bool il = (wl & BVH_LEAF_BIT) == 0u && dl < best.d2;
        bool ir = (wr & BVH_LEAF_BIT) == 0u && dr < best.d2;
        if (il && ir) {
            stack_node[min(sp, uint(BVH_STACK_SIZE - 1))] = left_first ? wr : wl;
            stack_d2[min(sp, uint(BVH_STACK_SIZE - 1))] = left_first ? dr : dl;
            sp += 1u;
            node = left_first ? wl : wr;
        } else if (il || ir) {
            node = il ? wl : wr;
        } else {
            // pop the nearest pending box still nearer than the best (pending boxes farther are dropped)
            bool found = false;
            while (sp > 0u && !found) {
                sp -= 1u;
                found = stack_d2[sp] < best.d2;
                node = stack_node[sp];
            }
            if (!found) {
                break;
            }
        }
    }
    return best;
}

#endif  // BVH_POINT_GLSL_INCLUDED
