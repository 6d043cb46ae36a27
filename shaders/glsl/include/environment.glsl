// The environment light (engine/scene/environment.py, the tables of engine/scene/envtables.py): radiance by
// direction, importance sampling with solid-angle pdfs, SH irradiance, GGX-prefiltered radiance and the split-sum
// BRDF table, all read from one storage buffer. Where frame.environment_constant is 1 (the `ambient` setting) the
// environment is the constant frame.ambient instead. Needs common.glsl and FRAME_BLOCK before it, and
//   #define ENV_BINDING n   (ENV_SET: the set, 0 unless defined)
// Directions: world space; the map is rotated about +Y; u = atan2(x, -z) / 2pi, v = acos(y) / pi (Mitsuba 3's).
#ifndef ENVIRONMENT_GLSL
#define ENVIRONMENT_GLSL

#ifndef ENV_SET
#define ENV_SET 0
#endif
layout(std430, set = ENV_SET, binding = ENV_BINDING) readonly buffer Environment { float env[]; };

// header words (envtables.py)
#define ENV_W 0
#define ENV_H 1
#define ENV_PW 2
#define ENV_PH 3
#define ENV_LEVELS 4
#define ENV_LUT 5
#define ENV_COS 6
#define ENV_SIN 7
#define ENV_MAP 8
#define ENV_MARGINAL 9
#define ENV_CONDITIONAL 10
#define ENV_PREFILTERED 11
#define ENV_BRDF 12
#define ENV_SH 16

bool env_constant() { return frame.environment_constant > 0.5; }
int env_int(int i) { return int(floatBitsToUint(env[i])); }

vec3 env_to_local(vec3 d) {
    float c = env[ENV_COS], s = env[ENV_SIN];
    return vec3(c * d.x - s * d.z, d.y, s * d.x + c * d.z);
}

vec3 env_to_world(vec3 d) {
    float c = env[ENV_COS], s = env[ENV_SIN];
    return vec3(c * d.x + s * d.z, d.y, -s * d.x + c * d.z);
}

vec2 env_uv(vec3 local) {
    float u = atan(local.x, -local.z) * (0.5 / PI);
    return vec2(u < 0.0 ? u + 1.0 : u, acos(clamp(local.y, -1.0, 1.0)) / PI);
}

vec3 env_dir(vec2 uv) {
    float theta = uv.y * PI, phi = uv.x * 2.0 * PI;
    float st = sin(theta);
    return vec3(st * sin(phi), cos(theta), -st * cos(phi));
}

vec3 env_texel(int base, int w, int x, int y) {
    int i = base + 3 * (y * w + x);
    return vec3(env[i], env[i + 1], env[i + 2]);
}

// Bilinear lookup of a w x h equirect image at `base`: wraps in u, clamps in v.
vec3 env_bilinear(int base, int w, int h, vec2 uv) {
    vec2 p = uv * vec2(w, h) - 0.5;
    vec2 f = p - floor(p);
    int x0 = int(floor(p.x)), y0 = int(floor(p.y));
    int x1 = x0 + 1, y1 = clamp(y0 + 1, 0, h - 1);
    x0 = (x0 % w + w) % w;
    x1 = (x1 % w + w) % w;
    y0 = clamp(y0, 0, h - 1);
    vec3 a = mix(env_texel(base, w, x0, y0), env_texel(base, w, x1, y0), f.x);
    vec3 b = mix(env_texel(base, w, x0, y1), env_texel(base, w, x1, y1), f.x);
    return mix(a, b, f.y);
}

// The environment's radiance arriving from world direction `dir` (unit).
vec3 environment_radiance(vec3 dir) {
    if (env_constant()) return frame.ambient;
    return env_bilinear(env_int(ENV_MAP), env_int(ENV_W), env_int(ENV_H), env_uv(env_to_local(dir)));
}

// The last index i in [0, n) with table[base + i] <= x (table[base] = 0, table[base + n] = 1).
int env_search(int base, int n, float x) {
    int lo = 0, hi = n;
    while (hi - lo > 1) {
        int mid = (lo + hi) >> 1;
        if (env[base + mid] <= x) lo = mid; else hi = mid;
    }
    return lo;
}

