// bvh_wide.glsl: the 8-wide BVH traversal (layout in engine/bvh/wide.py), included by bvh.glsl; selected there by
// BVH_WIDE. Same bindings as the binary layout: nodes are 5 texels (80 bytes), triangles
// the binary layout's 3 texels. Child boxes are dequantized exactly as the host checked them (p + q * 2^e in float32,
// the product exact), then tested with the binary layout's robust slab test; triangles with its watertight test.
//
// Traversal after Ylitie, Karras and Laine (HPG 2017): a node group is (first child node, hit bits << 24 | imask);
// hit bit 24 + (slot ^ oct_inv) marks a hit interior child, so that taking the highest bit first visits the children
// in the ray octant's order. Leaf children's triangles (at most 32 per node, one bit each) are tested right after
// their node. The stack holds node groups whose hits are still to visit.

#ifndef BVH_WIDE_GLSL_INCLUDED
#define BVH_WIDE_GLSL_INCLUDED

// A wide node's 5 texels: t0 = (grid origin p, exponents | imask << 24), t1 = (first child node, first triangle,
// meta of slots 0-3, meta of slots 4-7), t2..t4 = the 8-bit lo / hi planes of the 8 slots per axis.
struct BvhWideNode_ {
    uvec4 t1, t2, t3, t4;
    vec3 p;      // grid origin
    vec3 s;      // 2^e per axis, built from the exponent bytes
    uint imask;  // which slots are interior nodes
};

BvhWideNode_ bvh_wide_node_(uint node) {
    int b = int(node) * 5;
    uvec4 t0 = bvh_node_texel_(b);
    BvhWideNode_ n;
    n.t1 = bvh_node_texel_(b + 1);
    n.t2 = bvh_node_texel_(b + 2);
    n.t3 = bvh_node_texel_(b + 3);
    n.t4 = bvh_node_texel_(b + 4);
    n.p = uintBitsToFloat(t0.xyz);
    n.s = uintBitsToFloat(uvec3(t0.w << 23u, (t0.w >> 8u) << 23u, (t0.w >> 16u) << 23u) & 0x7F800000u);
    n.imask = t0.w >> 24u;
    return n;
}

// Slot j's box, dequantized exactly as the host checked it (p + q * 2^e), and its meta byte.
void bvh_wide_slot_(BvhWideNode_ n, uint j, out vec3 lo, out vec3 hi, out uint meta) {
    uint sh = (j & 3u) * 8u;
    bool up = j >= 4u;
    uvec3 ql = (uvec3(up ? n.t2.y : n.t2.x, up ? n.t2.w : n.t2.z, up ? n.t3.y : n.t3.x) >> sh) & 0xFFu;
    uvec3 qh = (uvec3(up ? n.t3.w : n.t3.z, up ? n.t4.y : n.t4.x, up ? n.t4.w : n.t4.z) >> sh) & 0xFFu;
    lo = n.p + vec3(ql) * n.s;
    hi = n.p + vec3(qh) * n.s;
    meta = ((up ? n.t1.w : n.t1.z) >> sh) & 0xFFu;
}

// The 8 children of node n against the ray: `hits` gets hit bit 24 + (slot ^ oct_inv) for every hit interior slot,
// `tris` one bit per triangle of every hit leaf slot (its meta byte: count << 5 | first, over the node's triangles
// from n.t1.y). Selects, not branches: lavapipe runs both sides of an `if`.
void bvh_wide_children_(BvhRay_ r, BvhWideNode_ n, uint oct_inv, float tmin, float best, out uint hits,
                        out uint tris) {
    hits = 0u;
    tris = 0u;
    for (uint j = 0u; j < 8u; ++j) {
        vec3 lo, hi;
        uint meta;
        bvh_wide_slot_(n, j, lo, hi, meta);
        vec2 sl = bvh_slab_(r, lo, hi, tmin, best);
        bool inner = ((n.imask >> j) & 1u) != 0u;
        bool h = sl.x <= sl.y;
        hits |= (h && inner) ? 1u << (24u + (j ^ oct_inv)) : 0u;
        tris |= (h && !inner) ? ((1u << (meta >> 5u)) - 1u) << (meta & 31u) : 0u;
    }
}

