// The scene's instances as the raster and the G-buffer resolve read them (engine/passes/gbuffer.py packs them, in
// draw order: grouped by mesh). An instance's triangles are ids prefix .. prefix + its mesh's triangles (all its
// levels of detail) - 1 of the visibility buffer (+ 1; 0 is the background), so one uint32 names instance, level
// and triangle.
#ifndef INSTANCES_GLSL
#define INSTANCES_GLSL

struct Instance {
    mat4 model;        // object -> world, this frame
    mat4 prev_model;   // the previous frame's (motion vectors, temporal reprojection)
    vec4 nrm[3];       // columns of the inverse transpose of model's 3x3 (normals)
    vec4 prev_nrm[3];  // the same of prev_model
    uvec4 ids;         // x: prefix (first visibility id - 1), y: the mesh's first triangle in the index buffer,
                       // z: the instance's index in scene.instances, w: material override (0xFFFFFFFF: none)
    uvec4 flat_ids;    // x: the instance's first triangle in the scene's flat arrays, y: its first object id,
                       // z: its run (cull.comp's group: instances of one mesh, override and mirroring)
};

// Record k read through texel views of the instance buffer: `f` RGBA32F and `u` RGBA32UI over the same bytes,
// INSTANCE_TEXELS texels per record (CPU devices: llvmpipe loads a storage buffer's struct lane by lane, texels for
// 8 lanes at once). Fields a shader does not use are not fetched.
const int INSTANCE_IDS_TEXEL = 14;   // `ids` (x: the prefix that the resolve's search reads alone)

Instance instance_from_texels(samplerBuffer f, usamplerBuffer u, uint k) {
    int t = INSTANCE_TEXELS * int(k);
    Instance r;
    r.model = mat4(texelFetch(f, t), texelFetch(f, t + 1), texelFetch(f, t + 2), texelFetch(f, t + 3));
    r.prev_model = mat4(texelFetch(f, t + 4), texelFetch(f, t + 5), texelFetch(f, t + 6), texelFetch(f, t + 7));
    for (int c = 0; c < 3; c++) {
        r.nrm[c] = texelFetch(f, t + 8 + c);
        r.prev_nrm[c] = texelFetch(f, t + 11 + c);
    }
    r.ids = texelFetch(u, t + INSTANCE_IDS_TEXEL);
    r.flat_ids = texelFetch(u, t + INSTANCE_IDS_TEXEL + 1);
    return r;
}

#endif
