#version 450
// The two-level BVH's top level built on the GPU (engine/gpu/tlas.py), in the layout engine/bvh/instanced.py makes
// on the host and bvh.glsl's BVH_INSTANCED walk reads: instance records, then a perfect binary tree over the
// instances sorted along a Morton curve, its nodes level by level. One shader, one step per dispatch (`pc.mode`):
//   WORLD    per instance: world box of its mesh's box (padded), world-to-object record, centre bounds (atomics)
//   MORTON   per sort slot: (Morton code of the box centre, instance) keys; slots past the instances sort last
//   SORT_*   bitonic sort of the keys: blocks of SORT_BLOCK in shared memory, longer strides one step a dispatch
//   LEAVES   the bottom level: a node per pair of sorted slots, their instances' boxes
//   LEVEL    level pc.level: a node per pair of level pc.level + 1 nodes, the unions of their child boxes
layout(local_size_x = 512) in;

const uint WORLD = 0u, MORTON = 1u, SORT_BLOCK_FULL = 2u, SORT_BLOCK_MERGE = 3u, SORT_STEP = 4u, LEAVES = 5u,
           LEVEL = 6u;
const uint SORT_BLOCK = 1024u;   // keys a workgroup sorts in shared memory (two per invocation)
const uint LEAF = 0x80000000u;
// relative padding of the float32 world boxes: covers the rounding of their float32 arithmetic and of the ray's
// float32 transform into object space, so that a box never shrinks below the instance the walk sees
const float PAD = 1e-5;

layout(push_constant) uniform Push {
    uint mode;
    uint count;       // instances
    uint slots;       // leaf slots of the perfect tree (a power of two)
    uint tlas_root;   // node index of the top level's root in the nodes buffer
    uint inst_base;   // node index of instance 0's record
    uint level;       // LEVEL: the level written (root: 0)
    uint k;           // SORT_*: the bitonic sequence length
    uint j;           // SORT_STEP: the compare distance
} pc;

// per instance: rows 0..2 of its object-to-world transform
layout(std430, set = 0, binding = 0) readonly restrict buffer Xf { vec4 xf[]; };
// per instance: (mesh, root node of its mesh, first triangle in the flattened scene, 0)
layout(std430, set = 0, binding = 1) readonly restrict buffer Info { uvec4 info[]; };
// per mesh: object box min, max
layout(std430, set = 0, binding = 2) readonly restrict buffer MeshBoxes { vec4 mesh_box[]; };
// per instance: world box min, max (scratch)
layout(std430, set = 0, binding = 3) restrict buffer Boxes { vec4 boxes[]; };
// the instance centres' bounds as order-preserving uints: 0..2 ~min, 4..6 max (cleared to 0 before WORLD)
layout(std430, set = 0, binding = 4) restrict buffer Bounds { uint bounds[]; };
// sort keys: (Morton code, instance)
layout(std430, set = 0, binding = 5) restrict buffer Keys { uvec2 keys[]; };
// the BVH nodes buffer as 16-byte texels (a node or a record is 4)
layout(set = 0, binding = 6, rgba32ui) uniform restrict uimageBuffer nodes;

shared uint s_bounds[6];
shared uvec2 s_keys[SORT_BLOCK];

uint ordered(float f) {   // a float's bits as a uint whose unsigned order is the float order
    uint u = floatBitsToUint(f);
    return (u & 0x80000000u) != 0u ? ~u : u | 0x80000000u;
}

float unordered(uint u) {
    return uintBitsToFloat((u & 0x80000000u) != 0u ? u & 0x7FFFFFFFu : ~u);
}

uint spread(uint x) {   // 10 bits to every third bit
    x &= 0x3FFu;
    x = (x | (x << 16)) & 0x030000FFu;
    x = (x | (x << 8)) & 0x0300F00Fu;
    x = (x | (x << 4)) & 0x030C30C3u;
    x = (x | (x << 2)) & 0x09249249u;
    return x;
}

