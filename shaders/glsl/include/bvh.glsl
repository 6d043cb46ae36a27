// bvh.glsl: the one shared BVH traversal for every tracing kernel.
//
// Use:
//     #version 450
//     #extension GL_GOOGLE_include_directive : require
//     #define BVH_SET 0          // descriptor set of the two buffers (default 0)
//     #define BVH_BINDING 2      // nodes at BVH_BINDING, triangles at BVH_BINDING + 1 (default 0), both bound as
//                                // uniform texel buffers of R32G32B32A32_UINT texels, and the same two buffers
//                                // at BVH_BINDING + 2, + 3 as storage texel buffers (BVH_IMAGE_FETCH)
//     #define BVH_STACK_SIZE 32  // optional; must be >= the BVH's stats["depth"] - 1 (the builder's default
//                                // max_depth of 32 guarantees that for the default 32)
//     #include "bvh.glsl"
//
// Provides
//     bool   bvh_occluded(vec3 o, vec3 d, float tmin, float tmax)   any hit with t in [tmin, tmax]; stops at the first
//     BvhHit bvh_intersect(vec3 o, vec3 d, float tmin, float tmax)  closest hit with t in [tmin, tmax]
//            BvhHit { float t; int prim; float u; float v; }: t = +inf and prim = -1 on a miss; prim is the original
//            triangle index; u, v are the barycentric weights of the triangle's second and third vertices, so the
//            hit point is (1 - u - v) * p0 + u * p1 + v * p2 = o + t * d.
//     bvh_occluded_first / bvh_intersect_first (+ out bool unresolved), bvh_occluded_full / bvh_intersect_full:
//            the same queries in two steps, the rare second walk left to a later dispatch (see below)
// Directions are used as given (not normalized); t is in units of d. Zero-area triangles are never hit.
//
// Buffer layout (documented in engine/bvh/layout.py, uploaded verbatim from BVH.nodes / BVH.tris). They are read as
// texel buffers, not storage buffers: lavapipe gathers texels for 8 lanes at once but loads storage buffers lane by
// lane; a texel is 16 bytes, so a node is 4 texels and a triangle 3.
//   node, 64 bytes: vec4 (lmin, left word), vec4 (lmax, right word), vec4 (rmin, left count), vec4 (rmax, right count)
//     child word: bit 31 set = leaf whose triangles are [word & 0x7fffffff, + count); clear = interior node index
//   triangle, 48 bytes: vec4 (v0, original index as int bits), vec4 (v1, alpha record + 1 or 0), vec4 (v2, 0)
//     (the alpha record: an includer that defines BVH_ALPHA_TEST, see alpha.glsl; others ignore it)
//
// Intersection is watertight (Woop, Benthin and Wald, JCGT 2013): every vertex is moved into a ray-aligned frame
// with exactly the same float operations whichever triangle it belongs to (the `precise` qualifiers forbid the
// compiler from fusing or reordering them), and the 2D edge functions of a shared edge are exact negatives of each
// other, so a ray cannot slip between two triangles that share an edge or a vertex. Box tests follow Ize's robust
// BVH traversal (the far distance is scaled by 1 + 2 gamma(3)) so rounding cannot cull a box that holds a hit.

#ifndef BVH_GLSL_INCLUDED
#define BVH_GLSL_INCLUDED

#ifndef BVH_SET
#define BVH_SET 0
#endif
#ifndef BVH_BINDING
#define BVH_BINDING 0
#endif
#ifndef BVH_STACK_SIZE
#define BVH_STACK_SIZE 32
#endif

struct BvhNode {
    vec4 a;  // xyz: left box min,  w: left child word (uint bits)
    vec4 b;  // xyz: left box max,  w: right child word
    vec4 c;  // xyz: right box min, w: left triangle count (0 for an interior child)
    vec4 d;  // xyz: right box max, w: right triangle count
};

struct BvhTri {
    vec4 v0;  // w: original triangle index (int bits)
    vec4 v1;
    vec4 v2;
};

struct BvhHit {
    float t;   // +inf on a miss
    int prim;  // original triangle index, -1 on a miss
    float u;   // barycentric weight of v1
    float v;   // barycentric weight of v2
};

