#version 450
// GPU refit of one mesh's bottom-level BVH (engine/gpu/refit.py; the host reference is engine/bvh/instanced.py's
// TwoLevel.refit, whose results this reproduces bit for bit).
//
// mode 0, one dispatch per node height (order[first, first + count): the mesh's nodes of one height, local indices):
//   each invocation takes one node; a leaf slot rewrites its triangles' records from the new positions (the alpha
//   and id words stay) and takes the min / max of their corners, an interior slot the unpadded box its child left in
//   raw[]. The node's four box rows are written one float step outwards (nextafter, as the host does); raw[] keeps
//   the node's unpadded union box for its parent and, in .w, the surface areas of its two padded slot boxes.
//   Coordinates are handled as bits: copied as they are, compared as order-preserving integer keys and stepped on
//   the bits, so no device's denormal flushing or min / max rounding rule can change a box.
// mode 1, the SAH reduction: workgroup g sums the areas of nodes [g * SAH_CHUNK, + SAH_CHUNK) (count: the mesh's
//   node count) into sah[1 + g]; sah[0] is the root's padded box area. The host's ratio is sum(sah[1:]) / sah[0].

layout(local_size_x = 128) in;
layout(std430, set = 0, binding = 0) readonly buffer Positions { uint positions[]; };    // (V, 3) float32 bits
layout(std430, set = 0, binding = 1) readonly buffer Faces { uint faces[]; };            // (T, 3), leaf order
layout(std430, set = 0, binding = 2) readonly buffer Order { uint order[]; };            // local nodes by height
layout(std430, set = 0, binding = 3) buffer Nodes { uint nodes[]; };                     // the whole nodes buffer
layout(std430, set = 0, binding = 4) buffer Tris { uint tris[]; };                       // the whole triangles buffer
layout(std430, set = 0, binding = 5) buffer Raw { uvec4 raw[]; };                        // 2 per local node
layout(std430, set = 0, binding = 6) buffer Sah { float sah[]; };                        // host-visible
layout(push_constant) uniform Push {
    uint node_base;   // the mesh's first node in the nodes buffer
    uint tri_base;    // its first triangle record
    uint first;       // mode 0: the level's first entry in order[]
    uint count;       // mode 0: the level's node count; mode 1: the mesh's node count
    uint mode;
} pc;

const uint LEAF = 0x80000000u;
const uint SIGN = 0x80000000u;
const uint SAH_PER_THREAD = 32u;
const uint SAH_CHUNK = 128u * SAH_PER_THREAD;
const uint KEY_POS_INF = 0xff800000u;   // key(+inf bits): an empty box's min
const uint KEY_NEG_INF = 0x007fffffu;   // key(-inf bits): an empty box's max
#define INF uintBitsToFloat(0x7f800000u)
shared float partial[128];

// float bits -> an unsigned key in the floats' order (-0 just below +0), and back
uint to_key(uint b) { return (b & SIGN) != 0u ? ~b : b | SIGN; }
uint from_key(uint k) { return (k & SIGN) != 0u ? k & ~SIGN : ~k; }
uvec3 to_key3(uvec3 b) { return uvec3(to_key(b.x), to_key(b.y), to_key(b.z)); }