bool key_less(uvec2 a, uvec2 b) {
    return a.x < b.x || (a.x == b.x && a.y < b.y);
}

void store_node(uint node, vec3 lmin, vec3 lmax, vec3 rmin, vec3 rmax, uint left, uint right, uint lc, uint rc) {
    int t = int(4u * (pc.tlas_root + node));
    imageStore(nodes, t, uvec4(floatBitsToUint(lmin), left));
    imageStore(nodes, t + 1, uvec4(floatBitsToUint(lmax), right));
    imageStore(nodes, t + 2, uvec4(floatBitsToUint(rmin), lc));
    imageStore(nodes, t + 3, uvec4(floatBitsToUint(rmax), rc));
}

void world() {
    uint i = gl_GlobalInvocationID.x;
    uint lid = gl_LocalInvocationID.x;
    if (lid < 6u) s_bounds[lid] = 0u;
    barrier();
    if (i < pc.count) {
        vec4 r0 = xf[3u * i], r1 = xf[3u * i + 1u], r2 = xf[3u * i + 2u];
        uvec4 inf = info[i];
        vec3 bmin = mesh_box[2u * inf.x].xyz, bmax = mesh_box[2u * inf.x + 1u].xyz;
        vec3 oc = 0.5 * (bmin + bmax), oh = 0.5 * (bmax - bmin);
        mat3 a = mat3(r0.x, r1.x, r2.x, r0.y, r1.y, r2.y, r0.z, r1.z, r2.z);   // columns
        vec3 t = vec3(r0.w, r1.w, r2.w);
        vec3 wc = a * oc + t;
        vec3 wh = abs(a[0]) * oh.x + abs(a[1]) * oh.y + abs(a[2]) * oh.z;
        vec3 size = abs(a[0] * oc.x) + abs(a[1] * oc.y) + abs(a[2] * oc.z) + abs(t) + wh;
        vec3 h = wh + PAD * size;
        boxes[2u * i] = vec4(wc - h, 0.0);
        boxes[2u * i + 1u] = vec4(wc + h, 0.0);
        // the inverse by cofactors: its rows are cross products of the columns, over the determinant
        vec3 c0 = cross(a[1], a[2]), c1 = cross(a[2], a[0]), c2 = cross(a[0], a[1]);
        float inv_det = 1.0 / dot(a[0], c0);
        c0 *= inv_det;
        c1 *= inv_det;
        c2 *= inv_det;
        int rec = int(4u * (pc.inst_base + i));
        imageStore(nodes, rec, uvec4(floatBitsToUint(vec4(c0, -dot(c0, t)))));
        imageStore(nodes, rec + 1, uvec4(floatBitsToUint(vec4(c1, -dot(c1, t)))));
        imageStore(nodes, rec + 2, uvec4(floatBitsToUint(vec4(c2, -dot(c2, t)))));
        imageStore(nodes, rec + 3, uvec4(inf.y, inf.z, i, 0u));
        for (int c = 0; c < 3; ++c) {
            atomicMax(s_bounds[c], ~ordered(wc[c]));
            atomicMax(s_bounds[3 + c], ordered(wc[c]));
        }
    }
    barrier();
    if (lid < 6u) atomicMax(bounds[lid < 3u ? lid : lid + 1u], s_bounds[lid]);
}

void morton() {
    uint s = gl_GlobalInvocationID.x;
    if (s >= pc.count) {
        keys[s] = uvec2(0xFFFFFFFFu);
        return;
    }
    vec3 lo = vec3(unordered(~bounds[0]), unordered(~bounds[1]), unordered(~bounds[2]));
    vec3 hi = vec3(unordered(bounds[4]), unordered(bounds[5]), unordered(bounds[6]));
    vec3 c = 0.5 * (boxes[2u * s].xyz + boxes[2u * s + 1u].xyz);
    uvec3 q = uvec3(clamp((c - lo) * (1023.0 / max(hi - lo, vec3(1e-30))), vec3(0.0), vec3(1023.0)));
    keys[s] = uvec2(spread(q.x) | (spread(q.y) << 1) | (spread(q.z) << 2), s);
}