layout(set = BVH_SET, binding = BVH_BINDING) uniform usamplerBuffer bvh_node_texels;
layout(set = BVH_SET, binding = BVH_BINDING + 1) uniform usamplerBuffer bvh_tri_texels;
// BVH_IMAGE_FETCH (set by engine/gpu/bvh.py bvh_spec; true on CPU devices): read the same two buffers through
// storage texel buffer views at BVH_BINDING + 2 and + 3 (imageLoad) instead of the uniform texel buffers. llvmpipe
// 22.3 emits a texel fetch from an R32G32B32A32 buffer as a call to a sampling function (its "simple format" inline
// path is only for RGBA8 unorm), and the call clobbers every vector register (spills in the node loop); an image
// load is inlined (16-byte loads and a transpose), no call. (An RGBA8-unorm view inlines its fetches but needs
// twice as many per node and a repack: slower.)
layout(constant_id = 11) const bool BVH_IMAGE_FETCH = false;
layout(set = BVH_SET, binding = BVH_BINDING + 2, rgba32ui) uniform readonly restrict uimageBuffer bvh_node_image;
layout(set = BVH_SET, binding = BVH_BINDING + 3, rgba32ui) uniform readonly restrict uimageBuffer bvh_tri_image;
uvec4 bvh_node_texel_(int i) {
    return BVH_IMAGE_FETCH ? imageLoad(bvh_node_image, i) : texelFetch(bvh_node_texels, i);
}
uvec4 bvh_tri_texel_(int i) {
    return BVH_IMAGE_FETCH ? imageLoad(bvh_tri_image, i) : texelFetch(bvh_tri_texels, i);
}

BvhNode bvh_node_(uint i) {
    int b = int(i) * 4;
    BvhNode n;
    n.a = uintBitsToFloat(bvh_node_texel_(b));
    n.b = uintBitsToFloat(bvh_node_texel_(b + 1));
    n.c = uintBitsToFloat(bvh_node_texel_(b + 2));
    n.d = uintBitsToFloat(bvh_node_texel_(b + 3));
    return n;
}

BvhTri bvh_tri_(uint i) {
    int b = int(i) * 3;
    BvhTri t;
    t.v0 = uintBitsToFloat(bvh_tri_texel_(b));
    t.v1 = uintBitsToFloat(bvh_tri_texel_(b + 1));
    t.v2 = uintBitsToFloat(bvh_tri_texel_(b + 2));
    return t;
}

// BVH_BRANCHLESS_PUSH (set by engine/gpu/bvh.py bvh_spec): push the far child with an unconditional store (sp only
// advances on a push) instead of a store under a branch. Faster on CPU devices, where llvmpipe runs a store under a
// branch lane by lane; GPUs prefer the branch (cheap there, unlike the extra store).
layout(constant_id = 0) const bool BVH_BRANCHLESS_PUSH = true;
// BVH_POSTPONE_LEAVES: see bvh_walk_ (postponed leaf tests; true on CPU devices).
layout(constant_id = 1) const bool BVH_POSTPONE_LEAVES = true;
// BVH_REG_STACK and BVH_STACK_REGS: the traversal stack as BVH_STACK_REGS (<= 32) plain variables shifted by one
// at every push and pop (BVH_REG_STACK, true on CPU devices) instead of an indexed local array. lavapipe runs an
// indexed local array lane by lane (8 extracts and scalar loads or stores per access, on every node step, since
// both sides of an `if` run), while the shift is 2 vector selects per entry, and entries past BVH_STACK_REGS
// fold away at pipeline creation. engine/gpu/bvh.py bvh_spec sets BVH_STACK_REGS to min(CPU_STACK_REGS, the BVH's
// depth - 1) on CPU devices (depth - 1 is the most the traversal pushes), with BVH_STACK_RETRY where that is fewer
// than depth - 1. Faster on CPU devices, the more so the fewer the entries.
layout(constant_id = 2) const bool BVH_REG_STACK = true;
layout(constant_id = 3) const int BVH_STACK_REGS = 32;
// BVH_STACK_RETRY: BVH_STACK_REGS may be less than the BVH needs (a short register stack, fewer vector
// registers live in the node loop): a push onto a full register stack drops its bottom entry and marks the ray;
// a marked ray whose walk ends without the answer (no hit for bvh_occluded; always for bvh_intersect) walks the
// tree again with the full array stack (the closest hit so far as tmax; of two hits at exactly that t either may be
// reported). Faster on lavapipe than a register stack as deep as the tree: the retries are rare.
layout(constant_id = 9) const bool BVH_STACK_RETRY = false;

