/* Host steps in C: the cell statistics of the BVH build's passes (engine/bvh/binning.py), and the key of each ray
 * and the gathers and scatters of rows in the keys' order for ray reordering (engine/rt/order.py; the sort itself
 * stays numpy's, vectorized and in place). numpy's versions of these steps are the reference (the same cells,
 * boxes, keys and order, bit for bit); engine/native.py compiles this file with the system's C compiler on first use
 * and falls back to numpy where there is none. Plain C99, no Python headers: loaded with ctypes. */
#include <stdint.h>
#include <math.h>
#include <string.h>

/* The cells of a pass of the binned build: for every triangle t[i] (i where t is null) of slot s[i] that its node
 * samples ((t & mask[s]) == 0; mask < 0: the node is not binned), its cell along each axis as binning.cell_axis
 * computes it (c * inv + off in float32, clamped to [0, 2^30], truncated, at most gmax), stored in cells[a * n + i]
 * where cells is not null; its count added to count[key] and its box folded into cbox[r * n_cells + key] as
 * np.minimum.at does (a tie takes the new value: signed zeros as numpy's), key = cell_base[s] + ((x * g + y) * g
 * + z) * cell_step[s] (step 1 where cell_step is null), g = grid[s]. cen is (3, stride) and box (6, stride)
 * float32; inv, off are (3, k). Returns how many triangles had a NaN box value, a NaN cell coordinate or a key
 * outside [0, n_cells) (numpy's path then runs instead). */
int64_t hybrid_cell_stats(const float *cen, const float *box, int64_t stride, const int64_t *t, const int64_t *s,
                          int64_t n, const int64_t *mask, const float *inv, const float *off, int64_t k,
                          const int32_t *gmax, const int32_t *grid, const int64_t *cell_base,
                          const int64_t *cell_step, int32_t *cells, int64_t *count, float *cbox, int64_t n_cells)
{
    int64_t bad = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t ti = t ? t[i] : i, si = s[i];
        if (mask && (mask[si] < 0 || (ti & mask[si]) != 0))
            continue;
        int32_t c[3];
        int nan = 0;
        for (int a = 0; a < 3; ++a) {
            float v = cen[a * stride + ti] * inv[a * k + si];
            v = v + off[a * k + si];
            nan |= v != v;
            v = v > 0.0f ? v : 0.0f;
            v = v < 1073741824.0f ? v : 1073741824.0f;
            c[a] = (int32_t)v < gmax[si] ? (int32_t)v : gmax[si];
            if (cells)
                cells[a * n + i] = c[a];
        }
        const int64_t g = grid[si];
        const int64_t key = cell_base[si] + ((c[0] * g + c[1]) * g + c[2]) * (cell_step ? cell_step[si] : 1);
        if (nan || key < 0 || key >= n_cells) {
            ++bad;
            continue;
        }
        count[key] += 1;
        for (int r = 0; r < 6; ++r) {   /* (branch-free: a NaN box counts as bad, so ties alone need care) */
            const float v = box[r * stride + ti], m = cbox[r * n_cells + key];
            bad += v != v;
            cbox[r * n_cells + key] = m < v ? m : v;
        }
    }
    return bad;
}

/* np.minimum's choice (the second operand on ties, a NaN first operand kept), and binning.half_area, in float32
 * with numpy's order of operations. */
static float min_np(float a, float b) { return (a < b || a != a) ? a : b; }

static float half_area(const float *b)
{
    const float sx = b[0] + b[3], sy = b[1] + b[4], sz = b[2] + b[5];
    const float p = sx * sy, q = sx + sy;
    return p + sz * q;
}

static double cost_of(double area_l, int64_t n_l, double area_r, int64_t n_r, double tie)
{
    const double a = area_l * (double)n_l, b = area_r * (double)n_r;
    return (a + b) + tie * (double)(n_l > n_r ? n_l - n_r : n_r - n_l);
}

/* binning.grid_sah for k nodes on g^3 grids (g = 4 or 8), node by node, with its arithmetic, its order of
 * operations (the folds of _slabs, the prefix and suffix minima) and its tie rules: node-major cells, cnt[node * g^3
 * + cell] and box[r * box_row + node * g^3 + cell], cell = (x * g + y) * g + z. Outputs as grid_sah's: axis, plane,
 * found (k) and child (2, 6, k). */