// The triangles whose bits `tris` holds (from tri_base) against the ray; true at the first hit when any_hit.
bool bvh_wide_triangles_(BvhRay_ r, uint tri_base, uint tris, float tmin, bool any_hit, inout float best,
                         inout BvhHit hit, inout bool found) {
    while (tris != 0u) {
        uint k = uint(findLSB(tris));
        tris &= tris - 1u;
        if (bvh_leaf_triangle_(r, tri_base + k, tmin, best, hit)) {
            found = true;
            if (any_hit) {
                return true;
            }
        }
    }
    return false;
}

// BVH_WIDE_CPU (CPU devices): the 8-wide traversal in lavapipe's terms, as the binary
// one: postponed leaf tests (the node walk is an inner loop that runs until the ray has triangles), the stack as
// shifted registers (min(BVH_STACK_REGS, 12) entries; with BVH_STACK_RETRY, which must be on where
// they can be fewer than the tree needs, a ray whose pushes overflowed them and that ends without its answer walks
// again with the array stack: inline, or in a later dispatch, see bvh.glsl), no store or load under a branch.
layout(constant_id = 12) const bool BVH_WIDE_CPU = false;

#define BVH_WSHIFT_(k, below) wold_ = w##k; \
    w##k = (k < regs_) ? (down ? wprev_ : (up ? below : w##k)) : uvec2(0u); wprev_ = wold_;

bool bvh_wide_walk_cpu_(BvhRay_ r, uint oct_inv, float tmin, float tmax, bool any_hit, bool full, inout BvhHit hit,
                        inout bool lost) {
    const bool reg_stack = BVH_REG_STACK && !full;
    const int regs_ = min(BVH_STACK_REGS, 12);
    float best = tmax;
    bool found = false;
    uvec2 stack[BVH_STACK_SIZE];
    uvec2 w0 = uvec2(0u), w1 = uvec2(0u), w2 = uvec2(0u), w3 = uvec2(0u), w4 = uvec2(0u), w5 = uvec2(0u),
          w6 = uvec2(0u), w7 = uvec2(0u), w8 = uvec2(0u), w9 = uvec2(0u), w10 = uvec2(0u), w11 = uvec2(0u);
    uvec2 wold_, wprev_;
    uint sp = 0u;
    uvec2 group = uvec2(0u, (1u << (24u + oct_inv)) | 1u);   // the root: interior slot 0 of a virtual parent
    bool done = false;
    for (;;) {
        uint tris = 0u;
        uint tri_base = 0u;
        while (tris == 0u && !done) {
            // the next interior child: from the current group, else from the top of the stack
            bool pop = group.y <= 0x00FFFFFFu;
            bool empty = sp == 0u;
            uvec2 top = reg_stack ? w0 : stack[max(sp, 1u) - 1u];
            bool fin = pop && empty;
            // when the walk ends, the stale top (no hit bits left) stands in as a group whose one hit is slot 0 of
            // node 0: the step's loads stay in bounds (the array stack's stale entry would pick a slot past its
            // group's children) and its result is dropped
            uvec2 g = fin ? uvec2(0u, 1u << (24u + oct_inv)) : (pop ? top : group);
            uint bit = uint(findMSB(g.y));
            g.y &= ~(1u << bit);
            uint slot = (bit - 24u) ^ oct_inv;
            uint node = g.x + uint(bitCount(g.y & ((1u << slot) - 1u)));   // low 8 bits: imask
            bool push = g.y > 0x00FFFFFFu;
            // stack: pop and push = the top replaced by g; pop alone: up one; push alone: down one, g on top
            bool up = pop && !push && !fin;
            bool down = push && !pop;
            if (reg_stack) {
                bool full_ = sp >= uint(regs_);
                lost = lost || (down && full_);
                w0 = (push && !fin) ? g : (up ? w1 : w0);
                wprev_ = top;
                BVH_WSHIFT_(1, w2) BVH_WSHIFT_(2, w3) BVH_WSHIFT_(3, w4) BVH_WSHIFT_(4, w5) BVH_WSHIFT_(5, w6)
                BVH_WSHIFT_(6, w7) BVH_WSHIFT_(7, w8) BVH_WSHIFT_(8, w9) BVH_WSHIFT_(9, w10) BVH_WSHIFT_(10, w11)
                BVH_WSHIFT_(11, uvec2(0u))
                sp += (down && !full_) ? 1u : 0u;
            } else {
                uint at = pop ? max(sp, 1u) - 1u : sp;
                stack[min(at, uint(BVH_STACK_SIZE - 1))] = g;
                sp += down ? 1u : 0u;
            }
            sp -= up ? 1u : 0u;

            BvhWideNode_ n = bvh_wide_node_(node);
            uint hits, tr;
            bvh_wide_children_(r, n, oct_inv, tmin, best, hits, tr);
            group = fin ? group : uvec2(n.t1.x, hits | n.imask);
            tris = fin ? 0u : tr;
            tri_base = n.t1.y;
            done = fin;
        }
        if (bvh_wide_triangles_(r, tri_base, tris, tmin, any_hit, best, hit, found)) {
            return true;
        }
        if (done) {
            break;
        }
    }
    return found;
}

