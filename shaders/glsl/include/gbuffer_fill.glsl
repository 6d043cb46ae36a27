// The G-buffer resolves body (gbuffer_resolve.comp; with CAMERA_RAYS defined, gbuffer_rays.comp: the triangle
// and the barycentrics come from traced primary rays instead, camera_rays.glsl). The resolve: from the visibility image (instance's first id + triangle + 1 per pixel; an instance's ids
// cover its mesh's levels of detail in a row, as the index buffer holds them) to world position +
// linear depth, unit normal facing the viewer and albedo, the values the rasterizer would have interpolated at the
// pixel centre. The instance is found by a binary search over the instances' first ids; its transform moves the
// object-space vertices (normals by the inverse transpose, renormalized; surfaces are two-sided, so a mirroring
// transform needs nothing more), and its previous transform gives the motion and where the point was.
//
// Perspective-correct barycentrics come from the triangle's clip-space vertices with homogeneous edge functions
// (Olano and Greer 1997): with the columns C_i = (x_i, y_i, w_i) and the pixel's NDC point P = (px, py, 1), the
// weights are b_i ~ dot(cross(C_i+1, C_i+2), P), normalized to sum 1. No division by w, so triangles that cross
// the camera plane need no clipping. The same weights one pixel to the right and one below give the UV
// derivatives, the pixel's footprint in the texture (what a fragment quad would have had).
#include "common.glsl"
#include "instances.glsl"
#include "terminator.glsl"
FRAME_BLOCK

#ifdef CAMERA_RAYS
#define INSTANCES_TEXEL_ID 31
#include "camera_rays.glsl"
#else
#define INSTANCES_TEXEL_ID 1
#define TEXTURES_SET 0
#define TEXTURES_BINDING 9
#define TEXTURE_ARRAYS_ID 0
#include "textures.glsl"
#endif

layout(local_size_x = 8, local_size_y = 8) in;
#ifndef CAMERA_RAYS
// Read, then set back to 0 (background) for the next frame: the raster pass loads it instead of clearing it.
layout(set = 0, binding = 1, r32ui) uniform uimage2D visibility;
#endif
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D g_position;
layout(set = 0, binding = 3, rgba32f) uniform writeonly image2D g_normal;
layout(set = 0, binding = 4, rgba16f) uniform writeonly image2D g_albedo;
// The normal again, 4 bytes (w: 1 where covered), for the denoiser's 25 taps per pixel and iteration: on GPUs the
// 16-byte loads of the full normal are a large part of the denoiser's time.
layout(set = 0, binding = 10, rgba8_snorm) uniform writeonly image2D g_normal8;
// The scene's buffers as texel buffers (lavapipe gathers texels for 8 lanes at once, storage buffers lane by lane)
layout(set = 0, binding = 5) uniform samplerBuffer vertices;       // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 6) uniform usamplerBuffer indices;       // each mesh's levels, material-sorted, 3 per tri
layout(set = 0, binding = 7) uniform usamplerBuffer tri_info;      // per triangle: material, index, object, error
layout(set = 0, binding = 8) uniform samplerBuffer materials;      // MATERIAL_TEXELS per material (interface.py)
// The data AOVs: linear view depth (+inf on background), the scene's triangle, object and material ids (-1 as uint on
// background), and the pixel's motion since the previous frame (now - then, in pixels).
layout(set = 0, binding = 11, r32f) uniform writeonly image2D g_depth;
layout(set = 0, binding = 12, r32ui) uniform writeonly uimage2D g_triangle;
layout(set = 0, binding = 13, r32ui) uniform writeonly uimage2D g_object;
layout(set = 0, binding = 14, r32ui) uniform writeonly uimage2D g_material;
layout(set = 0, binding = 15, rg32f) uniform writeonly image2D g_motion;
// The lighting's material inputs: (roughness, metallic, occlusion, 1 where covered) and the emitted radiance.
layout(set = 0, binding = 16, rgba8) uniform writeonly image2D g_pbr;
layout(set = 0, binding = 17, rgba16f) uniform writeonly image2D g_emissive;
// The instance (its index in scene.instances; -1 as uint on background), and where the pixel's surface point was
// in the previous frame (world position, w: 1 where covered; its normal) for the temporal reprojection's tests.
layout(set = 0, binding = 18, r32ui) uniform writeonly uimage2D g_instance;
layout(set = 0, binding = 19, rgba32f) uniform writeonly image2D g_prev_position;
layout(set = 0, binding = 20, rgba16f) uniform writeonly image2D g_prev_normal;
layout(std430, set = 0, binding = 21) readonly buffer Instances { Instance instances[]; };
// The same records as texel buffers, INSTANCE_TEXELS RGBA32F texels each, and the same bytes as RGBA32UI:
// INSTANCES_TEXEL (CPU devices) reads them there, as llvmpipe loads a storage buffer's struct lane by lane.
layout(set = 0, binding = 22) uniform samplerBuffer instance_texels;
layout(set = 0, binding = 23) uniform usamplerBuffer instance_words;
// Where the shadow rays start relative to g_position (terminator.glsl; 0 for flat-shaded triangles).
layout(set = 0, binding = 24, rgba16f) uniform writeonly image2D g_terminator;
layout(constant_id = INSTANCES_TEXEL_ID) const bool INSTANCES_TEXEL = false;
layout(push_constant) uniform Push { uint instance_count; } pc;