void hybrid_grid_sah(const int64_t *cnt, const float *box, int64_t box_row, int64_t k, int64_t g, const uint8_t *exact,
                     const int64_t *cap, int64_t *axis_out, int64_t *plane, uint8_t *found, float *child)
{
    const int64_t g3 = g * g * g;
    for (int64_t j = 0; j < k; ++j) {
        int64_t c[512];
        float b[6][512];
        int64_t cxy[64], cyz[64], sn[3][8];
        float bxy[6][64], byz[6][64], sb[3][6][8];
        for (int64_t q = 0; q < g3; ++q) {
            c[q] = cnt[j * g3 + q];
            for (int r = 0; r < 6; ++r)
                b[r][q] = box[r * box_row + j * g3 + q];
        }
        /* xy: z folded; yz: x folded; then the x slabs fold y of xy, the y slabs x of xy, the z slabs y of yz */
        for (int u = 0; u < g; ++u)
            for (int v = 0; v < g; ++v) {
                cxy[u * g + v] = 0;
                cyz[u * g + v] = 0;
                for (int w = 0; w < g; ++w) {
                    cxy[u * g + v] += c[(u * g + v) * g + w];
                    cyz[u * g + v] += c[(w * g + u) * g + v];
                }
                for (int r = 0; r < 6; ++r) {
                    float a = min_np(b[r][(u * g + v) * g], b[r][(u * g + v) * g + 1]);
                    float z = min_np(b[r][u * g + v], b[r][(g + u) * g + v]);
                    for (int w = 2; w < g; ++w) {
                        a = min_np(a, b[r][(u * g + v) * g + w]);
                        z = min_np(z, b[r][(w * g + u) * g + v]);
                    }
                    bxy[r][u * g + v] = a;
                    byz[r][u * g + v] = z;
                }
            }
        for (int u = 0; u < g; ++u) {
            sn[0][u] = sn[1][u] = sn[2][u] = 0;
            for (int w = 0; w < g; ++w) {
                sn[0][u] += cxy[u * g + w];
                sn[1][u] += cxy[w * g + u];
                sn[2][u] += cyz[w * g + u];
            }
            for (int r = 0; r < 6; ++r) {
                float x = min_np(bxy[r][u * g], bxy[r][u * g + 1]);
                float y = min_np(bxy[r][u], bxy[r][g + u]);
                float z = min_np(byz[r][u], byz[r][g + u]);
                for (int w = 2; w < g; ++w) {
                    x = min_np(x, bxy[r][u * g + w]);
                    y = min_np(y, bxy[r][w * g + u]);
                    z = min_np(z, byz[r][w * g + u]);
                }
                sb[0][r][u] = x;
                sb[1][r][u] = y;
                sb[2][r][u] = z;
            }
        }
        /* per axis: prefix and suffix boxes, the costs of the g - 1 planes; argmin: the first minimum, a NaN first */
        float pre[3][8][6], suf[3][8][6];
        int best = -1;
        double best_cost = 0.0;
        for (int a = 0; a < 3; ++a) {
            for (int i = 0; i < g; ++i)
                for (int r = 0; r < 6; ++r)
                    pre[a][i][r] = suf[a][i][r] = sb[a][r][i];
            int64_t n_l[8];
            for (int i = 0; i < g - 1; ++i)
                n_l[i] = sn[a][i];
            for (int i = 1; i < g; ++i) {
                for (int r = 0; r < 6; ++r) {
                    pre[a][i][r] = min_np(pre[a][i][r], pre[a][i - 1][r]);
                    suf[a][g - 1 - i][r] = min_np(suf[a][g - 1 - i][r], suf[a][g - i][r]);
                }
                if (i < g - 1)
                    n_l[i] = n_l[i] + n_l[i - 1];
            }
            const int64_t total = n_l[g - 2] + sn[a][g - 1];
            const double tie = ((double)half_area(pre[a][g - 1]) + 1e-30) * 1e-6;
            for (int i = 0; i < g - 1; ++i) {
                const int64_t nr = total - n_l[i];
                double cst = cost_of((double)half_area(pre[a][i]), n_l[i], (double)half_area(suf[a][i + 1]), nr, tie);
                const int ok = n_l[i] > 0 && nr > 0 && (!exact[j] || (n_l[i] <= cap[j] && nr <= cap[j]));
                if (!ok)
                    cst = INFINITY;
                if (best < 0 || (best_cost == best_cost && (cst < best_cost || cst != cst))) {
                    best = a * (int)(g - 1) + i;
                    best_cost = cst;
                }
            }
        }
        const int a = best / (int)(g - 1), i = best % (int)(g - 1);
        axis_out[j] = a;
        plane[j] = i + 1;
        found[j] = isfinite(best_cost);
        for (int r = 0; r < 6; ++r) {
            child[r * k + j] = r < 3 ? pre[a][i][r] : -pre[a][i][r];
            child[(6 + r) * k + j] = r < 3 ? suf[a][i + 1][r] : -suf[a][i + 1][r];
        }
    }
}