// BVH_COMPRESSED: the nodes are the 32-byte compressed ones (engine/bvh/layout.py CNODE, made by
// engine/bvh/compress.py): 2 texels per node instead of 4, child boxes as 8-bit offsets in a per-node frame.
layout(constant_id = 8) const bool BVH_COMPRESSED = false;

const uint BVH_LEAF_BIT = 0x80000000u;
const uint BVH_CFIRST_MASK = 0x07FFFFFFu;  // compressed child word: first triangle (bits 0..26), count (27..30)
#define BVH_INF uintBitsToFloat(0x7F800000u)
// Ize, "Robust BVH Ray Traversal" (JCGT 2013): 1 + 2 gamma(3), gamma(n) = n eps / (1 - n eps), eps = 2^-24
const float BVH_FAR_SCALE = 1.0000004;

// A compressed node decoded into the 64-byte node's form (boxes rounded outwards on the host; words as there).
BvhNode bvh_cnode_(uint i) {
    int b = int(i) * 2;
    uvec4 h = bvh_node_texel_(b);
    uvec4 q = bvh_node_texel_(b + 1);
    vec3 org = uintBitsToFloat(h.xyz & 0xFFFFFF00u);
    vec3 scl = uintBitsToFloat((h.xyz & 0xFFu) << 23);
    // q * scale is exact (8 bits times a power of two), so this is one rounding whether fused or not
    vec3 lmin = org + vec3(q.xyz & 0xFFu) * scl;
    vec3 lmax = org + vec3((q.xyz >> 8) & 0xFFu) * scl;
    vec3 rmin = org + vec3((q.xyz >> 16) & 0xFFu) * scl;
    vec3 rmax = org + vec3(q.xyz >> 24) * scl;
    bool ll = (h.w & BVH_LEAF_BIT) != 0u;
    bool lr = (q.w & BVH_LEAF_BIT) != 0u;
    BvhNode n;
    n.a = vec4(lmin, uintBitsToFloat(ll ? (h.w & (BVH_LEAF_BIT | BVH_CFIRST_MASK)) : h.w));
    n.b = vec4(lmax, uintBitsToFloat(lr ? (q.w & (BVH_LEAF_BIT | BVH_CFIRST_MASK)) : q.w));
    n.c = vec4(rmin, uintBitsToFloat(ll ? ((h.w >> 27) & 15u) : 0u));
    n.d = vec4(rmax, uintBitsToFloat(lr ? ((q.w >> 27) & 15u) : 0u));
    return n;
}

// Everything about a ray that traversal and the triangle test reuse.
struct BvhRay_ {
    vec3 o;
    vec3 inv_d;    // 1 / d, with zero components replaced by +-1e-30 so that no 0 * inf appears
    int kx, ky, kz;  // kz: the dominant axis of d; kx, ky: the other two (cyclic)
    float sx, sy, sz;  // shear: x' = p[kx] - sx p[kz], y' = p[ky] - sy p[kz], z' = sz p[kz]
};

BvhRay_ bvh_make_ray_(vec3 o, vec3 d) {
    BvhRay_ r;
    r.o = o;
    const float tiny = 1e-30;
    vec3 safe = mix(d, mix(vec3(tiny), vec3(-tiny), lessThan(d, vec3(0.0))), lessThan(abs(d), vec3(tiny)));
    r.inv_d = 1.0 / safe;
    vec3 ad = abs(d);
    r.kz = (ad.x > ad.y) ? ((ad.x > ad.z) ? 0 : 2) : ((ad.y > ad.z) ? 1 : 2);
    r.kx = (r.kz == 2) ? 0 : r.kz + 1;
    r.ky = (r.kx == 2) ? 0 : r.kx + 1;
    float inv_dz = 1.0 / d[r.kz];
    r.sx = d[r.kx] * inv_dz;
    r.sy = d[r.ky] * inv_dz;
    r.sz = inv_dz;
    return r;
}