uvec3 vertex(uint v) {
    return uvec3(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
}

// nextafter(x, -inf) and nextafter(x, +inf) on float bits
uint step_down(uint b) {
    if ((b & ~SIGN) > 0x7f800000u || b == 0xff800000u) return b;   // NaN, -inf
    if ((b & ~SIGN) == 0u) return 0x80000001u;                      // +-0: the negative denormal
    return (b & SIGN) != 0u ? b + 1u : b - 1u;
}

uint step_up(uint b) {
    if ((b & ~SIGN) > 0x7f800000u || b == 0x7f800000u) return b;   // NaN, +inf
    if ((b & ~SIGN) == 0u) return 0x00000001u;
    return (b & SIGN) != 0u ? b - 1u : b + 1u;
}

// a box's padded corners (float bits) from its unpadded keys
uvec3 down3(uvec3 k) { return uvec3(step_down(from_key(k.x)), step_down(from_key(k.y)), step_down(from_key(k.z))); }
uvec3 up3(uvec3 k) { return uvec3(step_up(from_key(k.x)), step_up(from_key(k.y)), step_up(from_key(k.z))); }

// half the surface area of a box (extents below 0 or not finite count 0), as the host's SAH measures it
float area(uvec3 lo_bits, uvec3 hi_bits) {
    vec3 e = uintBitsToFloat(hi_bits) - uintBitsToFloat(lo_bits);
    e = vec3(e.x > 0.0 && e.x < INF ? e.x : 0.0, e.y > 0.0 && e.y < INF ? e.y : 0.0,
             e.z > 0.0 && e.z < INF ? e.z : 0.0);
    return e.x * e.y + e.y * e.z + e.z * e.x;
}

void store3(uint word, uvec3 v) {
    nodes[word] = v.x;
    nodes[word + 1u] = v.y;
    nodes[word + 2u] = v.z;
}

void put_corner(uint word, uvec3 v) {
    tris[word] = v.x;
    tris[word + 1u] = v.y;
    tris[word + 2u] = v.z;
}

// the unpadded box (keys) of one child slot (`word`, `count` as in engine/bvh/layout.py)
void slot_box(uint word, uint count, out uvec3 lo, out uvec3 hi) {
    if ((word & LEAF) == 0u) {
        uint c = 2u * (word - pc.node_base);
        lo = raw[c].xyz;
        hi = raw[c + 1u].xyz;
        return;
    }
    lo = uvec3(KEY_POS_INF);
    hi = uvec3(KEY_NEG_INF);
    uint first = word & ~LEAF;
    for (uint i = 0u; i < count; ++i) {
        uint g = first + i;
        uint f = 3u * (g - pc.tri_base);
        uvec3 p0 = vertex(faces[f]), p1 = vertex(faces[f + 1u]), p2 = vertex(faces[f + 2u]);
        put_corner(12u * g, p0);
        put_corner(12u * g + 4u, p1);
        put_corner(12u * g + 8u, p2);
        uvec3 k0 = to_key3(p0), k1 = to_key3(p1), k2 = to_key3(p2);
        lo = min(lo, min(min(k0, k1), k2));
        hi = max(hi, max(max(k0, k1), k2));
    }
}

void refit_node() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    uint local = order[pc.first + i];
    uint w = 16u * (pc.node_base + local);
    uvec3 llo, lhi, rlo, rhi;
    slot_box(nodes[w + 3u], nodes[w + 11u], llo, lhi);
    slot_box(nodes[w + 7u], nodes[w + 15u], rlo, rhi);
    uvec3 plo = down3(llo), phi = up3(lhi), qlo = down3(rlo), qhi = up3(rhi);
    store3(w, plo);
    store3(w + 4u, phi);
    store3(w + 8u, qlo);
    store3(w + 12u, qhi);
    raw[2u * local] = uvec4(min(llo, rlo), floatBitsToUint(area(plo, phi) + area(qlo, qhi)));
    // the root (local node 0) also keeps its padded box's area, the SAH's denominator
    uvec3 ulo = min(llo, rlo), uhi = max(lhi, rhi);
    raw[2u * local + 1u] = uvec4(uhi, floatBitsToUint(local == 0u ? area(down3(ulo), up3(uhi)) : 0.0));
}

void sah_sum() {
    uint t = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * SAH_CHUNK + t;
    float s = 0.0;
    for (uint j = 0u; j < SAH_PER_THREAD; ++j) {
        uint n = base + j * 128u;
        if (n < pc.count) s += uintBitsToFloat(raw[2u * n].w);
    }
    partial[t] = s;
    barrier();
    for (uint k = 64u; k > 0u; k >>= 1u) {
        if (t < k) partial[t] += partial[t + k];
        barrier();
    }
    if (t == 0u) {
        sah[1u + gl_WorkGroupID.x] = partial[0];
        if (gl_WorkGroupID.x == 0u) sah[0] = uintBitsToFloat(raw[1].w);
    }
}

void main() {
    if (pc.mode == 0u) refit_node();
    else sah_sum();
}
