#version 450
// The two-level BVH's top level built on the GPU (engine/gpu/tlas.py), in the layout engine/bvh/instanced.py makes
// on the host and bvh.glsl's BVH_INSTANCED walk reads: instance records, then the radix tree (Karras 2012) over the
// instances sorted along a Morton curve, its N - 1 nodes from the root. One shader, one step per dispatch (`pc.mode`):
//   WORLD    per instance: world box of its mesh's box (padded), world-to-object record, centre bounds (atomics)
//   MORTON   per sort slot: (Morton code of the box centre, instance) keys; slots past the instances sort last
//   SORT_*   bitonic sort of the keys: blocks of SORT_BLOCK in shared memory, longer strides one step a dispatch
//   SEG_*    a segment tree of the sorted instances' boxes: the leaves, then one level a dispatch (range unions)
//   TREE     per internal node: its range of sorted leaves and split (radix_tree in instanced.py), and the node
//            with its two children's boxes, unions of their ranges from the segment tree
layout(local_size_x = 512) in;

const uint WORLD = 0u, MORTON = 1u, SORT_BLOCK_FULL = 2u, SORT_BLOCK_MERGE = 3u, SORT_STEP = 4u, SEG_LEAVES = 5u,
           SEG_LEVEL = 6u, TREE = 7u;
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
    uint level;       // SEG_LEVEL: the segment tree's level written (nodes [2^level, 2^(level + 1)))
    uint k;           // SORT_*: the bitonic sequence length
    uint j;           // SORT_STEP: the compare distance
} pc;

// per instance: rows 0..2 of its object-to-world transform
layout(std430, set = 0, binding = 0) readonly restrict buffer Xf { vec4 xf[]; };
// per instance: (mesh, root node of its mesh, first triangle in the flattened scene, 0)
layout(std430, set = 0, binding = 1) readonly restrict buffer Info { uvec4 info[]; };
// per mesh: object box min (w: the radius of a sphere about the box's centre bounding the mesh), max
layout(std430, set = 0, binding = 2) readonly restrict buffer MeshBoxes { vec4 mesh_box[]; };
// per instance: world box min, max (scratch)
layout(std430, set = 0, binding = 3) restrict buffer Boxes { vec4 boxes[]; };
// the instance centres' bounds as order-preserving uints: 0..2 ~min, 4..6 max (cleared to 0 before WORLD)
layout(std430, set = 0, binding = 4) restrict buffer Bounds { uint bounds[]; };
// sort keys: (Morton code, instance)
layout(std430, set = 0, binding = 5) restrict buffer Keys { uvec2 keys[]; };
// the BVH nodes buffer as 16-byte texels (a node or a record is 4)
layout(set = 0, binding = 6, rgba32ui) uniform restrict uimageBuffer nodes;
// the segment tree over the sorted instances' boxes (min, max), node k at 2k, 2k + 1: leaves from pc.slots
layout(std430, set = 0, binding = 7) restrict buffer Segments { vec4 seg[]; };

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
        float radius = mesh_box[2u * inf.x].w;   // of a sphere about the box's centre that bounds the mesh
        vec3 oc = 0.5 * (bmin + bmax), oh = 0.5 * (bmax - bmin);
        mat3 a = mat3(r0.x, r1.x, r2.x, r0.y, r1.y, r2.y, r0.z, r1.z, r2.z);   // columns
        vec3 t = vec3(r0.w, r1.w, r2.w);
        vec3 wc = a * oc + t;
        // the turned box's half extent, or the turned sphere's (its radius times each row's length) where tighter
        vec3 wh = min(abs(a[0]) * oh.x + abs(a[1]) * oh.y + abs(a[2]) * oh.z,
                      radius * sqrt(vec3(dot(r0.xyz, r0.xyz), dot(r1.xyz, r1.xyz), dot(r2.xyz, r2.xyz))));
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
    // one scale for all three axes (the centres' largest extent): a thin axis (instances on a floor, bobbing a
    // little) then keeps few significant bits instead of splitting every third level on noise
    vec3 ext = hi - lo;
    float scale = 1023.0 / max(max(ext.x, ext.y), max(ext.z, 1e-30));
    uvec3 q = uvec3(clamp((c - lo) * scale, vec3(0.0), vec3(1023.0)));
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