shared uint tile_arrays;   // bit a: some pixel of this workgroup samples texture array a

vec3 weights(vec3 e0, vec3 e1, vec3 e2, vec3 p) {
    vec3 b = vec3(dot(e0, p), dot(e1, p), dot(e2, p));
    return b / (b.x + b.y + b.z);
}

uint instance_prefix(uint k) {
    if (INSTANCES_TEXEL) return texelFetch(instance_words, INSTANCE_TEXELS * int(k) + INSTANCE_IDS_TEXEL).x;
    return instances[k].ids.x;
}

// The instance whose ids hold `id0` (visibility id - 1): the last one whose prefix is <= id0.
uint find_instance(uint id0) {
    uint lo = 0u, hi = pc.instance_count;   // instances[lo].prefix <= id0 < instances[hi].prefix
    while (hi - lo > 1u) {
        uint mid = (lo + hi) >> 1;
        if (instance_prefix(mid) <= id0) lo = mid; else hi = mid;
    }
    return lo;
}

Instance load_instance(uint k) {
    if (INSTANCES_TEXEL) return instance_from_texels(instance_texels, instance_words, k);
    return instances[k];   // (not a ?: between the two: their struct types differ in SPIR-V)
}

vec3 xform(mat4 m, vec3 p) { return (m * vec4(p, 1.0)).xyz; }
vec3 xnormal(vec4 c[3], vec3 n) { return c[0].xyz * n.x + c[1].xyz * n.y + c[2].xyz * n.z; }

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uvec2 size = uvec2(frame.width, frame.height);
    bool inside = px.x < int(size.x) && px.y < int(size.y);
#ifdef CAMERA_RAYS
    CameraHit ray = camera_trace(px, inside, pc.instance_count);   // the pixel's primary ray and its closest hit (camera_rays.glsl)
    uint id = ray.hit ? 1u : 0u;
#else
    uint id = inside ? imageLoad(visibility, px).x : 0u;
    if (id != 0u) imageStore(visibility, px, uvec4(0u));