// Entry and exit distance of a box, clipped to [tmin, tmax]; the box is hit when .x <= .y.
// BVH_SELECT_MINMAX: min and max written as compare-and-select: llvmpipe's min/max
// keep GLSL's NaN rule with an extra unordered compare and blend each, a select is one vminps/vmaxps on x86.
// No NaN reaches here from a finite ray (inv_d is finite, the box planes finite or +-inf).
layout(constant_id = 10) const bool BVH_SELECT_MINMAX = false;
float bvh_min_(float a, float b) { return BVH_SELECT_MINMAX ? (a < b ? a : b) : min(a, b); }
float bvh_max_(float a, float b) { return BVH_SELECT_MINMAX ? (a > b ? a : b) : max(a, b); }

vec2 bvh_slab_(BvhRay_ r, vec3 bmin, vec3 bmax, float tmin, float tmax) {
    vec3 t0 = (bmin - r.o) * r.inv_d;
    vec3 t1 = (bmax - r.o) * r.inv_d;
    if (BVH_SELECT_MINMAX) {
        vec3 tn = mix(t1, t0, lessThan(t0, t1));
        vec3 tf = mix(t0, t1, lessThan(t0, t1));
        float tnear = bvh_max_(bvh_max_(tn.x, tn.y), bvh_max_(tn.z, tmin));
        float tfar = bvh_min_(bvh_min_(tf.x, tf.y), bvh_min_(tf.z, tmax)) * BVH_FAR_SCALE;
        return vec2(tnear, tfar);
    }
    vec3 tn = min(t0, t1);
    vec3 tf = max(t0, t1);
    float tnear = max(max(tn.x, tn.y), max(tn.z, tmin));
    float tfar = min(min(tf.x, tf.y), min(tf.z, tmax)) * BVH_FAR_SCALE;
    return vec2(tnear, tfar);
}

// Watertight ray-triangle test; on a hit with t in [tmin, tmax] returns true with t and the barycentrics of p1, p2.
bool bvh_triangle_(BvhRay_ r, vec3 p0, vec3 p1, vec3 p2, float tmin, float tmax,
                   out float t, out float b1, out float b2) {
    t = 0.0;
    b1 = 0.0;
    b2 = 0.0;
    precise vec3 a = p0 - r.o;
    precise vec3 b = p1 - r.o;
    precise vec3 c = p2 - r.o;
    float az = a[r.kz], bz = b[r.kz], cz = c[r.kz];
    precise float ax = a[r.kx] - r.sx * az;
    precise float ay = a[r.ky] - r.sy * az;
    precise float bx = b[r.kx] - r.sx * bz;
    precise float by = b[r.ky] - r.sy * bz;
    precise float cx = c[r.kx] - r.sx * cz;
    precise float cy = c[r.ky] - r.sy * cz;
    // 2D edge functions at the origin; a shared edge gives exact negatives in its two triangles
    precise float e0 = cx * by - cy * bx;  // edge p1 p2: weight of p0
    precise float e1 = ax * cy - ay * cx;  // edge p2 p0: weight of p1
    precise float e2 = bx * ay - by * ax;  // edge p0 p1: weight of p2
    if ((e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0)) {
        return false;
    }
    float det = e0 + e1 + e2;
    if (det == 0.0) {
        return false;  // edge-on, or a zero-area triangle
    }
    float tt = (e0 * az + e1 * bz + e2 * cz) * r.sz;  // t * det
    float inv_det = 1.0 / det;
    t = tt * inv_det;
    if (!(t >= tmin && t <= tmax)) {
        return false;
    }
    b1 = e1 * inv_det;
    b2 = e2 * inv_det;
    return true;
}

// Triangle i of the leaf order against the ray; on a hit with t in [tmin, best]: best = t and hit = (t, prim, u, v).
bool bvh_leaf_triangle_(BvhRay_ r, uint i, float tmin, inout float best, inout BvhHit hit) {
    BvhTri tri = bvh_tri_(i);
    float t, u, v;
    if (!bvh_triangle_(r, tri.v0.xyz, tri.v1.xyz, tri.v2.xyz, tmin, best, t, u, v)) {
        return false;
    }
#ifdef BVH_ALPHA_TEST
    // alpha-tested triangle (v1.w = 1 + its alpha record): the includer's bvh_alpha_passes decides (alpha.glsl)
    uint alpha_ = floatBitsToUint(tri.v1.w);
    if (BVH_ALPHA_TEST && alpha_ != 0u && !bvh_alpha_passes(alpha_ - 1u, u, v)) {
        return false;
    }
#endif
    best = t;
    hit.t = t;
    hit.prim = floatBitsToInt(tri.v0.w);
    hit.u = u;
    hit.v = v;
    return true;
}