// common prefix length of the sorted keys i and j (code, then index); -1 where j is outside [0, N)
int delta(int i, int j) {
    if (j < 0 || j >= int(pc.count)) return -1;
    uint x = keys[i].x ^ keys[j].x;
    return x != 0u ? 31 - findMSB(x) : 63 - findMSB(uint(i ^ j));
}

void seg_leaves() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.slots) return;
    const float INF = uintBitsToFloat(0x7F800000u);
    vec4 lo = vec4(INF), hi = vec4(-INF);
    if (i < pc.count) {
        uint inst = keys[i].y;
        lo = boxes[2u * inst];
        hi = boxes[2u * inst + 1u];
    }
    seg[2u * (pc.slots + i)] = lo;
    seg[2u * (pc.slots + i) + 1u] = hi;
}

void seg_level() {
    uint k = (1u << pc.level) + gl_GlobalInvocationID.x;
    if (k >= (2u << pc.level)) return;
    seg[2u * k] = min(seg[4u * k], seg[4u * k + 2u]);
    seg[2u * k + 1u] = max(seg[4u * k + 1u], seg[4u * k + 3u]);
}

// the union of the sorted instances' boxes [first, last]
void range_box(int first, int last, out vec3 lo, out vec3 hi) {
    const float INF = uintBitsToFloat(0x7F800000u);
    lo = vec3(INF);
    hi = vec3(-INF);
    uint l = pc.slots + uint(first), r = pc.slots + uint(last) + 1u;
    while (l < r) {
        if ((l & 1u) != 0u) {
            lo = min(lo, seg[2u * l].xyz);
            hi = max(hi, seg[2u * l + 1u].xyz);
            l += 1u;
        }
        if ((r & 1u) != 0u) {
            r -= 1u;
            lo = min(lo, seg[2u * r].xyz);
            hi = max(hi, seg[2u * r + 1u].xyz);
        }
        l >>= 1u;
        r >>= 1u;
    }
}

void tree() {
    int i = int(gl_GlobalInvocationID.x);
    int n = int(pc.count);
    if (n == 1 && i == 0) {   // one node: the instance on the left, an empty right slot
        const float INF = uintBitsToFloat(0x7F800000u);
        uint inst = keys[0].y;
        store_node(0u, boxes[2u * inst].xyz, boxes[2u * inst + 1u].xyz, vec3(INF), vec3(-INF), LEAF | inst, LEAF,
                   1u, 0u);
    }
    if (i >= n - 1) return;
    // the direction of the node's range, its length (doubling bound, then binary search), then the split
    int d = delta(i, i + 1) > delta(i, i - 1) ? 1 : -1;
    int dmin = delta(i, i - d);
    int lmax = 2;
    while (delta(i, i + lmax * d) > dmin) lmax *= 2;
    int span = 0;
    for (int t = lmax / 2; t >= 1; t /= 2) {
        if (delta(i, i + (span + t) * d) > dmin) span += t;
    }
    int j = i + span * d;
    int dnode = delta(i, j);
    int s = 0;
    int t = span;
    do {
        t = (t + 1) >> 1;
        if (delta(i, i + (s + t) * d) > dnode) s += t;
    } while (t > 1);
    int split = i + s * d + min(d, 0);
    int first = min(i, j), last = max(i, j);
    bool lleaf = first == split, rleaf = last == split + 1;
    uint left = lleaf ? (LEAF | keys[split].y) : pc.tlas_root + uint(split);
    uint right = rleaf ? (LEAF | keys[split + 1].y) : pc.tlas_root + uint(split + 1);
    vec3 lmin, lmax_, rmin, rmax;
    range_box(first, split, lmin, lmax_);
    range_box(split + 1, last, rmin, rmax);
    store_node(uint(i), lmin, lmax_, rmin, rmax, left, right, lleaf ? 1u : 0u, rleaf ? 1u : 0u);
}

void main() {
    switch (pc.mode) {
        case WORLD: world(); break;
        case MORTON: morton(); break;
        case SORT_BLOCK_FULL: sort_block(true); break;
        case SORT_BLOCK_MERGE: sort_block(false); break;
        case SORT_STEP: sort_step(); break;
        case SEG_LEAVES: seg_leaves(); break;
        case SEG_LEVEL: seg_level(); break;
        default: tree(); break;
    }
}
