/* The functions engine/native.c exports: the one list of their signatures. native.c includes this file, and
 * engine/_native_build.py hands it to cffi (the lines starting with '#' left out), which compiles both into the
 * extension module engine._native when the package is built; engine/native.py calls them through it.
 * Arrays are C-contiguous unless a row length (box_row, stride) says otherwise; what each function computes is
 * described at its definition in native.c. Only declarations cffi's parser reads: no macros, no attributes. */
#ifndef HYBRID_NATIVE_H
#define HYBRID_NATIVE_H
#include <stdint.h>

/* binning.grid_sah for k nodes on g^3 grids (g = 4 or 8). */
void hybrid_grid_sah(const int64_t *cnt, const float *box, int64_t box_row, int64_t k, int64_t g, const uint8_t *exact,
                     const int64_t *cap, int64_t *axis_out, int64_t *plane, uint8_t *found, float *child);

/* binning._octant_sah for k nodes on 2^3 grids. */
void hybrid_octant_sah(const int64_t *cnt, const float *box, int64_t box_row, int64_t k, const uint8_t *exact,
                       const int64_t *cap, const int64_t *cap2, int64_t max_leaf, const int64_t *split,
                       const int64_t *axis2, int64_t *axis_out, uint8_t *found, float *child, int64_t *axis2_out,
                       uint8_t *found2, float *grand);

/* hybrid_grow's inputs and outputs (grow._grow_from's pass loop): the shapes are those native.grow allocates. */
struct hybrid_grow_io {
    /* in: the triangles' boxes (6, stride) and centres (3, stride); n_tri, the size cap's bound */
    const float *box;
    const float *cen;
    int64_t stride;
    int64_t n_tri;
    /* in: the n active triangles (tid increasing, slot their node) and the k0 active nodes' count, depth and
     * binning domain dom0 (6, k0) */
    const int64_t *tid0;
    const int64_t *slot0;
    int64_t n;
    const int64_t *count0;
    const int64_t *depth0;
    const float *dom0;
    int64_t k0;
    /* in: the build's settings; split and axis2_table, octant_sah's tables; chunk > 0: stop at the chunk groups */
    int64_t max_leaf;
    int64_t max_depth;
    int64_t stat_boxes;
    const int64_t *split;
    const int64_t *axis2_table;
    int64_t chunk;
    int64_t threads;
    /* out: the records (rows_cap rows of 2 in rec_child and rec_rec; rec_rows, recs_cap records' row counts) */
    int64_t *rec_child;
    int64_t *rec_rec;
    int64_t rows_cap;
    int64_t *rec_rows;
    int64_t recs_cap;
    /* out: the leaves (leaves_cap of them; leaf_box 6 floats each) and their triangles in leaf order */
    int64_t *leaf_tid;
    int64_t *leaf_size;
    int64_t *leaf_depth;
    float *leaf_box;
    int64_t leaves_cap;
    /* out: the loop's state where it stopped at the chunk groups; made, 8 counts (see hybrid_grow) */
    int64_t *state_tid;
    int64_t *state_slot;
    int64_t *state_count;
    int64_t *state_depth;
    float *state_dom;
    int64_t *made;
};

/* grow._grow_from's pass loop from its first pass: 0, or why numpy's loop must run instead (1-4). */
int64_t hybrid_grow(const struct hybrid_grow_io *io);

/* pack.finish's packed nodes, root box and SAH terms: 0, or -1 for a reference out of range. */
int64_t hybrid_finish(const int64_t *child, const int64_t *rec, const int64_t *rows, int64_t n_rec,
                      const float *leaf_box, const int64_t *leaf_first, const int64_t *leaf_size, int64_t n_leaves,
                      int64_t widen, uint32_t *out, float *root_box, double *terms);

/* triangles.py's records of triangles faces[perm]: the number of zero-area ones, or -1 for an index out of range. */
int64_t hybrid_triangle_records(const float *vt, int64_t nv, const int64_t *faces, const int64_t *perm, int64_t n,
                                float *out);

/* order.ray_keys's keys in the high halves of `words`, the row numbers first + i in the low halves (origins
 * o_stride floats apart). */
void hybrid_ray_keys(const float *o, int64_t o_stride, int64_t n, const float *lo, const float *scale, const float *top,
                     const uint32_t *table, const uint32_t *offsets, const float *up, int64_t up_stride,
                     int64_t first, uint64_t *words);

/* The row numbers of sorted key words, in place. */
void hybrid_rows_of(uint64_t *words, int64_t n);

/* dst[i] = src[rows[i]] for rows of `size` bytes. */
void hybrid_gather_rows(const uint8_t *src, const int64_t *rows, int64_t n, int64_t size, uint8_t *dst);

/* The same for source rows `stride` bytes apart. */
void hybrid_gather_strided(const uint8_t *src, int64_t stride, const int64_t *rows, int64_t n, int64_t size,
                           uint8_t *dst);

/* out[rows[i]] = words[i] != 0. */
void hybrid_scatter_flags(const uint32_t *words, const int64_t *rows, int64_t n, uint8_t *out);

/* The nearest point of a BVH's triangles (bvh/layout.py's records) to each of n points (xyz, float64): its distance,
   the triangle's original index, and the barycentric weights of the triangle's vertices 1 and 2 there. */
void hybrid_closest_points(const float *nodes, const float *tris, const double *points, int64_t n, float *dist,
                           int32_t *prim, float *u, float *v);

/* The front ends' answers from the trace kernels' hit records (t, prim, u, v; n of them), written to row rows[i]
 * (rows NULL: row i) of each output given (NULL: not written); see hybrid_scene_hits in native.c. */
void hybrid_scene_hits(const float *rec, int64_t n, const int64_t *rows, const uint32_t *geometry,
                       const uint32_t *primitive, const float *normal, int64_t n_tri, const float *verts,
                       const int64_t *faces, const double *center, float *t_out, uint32_t *gid_out,
                       uint32_t *pid_out, int64_t *prim_out, float *uv_out, float *normal_out, float *point_out);

/* RayMeshIntersector's rays in its frame: float32 (o - center) * factor and d / |d| (computed in double) of n rays
 * of float32 (f32 != 0) or double rows `stride` elements apart; the first bad ray (not finite, zero length, beyond
 * bound in the frame), or -1. */
int64_t hybrid_frame_rays(const void *o, const void *d, int64_t n, int64_t stride, int64_t f32, const double *center,
                          double factor, double bound, float *o_out, float *d_out);

/* The first of n float32 points (rows `stride` floats apart) not finite or beyond +-bound, or -1. */
int64_t hybrid_first_bad_point(const float *p, int64_t n, int64_t stride, double bound);

/* One round of RaycastingScene's walk along its rays (raycasting.py _all_hits): the live rays' float32 origins
 * o + d * start and directions, from float64 rays `stride` doubles apart; see hybrid_walk_rays in native.c. */
void hybrid_walk_rays(const double *o, const double *d, int64_t stride, const int64_t *live, int64_t m,
                      const double *start, float *o_out, float *d_out);

/* The round's hits taken and the rays stepped past them; the hits found and the rays still going, counted in
 * counts[0], counts[1]. */
void hybrid_walk_hits(const float *rec, const int64_t *live, int64_t m, double *start, double *step,
                      const double *base, int64_t *last, int64_t *ray_out, int64_t *prim_out, double *t_out,
                      float *u_out, float *v_out, int64_t *live_out, int64_t *counts);

#endif