// One entry of the register stack; entries at or past BVH_STACK_REGS stay 0 (and fold away).
#define BVH_SHIFT_(k, below) old_ = s##k; \
    s##k = (k < regs_) ? (push ? prev_ : (pop ? below : s##k)) : 0u; prev_ = old_;

// The traversal behind both queries. Ordered (nearer child first), leaves tested straight from their parent's slot.
// any_hit: stop at the first hit (its t, prim, u, v are still reported).
//
// Two nested loops (Aila and Laine's "while-while"): the inner one walks nodes until this ray has leaf triangles to
// test (the triangles of both leaf children of one node) or is done; the triangle loop then tests them. With
// BVH_POSTPONE_LEAVES (true on CPU devices) the node loop keeps walking until the ray has triangles; false: one
// node step per outer iteration (the classic single loop). On lavapipe a loop body always runs at least once,
// masked, for all 8 lanes, so a single loop pays the whole triangle test (3 texel fetches, the watertight test) at
// every node step although a ray visits far more nodes than it tests triangles; postponed, the triangle code runs
// once per leaf batch, which is faster there for both queries.
// The node loop's exit is its `while` condition on purpose: an unconditional `for (;;)` ended by
// `if (total != 0u || done) break;` was miscompiled by llvmpipe 22.3 (some shadow rays missed their hit).
// full: the array stack whatever BVH_REG_STACK says (the retry walk). lost: set where a push dropped an entry.
// root: the node to start from (0; an instance's bottom-level root in a two-level scene).
bool bvh_walk_(BvhRay_ r, float tmin, float tmax, bool any_hit, bool full, uint root, inout BvhHit hit,
               inout bool lost) {
    const bool reg_stack = BVH_REG_STACK && !full;
    const int regs_ = BVH_STACK_REGS;
    float best = tmax;
    bool found = false;
    uint stack[BVH_STACK_SIZE];     // far children still to visit (the array stack)
    // the register stack (BVH_REG_STACK): s0 is the top
    uint s0 = 0u, s1 = 0u, s2 = 0u, s3 = 0u, s4 = 0u, s5 = 0u, s6 = 0u, s7 = 0u, s8 = 0u, s9 = 0u, s10 = 0u,
         s11 = 0u, s12 = 0u, s13 = 0u, s14 = 0u, s15 = 0u, s16 = 0u, s17 = 0u, s18 = 0u, s19 = 0u, s20 = 0u,
         s21 = 0u, s22 = 0u, s23 = 0u, s24 = 0u, s25 = 0u, s26 = 0u, s27 = 0u, s28 = 0u, s29 = 0u, s30 = 0u,
         s31 = 0u;
    uint old_, prev_;
    uint sp = 0u;
    uint node = root;
    bool done = false;              // no node left to visit (the pending triangles may still be tested)
    for (;;) {
        // triangles to test: [f0, f0 + c0) then [f1, f1 + total - c0), the nearer leaf's first
        uint f0 = 0u, f1 = 0u, c0 = 0u, total = 0u;
        while (total == 0u && !done) {
            BvhNode n;
            if (BVH_COMPRESSED) {
                n = bvh_cnode_(node);
            } else {
                n = bvh_node_(node);
            }
            vec2 sl = bvh_slab_(r, n.a.xyz, n.b.xyz, tmin, best);
            vec2 sr = bvh_slab_(r, n.c.xyz, n.d.xyz, tmin, best);
            uint wl = floatBitsToUint(n.a.w);
            uint wr = floatBitsToUint(n.b.w);
            bool hl = sl.x <= sl.y;
            bool hr = sr.x <= sr.y;
            bool leaf_l = (wl & BVH_LEAF_BIT) != 0u;
            bool leaf_r = (wr & BVH_LEAF_BIT) != 0u;
            bool left_first = sl.x <= sr.x;
            uint cl = (hl && leaf_l) ? floatBitsToUint(n.c.w) : 0u;
            uint cr = (hr && leaf_r) ? floatBitsToUint(n.d.w) : 0u;
            f0 = (left_first ? wl : wr) & ~BVH_LEAF_BIT;
            f1 = (left_first ? wr : wl) & ~BVH_LEAF_BIT;
            c0 = left_first ? cl : cr;
            total = cl + cr;
            bool il = hl && !leaf_l;
            bool ir = hr && !leaf_r;
            bool near_left = il && (!ir || left_first);
            bool push = il && ir;
            uint top = s0;
            if (reg_stack) {
                // push: every entry moves down one (prev_ is the entry above, before this step); pop: up one
                bool pop = !il && !ir;
                prev_ = near_left ? wr : wl;
                BVH_SHIFT_(0, s1) BVH_SHIFT_(1, s2) BVH_SHIFT_(2, s3) BVH_SHIFT_(3, s4) BVH_SHIFT_(4, s5)
                BVH_SHIFT_(5, s6) BVH_SHIFT_(6, s7) BVH_SHIFT_(7, s8) BVH_SHIFT_(8, s9) BVH_SHIFT_(9, s10)
                BVH_SHIFT_(10, s11) BVH_SHIFT_(11, s12) BVH_SHIFT_(12, s13) BVH_SHIFT_(13, s14)
                BVH_SHIFT_(14, s15) BVH_SHIFT_(15, s16) BVH_SHIFT_(16, s17) BVH_SHIFT_(17, s18)
                BVH_SHIFT_(18, s19) BVH_SHIFT_(19, s20) BVH_SHIFT_(20, s21) BVH_SHIFT_(21, s22)
                BVH_SHIFT_(22, s23) BVH_SHIFT_(23, s24) BVH_SHIFT_(24, s25) BVH_SHIFT_(25, s26)
                BVH_SHIFT_(26, s27) BVH_SHIFT_(27, s28) BVH_SHIFT_(28, s29) BVH_SHIFT_(29, s30)
                BVH_SHIFT_(30, s31) BVH_SHIFT_(31, 0u)
                if (BVH_STACK_RETRY) {
                    bool full_ = sp >= uint(regs_);
                    lost = lost || (push && full_);
                    sp += (push && !full_) ? 1u : 0u;
                } else {
                    sp += push ? 1u : 0u;
                }
            } else if (BVH_BRANCHLESS_PUSH) {
                stack[min(sp, uint(BVH_STACK_SIZE - 1))] = near_left ? wr : wl;
                sp += (il && ir) ? 1u : 0u;
            } else if (push) {
                stack[sp] = near_left ? wr : wl;
                sp += 1u;
            }
            if (il || ir) {
                node = near_left ? wl : wr;
            } else if (sp == 0u) {
                done = true;
            } else {
                sp -= 1u;
                node = reg_stack ? top : stack[sp];
            }
            if (!BVH_POSTPONE_LEAVES) {
                break;
            }
        }
        for (uint j = 0u; j < total; ++j) {
            if (bvh_leaf_triangle_(r, j < c0 ? f0 + j : f1 + (j - c0), tmin, best, hit)) {
                found = true;
                if (any_hit) {
                    return true;
                }
            }
        }
        if (done) {
            break;
        }
    }
    return found;
}

