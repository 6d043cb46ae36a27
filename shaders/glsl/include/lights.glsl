// Shadow-ray set-up per light: where a ray from surface point p goes to reach a point of the light.
// Needs common.glsl and sampling.glsl. `xi` picks the point on the light's area / solid angle;
// xi = vec2(-1) asks for the light's centre (hard shadows).
#ifndef LIGHTS_GLSL
#define LIGHTS_GLSL

// Returns the (unnormalized) direction d from p to the sampled light point and its tmax (the hit
// point of the light is p + d * tmax with tmax slightly below 1, or "infinity" for directional lights).
vec3 light_ray(Light l, vec3 p, vec2 xi, float scene_scale, out float tmax) {
    int type = int(l.pos_type.w);
    bool centre = xi.x < 0.0;
    if (type == LIGHT_DIRECTIONAL) {
        vec3 to_light = -l.dir_radius.xyz;
        float tan_a = l.u.w;
        if (!centre && tan_a > 0.0) {
            float cos_max = inversesqrt(1.0 + tan_a * tan_a);
            to_light = sample_cone(to_light, cos_max, xi);
        }
        tmax = 4.0 * scene_scale;     // the ray only has to leave the scene
        return to_light;
    }
    vec3 target = l.pos_type.xyz;
    if (!centre) {
        if (type == LIGHT_RECT) {
            target += (xi.x - 0.5) * l.u.xyz + (xi.y - 0.5) * l.v.xyz;
        } else if (l.dir_radius.w > 0.0) {
            // Sphere light: a disc of the sphere's radius facing p (its silhouette) is a close stand-in.
            vec3 n = normalize(p - target);
            target = sample_disc(target, n, l.dir_radius.w, xi);
        }
    }
    tmax = 1.0 - 1e-4;              // stop just short of the light point
    return target - p;
}

#endif
