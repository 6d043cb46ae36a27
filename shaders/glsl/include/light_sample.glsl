// Next-event estimation of the analytic lights from a surface point: a sample of each light (direction, distance,
// radiance, pdf) and the shadow ray that tests it. Needs common.glsl, sampling.glsl, rayutil.glsl and bvh.glsl.
#ifndef LIGHT_SAMPLE_GLSL
#define LIGHT_SAMPLE_GLSL

// ---- lights ---------------------------------------------------------------------------------------------------
// A spot light's falloff at cosine `c` to its axis: 1 inside the inner cone, 0 outside the outer one, smoothstep
// between (a hard edge where the cones are one: smoothstep's edges may not be equal).
float spot_falloff(Light l, float c) {
    float outer = l.color.w, inner = l.u.w;
    return inner > outer ? smoothstep(outer, inner, c) : (c >= outer ? 1.0 : 0.0);
}

// A sample of light `l` from p: direction wi, distance to the emitting point (or -1: at infinity), the radiance (for
// delta lights: the irradiance-like quantity that times f cos gives the reflected radiance), its solid-angle pdf
// (0: a delta light, no MIS). False where the light sends nothing towards p.
bool sample_light(Light l, vec3 p, vec2 xi, out vec3 wi, out float dist, out vec3 li, out float pdf) {
    int type = int(l.pos_type.w);
    vec3 power = PI * l.color.rgb;
    if (type == LIGHT_DIRECTIONAL) {
        vec3 axis = -l.dir_radius.xyz;
        float tan_a = l.u.w;
        dist = -1.0;
        if (tan_a > 0.0) {
            float cos_max = inversesqrt(1.0 + tan_a * tan_a);
            wi = sample_cone(axis, cos_max, xi);
            pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
            li = power / (PI * (1.0 - cos_max * cos_max));   // a disc of uniform radiance: irradiance E at normal
        } else {
            wi = axis;
            pdf = 0.0;
            li = power;
        }
        return true;
    }
    if (type == LIGHT_RECT) {
        vec3 q = l.pos_type.xyz + (xi.x - 0.5) * l.u.xyz + (xi.y - 0.5) * l.v.xyz;
        vec3 to = q - p;
        float d2 = dot(to, to);
        dist = sqrt(d2);
        wi = to / dist;
        float cos_l = dot(-wi, l.dir_radius.xyz);
        if (cos_l <= 0.0) return false;
        pdf = d2 / (length(cross(l.u.xyz, l.v.xyz)) * cos_l);
        li = power;
        return true;
    }
    vec3 c = l.pos_type.xyz;
    vec3 to = c - p;
    float d2 = dot(to, to);
    float r = l.dir_radius.w;
    vec3 axis = to * inversesqrt(d2);
    if (r > 0.0) {
        if (d2 <= r * r) return false;
        float cos_max = sqrt(max(0.0, 1.0 - r * r / d2));
        wi = sample_cone(axis, cos_max, xi);
        pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
        // the distance to the sphere's near side along wi
        float b = dot(to, wi);
        dist = b - sqrt(max(0.0, b * b - (d2 - r * r)));
        li = power / (PI * r * r);   // a sphere of intensity I has radiance I / (pi r^2)
    } else {
        wi = axis;
        dist = sqrt(d2);
        pdf = 0.0;
        li = power / d2;
    }
    if (type == LIGHT_SPOT) li *= spot_falloff(l, dot(-axis, l.dir_radius.xyz));
    return true;
}

bool visible(vec3 p, vec3 ng, vec3 wi, float dist, float scene_scale) {
    vec3 o = offset_ray(p, ng);
    float tmax = dist < 0.0 ? 4.0 * scene_scale : dist * (1.0 - 1e-4);
    return !bvh_occluded(o, wi, 0.0, tmax);
}

#endif