#endif

    vec3 pos = vec3(0.0), nrm = vec3(0.0), prev_pos = vec3(0.0), prev_nrm = vec3(0.0), shift = vec3(0.0);
    bool still = false;   // the pixel's instance has the same transform as in the previous frame
    vec2 uv = vec2(0.0), duv_dx = vec2(0.0), duv_dy = vec2(0.0);
    vec4 albedo = vec4(0.0);
    uvec4 handles = uvec4(TEXTURE_NONE);   // base colour, metallic-roughness, normal, emissive
    vec3 tangent = vec3(0.0), bitangent = vec3(0.0);
    float normal_scale = 1.0;
    vec4 pbr = vec4(0.0);        // roughness, metallic, occlusion, covered
    vec3 emissive = vec3(0.0);
    uint occlusion_handle = TEXTURE_NONE;
    float occlusion_strength = 0.0;
    uvec4 info = uvec4(0xFFFFFFFFu);
    uint instance_id = 0xFFFFFFFFu;
    if (id != 0u) {
#ifdef CAMERA_RAYS
        uint k = ray.slot;
        Instance inst = load_instance(k);
        uint local = ray.local;
#else
        uint k = find_instance(id - 1u);
        Instance inst = load_instance(k);
        uint local = id - 1u - inst.ids.x;   // the triangle within its mesh
#endif
        int tri = int(inst.ids.y + local);
        int i0 = int(texelFetch(indices, 3 * tri).x), i1 = int(texelFetch(indices, 3 * tri + 1).x);
        int i2 = int(texelFetch(indices, 3 * tri + 2).x);
        vec4 a0 = texelFetch(vertices, 2 * i0), a1 = texelFetch(vertices, 2 * i1), a2 = texelFetch(vertices, 2 * i2);
        vec4 b0 = texelFetch(vertices, 2 * i0 + 1), b1 = texelFetch(vertices, 2 * i1 + 1);
        vec4 b2 = texelFetch(vertices, 2 * i2 + 1);
        vec3 p0 = xform(inst.model, a0.xyz), p1 = xform(inst.model, a1.xyz), p2 = xform(inst.model, a2.xyz);
#ifdef CAMERA_RAYS
        vec3 b = ray_weights(ray.o, ray.d, p0, p1, p2);   // the neighbours' rays on the same triangle's plane
        vec3 bx = ray_weights(ray.ox, ray.dx, p0, p1, p2), by = ray_weights(ray.oy, ray.dy, p0, p1, p2);
#else
        vec4 c0 = frame.view_proj * vec4(p0, 1.0);
        vec4 c1 = frame.view_proj * vec4(p1, 1.0);
        vec4 c2 = frame.view_proj * vec4(p2, 1.0);
        vec3 C0 = c0.xyw, C1 = c1.xyw, C2 = c2.xyw;
        vec3 e0 = cross(C1, C2), e1 = cross(C2, C0), e2 = cross(C0, C1);
        vec2 step_ndc = 2.0 / vec2(size);
        vec3 P = vec3((vec2(px) + 0.5 + frame.jitter) * step_ndc - 1.0, 1.0);   // the raster's sample point
        vec3 b = weights(e0, e1, e2, P);
        vec3 bx = weights(e0, e1, e2, P + vec3(step_ndc.x, 0.0, 0.0));
        vec3 by = weights(e0, e1, e2, P + vec3(0.0, step_ndc.y, 0.0));
#endif

        pos = b.x * p0 + b.y * p1 + b.z * p2;
        vec3 n_obj = b.x * vec3(a0.w, b0.xy) + b.y * vec3(a1.w, b1.xy) + b.z * vec3(a2.w, b2.xy);
        vec3 n = xnormal(inst.nrm, n_obj);
        float len = length(n);
        // a degenerate interpolated normal falls back to the facet normal
        n = len > 1e-6 ? n / len : normalize(cross(p1 - p0, p2 - p0));
#ifdef CAMERA_RAYS
        float side = dot(n, ray.d) > 0.0 ? -1.0 : 1.0;
#else
        float side = dot(n, frame.eye - pos) < 0.0 ? -1.0 : 1.0;
#endif
        n *= side;   // two-sided surfaces: the side we see
        nrm = n;
        // the shadow rays' origin off the flat triangle towards the smooth surface (Hanika 2021)
        vec3 m0 = xnormal(inst.nrm, vec3(a0.w, b0.xy)), m1 = xnormal(inst.nrm, vec3(a1.w, b1.xy));
        vec3 m2 = xnormal(inst.nrm, vec3(a2.w, b2.xy));
        if (min(dot(m0, m0), min(dot(m1, m1), dot(m2, m2))) > 1e-12)
            shift = terminator_offset(pos, b, p0, p1, p2, side * normalize(m0), side * normalize(m1),
                                      side * normalize(m2)) - pos;

        // The same object-space point and normal under the previous frame's transform: the point itself where the
        // instance did not move (so that a still surface has no motion at all, whatever the compiler fuses).
        still = inst.model == inst.prev_model;
        if (still) {
            prev_pos = pos;
            prev_nrm = nrm;
        } else {
            vec3 q0 = xform(inst.prev_model, a0.xyz), q1 = xform(inst.prev_model, a1.xyz);
            vec3 q2 = xform(inst.prev_model, a2.xyz);
            prev_pos = b.x * q0 + b.y * q1 + b.z * q2;
            vec3 m = xnormal(inst.prev_nrm, n_obj);
            float mlen = length(m);
            prev_nrm = side * (mlen > 1e-6 ? m / mlen : normalize(cross(q1 - q0, q2 - q0)));
        }

        // material, triangle within the mesh (of the full mesh, for a coarser level's triangle), object within the
        // mesh, the level's object-space error. A coarser level's surface lies up to that error from the full
        // mesh, which the shadow and AO rays trace: the point moves toward the eye along the pixel's ray (so that
        // depth and position still agree) until it is that error (scaled by the instance) off the surface, at most
        // 4x the error at grazing angles, so that those rays start outside the full mesh (0 for the full mesh).
        info = texelFetch(tri_info, tri);
        float lod_error = uintBitsToFloat(info.w);
        if (lod_error > 0.0) {
            mat3 a = mat3(inst.model);
            vec3 to_eye = normalize(frame.eye - pos);
            float lift = lod_error * max(length(a[0]), max(length(a[1]), length(a[2])))
                       / max(dot(n, to_eye), 0.25);
            pos += to_eye * lift;
            prev_pos += to_eye * lift;
        }

        vec2 t0 = b0.zw, t1 = b1.zw, t2 = b2.zw;
        uv = b.x * t0 + b.y * t1 + b.z * t2;
        duv_dx = bx.x * t0 + bx.y * t1 + bx.z * t2 - uv;
        duv_dy = by.x * t0 + by.y * t1 + by.z * t2 - uv;

        // the instance's material override and its places in the flat arrays
        if (inst.ids.w != 0xFFFFFFFFu) info.x = inst.ids.w;
        info.y += inst.flat_ids.x;
        info.z += inst.flat_ids.y;
        instance_id = inst.ids.z;
        int material = MATERIAL_TEXELS * int(info.x);
        albedo = vec4(texelFetch(materials, material).rgb, 1.0);
        handles = floatBitsToUint(texelFetch(materials, material + 1));
        vec4 factors = texelFetch(materials, material + 2);
        pbr = vec4(factors.y, factors.x, 1.0, 1.0);
        occlusion_strength = factors.z;
        normal_scale = factors.w;
        emissive = texelFetch(materials, material + 3).rgb;
        occlusion_handle = floatBitsToUint(texelFetch(materials, material + 4).x);

        // The normal map's tangent frame: T = dP/du of the triangle, orthonormalized against the interpolated
        // normal; B = cross(N, T), its sign making B point along -dP/dv (up in the image: glTF's +Y), which also
        // holds for mirrored UVs; seen from the back, the whole frame turns (the mapped normal is the front's,
        // negated). Degenerate UVs: no normal map.
        vec2 d1 = t1 - t0, d2 = t2 - t0;
        float det = d1.x * d2.y - d2.x * d1.y;
        if (handles.z != TEXTURE_NONE && abs(det) > 1e-20) {
            vec3 e1w = p1 - p0, e2w = p2 - p0;
            vec3 dp_du = (e1w * d2.y - e2w * d1.y) / det, dp_dv = (e2w * d1.x - e1w * d2.x) / det;
            vec3 t = dp_du - n * dot(n, dp_du);
            if (dot(t, t) > 1e-30) {
                tangent = normalize(t);
                bitangent = cross(n, tangent);
                if (dot(bitangent, dp_dv) > 0.0) bitangent = -bitangent;
                tangent *= side;
                bitangent *= side;
            }
        }
    }

    // Texture sampling (textures.glsl): each array this workgroup's pixels use is sampled in a branch that is
    // uniform over the workgroup, with explicit UV derivatives (trilinear; anisotropic where the sampler has it).
    if (gl_LocalInvocationIndex == 0u) tile_arrays = 0u;
    barrier();
    uint bits = texture_bit(handles.x) | texture_bit(handles.y) | texture_bit(handles.z) | texture_bit(handles.w)
              | texture_bit(occlusion_handle);
    if (bits != 0u) atomicOr(tile_arrays, bits);
    barrier();
    uint used = tile_arrays;
    if (used != 0u) {
        albedo.rgb *= sample_texture_masked(handles.x, uv, duv_dx, duv_dy, used).rgb;
        vec4 mr = sample_texture_masked(handles.y, uv, duv_dx, duv_dy, used);   // G roughness, B metallic
        pbr.xy *= mr.gb;
        emissive *= sample_texture_masked(handles.w, uv, duv_dx, duv_dy, used).rgb;
        float occlusion = sample_texture_masked(occlusion_handle, uv, duv_dx, duv_dy, used).r;
        pbr.z = 1.0 + occlusion_strength * (occlusion - 1.0);   // glTF occlusionTexture.strength
        vec3 tn = sample_texture_masked(handles.z, uv, duv_dx, duv_dy, used).xyz * 2.0 - 1.0;
        if (tangent != vec3(0.0)) {   // tangent-space normal, x and y scaled (glTF normalTexture.scale)
            vec3 mapped = tangent * (tn.x * normal_scale) + bitangent * (tn.y * normal_scale) + nrm * tn.z;
            float len = length(mapped);
            if (len > 1e-6) nrm = mapped / len;
        }
    }

    if (!inside) return;