/* binning._octant_sah for k nodes on 2^3 grids, node by node, with its arithmetic, its order of operations and
 * its tie rules: cnt (8, k), boxes box[r * box_row + cell * k + node]; split (3, 2, 2, 2) and axis2 (3, 2) are
 * _SPLIT_TABLE and _AXIS2_TABLE. Outputs as _octant_sah's: axis, found (k); child (2, 6, k); axis2_out, found2
 * (2, k); grand (2, 2, 6, k). */
void hybrid_octant_sah(const int64_t *cnt, const float *box, int64_t box_row, int64_t k, const uint8_t *exact,
                       const int64_t *cap, const int64_t *cap2, int64_t max_leaf, const int64_t *split,
                       const int64_t *axis2, int64_t *axis_out, uint8_t *found, float *child, int64_t *axis2_out,
                       uint8_t *found2, float *grand)
{
    for (int64_t j = 0; j < k; ++j) {
        float g[8][6], e[12][6], f[3][2][6];
        int64_t gc[8], ec[12], fc[3][2];
        for (int c = 0; c < 8; ++c) {
            gc[c] = cnt[c * k + j];
            for (int r = 0; r < 6; ++r)
                g[c][r] = box[r * box_row + c * k + j];
        }
        for (int q = 0; q < 4; ++q) {   /* edges along x by (y, z), along y by (x, z), along z by (x, y) */
            const int hi = q >> 1, lo = q & 1;
            const int cells[3][2] = {{q, 4 + q}, {hi * 4 + lo, hi * 4 + 2 + lo},
                                     {hi * 4 + lo * 2, hi * 4 + lo * 2 + 1}};
            for (int d = 0; d < 3; ++d) {
                ec[4 * d + q] = gc[cells[d][0]] + gc[cells[d][1]];
                for (int r = 0; r < 6; ++r)
                    e[4 * d + q][r] = min_np(g[cells[d][0]][r], g[cells[d][1]][r]);
            }
        }
        for (int sd = 0; sd < 2; ++sd) {   /* halves: x from the y-edges, y and z from the x-edges (_faces) */
            const int pairs[3][2] = {{4 + 2 * sd, 5 + 2 * sd}, {2 * sd, 2 * sd + 1}, {sd, 2 + sd}};
            for (int a = 0; a < 3; ++a) {
                fc[a][sd] = ec[pairs[a][0]] + ec[pairs[a][1]];
                for (int r = 0; r < 6; ++r)
                    f[a][sd][r] = min_np(e[pairs[a][0]][r], e[pairs[a][1]][r]);
            }
        }
        double ea[12];
        for (int q = 0; q < 12; ++q)
            ea[q] = (double)half_area(e[q]);
        float whole[6];
        for (int r = 0; r < 6; ++r)
            whole[r] = min_np(f[0][0][r], f[0][1][r]);
        const double tie = ((double)half_area(whole) + 1e-30) * 1e-6;

        /* first split: one of three planes (argmin: the first minimum, a NaN first) */
        int best = -1;
        double best_cost = 0.0;
        for (int a = 0; a < 3; ++a) {
            const int64_t nl = fc[a][0], nr = fc[a][1];
            double c = cost_of((double)half_area(f[a][0]), nl, (double)half_area(f[a][1]), nr, tie);
            const int ok = nl > 0 && nr > 0 && (!exact[j] || (nl <= cap[j] && nr <= cap[j]));
            if (!ok)
                c = INFINITY;
            if (best < 0 || (best_cost == best_cost && (c < best_cost || c != c))) {
                best = a;
                best_cost = c;
            }
        }
        axis_out[j] = best;
        found[j] = isfinite(best_cost);
        for (int sd = 0; sd < 2; ++sd)
            for (int r = 0; r < 6; ++r)
                child[(sd * 6 + r) * k + j] = r < 3 ? f[best][sd][r] : -f[best][sd][r];

        /* second split, per half of the chosen axis: one of the two other axes' planes */
        for (int sd = 0; sd < 2; ++sd) {
            double mine[2];
            int el[2], er[2];
            for (int ch = 0; ch < 2; ++ch) {
                el[ch] = (int)split[((best * 2 + sd) * 2 + ch) * 2];
                er[ch] = (int)split[((best * 2 + sd) * 2 + ch) * 2 + 1];
                const int64_t nl = ec[el[ch]], nr = ec[er[ch]];
                const int good = fc[best][sd] > max_leaf && nl > 0 && nr > 0 && nl <= cap2[j] && nr <= cap2[j];
                mine[ch] = good ? cost_of(ea[el[ch]], nl, ea[er[ch]], nr, tie) : INFINITY;
            }
            const int pick = mine[1] < mine[0];
            const double low = (mine[0] < mine[1] || mine[0] != mine[0]) ? mine[0] : mine[1];
            found2[sd * k + j] = isfinite(low) && exact[j] && found[j];
            axis2_out[sd * k + j] = axis2[best * 2 + pick];
            for (int t = 0; t < 2; ++t) {
                const float *eb = e[t ? er[pick] : el[pick]];
                for (int r = 0; r < 6; ++r)
                    grand[((sd * 2 + t) * 6 + r) * k + j] = r < 3 ? eb[r] : -eb[r];
            }
        }
    }
}