// How bvh_trace_ walks a ray (a constant argument: the other paths fold away):
const int BVH_BOTH_ = 0;   // the register-stack walk, then the array-stack walk if it lost an entry and the answer
const int BVH_FIRST_ = 1;  // the register-stack walk only; `unresolved` says the ray needs the array-stack walk
const int BVH_FULL_ = 2;   // the array-stack walk only, from the first walk's closest hit in `hit` (if any)

bool bvh_trace_(vec3 o, vec3 d, float tmin, float tmax, bool any_hit, int mode, inout BvhHit hit,
                out bool unresolved) {
    BvhRay_ r = bvh_make_ray_(o, d);
    unresolved = false;
    bool lost = false;
    if (mode == BVH_FULL_) {
        bool had = hit.prim >= 0;
        return bvh_walk_(r, tmin, had ? hit.t : tmax, any_hit, true, 0u, hit, lost) || had;
    }
    bool found = bvh_walk_(r, tmin, tmax, any_hit, false, 0u, hit, lost);
    if (BVH_STACK_RETRY && BVH_REG_STACK) {
        if (lost && !(any_hit && found)) {
            if (mode == BVH_FIRST_) {
                unresolved = true;
            } else {
                bool unused = false;
                found = bvh_walk_(r, tmin, found ? hit.t : tmax, any_hit, true, 0u, hit, unused) || found;
            }
        }
    }
    return found;
}

