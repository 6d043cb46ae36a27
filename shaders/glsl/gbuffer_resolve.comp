#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer resolve: from the visibility image (instance's first id + triangle + 1 per pixel) to world position +
// linear depth, unit normal facing the viewer and albedo, the values the rasterizer would have interpolated at the
// pixel centre. The instance is found by a binary search over the instances' first ids; its transform moves the
// object-space vertices (normals by the inverse transpose, renormalized; surfaces are two-sided, so a mirroring
// transform needs nothing more), and its previous transform gives the motion and where the point was.
//
// Perspective-correct barycentrics come from the triangle's clip-space vertices with homogeneous edge functions
// (Olano and Greer 1997): with the columns C_i = (x_i, y_i, w_i) and the pixel's NDC point P = (px, py, 1), the
// weights are b_i ~ dot(cross(C_i+1, C_i+2), P), normalized to sum 1. No division by w, so triangles that cross
// the camera plane need no clipping. The same weights one pixel to the right and one below give the UV
// derivatives, and from them the texture's level of detail (what a fragment quad would have had).
#include "common.glsl"
#include "instances.glsl"
FRAME_BLOCK

layout(constant_id = 0) const int TEXTURE_SLOTS = MAX_TEXTURES;

// Slot k of `textures` at the pixel's UV, with the level of detail a fragment quad would have used (isotropic: the
// sampler has no anisotropy), given explicitly; multiplied into the albedo of the pixels whose material uses it.
#define SAMPLE_SLOT(k)                                                                                          \
    if (k < TEXTURE_SLOTS && (used & (1u << k)) != 0u) {                                                       \
        vec2 texels = vec2(textureSize(textures[k], 0));                                                       \
        float rho = max(length(duv_dx * texels), length(duv_dy * texels));                                     \
        vec4 texel = textureLod(textures[k], uv, log2(max(rho, 1e-30)));                                       \
        if (slot == k) albedo.rgb *= texel.rgb;                                                                \
    }

layout(local_size_x = 8, local_size_y = 8) in;
// Read, then set back to 0 (background) for the next frame: the raster pass loads it instead of clearing it.
layout(set = 0, binding = 1, r32ui) uniform uimage2D visibility;
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D g_position;
layout(set = 0, binding = 3, rgba32f) uniform writeonly image2D g_normal;
layout(set = 0, binding = 4, rgba16f) uniform writeonly image2D g_albedo;
// The normal again, 4 bytes (w: 1 where covered), for the denoiser's 25 taps per pixel and iteration: on GPUs the
// 16-byte loads of the full normal are a large part of the denoiser's time.
layout(set = 0, binding = 10, rgba8_snorm) uniform writeonly image2D g_normal8;
// The scene's buffers as texel buffers (lavapipe gathers texels for 8 lanes at once, storage buffers lane by lane)
layout(set = 0, binding = 5) uniform samplerBuffer vertices;       // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 6) uniform usamplerBuffer indices;       // material-sorted, 3 per triangle
layout(set = 0, binding = 7) uniform usamplerBuffer tri_info;      // per mesh triangle: material, its index in the mesh, object
layout(set = 0, binding = 8) uniform samplerBuffer materials;      // 2 texels: base colour, (texture slot bits, ...)
layout(set = 0, binding = 9) uniform sampler2D textures[MAX_TEXTURES];
// The data AOVs: linear view depth (+inf on background), the scene's triangle, object and material ids (-1 as uint on
// background), and the pixel's motion since the previous frame (now - then, in pixels).
layout(set = 0, binding = 11, r32f) uniform writeonly image2D g_depth;
layout(set = 0, binding = 12, r32ui) uniform writeonly uimage2D g_triangle;
layout(set = 0, binding = 13, r32ui) uniform writeonly uimage2D g_object;
layout(set = 0, binding = 14, r32ui) uniform writeonly uimage2D g_material;
layout(set = 0, binding = 15, rg32f) uniform writeonly image2D g_motion;
// The instance (its index in scene.instances; -1 as uint on background), and where the pixel's surface point was
// in the previous frame (world position, w: 1 where covered; its normal) for the temporal reprojection's tests.
layout(set = 0, binding = 16, r32ui) uniform writeonly uimage2D g_instance;
layout(set = 0, binding = 17, rgba32f) uniform writeonly image2D g_prev_position;
layout(set = 0, binding = 18, rgba16f) uniform writeonly image2D g_prev_normal;
layout(std430, set = 0, binding = 19) readonly buffer Instances { Instance instances[]; };
layout(push_constant) uniform Push { uint instance_count; } pc;

