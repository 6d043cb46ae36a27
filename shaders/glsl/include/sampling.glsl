// Random numbers and sampling: R2 low-discrepancy sequence, per-pixel Cranley-Patterson rotation,
// cosine-weighted hemisphere, light sampling (cone, sphere, rectangle).
#ifndef SAMPLING_GLSL
#define SAMPLING_GLSL

// PCG hash (Jarzynski & Olano 2020): a well-mixed 32-bit hash.
uint pcg_hash(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

float u01(uint h) { return float(h >> 8) * (1.0 / 16777216.0); }

// Per-pixel, per-stream random rotation in [0,1)^2, stable over frames.
vec2 pixel_rotation(uvec2 px, uint stream) {
    uint h = pcg_hash(px.x + pcg_hash(px.y + pcg_hash(stream)));
    return vec2(u01(h), u01(pcg_hash(h)));
}

// R2 sequence (Roberts 2018): point i of a 2D low-discrepancy sequence, rotated by `rot`.
vec2 r2(uint i, vec2 rot) {
    const vec2 alpha = vec2(0.7548776662466927, 0.5698402909980532);
    return fract(rot + alpha * float(i));
}

// Orthonormal basis around unit n (Duff et al. 2017).
void basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

vec3 cosine_hemisphere(vec3 n, vec2 xi) {
    float r = sqrt(xi.x);
    float phi = 2.0 * 3.14159265358979 * xi.y;
    vec3 t, b;
    basis(n, t, b);
    return normalize(t * (r * cos(phi)) + b * (r * sin(phi)) + n * sqrt(max(0.0, 1.0 - xi.x)));
}

// Uniform direction in the cone of half-angle with cosine cos_max around unit axis.
vec3 sample_cone(vec3 axis, float cos_max, vec2 xi) {
    float cos_t = mix(1.0, cos_max, xi.x);
    float sin_t = sqrt(max(0.0, 1.0 - cos_t * cos_t));
    float phi = 2.0 * 3.14159265358979 * xi.y;
    vec3 t, b;
    basis(axis, t, b);
    return t * (sin_t * cos(phi)) + b * (sin_t * sin(phi)) + axis * cos_t;
}

// Uniform point on the disc of radius r centred at c, facing direction n.
vec3 sample_disc(vec3 c, vec3 n, float r, vec2 xi) {
    float rr = r * sqrt(xi.x);
    float phi = 2.0 * 3.14159265358979 * xi.y;
    vec3 t, b;
    basis(n, t, b);
    return c + t * (rr * cos(phi)) + b * (rr * sin(phi));
}

#endif