/* The triangle records of engine/bvh/triangles.py for rows [0, n): the corners of triangle faces[perm[i]] (faces
 * (T, 3), vertices vt (3, nv) float32) as 12 floats per row (v0, prim = perm[i], v1, 0, v2, 0), a zero-area
 * triangle (its edge cross product exactly zero in float64) collapsed onto v0. The zero-area test is
 * triangles._degenerate's: a float32 pass keeps as candidates the triangles whose cross product is tiny against
 * their edges (or NaN), and only those take the float64 test. Returns the number of zero-area triangles, or -1 for
 * a vertex index outside [0, nv). */
int64_t hybrid_triangle_records(const float *vt, int64_t nv, const int64_t *faces, const int64_t *perm, int64_t n,
                                float *out)
{
    int64_t degenerate = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t *f = faces + 3 * perm[i];
        if ((uint64_t)f[0] >= (uint64_t)nv || (uint64_t)f[1] >= (uint64_t)nv || (uint64_t)f[2] >= (uint64_t)nv)
            return -1;   /* (an index out of range: numpy's steps then report it) */
        float c[3][3];
        for (int k = 0; k < 3; ++k)
            for (int a = 0; a < 3; ++a)
                c[k][a] = vt[a * nv + f[k]];
        float e1[3], e2[3];
        for (int a = 0; a < 3; ++a) {
            e1[a] = c[1][a] - c[0][a];
            e2[a] = c[2][a] - c[0][a];
        }
        int nan = 0, big = 0;
        float size = fabsf(e1[0]) > fabsf(e1[1]) ? fabsf(e1[0]) : fabsf(e1[1]);
        size = size > fabsf(e1[2]) ? size : fabsf(e1[2]);
        float size2 = fabsf(e2[0]) > fabsf(e2[1]) ? fabsf(e2[0]) : fabsf(e2[1]);
        size2 = size2 > fabsf(e2[2]) ? size2 : fabsf(e2[2]);
        nan |= (e1[0] != e1[0]) | (e1[1] != e1[1]) | (e1[2] != e1[2]) | (e2[0] != e2[0]) | (e2[1] != e2[1])
               | (e2[2] != e2[2]);
        size = size * size2;
        size = size * 1e-3f;
        static const int I[3] = {1, 2, 0}, J[3] = {2, 0, 1};
        for (int q = 0; q < 3; ++q) {
            float comp = e1[I[q]] * e2[J[q]];
            comp = comp - e1[J[q]] * e2[I[q]];
            nan |= comp != comp;
            big |= fabsf(comp) > size;
        }
        int zero = 0;
        if (nan || !big) {   /* (a candidate: the exact test decides) */
            double g1[3], g2[3];
            for (int a = 0; a < 3; ++a) {
                g1[a] = (double)c[1][a] - (double)c[0][a];
                g2[a] = (double)c[2][a] - (double)c[0][a];
            }
            zero = g1[1] * g2[2] == g1[2] * g2[1] && g1[2] * g2[0] == g1[0] * g2[2] && g1[0] * g2[1] == g1[1] * g2[0];
        }
        float *row = out + 12 * i;
        for (int k = 0; k < 3; ++k)
            for (int a = 0; a < 3; ++a)
                row[4 * k + a] = c[zero ? 0 : k][a];
        const int32_t prim = (int32_t)perm[i];
        memcpy(row + 3, &prim, 4);
        row[7] = 0.0f;
        row[11] = 0.0f;
        degenerate += zero;
    }
    return degenerate;
}