// A direction drawn in proportion to luminance x sin(theta) over the map's texels (u: two uniform numbers in
// [0, 1)) and its solid-angle pdf; the constant environment is sampled uniformly over the sphere.
vec3 environment_sample(vec2 u, out float pdf) {
    if (env_constant()) {
        float z = 1.0 - 2.0 * u.y, r = sqrt(max(0.0, 1.0 - z * z)), phi = 2.0 * PI * u.x;
        pdf = 1.0 / (4.0 * PI);
        return vec3(r * cos(phi), z, r * sin(phi));
    }
    int w = env_int(ENV_W), h = env_int(ENV_H);
    int marg = env_int(ENV_MARGINAL);
    int j = env_search(marg, h, u.y);
    float m0 = env[marg + j], m1 = env[marg + j + 1];
    float dv = (u.y - m0) / max(m1 - m0, 1e-30);
    int row = env_int(ENV_CONDITIONAL) + j * (w + 1);
    int i = env_search(row, w, u.x);
    float c0 = env[row + i], c1 = env[row + i + 1];
    float du = (u.x - c0) / max(c1 - c0, 1e-30);
    vec2 uv = vec2((float(i) + du) / float(w), (float(j) + dv) / float(h));
    float st = sin(uv.y * PI);
    float pdf_uv = (m1 - m0) * float(h) * (c1 - c0) * float(w);
    pdf = st > 0.0 ? pdf_uv / (2.0 * PI * PI * st) : 0.0;
    return env_to_world(env_dir(uv));
}

// The solid-angle pdf with which environment_sample draws world direction `dir` (unit).
float environment_pdf(vec3 dir) {
    if (env_constant()) return 1.0 / (4.0 * PI);
    int w = env_int(ENV_W), h = env_int(ENV_H);
    vec3 l = env_to_local(dir);
    vec2 uv = env_uv(l);
    int i = min(int(uv.x * float(w)), w - 1), j = min(int(uv.y * float(h)), h - 1);
    int marg = env_int(ENV_MARGINAL), row = env_int(ENV_CONDITIONAL) + j * (w + 1);
    float pdf_uv = (env[marg + j + 1] - env[marg + j]) * float(h) * (env[row + i + 1] - env[row + i]) * float(w);
    float st = sqrt(max(0.0, 1.0 - l.y * l.y));
    return st > 0.0 ? pdf_uv / (2.0 * PI * PI * st) : 0.0;
}

// The irradiance / pi at a surface of unit normal n (what a white Lambert surface reflects), from the map's
// 9 spherical-harmonics coefficients (Ramamoorthi and Hanrahan 2001).
vec3 environment_irradiance(vec3 n) {
    if (env_constant()) return frame.ambient;
    vec3 d = env_to_local(n);
    float basis[9] = float[9](0.282095, 0.488603 * d.y, 0.488603 * d.z, 0.488603 * d.x, 1.092548 * d.x * d.y,
                              1.092548 * d.y * d.z, 0.315392 * (3.0 * d.z * d.z - 1.0), 1.092548 * d.x * d.z,
                              0.546274 * (d.x * d.x - d.y * d.y));
    vec3 e = vec3(0.0);
    for (int k = 0; k < 9; ++k)
        e += basis[k] * vec3(env[ENV_SH + 3 * k], env[ENV_SH + 3 * k + 1], env[ENV_SH + 3 * k + 2]);
    return max(e, vec3(0.0));
}

// The radiance around world direction r filtered by the GGX lobe of perceptual roughness `roughness` (the split
// sum's first factor): between the map (roughness 0) and the prefiltered levels at roughness (k + 1) / levels.
vec3 environment_specular(vec3 r, float roughness) {
    if (env_constant()) return frame.ambient;
    vec2 uv = env_uv(env_to_local(r));
    int levels = env_int(ENV_LEVELS), pw = env_int(ENV_PW), ph = env_int(ENV_PH);
    int pre = env_int(ENV_PREFILTERED), size = 3 * pw * ph;
    float t = clamp(roughness, 0.0, 1.0) * float(levels) - 1.0;   // the level's index, -1: the map
    int k = int(floor(t));
    vec3 lo = k < 0 ? env_bilinear(env_int(ENV_MAP), env_int(ENV_W), env_int(ENV_H), uv)
                    : env_bilinear(pre + k * size, pw, ph, uv);
    if (k + 1 >= levels) return lo;
    vec3 hi = env_bilinear(pre + (k + 1) * size, pw, ph, uv);
    return mix(lo, hi, t - float(k));
}

// The split sum's second factor: (A, B) with the GGX lobe's directional albedo F0 A + B, from the table.
vec2 environment_brdf(float n_v, float roughness) {
    int n = env_int(ENV_LUT), base = env_int(ENV_BRDF);
    vec2 p = clamp(vec2(n_v, roughness) * float(n) - 0.5, vec2(0.0), vec2(float(n - 1)));
    ivec2 i0 = ivec2(floor(p)), i1 = min(i0 + 1, ivec2(n - 1));
    vec2 f = p - vec2(i0);
    #define ENV_LUT_AT(a, b) vec2(env[base + 2 * ((a) * n + (b))], env[base + 2 * ((a) * n + (b)) + 1])
    vec2 x0 = mix(ENV_LUT_AT(i0.x, i0.y), ENV_LUT_AT(i0.x, i1.y), f.y);
    vec2 x1 = mix(ENV_LUT_AT(i1.x, i0.y), ENV_LUT_AT(i1.x, i1.y), f.y);
    #undef ENV_LUT_AT
    return mix(x0, x1, f.x);
}

#endif