void compare_swap(inout uvec2 a, inout uvec2 b, bool ascending) {
    if (key_less(b, a) == ascending) {
        uvec2 t = a;
        a = b;
        b = t;
    }
}

void sort_block(bool full) {
    uint lid = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * SORT_BLOCK;
    s_keys[lid] = keys[base + lid];
    s_keys[lid + SORT_BLOCK / 2u] = keys[base + lid + SORT_BLOCK / 2u];
    uint k0 = full ? 2u : pc.k, k1 = full ? SORT_BLOCK : pc.k;
    for (uint k = k0; k <= k1; k <<= 1) {
        for (uint j = min(k >> 1, SORT_BLOCK / 2u); j > 0u; j >>= 1) {
            barrier();
            uint i = 2u * j * (lid / j) + lid % j;
            uvec2 a = s_keys[i], b = s_keys[i + j];
            compare_swap(a, b, ((base + i) & k) == 0u);
            s_keys[i] = a;
            s_keys[i + j] = b;
        }
    }
    barrier();
    keys[base + lid] = s_keys[lid];
    keys[base + lid + SORT_BLOCK / 2u] = s_keys[lid + SORT_BLOCK / 2u];
}

void sort_step() {
    uint t = gl_GlobalInvocationID.x;
    uint i = 2u * pc.j * (t / pc.j) + t % pc.j;
    uvec2 a = keys[i], b = keys[i + pc.j];
    compare_swap(a, b, (i & pc.k) == 0u);
    keys[i] = a;
    keys[i + pc.j] = b;
}

void leaves() {
    uint s = gl_GlobalInvocationID.x;
    if (s >= pc.slots / 2u) return;
    const float INF = uintBitsToFloat(0x7F800000u);
    vec3 lo[2] = vec3[2](vec3(INF), vec3(INF)), hi[2] = vec3[2](vec3(-INF), vec3(-INF));
    uint word[2] = uint[2](LEAF, LEAF), n[2] = uint[2](0u, 0u);
    for (uint c = 0u; c < 2u; ++c) {
        uint slot = 2u * s + c;
        if (slot < pc.count) {
            uint inst = keys[slot].y;
            lo[c] = boxes[2u * inst].xyz;
            hi[c] = boxes[2u * inst + 1u].xyz;
            word[c] = LEAF | inst;
            n[c] = 1u;
        }
    }
    store_node(pc.slots / 2u - 1u + s, lo[0], hi[0], lo[1], hi[1], word[0], word[1], n[0], n[1]);
}

void level() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= (1u << pc.level)) return;
    uint node = (1u << pc.level) - 1u + i;
    vec3 lo[2], hi[2];
    for (uint c = 0u; c < 2u; ++c) {
        int t = int(4u * (pc.tlas_root + 2u * node + 1u + c));
        vec3 lmin = uintBitsToFloat(imageLoad(nodes, t).xyz), lmax = uintBitsToFloat(imageLoad(nodes, t + 1).xyz);
        vec3 rmin = uintBitsToFloat(imageLoad(nodes, t + 2).xyz), rmax = uintBitsToFloat(imageLoad(nodes, t + 3).xyz);
        lo[c] = min(lmin, rmin);
        hi[c] = max(lmax, rmax);
    }
    store_node(node, lo[0], hi[0], lo[1], hi[1], pc.tlas_root + 2u * node + 1u, pc.tlas_root + 2u * node + 2u,
               0u, 0u);
}

void main() {
    switch (pc.mode) {
        case WORLD: world(); break;
        case MORTON: morton(); break;
        case SORT_BLOCK_FULL: sort_block(true); break;
        case SORT_BLOCK_MERGE: sort_block(false); break;
        case SORT_STEP: sort_step(); break;
        case LEAVES: leaves(); break;
        default: level(); break;
    }
}