/* Keys as order.ray_keys computes them, into the high halves of `words` (row numbers first + i in the low
 * halves): per coordinate a = (o - lo) * scale, clamped to [0, top], truncated, its bits looked up in `table` at
 * offsets[axis]; then, unless `up` is null, bit 0 set where up[i * up_stride] > 0 (the direction's y). */
#if defined(__GNUC__) && defined(__x86_64__) && defined(__GLIBC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))   /* (AVX2's gathers vectorize the table lookups) */
#endif
void hybrid_ray_keys(const float *o, int64_t n, const float *lo, const float *scale, const float *top,
                     const uint32_t *table, const uint32_t *offsets, const float *up, int64_t up_stride,
                     int64_t first, uint64_t *words)
{
    for (int64_t i = 0; i < n; ++i) {
        uint32_t key = 0;
        for (int a = 0; a < 3; ++a) {
            float q = o[3 * i + a] - lo[a];
            q = q * scale[a];
            q = q > 0.0f ? q : 0.0f;   /* (NaN -> 0, as numpy's maximum then minimum would not promise) */
            q = q < top[a] ? q : top[a];
            key |= table[offsets[a] + (uint32_t)q];
        }
        if (up && up[i * up_stride] > 0.0f)
            key |= 1u;
        words[i] = ((uint64_t)key << 32) | (uint64_t)(first + i);
    }
}

/* The row numbers of key words sorted by numpy (the low halves), in place, as int64. */
void hybrid_rows_of(uint64_t *words, int64_t n)
{
    for (int64_t i = 0; i < n; ++i)
        words[i] &= 0xFFFFFFFFu;
}

/* dst[i] = src[rows[i]] for rows of `size` bytes (12: a float32 xyz), the source rows prefetched ahead. */
void hybrid_gather_rows(const uint8_t *src, const int64_t *rows, int64_t n, int64_t size, uint8_t *dst)
{
    const int64_t ahead = 64;   /* (rows this far ahead: a random row is a miss to memory) */
    if (size == 12) {   /* (a constant size: an inlined copy) */
        for (int64_t i = 0; i < n; ++i) {
            if (i + ahead < n)
                __builtin_prefetch(src + rows[i + ahead] * 12);
            memcpy(dst + i * 12, src + rows[i] * 12, 12);
        }
        return;
    }
    for (int64_t i = 0; i < n; ++i) {
        if (i + ahead < n)
            __builtin_prefetch(src + rows[i + ahead] * size);
        memcpy(dst + i * size, src + rows[i] * size, (size_t)size);
    }
}

/* out[rows[i]] = words[i] != 0 (occlusion results back into the caller's order). */
void hybrid_scatter_flags(const uint32_t *words, const int64_t *rows, int64_t n, uint8_t *out)
{
    for (int64_t i = 0; i < n; ++i)
        out[rows[i]] = words[i] != 0;
}
