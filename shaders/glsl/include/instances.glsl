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

#endif