// BVH_WIDE (set by engine/gpu/bvh.py bvh_spec): the bound buffers hold the 8-wide layout
// (engine/bvh/wide.py) instead of the binary one; traversal in bvh_wide.glsl.
layout(constant_id = 4) const bool BVH_WIDE = false;

#include "bvh_wide.glsl"

BvhHit bvh_miss_() {
    BvhHit hit;
    hit.t = BVH_INF;
    hit.prim = -1;
    hit.u = 0.0;
    hit.v = 0.0;
    return hit;
}

// BVH_INSTANCED (set by engine/gpu/bvh.py for a scene of instances): a two-level BVH in the same two buffers
// (engine/bvh/instanced.py): the nodes buffer holds every mesh's bottom-level nodes, then the top level's nodes
// from BVH_TLAS_ROOT (leaf slots are instance records, one instance each), then from BVH_INST_BASE one 64-byte
// record per instance: three texels, the rows of its world-to-object 3x4 transform, and a texel (bottom-level
// root node, first flat triangle index, instance id, 0). At an instance the ray moves into object space (the
// direction not renormalized, so t stays the world t) and walks that mesh's tree; the triangle ids it reports are
// the flattened scene's (the instance's first flat triangle + the mesh's triangle). No second dispatch: a ray whose
// register stack overflowed walks that instance again at once with the array stack.
layout(constant_id = 20) const bool BVH_INSTANCED = false;
layout(constant_id = 21) const int BVH_TLAS_ROOT = 0;
layout(constant_id = 22) const int BVH_INST_BASE = 0;
#ifndef BVH_TLAS_STACK_SIZE
#define BVH_TLAS_STACK_SIZE 64
#endif

bool bvh_trace_instanced_(vec3 o, vec3 d, float tmin, float tmax, bool any_hit, inout BvhHit hit) {
    BvhRay_ r = bvh_make_ray_(o, d);
    float best = hit.prim >= 0 ? hit.t : tmax;
    bool found = false;
    uint stack[BVH_TLAS_STACK_SIZE];   // child words still to visit: top-level nodes or instance slots
    uint sp = 1u;
    stack[0] = uint(BVH_TLAS_ROOT);
    bool more = true;
    while (more) {
        // top-level steps until this ray has an instance to walk (or none is left): the lanes of a SIMD group
        // then walk their instances together, as postponed leaf tests do (BVH_POSTPONE_LEAVES)
        uint slot = BVH_LEAF_BIT;
        while (slot == BVH_LEAF_BIT && sp > 0u) {
            sp -= 1u;
            uint w = stack[sp];
            if ((w & BVH_LEAF_BIT) != 0u) {
                slot = w & ~BVH_LEAF_BIT;
            } else {
                BvhNode n = bvh_node_(w);
                vec2 sl = bvh_slab_(r, n.a.xyz, n.b.xyz, tmin, best);
                vec2 sr = bvh_slab_(r, n.c.xyz, n.d.xyz, tmin, best);
                uint wl = floatBitsToUint(n.a.w);
                uint wr = floatBitsToUint(n.b.w);
                // an empty slot (count 0 at a leaf word) holds nothing
                bool hl = sl.x <= sl.y && ((wl & BVH_LEAF_BIT) == 0u || floatBitsToUint(n.c.w) != 0u);
                bool hr = sr.x <= sr.y && ((wr & BVH_LEAF_BIT) == 0u || floatBitsToUint(n.d.w) != 0u);
                bool left_first = sl.x <= sr.x;
                // the far child first, so that the near one is popped next
                uint first = (hl && hr) ? (left_first ? wr : wl) : (hl ? wl : wr);
                stack[min(sp, uint(BVH_TLAS_STACK_SIZE - 1))] = first;
                sp += (hl || hr) ? 1u : 0u;
                stack[min(sp, uint(BVH_TLAS_STACK_SIZE - 1))] = left_first ? wl : wr;
                sp += (hl && hr) ? 1u : 0u;
            }
        }
        more = slot != BVH_LEAF_BIT;
        if (more) {
            int rec = (BVH_INST_BASE + int(slot)) * 4;
            vec4 m0 = uintBitsToFloat(bvh_node_texel_(rec));
            vec4 m1 = uintBitsToFloat(bvh_node_texel_(rec + 1));
            vec4 m2 = uintBitsToFloat(bvh_node_texel_(rec + 2));
            uvec4 info = bvh_node_texel_(rec + 3);
            vec3 oo = vec3(dot(m0.xyz, o) + m0.w, dot(m1.xyz, o) + m1.w, dot(m2.xyz, o) + m2.w);
            vec3 dd = vec3(dot(m0.xyz, d), dot(m1.xyz, d), dot(m2.xyz, d));
            BvhRay_ ro = bvh_make_ray_(oo, dd);
            BvhHit h = hit;
            bool lost = false;
            bool f = bvh_walk_(ro, tmin, best, any_hit, false, info.x, h, lost);
            if (BVH_STACK_RETRY && BVH_REG_STACK && lost && !(any_hit && f)) {
                bool unused = false;
                f = bvh_walk_(ro, tmin, f ? h.t : best, any_hit, true, info.x, h, unused) || f;
            }
            if (f) {
                hit = h;
                hit.prim += int(info.y);
                best = h.t;
                found = true;
                more = !any_hit;
            }
        }
    }
    return found;
}