#ifdef CAMERA_RAYS
    float depth = id != 0u ? camera_depth(pos) : 0.0;
#else
    float depth = id != 0u ? dot(pos - frame.eye, frame.forward) : 0.0;
#endif
#ifdef CAMERA_RAYS
    // on the background, w: the ray's direction for the lighting's environment (background_ray.glsl)
    imageStore(g_position, px, vec4(pos, id != 0u ? depth : encode_background_ray(ray.d)));
#else
    imageStore(g_position, px, vec4(pos, depth));
#endif
    imageStore(g_normal, px, vec4(nrm, id != 0u ? 1.0 : 0.0));
    imageStore(g_terminator, px, vec4(shift, 0.0));
    imageStore(g_albedo, px, albedo);
    imageStore(g_normal8, px, vec4(nrm, id != 0u ? 1.0 : 0.0));
    imageStore(g_depth, px, vec4(id != 0u ? depth : uintBitsToFloat(0x7F800000u)));
    imageStore(g_triangle, px, uvec4(info.y));
    imageStore(g_object, px, uvec4(info.z));
    imageStore(g_material, px, uvec4(info.x));
    imageStore(g_pbr, px, pbr);
    imageStore(g_emissive, px, vec4(emissive, 0.0));
    imageStore(g_instance, px, uvec4(instance_id));
    imageStore(g_prev_position, px, vec4(prev_pos, id != 0u ? 1.0 : 0.0));
    imageStore(g_prev_normal, px, vec4(prev_nrm, 0.0));
    vec2 motion = vec2(0.0);
    // where this surface point is on screen minus where it was in the previous frame (none for a still instance
    // seen by a still camera)
#ifdef CAMERA_RAYS
    if (id != 0u) motion = camera_motion(pos, prev_pos, vec2(size));
#else
    if (id != 0u && !(still && frame.view_proj == frame.prev_view_proj)) {
        vec4 now = frame.view_proj * vec4(pos, 1.0), prev = frame.prev_view_proj * vec4(prev_pos, 1.0);
        vec2 d = (now.xy / now.w - prev.xy / prev.w) * 0.5 * vec2(size);
        motion = prev.w > 0.0 ? d : vec2(0.0);
    }
#endif
    imageStore(g_motion, px, vec4(motion, 0.0, 0.0));
}
