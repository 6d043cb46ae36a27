// bvh_wide.glsl: the 8-wide BVH traversal (layout in engine/bvh/wide.py), included by bvh.glsl; selected there by
// specialization constant 1, BVH_WIDE. Same bindings as the binary layout: nodes are 5 texels (80 bytes), triangles
// the binary layout's 3 texels. Child boxes: the host checked p + q * 2^e (float32) encloses each subtree; the box
// test here bounds its own rounding with an absolute slack (below) instead of the binary test's relative scaling,
// which would not hold for the fma form. Triangles: the binary layout's watertight test.
//
// Traversal after Ylitie, Karras and Laine (HPG 2017): a node group is (first child node, hit bits << 24 | imask);
// hit bit 24 + (slot ^ oct_inv) marks a hit interior child, so that taking the highest bit first visits the children
// in the ray octant's order. Leaf children's triangles (at most 32 per node, one bit each) are tested right after
// their node. The stack holds node groups whose hits are still to visit.

#ifndef BVH_WIDE_GLSL_INCLUDED
#define BVH_WIDE_GLSL_INCLUDED

const float BVH_WIDE_EPS8 = 4.76837158e-7;   // 8 * 2^-24

bool bvh_trace_wide_(vec3 o, vec3 d, float tmin, float tmax, bool any_hit, inout BvhHit hit) {
    BvhRay_ r = bvh_make_ray_(o, d);
    // 7 - octant, octant bit a set = d negative along axis a (the host's slot order)
    uint oct_inv = (d.x < 0.0 ? 0u : 1u) | (d.y < 0.0 ? 0u : 2u) | (d.z < 0.0 ? 0u : 4u);
    float best = tmax;
    bool found = false;
    uvec2 stack[BVH_STACK_SIZE];
    uint sp = 0u;
    uvec2 group = uvec2(0u, (1u << (24u + oct_inv)) | 1u);   // the root: interior slot 0 of a virtual parent
    for (;;) {
        if (group.y <= 0x00FFFFFFu) {
            if (sp == 0u) {
                break;
            }
            sp -= 1u;
            group = stack[sp];
        }
        uint bit = uint(findMSB(group.y));
        group.y &= ~(1u << bit);
        uint slot = (bit - 24u) ^ oct_inv;
        uint node = group.x + uint(bitCount(group.y & ((1u << slot) - 1u)));   // low 8 bits: imask
        if (group.y > 0x00FFFFFFu) {
            stack[min(sp, uint(BVH_STACK_SIZE - 1))] = group;
            sp += 1u;
        }

        int b = int(node) * 5;
        uvec4 t0 = texelFetch(bvh_node_texels, b);
        uvec4 t1 = texelFetch(bvh_node_texels, b + 1);
        uvec4 t2 = texelFetch(bvh_node_texels, b + 2);
        uvec4 t3 = texelFetch(bvh_node_texels, b + 3);
        uvec4 t4 = texelFetch(bvh_node_texels, b + 4);
        vec3 p = uintBitsToFloat(t0.xyz);
        vec3 s = uintBitsToFloat(uvec3(t0.w << 23u, (t0.w >> 8u) << 23u, (t0.w >> 16u) << 23u) & 0x7F800000u);
        uint imask = t0.w >> 24u;
        // A plane at p + q s is at t = q (s / d) + (p - o) / d: one fma per plane (the paper's form). s / d is
        // exact (s is a power of two); the other roundings (1 / d, p - o, the product, the fma) move each plane by
        // at most 5 eps (|p - o| + 255 s) / |d| (cancellation makes a relative bound useless), so a box counts as
        // hit when its near t <= far t + 2 err with err of 8 eps that size: conservative, as the exact test is.
        vec3 po = p - r.o;
        vec3 a3 = s * r.inv_d;
        vec3 b3 = po * r.inv_d;
        vec3 e3 = (abs(po) + 255.0 * s) * abs(r.inv_d);
        float slack = 2.0 * BVH_WIDE_EPS8 * max(max(e3.x, e3.y), e3.z);
        uint hits = 0u;
        uint tris = 0u;
        for (uint j = 0u; j < 8u; ++j) {
            uint sh = (j & 3u) * 8u;
            bool up = j >= 4u;
            // bytes to floats without an int-to-float conversion: the bits of 2^23 + q, minus 2^23 (exact)
            uvec3 ql = (uvec3(up ? t2.y : t2.x, up ? t2.w : t2.z, up ? t3.y : t3.x) >> sh) & 0xFFu;
            uvec3 qh = (uvec3(up ? t3.w : t3.z, up ? t4.y : t4.x, up ? t4.w : t4.z) >> sh) & 0xFFu;
            vec3 fl = uintBitsToFloat(ql | 0x4B000000u) - 8388608.0;
            vec3 fh = uintBitsToFloat(qh | 0x4B000000u) - 8388608.0;
            vec3 tl = fl * a3 + b3;
            vec3 th = fh * a3 + b3;
            vec3 tn = min(tl, th);
            vec3 tf = max(tl, th);
            float tnear = max(max(tn.x, tn.y), max(tn.z, tmin));
            float tfar = min(min(tf.x, tf.y), min(tf.z, best));
            if (tnear <= tfar + slack) {
                uint meta = ((up ? t1.w : t1.z) >> sh) & 0xFFu;
                if (((imask >> j) & 1u) != 0u) {
                    hits |= 1u << (24u + (j ^ oct_inv));
                } else {
                    tris |= ((1u << (meta >> 5u)) - 1u) << (meta & 31u);
                }
            }
        }
        group = uvec2(t1.x, hits | imask);

        uint tri_base = t1.y;
        while (tris != 0u) {
            uint k = uint(findLSB(tris));
            tris &= tris - 1u;
            BvhTri tri = bvh_tri_(tri_base + k);
            float t, u, v;
            if (bvh_triangle_(r, tri.v0.xyz, tri.v1.xyz, tri.v2.xyz, tmin, best, t, u, v)) {
                best = t;
                found = true;
                hit.t = t;
                hit.prim = floatBitsToInt(tri.v0.w);
                hit.u = u;
                hit.v = v;
                if (any_hit) {
                    return true;
                }
            }
        }
    }
    return found;
}

#endif  // BVH_WIDE_GLSL_INCLUDED