// mode and unresolved: as bvh_trace_ (bvh.glsl); only the CPU walk's register stack can leave a ray unresolved.
bool bvh_trace_wide_(vec3 o, vec3 d, float tmin, float tmax, bool any_hit, int mode, inout BvhHit hit,
                     out bool unresolved) {
    unresolved = false;
    bool had = mode == BVH_FULL_ && hit.prim >= 0;   // the full walk starts from the first walk's closest hit
    tmax = had ? hit.t : tmax;
    if (BVH_WIDE_CPU) {
        BvhRay_ r = bvh_make_ray_(o, d);
        uint oct_inv = (d.x < 0.0 ? 0u : 1u) | (d.y < 0.0 ? 0u : 2u) | (d.z < 0.0 ? 0u : 4u);
        bool lost = false;
        if (mode == BVH_FULL_) {
            return bvh_wide_walk_cpu_(r, oct_inv, tmin, tmax, any_hit, true, hit, lost) || had;
        }
        bool found = bvh_wide_walk_cpu_(r, oct_inv, tmin, tmax, any_hit, false, hit, lost);
        if (BVH_STACK_RETRY && BVH_REG_STACK && lost && !(any_hit && found)) {
            if (mode == BVH_FIRST_) {
                unresolved = true;
            } else {
                bool unused = false;
                found = bvh_wide_walk_cpu_(r, oct_inv, tmin, found ? hit.t : tmax, any_hit, true, hit, unused)
                        || found;
            }
        }
        return found;
    }
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

        BvhWideNode_ n = bvh_wide_node_(node);
        // bvh_wide_children_'s test with branches, which GPUs prefer (the selects are for lavapipe)
        uint hits = 0u;
        uint tris = 0u;
        for (uint j = 0u; j < 8u; ++j) {
            vec3 lo, hi;
            uint meta;
            bvh_wide_slot_(n, j, lo, hi, meta);
            vec2 sl = bvh_slab_(r, lo, hi, tmin, best);
            if (sl.x <= sl.y) {
                if (((n.imask >> j) & 1u) != 0u) {
                    hits |= 1u << (24u + (j ^ oct_inv));
                } else {
                    tris |= ((1u << (meta >> 5u)) - 1u) << (meta & 31u);
                }
            }
        }
        group = uvec2(n.t1.x, hits | n.imask);
        if (bvh_wide_triangles_(r, n.t1.y, tris, tmin, any_hit, best, hit, found)) {
            return true;
        }
    }
    return found || had;
}

#endif  // BVH_WIDE_GLSL_INCLUDED
