// The primary rays of the camera models other than the pinhole (engine/scene/camera_models.py), for
// gbuffer_rays.comp: each pixel's ray (a camera-space direction per pixel from `camera_dirs`, which the host
// computes in float64 from the model's inverse; the orthographic camera's parallel rays from K), its closest hit in
// the scene's BVH (alpha-tested where the material says so) turned into the instance and triangle the resolve
// reads, the barycentrics of a ray on a triangle's plane, and the models' forward projection (motion vectors).
// Camera space is OpenCV's: x right, y down, z forward. Bindings 40-43 (the resolve's own run below them).
#ifndef CAMERA_RAYS_GLSL
#define CAMERA_RAYS_GLSL

#define TEXTURES_BINDING 9
#define ALPHA_BINDING 43
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"
#include "background_ray.glsl"

const uint CAMERA_PINHOLE = 0u;
const uint CAMERA_OPENCV = 1u;
const uint CAMERA_FISHEYE = 2u;
const uint CAMERA_ORTHOGRAPHIC = 3u;
const uint CAMERA_EQUIRECT = 4u;

struct CameraModel {
    mat4 to_world;   // camera-to-world: columns right, down, forward, eye
    vec4 k;          // fx, fy, cx, cy at the render's size (equirect: radians to pixels)
    vec4 d0;         // OpenCV: k1, k2, p1, p2; fisheye: k1, k2, k3, k4
    vec4 d1;         // x: OpenCV k3; y: fisheye's largest theta; z: where rays start (near; 0 orthographic)
    uvec4 kind;      // x: CAMERA_*
};
// This frame's camera and the previous frame's (motion), written per frame by the host.
layout(std140, set = 0, binding = 40) uniform CameraRays { CameraModel now; CameraModel prev; } camera;
layout(set = 0, binding = 41) uniform samplerBuffer camera_dirs;   // per pixel, row-major: direction, w: 1 if any
// The BVH's triangle (the scene's flat order) to the resolve's: for n scene instances, [0, n) each one's first
// flat triangle, [n, 2n) its draw slot, [2n, 3n) where its mesh's ranks start, then per mesh triangle its place
// in the mesh's first level (sorted by material).
layout(set = 0, binding = 42) uniform usamplerBuffer ray_ids;

struct CameraHit {
    bool hit;
    uint slot;    // the instance's draw slot
    uint local;   // the triangle within its mesh's levels
    vec3 o, d;    // the pixel's ray, and the rays of the pixels right of and below it (texture footprints)
    vec3 ox, dx, oy, dy;
};

bool camera_ray(ivec2 q, out vec3 o, out vec3 d) {
    ivec2 size = ivec2(frame.width, frame.height);
    q = clamp(q, ivec2(0), size - 1);
    mat4 m = camera.now.to_world;
    if (camera.now.kind.x == CAMERA_ORTHOGRAPHIC) {
        vec2 xy = (vec2(q) + 0.5 - camera.now.k.zw) / camera.now.k.xy;
        o = (m * vec4(xy, 0.0, 1.0)).xyz;
        d = m[2].xyz;
        return true;
    }
    vec4 c = texelFetch(camera_dirs, q.y * size.x + q.x);
    o = m[3].xyz;
    d = mat3(m) * c.xyz;
    return c.w > 0.0;
}

CameraHit camera_trace(ivec2 px, bool inside, uint n) {
    CameraHit r;
    r.hit = false;
    r.slot = 0u;
    r.local = 0u;
    bool ok = camera_ray(px, r.o, r.d);
    camera_ray(px + ivec2(1, 0), r.ox, r.dx);
    camera_ray(px + ivec2(0, 1), r.oy, r.dy);
    if (!inside || !ok) return r;
    BvhHit h = bvh_intersect(r.o, r.d, camera.now.d1.z, 3.0e38);
    if (h.prim < 0) return r;
    uint prim = uint(h.prim);
    uint lo = 0u, hi = n;   // the last instance whose first flat triangle is <= prim
    while (hi - lo > 1u) {
        uint mid = (lo + hi) >> 1;
        if (texelFetch(ray_ids, int(mid)).x <= prim) lo = mid; else hi = mid;
    }
    uint local = prim - texelFetch(ray_ids, int(lo)).x;
    r.slot = texelFetch(ray_ids, int(n + lo)).x;
    r.local = texelFetch(ray_ids, int(3u * n + texelFetch(ray_ids, int(2u * n + lo)).x + local)).x;
    r.hit = true;
    return r;
}

// Barycentric weights of the point where the ray (o, d) meets the plane of (p0, p1, p2).
vec3 ray_weights(vec3 o, vec3 d, vec3 p0, vec3 p1, vec3 p2) {
    vec3 e1 = p1 - p0, e2 = p2 - p0, pv = cross(d, e2), tv = o - p0;
    float inv = 1.0 / dot(e1, pv);
    float u = dot(tv, pv) * inv, v = dot(d, cross(tv, e1)) * inv;
    return vec3(1.0 - u - v, u, v);
}

// The depth AOV: the distance along the optical axis (OpenCV's Z), or the distance to the eye (equirect).
float camera_depth(vec3 p) {
    vec3 rel = p - camera.now.to_world[3].xyz;
    return camera.now.kind.x == CAMERA_EQUIRECT ? length(rel) : dot(rel, camera.now.to_world[2].xyz);
}

// A world point's pixel coordinates under a camera model (OpenCV's formulas); `ok` false where it does not see it.
vec2 camera_project(CameraModel c, vec3 p, out bool ok) {
    vec3 q = transpose(mat3(c.to_world)) * (p - c.to_world[3].xyz);
    uint kind = c.kind.x;
    ok = true;
    vec2 xy;
    if (kind == CAMERA_EQUIRECT) {
        xy = vec2(atan(q.x, q.z), atan(q.y, length(q.xz)));
    } else if (kind == CAMERA_ORTHOGRAPHIC) {
        xy = q.xy;
    } else if (kind == CAMERA_FISHEYE) {
        float r = length(q.xy), theta = atan(r, q.z), t2 = theta * theta;
        float td = theta * (1.0 + t2 * (c.d0.x + t2 * (c.d0.y + t2 * (c.d0.z + t2 * c.d0.w))));
        ok = theta <= c.d1.y;
        xy = r > 0.0 ? q.xy * (td / r) : vec2(0.0);
    } else {
        ok = q.z > 0.0;
        vec2 a = q.xy / q.z;
        float r2 = dot(a, a), radial = 1.0 + r2 * (c.d0.x + r2 * (c.d0.y + r2 * c.d1.x));
        xy = a * radial + vec2(2.0 * c.d0.z * a.x * a.y + c.d0.w * (r2 + 2.0 * a.x * a.x),
                               c.d0.z * (r2 + 2.0 * a.y * a.y) + 2.0 * c.d0.w * a.x * a.y);
    }
    return xy * c.k.xy + c.k.zw;
}

// Where the point is now minus where it was in the previous frame (pixels; equirect: the short way round).
vec2 camera_motion(vec3 pos, vec3 prev_pos, vec2 size) {
    bool ok_now, ok_prev;
    vec2 d = camera_project(camera.now, pos, ok_now) - camera_project(camera.prev, prev_pos, ok_prev);
    if (camera.now.kind.x == CAMERA_EQUIRECT && camera.prev.kind.x == CAMERA_EQUIRECT)
        d.x -= size.x * round(d.x / size.x);
    return ok_now && ok_prev ? d : vec2(0.0);
}

#endif