shared uint tile_slots;   // bit s: some pixel of this workgroup samples texture slot s

vec3 weights(vec3 e0, vec3 e1, vec3 e2, vec3 p) {
    vec3 b = vec3(dot(e0, p), dot(e1, p), dot(e2, p));
    return b / (b.x + b.y + b.z);
}

// The instance whose ids hold `id0` (visibility id - 1): the last one whose prefix is <= id0.
uint find_instance(uint id0) {
    uint lo = 0u, hi = pc.instance_count;   // instances[lo].prefix <= id0 < instances[hi].prefix
    while (hi - lo > 1u) {
        uint mid = (lo + hi) >> 1;
        if (instances[mid].ids.x <= id0) lo = mid; else hi = mid;
    }
    return lo;
}

vec3 xform(mat4 m, vec3 p) { return (m * vec4(p, 1.0)).xyz; }
vec3 xnormal(vec4 c[3], vec3 n) { return c[0].xyz * n.x + c[1].xyz * n.y + c[2].xyz * n.z; }

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uvec2 size = uvec2(frame.width, frame.height);
    bool inside = px.x < int(size.x) && px.y < int(size.y);
    uint id = inside ? imageLoad(visibility, px).x : 0u;
    if (id != 0u) imageStore(visibility, px, uvec4(0u));

    vec3 pos = vec3(0.0), nrm = vec3(0.0), prev_pos = vec3(0.0), prev_nrm = vec3(0.0);
    vec2 uv = vec2(0.0), duv_dx = vec2(0.0), duv_dy = vec2(0.0);
    vec4 albedo = vec4(0.0);
    int slot = -1;
    uvec4 info = uvec4(0xFFFFFFFFu);
    uint instance_id = 0xFFFFFFFFu;
    if (id != 0u) {
        uint k = find_instance(id - 1u);
        Instance inst = instances[k];
        uint local = id - 1u - inst.ids.x;   // the triangle within its mesh
        int tri = int(inst.ids.y + local);
        int i0 = int(texelFetch(indices, 3 * tri).x), i1 = int(texelFetch(indices, 3 * tri + 1).x);
        int i2 = int(texelFetch(indices, 3 * tri + 2).x);
        vec4 a0 = texelFetch(vertices, 2 * i0), a1 = texelFetch(vertices, 2 * i1), a2 = texelFetch(vertices, 2 * i2);
        vec4 b0 = texelFetch(vertices, 2 * i0 + 1), b1 = texelFetch(vertices, 2 * i1 + 1);
        vec4 b2 = texelFetch(vertices, 2 * i2 + 1);
        vec3 p0 = xform(inst.model, a0.xyz), p1 = xform(inst.model, a1.xyz), p2 = xform(inst.model, a2.xyz);
        vec4 c0 = frame.view_proj * vec4(p0, 1.0);
        vec4 c1 = frame.view_proj * vec4(p1, 1.0);
        vec4 c2 = frame.view_proj * vec4(p2, 1.0);
        vec3 C0 = c0.xyw, C1 = c1.xyw, C2 = c2.xyw;
        vec3 e0 = cross(C1, C2), e1 = cross(C2, C0), e2 = cross(C0, C1);
        vec2 step_ndc = 2.0 / vec2(size);
        vec3 P = vec3((vec2(px) + 0.5) * step_ndc - 1.0, 1.0);
        vec3 b = weights(e0, e1, e2, P);
        vec3 bx = weights(e0, e1, e2, P + vec3(step_ndc.x, 0.0, 0.0));
        vec3 by = weights(e0, e1, e2, P + vec3(0.0, step_ndc.y, 0.0));

        pos = b.x * p0 + b.y * p1 + b.z * p2;
        vec3 n_obj = b.x * vec3(a0.w, b0.xy) + b.y * vec3(a1.w, b1.xy) + b.z * vec3(a2.w, b2.xy);
        vec3 n = xnormal(inst.nrm, n_obj);
        float len = length(n);
        // a degenerate interpolated normal falls back to the facet normal
        n = len > 1e-6 ? n / len : normalize(cross(p1 - p0, p2 - p0));
        float side = dot(n, frame.eye - pos) < 0.0 ? -1.0 : 1.0;   // two-sided surfaces: the side we see
        nrm = side * n;

        // The same object-space point and normal under the previous frame's transform.
        vec3 q0 = xform(inst.prev_model, a0.xyz), q1 = xform(inst.prev_model, a1.xyz);
        vec3 q2 = xform(inst.prev_model, a2.xyz);
        prev_pos = b.x * q0 + b.y * q1 + b.z * q2;
        vec3 m = xnormal(inst.prev_nrm, n_obj);
        float mlen = length(m);
        prev_nrm = side * (mlen > 1e-6 ? m / mlen : normalize(cross(q1 - q0, q2 - q0)));

        vec2 t0 = b0.zw, t1 = b1.zw, t2 = b2.zw;
        uv = b.x * t0 + b.y * t1 + b.z * t2;
        duv_dx = bx.x * t0 + bx.y * t1 + bx.z * t2 - uv;
        duv_dy = by.x * t0 + by.y * t1 + by.z * t2 - uv;

        info = texelFetch(tri_info, tri);   // material, triangle within the mesh, object within the mesh
        if (inst.ids.w != 0xFFFFFFFFu) info.x = inst.ids.w;
        info.y = inst.flat_ids.x + local;
        info.z += inst.flat_ids.y;
        instance_id = inst.ids.z;
        int material = int(info.x);
        albedo = vec4(texelFetch(materials, 2 * material).rgb, 1.0);
        slot = floatBitsToInt(texelFetch(materials, 2 * material + 1).x);
    }

    // Texture sampling: one block per slot, each with a constant index, taken where some pixel of this workgroup
    // samples that slot (the bits in tile_slots: a branch that is uniform over the workgroup). Constant indices,
    // not a loop over textures[s]: lavapipe 22.3 samples a dynamically indexed array lane by lane, and in rare
    // launches put the wrong texture on one object for the whole run.
    // TEXTURE_SLOTS (set by engine/passes/gbuffer.py) is the number of slots the scene uses: the blocks past it go.
    if (gl_LocalInvocationIndex == 0u) tile_slots = 0u;
    barrier();
    if (slot >= 0) atomicOr(tile_slots, 1u << uint(slot));
    barrier();
    uint used = tile_slots;
    SAMPLE_SLOT(0) SAMPLE_SLOT(1) SAMPLE_SLOT(2) SAMPLE_SLOT(3) SAMPLE_SLOT(4) SAMPLE_SLOT(5) SAMPLE_SLOT(6)
    SAMPLE_SLOT(7) SAMPLE_SLOT(8) SAMPLE_SLOT(9) SAMPLE_SLOT(10) SAMPLE_SLOT(11) SAMPLE_SLOT(12) SAMPLE_SLOT(13)
    SAMPLE_SLOT(14) SAMPLE_SLOT(15)

    if (!inside) return;
    float depth = id != 0u ? dot(pos - frame.eye, frame.forward) : 0.0;
    imageStore(g_position, px, vec4(pos, depth));
    imageStore(g_normal, px, vec4(nrm, id != 0u ? 1.0 : 0.0));
    imageStore(g_albedo, px, albedo);
    imageStore(g_normal8, px, vec4(nrm, id != 0u ? 1.0 : 0.0));
    imageStore(g_depth, px, vec4(id != 0u ? depth : uintBitsToFloat(0x7F800000u)));
    imageStore(g_triangle, px, uvec4(info.y));
    imageStore(g_object, px, uvec4(info.z));
    imageStore(g_material, px, uvec4(info.x));
    imageStore(g_instance, px, uvec4(instance_id));
    imageStore(g_prev_position, px, vec4(prev_pos, id != 0u ? 1.0 : 0.0));
    imageStore(g_prev_normal, px, vec4(prev_nrm, 0.0));
    vec2 motion = vec2(0.0);
    if (id != 0u) {   // where this surface point is on screen minus where it was in the previous frame
        vec4 now = frame.view_proj * vec4(pos, 1.0), prev = frame.prev_view_proj * vec4(prev_pos, 1.0);
        vec2 d = (now.xy / now.w - prev.xy / prev.w) * 0.5 * vec2(size);   // exactly 0 for the same matrices
        motion = prev.w > 0.0 ? d : vec2(0.0);
    }
    imageStore(g_motion, px, vec4(motion, 0.0, 0.0));
}