bool bvh_trace_any_(vec3 o, vec3 d, float tmin, float tmax, bool any_hit, int mode, inout BvhHit hit,
                    out bool unresolved) {
    if (BVH_INSTANCED) {
        unresolved = false;
        return (mode == BVH_FULL_) ? hit.prim >= 0 : bvh_trace_instanced_(o, d, tmin, tmax, any_hit, hit);
    }
    return BVH_WIDE ? bvh_trace_wide_(o, d, tmin, tmax, any_hit, mode, hit, unresolved)
                    : bvh_trace_(o, d, tmin, tmax, any_hit, mode, hit, unresolved);
}

BvhHit bvh_intersect(vec3 o, vec3 d, float tmin, float tmax) {
    BvhHit hit = bvh_miss_();
    bool unused;
    bvh_trace_any_(o, d, tmin, tmax, false, BVH_BOTH_, hit, unused);
    return hit;
}

bool bvh_occluded(vec3 o, vec3 d, float tmin, float tmax) {
    BvhHit hit = bvh_miss_();
    bool unused;
    return bvh_trace_any_(o, d, tmin, tmax, true, BVH_BOTH_, hit, unused);
}

// The same two queries in two steps, for kernels that run the rare second walk in a later dispatch (the batch
// kernels on CPU devices: lavapipe runs a walk's loop body at least once for every 8 lanes, even when no lane needs
// it, so the inline second walk cost every ray; see engine/rt/tracer.py). `*_first`: the register-stack walk, with
// `unresolved` set where the ray lost a stack entry and has no answer yet (never when BVH_STACK_RETRY is off);
// such a ray's answer is only complete after `*_full` (the array-stack walk; for
// bvh_intersect_full, `so_far` is what bvh_intersect_first returned).
bool bvh_occluded_first(vec3 o, vec3 d, float tmin, float tmax, out bool unresolved) {
    BvhHit hit = bvh_miss_();
    return bvh_trace_any_(o, d, tmin, tmax, true, BVH_FIRST_, hit, unresolved);
}

BvhHit bvh_intersect_first(vec3 o, vec3 d, float tmin, float tmax, out bool unresolved) {
    BvhHit hit = bvh_miss_();
    bvh_trace_any_(o, d, tmin, tmax, false, BVH_FIRST_, hit, unresolved);
    return hit;
}

bool bvh_occluded_full(vec3 o, vec3 d, float tmin, float tmax) {
    BvhHit hit = bvh_miss_();
    bool unused;
    return bvh_trace_any_(o, d, tmin, tmax, true, BVH_FULL_, hit, unused);
}

BvhHit bvh_intersect_full(vec3 o, vec3 d, float tmin, float tmax, BvhHit so_far) {
    BvhHit hit = so_far;
    bool unused;
    bvh_trace_any_(o, d, tmin, tmax, false, BVH_FULL_, hit, unused);
    return hit;
}

#endif  // BVH_GLSL_INCLUDED
