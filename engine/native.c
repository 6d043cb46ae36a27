/* Host steps in C: the pass loop of the BVH build (engine/bvh/grow.py) with its SAH (binning.py), its node packing
 * (pack.py) and its triangle records (triangles.py); the key of each ray and the gathers and scatters of rows in the
 * keys' order for ray reordering (engine/rt/order.py; the sort itself stays numpy's, vectorized and in place).
 * numpy's versions of these steps are the reference (the same records, leaves, nodes, keys and order, bit for
 * bit). native.h declares the exported functions; engine/_native_build.py compiles this file into the extension
 * module engine._native when the package is built, and engine/native.py calls it (numpy's steps where the package
 * was installed without it). Plain C99 and pthreads, no Python headers (cffi's generated wrapper has those). */
#include "native.h"

#include <pthread.h>
#include <stdint.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

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

/* ceil(log2(n)) for n >= 1: the bit length of n - 1 (binning.ceil_log2). */
static int64_t ceil_log2_of(int64_t n)
{
    int64_t b = 0;
    for (uint64_t x = (uint64_t)(n - 1); x; x >>= 1)
        ++b;
    return b;
}

/* A node's cell along axis a of its grid, as binning.cell_axis: c * inv + off in float32, clamped to [0, 2^30],
 * truncated, at most gmax; -1 for a NaN (numpy's loop then runs). */
static int32_t cell_of(float c, float inv, float off, int32_t gmax)
{
    float v = c * inv;
    v = v + off;
    if (v != v)
        return -1;
    v = v > 0.0f ? v : 0.0f;
    v = v < 1073741824.0f ? v : 1073741824.0f;
    return (int32_t)v < gmax ? (int32_t)v : gmax;
}

/* A triangle as the passes of hybrid_grow move it: its centre, its box (six-row form) and its index. */
struct tri_row {
    float c[3], b[6];
    int32_t id;
};

/* The count and box (six rows of g^3, +inf where empty) of every cell of one node's grid, from its triangles
 * rows[0, m) (increasing) that it samples ((id & mask) == 0), folded in that order as np.minimum.at does (a tie
 * takes the new value: signed zeros as numpy's; the boxes hold no NaN). Returns nonzero where a cell was NaN. */
static int node_cells(const struct tri_row *rows, int64_t m, int64_t mask, const float *inv, const float *off,
                      int64_t k, int32_t gmax, int64_t g, int64_t *cnt, float *cbox)
{
    const int64_t g3 = g * g * g;
    memset(cnt, 0, sizeof(int64_t) * g3);
    for (int64_t q = 0; q < 6 * g3; ++q)
        cbox[q] = INFINITY;
    for (int64_t i = 0; i < m; ++i) {
        const struct tri_row *t = rows + i;
        if (t->id & mask)
            continue;
        const int32_t x = cell_of(t->c[0], inv[0], off[0], gmax);
        const int32_t y = cell_of(t->c[1], inv[k], off[k], gmax);
        const int32_t z = cell_of(t->c[2], inv[2 * k], off[2 * k], gmax);
        if ((x | y | z) < 0)
            return 1;
        const int64_t key = (x * g + y) * g + z;
        ++cnt[key];
        for (int r = 0; r < 6; ++r) {
            const float v = t->b[r], c = cbox[r * g3 + key];
            cbox[r * g3 + key] = c < v ? c : v;
        }
    }
    return 0;
}

/* Passes of fewer active triangles than this run on one thread (a thread's start costs more than they gain). */
#define PASS_THREAD_MIN 8192

/* One pass's state and outputs, per node (see hybrid_grow): what its nodes read and write. */
struct pass {
    const struct tri_row *idx;
    struct tri_row *tmp;
    uint8_t *part;
    const int64_t *beg, *count, *rate, *cap, *cap2;
    const int32_t *gmax, *grid;
    const float *inv, *off;
    const uint8_t *exact;
    int64_t K, max_leaf;
    int all_exact, any_exact;
    const int64_t *split, *axis2_table;
    int64_t *axis, *plane, *axis2, *ocount, *obeg;
    uint8_t *found, *found2, *median;
    float *child_dom, *grand_dom;
};

/* Nodes [k0, k1) of a pass: each one's cells, its SAH (2^3 grids also choose their children's splits) and the
 * stable partition of its range into tmp. Returns 0, or 1 where a cell was NaN. */
static int64_t pass_range(const struct pass *P, int64_t k0, int64_t k1)
{
    const int64_t K = P->K, K2 = 2 * K, max_leaf = P->max_leaf;
    const int all_exact = P->all_exact, any_exact = P->any_exact;
    const int64_t *beg = P->beg, *count = P->count, *cap = P->cap;
    const int32_t *gmax = P->gmax;
    const float *inv = P->inv, *off = P->off;
    const uint8_t *exact = P->exact;
    int64_t *axis = P->axis, *plane = P->plane, *axis2 = P->axis2, *ocount = P->ocount, *obeg = P->obeg;
    uint8_t *found = P->found, *found2 = P->found2, *median = P->median;
    int64_t lc[512], a_out[3];
    float lb[6 * 512];
    for (int64_t k = k0; k < k1; ++k) {
        const int64_t b = beg[k], m = count[k], g = P->grid[k];
        const int64_t mask = ((int64_t)1 << P->rate[k]) - 1;
        if (node_cells(P->idx + b, m, mask, inv + k, off + k, K, gmax[k], g, lc, lb))
            return 1;
        float cb[12], gb[24];
        uint8_t fo[3];
        if (g == 2) {
            hybrid_octant_sah(lc, lb, 8, 1, exact + k, cap + k, P->cap2 + k, max_leaf, P->split, P->axis2_table,
                              a_out, fo, cb, a_out + 1, fo + 1, gb);
            plane[k] = 1;
            axis2[k] = a_out[1];
            axis2[K + k] = a_out[2];
            found2[k] = fo[1] && all_exact;
            found2[K + k] = fo[2] && all_exact;
        } else {
            hybrid_grid_sah(lc, lb, g * g * g, 1, g, exact + k, cap + k, a_out, a_out + 1, fo, cb);
            plane[k] = a_out[1];
            axis2[k] = axis2[K + k] = 0;
            found2[k] = found2[K + k] = 0;
        }
        axis[k] = a_out[0];
        found[k] = fo[0];
        for (int q = 0; q < 12; ++q)
            P->child_dom[q * K + k] = cb[q];
        if (g == 2)
            for (int q = 0; q < 24; ++q)
                P->grand_dom[q * K + k] = gb[q];
        /* nodes whose counts are estimates and could break the depth cap are split at the median */
        median[k] = !found[k] || (!exact[k] && count[k] > cap[k]);
        if (median[k])
            found2[k] = found2[K + k] = 0;

        /* every triangle goes left or right (the same arithmetic as its cell), and on into a grandchild: part 0 /
         * 1 the children, 2 + 2 side + cell the grandchildren */
        const int64_t a = axis[k];
        const float iv = inv[a * K + k], of = off[a * K + k];
        const double sp = ((double)plane[k] - (double)of) / (double)(iv > 0 ? iv : 1.0f);
        uint8_t *part = P->part + b;
        int64_t pc[6] = {0, 0, 0, 0, 0, 0};
        for (int64_t i = 0; i < m; ++i) {
            const struct tri_row *t = P->idx + b + i;
            const float c = t->c[a];
            int right;
            if (!any_exact) {
                right = (double)c >= sp;
            } else {
                const int32_t x = cell_of(c, iv, of, gmax[k]);
                if (x < 0)
                    return 1;
                right = x >= plane[k];
            }
            if (median[k])
                right = i >= m / 2;
            int p = right;
            if (found2[right * K + k]) {
                const int64_t a2 = axis2[right * K + k];
                p = 2 + 2 * right + cell_of(t->c[a2], inv[a2 * K + k], off[a2 * K + k], gmax[k]);
            }
            part[i] = (uint8_t)p;
            ++pc[p];
        }
        /* the stable partition of the range: side 0 (or its two grandchildren), then side 1 */
        static const int ORDER[6] = {0, 2, 3, 1, 4, 5};
        int64_t at[6];
        int64_t pos = b;
        for (int q = 0; q < 6; ++q) {
            const int p = ORDER[q];
            const int64_t o = p < 2 ? 2 * k + p : K2 + 4 * k + (p - 2);
            at[p] = pos;
            obeg[o] = pos;
            ocount[o] = pc[p];
            pos += pc[p];
        }
        for (int64_t i = 0; i < m; ++i)
            P->tmp[at[part[i]]++] = P->idx[b + i];
    }
    return 0;
}

struct pass_part {
    const struct pass *p;
    int64_t k0, k1, rc;
};

static void *pass_thread(void *arg)
{
    struct pass_part *q = arg;
    q->rc = pass_range(q->p, q->k0, q->k1);
    return NULL;
}

/* A pass's nodes on up to `threads` threads, in parts of about equal triangle counts (the nodes are independent:
 * each writes its own outputs and its own range). Small passes stay on this thread. */
static int64_t pass_nodes(const struct pass *P, int64_t threads, int64_t active)
{
    enum { MAX_THREADS = 64 };
    const int64_t K = P->K;
    int64_t t = threads < MAX_THREADS ? threads : MAX_THREADS;
    if (t > K)
        t = K;
    if (t <= 1 || active < PASS_THREAD_MIN)
        return pass_range(P, 0, K);
    struct pass_part parts[MAX_THREADS];
    pthread_t ids[MAX_THREADS];
    int started[MAX_THREADS] = {0};
    int64_t k = 0, seen = 0;
    for (int64_t j = 0; j < t; ++j) {   /* part j ends where the running count passes (j + 1) / t of the total */
        parts[j].p = P;
        parts[j].k0 = k;
        while (k < K && (j == t - 1 || seen + P->count[k] <= active * (j + 1) / t || k == parts[j].k0))
            seen += P->count[k++];
        parts[j].k1 = k;
        parts[j].rc = 0;
    }
    for (int64_t j = 1; j < t; ++j)
        started[j] = pthread_create(&ids[j], NULL, pass_thread, &parts[j]) == 0;
    int64_t rc = pass_range(P, parts[0].k0, parts[0].k1);
    for (int64_t j = 1; j < t; ++j) {
        if (started[j])
            pthread_join(ids[j], NULL);
        else   /* (no thread to be had: this one) */
            parts[j].rc = pass_range(P, parts[j].k0, parts[j].k1);
        rc = rc ? rc : parts[j].rc;
    }
    return rc;
}

/* The state of the pass loop in grow._grow_from's terms: the active triangles in increasing order with their
 * node, and the nodes' count, depth and domain (6, K). Returns 3 where memory ran out. */
static int64_t hand_back(const struct tri_row *rows, const int64_t *beg, const int64_t *count, const int64_t *depth,
                         const float *dom, int64_t K, int64_t stride, int64_t *tid, int64_t *slot, int64_t *count_out,
                         int64_t *depth_out, float *dom_out)
{
    int32_t *node_of = malloc(sizeof(int32_t) * (stride + 1));
    if (!node_of)
        return 3;
    for (int64_t t = 0; t < stride; ++t)
        node_of[t] = -1;
    for (int64_t k = 0; k < K; ++k)
        for (int64_t i = beg[k]; i < beg[k] + count[k]; ++i)
            node_of[rows[i].id] = (int32_t)k;
    int64_t n = 0;
    for (int64_t t = 0; t < stride; ++t)
        if (node_of[t] >= 0) {
            tid[n] = t;
            slot[n++] = node_of[t];
        }
    free(node_of);
    memcpy(count_out, count, sizeof(int64_t) * K);
    memcpy(depth_out, depth, sizeof(int64_t) * K);
    memcpy(dom_out, dom, sizeof(float) * 6 * K);
    return 0;
}

/* The pass loop of grow._grow_from from its first pass, with its arithmetic, its order and its tie rules, so that
 * its records and leaves are numpy's, number for number. Where numpy bins every node of a pass into one array of
 * cells, this keeps each node's triangles together (a stable partition of the node's range: in increasing order,
 * the order of numpy's folds) and bins them node by node on a grid that stays in the L1 cache.
 * In (io's fields, native.h): the triangles' boxes (6, stride) and centres (3, stride) float32; the n active
 * triangles tid (increasing) and slot; k0 active nodes' count, depth and binning domain dom0 (6, k0) float32; n_tri,
 * the size cap's bound (grow's box.shape[1]); split and axis2_table, octant_sah's tables; chunk: where > 0, the loop
 * stops once the active triangles are more than chunk and every node holds at most chunk (grow's chunk groups
 * follow); threads: how many threads a pass's nodes use (pass_nodes; the same results for any number).
 * Out: record r has rec_rows[r] rows of rec_child and rec_rec (rows of 2); leaf l has leaf_size[l], leaf_depth[l],
 * a box leaf_box[6 l .. 6 l + 5] (six-row form) and its triangles next in leaf_tid (in leaf order); made =
 * (records, rows, leaves, triangles, K, then the last pass's next record, its record and whether it made
 * intermediate nodes) where the loop stopped with K nodes left, their state in state_* (see hand_back), else K =
 * -1. Returns 0, or 1 where a cell was not computable (a NaN), 2 where an output is full, 3 where memory ran out,
 * 4 where a node reached max_depth or a count disagreed with the slots (numpy's loop then runs instead, and says
 * so). */
int64_t hybrid_grow(const struct hybrid_grow_io *io)
{
    /* (the arguments under the names the loop uses) */
    const float *box = io->box, *cen = io->cen, *dom0 = io->dom0;
    const int64_t stride = io->stride, n_tri = io->n_tri, n = io->n, k0 = io->k0;
    const int64_t *tid0 = io->tid0, *slot0 = io->slot0, *count0 = io->count0, *depth0 = io->depth0;
    const int64_t max_leaf = io->max_leaf, max_depth = io->max_depth, stat_boxes = io->stat_boxes;
    const int64_t *split = io->split, *axis2_table = io->axis2_table;
    const int64_t chunk = io->chunk, threads = io->threads;
    int64_t *rec_child = io->rec_child, *rec_rec = io->rec_rec, *rec_rows = io->rec_rows;
    const int64_t rows_cap = io->rows_cap, recs_cap = io->recs_cap, leaves_cap = io->leaves_cap;
    int64_t *leaf_tid = io->leaf_tid, *leaf_size = io->leaf_size, *leaf_depth = io->leaf_depth;
    float *leaf_box = io->leaf_box;
    int64_t *state_tid = io->state_tid, *state_slot = io->state_slot, *state_count = io->state_count;
    int64_t *state_depth = io->state_depth, *made = io->made;
    float *state_dom = io->state_dom;
    int64_t rc = 0, n_rec = 0, n_rows = 0, n_leaves = 0, n_tids = 0, K = k0, last_here = 0, last_mid = 0;
    made[4] = -1;
    struct tri_row *idx = malloc(sizeof(struct tri_row) * (n + 1)), *tmp = malloc(sizeof(struct tri_row) * (n + 1));
    uint8_t *part = malloc(n + 1);
    int64_t *count = malloc(sizeof(int64_t) * (K + 1)), *depth = malloc(sizeof(int64_t) * (K + 1));
    int64_t *beg = calloc((size_t)K + 1, sizeof(int64_t));
    float *dom = malloc(sizeof(float) * (6 * K + 1));
    if (!idx || !tmp || !part || !count || !depth || !beg || !dom) {
        rc = 3;
        goto out;
    }
    memcpy(count, count0, sizeof(int64_t) * K);
    memcpy(depth, depth0, sizeof(int64_t) * K);
    memcpy(dom, dom0, sizeof(float) * 6 * K);
    /* each node's triangles together, in increasing order (a stable counting sort by slot) */
    for (int64_t i = 0; i < n; ++i)
        ++beg[slot0[i] + 1];
    for (int64_t k = 0; k < K; ++k) {
        if (beg[k + 1] != count[k]) {
            rc = 4;
            goto out;
        }
        beg[k + 1] += beg[k];
    }
    int nan = 0;   /* (a NaN box: numpy's loop, whose minima keep it) */
    for (int64_t i = 0; i < n; ++i) {
        struct tri_row *t = idx + beg[slot0[i]]++;
        t->id = (int32_t)tid0[i];
        for (int a = 0; a < 3; ++a)
            t->c[a] = cen[a * stride + tid0[i]];
        for (int r = 0; r < 6; ++r) {
            t->b[r] = box[r * stride + tid0[i]];
            nan |= t->b[r] != t->b[r];
        }
    }
    if (nan) {
        rc = 1;
        goto out;
    }
    for (int64_t k = K; k > 0; --k)
        beg[k] = beg[k - 1];
    beg[0] = 0;

    while (K > 0 && rc == 0) {
        /* once every node fits a chunk (and a pass has pointed its new nodes at a record): handed back */
        int64_t active = 0, biggest = 0;
        for (int64_t k = 0; k < K; ++k) {
            active += count[k];
            biggest = count[k] > biggest ? count[k] : biggest;
        }
        if (chunk > 0 && n_rec && active > chunk && biggest <= chunk) {
            rc = hand_back(idx, beg, count, depth, dom, K, stride, state_tid, state_slot, state_count, state_depth,
                           state_dom);
            made[4] = K;
            made[5] = n_rec;
            made[6] = last_here;
            made[7] = last_mid;
            break;
        }
        /* per node (K) and per outcome (6K: children 2k + side, then grandchildren 2K + 2 child + side) */
        const int64_t K2 = 2 * K, K6 = 6 * K;
        int64_t *cap = malloc(sizeof(int64_t) * (7 * K + 5 * K6 + 8));
        float *fl = malloc(sizeof(float) * (6 * K + 12 * K + 24 * K + 6 * K6 + 8));
        int32_t *i32 = malloc(sizeof(int32_t) * (2 * K + 8));
        uint8_t *u8 = malloc(5 * K + 3 * K6 + 8);
        if (!cap || !fl || !i32 || !u8) {
            rc = 3;
            goto pass_end;
        }
        int64_t *cap2 = cap + K, *rate = cap + 2 * K, *axis = cap + 3 * K, *plane = cap + 4 * K;
        int64_t *axis2 = cap + 5 * K;
        int64_t *ocount = cap + 7 * K, *out_index = ocount + K6, *out_rec = ocount + 2 * K6;
        int64_t *out_depth = ocount + 3 * K6, *obeg = ocount + 4 * K6;
        float *inv = fl, *off = fl + 3 * K, *child_dom = fl + 6 * K, *grand_dom = fl + 18 * K, *odom = fl + 42 * K;
        int32_t *gmax = i32, *grid = i32 + K;
        uint8_t *exact = u8, *found = u8 + K, *found2 = u8 + 2 * K, *median = u8 + 4 * K;
        uint8_t *used = u8 + 5 * K, *inner = used + K6, *is_leaf = used + 2 * K6;

        int64_t dmax = -1;
        for (int64_t k = 0; k < K; ++k)
            dmax = depth[k] > dmax ? depth[k] : dmax;
        if (dmax >= max_depth) {
            rc = 4;
            goto pass_end;
        }
        /* caps, grids, sampling, the cells' scale and offset */
        int64_t sampled = 0;
        for (int64_t k = 0; k < K; ++k) {
            const int64_t room = max_depth - depth[k] - 1 < 40 ? max_depth - depth[k] - 1 : 40;
            const int64_t r1 = room - 1 > 0 ? room - 1 : 0;
            cap[k] = (max_leaf << room) < n_tri ? (max_leaf << room) : n_tri;
            cap2[k] = room >= 1 ? ((max_leaf << r1) < n_tri ? (max_leaf << r1) : n_tri) : 0;
            grid[k] = count[k] <= 64 ? 2 : count[k] <= 2048 ? 4 : 8;
            const int64_t r = ceil_log2_of(count[k]) - ceil_log2_of(grid[k] == 8 ? 4096 : 128);
            rate[k] = grid[k] == 2 ? 0 : (r > 0 ? r : 0);
            if (rate[k] > 0)
                sampled += count[k];
        }
        int all_exact = 1, any_exact = 0;
        for (int64_t k = 0; k < K; ++k) {
            if (sampled * 4 < active)
                rate[k] = 0;
            exact[k] = rate[k] == 0;
            all_exact &= exact[k];
            any_exact |= exact[k];
            gmax[k] = grid[k] - 1;
            for (int a = 0; a < 3; ++a) {
                const float ext = dom[(3 + a) * K + k] - dom[a * K + k];
                inv[a * K + k] = ext > 0 ? (float)((double)grid[k] / (double)ext) : 0.0f;
                const float neg = -dom[a * K + k];
                off[a * K + k] = neg * inv[a * K + k];
            }
        }
        /* node by node: its cells, its SAH, its partition; the nodes in parts on `threads` threads */
        memset(ocount, 0, sizeof(int64_t) * K6);
        memset(grand_dom, 0, sizeof(float) * 24 * K);
        struct pass p = {idx, tmp, part, beg, count, rate, cap, cap2, gmax, grid, inv, off, exact, K, max_leaf,
                         all_exact, any_exact, split, axis2_table, axis, plane, axis2, ocount, obeg, found, found2,
                         median, child_dom, grand_dom};
        if ((rc = pass_nodes(&p, threads, active)))
            goto pass_end;
        {   /* (the partitioned ranges are in tmp: the buffers swap) */
            struct tri_row *was = idx;
            idx = tmp;
            tmp = was;
        }
        /* outcomes: intermediate nodes (children split here), new active nodes, leaves */
        int64_t n_inner = 0, n_leaf = 0, n_mid = 0;
        for (int64_t o = 0; o < K6; ++o) {
            used[o] = o < K2 ? !found2[(o & 1) * K + (o >> 1)] : found2[(((o - K2) >> 1) & 1) * K + ((o - K2) >> 2)];
            inner[o] = used[o] && ocount[o] > max_leaf;
            is_leaf[o] = used[o] && !inner[o];
            out_index[o] = inner[o] ? n_inner++ : is_leaf[o] ? n_leaves + n_leaf++ : o < K2 ? n_mid++ : -1;
            out_depth[o] = o < K2 ? depth[o >> 1] + 1 : depth[(o - K2) >> 2] + 2;
        }
        const int64_t rec_here = n_rec, rec_mid = rec_here + 1, rec_next = rec_here + (n_mid ? 2 : 1);
        last_here = rec_here;
        last_mid = n_mid > 0;
        for (int64_t o = 0; o < K6; ++o)
            out_rec[o] = inner[o] ? rec_next : (o < K2 && !used[o]) ? rec_mid : -1;
        if (n_rec + 2 > recs_cap || n_rows + K + n_mid > rows_cap || n_leaves + n_leaf > leaves_cap) {
            rc = 2;
            goto pass_end;
        }
        for (int64_t o = 0; o < K2; ++o) {   /* the records: this pass's nodes, then its intermediate ones */
            rec_child[2 * n_rows + o] = out_index[o];
            rec_rec[2 * n_rows + o] = out_rec[o];
        }
        n_rows += K;
        rec_rows[n_rec++] = K;
        if (n_mid) {
            for (int64_t c = 0; c < K2; ++c) {
                if (used[c])
                    continue;
                for (int t = 0; t < 2; ++t) {
                    const int64_t o = K2 + 2 * c + t;
                    rec_child[2 * n_rows + t] = out_index[o];
                    rec_rec[2 * n_rows + t] = out_rec[o];
                }
                ++n_rows;
            }
            rec_rows[n_rec++] = n_mid;
        }
        /* the outcomes' domains: children of median splits keep the parent's */
        for (int64_t o = 0; o < K6; ++o)
            for (int r = 0; r < 6; ++r) {
                float v;
                if (o < K2) {
                    const int64_t k = o >> 1;
                    v = median[k] ? dom[r * K + k] : child_dom[((o & 1) * 6 + r) * K + k];
                } else {
                    const int64_t q = o - K2, k = q >> 2;
                    v = grand_dom[((((q >> 1) & 1) * 2 + (q & 1)) * 6 + r) * K + k];
                }
                odom[r * K6 + o] = v;
            }
        /* this pass's leaves, in id order: boxes from the statistics where exact, else their triangles' union */
        for (int64_t o = 0; o < K6; ++o) {
            if (!is_leaf[o])
                continue;
            const int64_t l = out_index[o], b = obeg[o], m = ocount[o];
            const int known = stat_boxes && (o < K2 ? exact[o >> 1] && !median[o >> 1] : 1);
            leaf_size[l] = m;
            leaf_depth[l] = out_depth[o];
            for (int64_t i = 0; i < m; ++i)
                leaf_tid[n_tids + i] = idx[b + i].id;
            n_tids += m;
            float *lbx = leaf_box + 6 * l;
            for (int r = 0; r < 6; ++r)
                lbx[r] = !known ? INFINITY : r < 3 ? odom[r * K6 + o] : -odom[r * K6 + o];
            if (!known)
                for (int64_t i = 0; i < m; ++i)
                    for (int r = 0; r < 6; ++r)
                        lbx[r] = min_np(lbx[r], idx[b + i].b[r]);
        }
        n_leaves += n_leaf;
        /* the next pass's nodes (up to four per node) */
        int64_t *nc = realloc(count, sizeof(int64_t) * (n_inner + 1));
        count = nc ? nc : count;
        int64_t *nd = nc ? realloc(depth, sizeof(int64_t) * (n_inner + 1)) : NULL;
        depth = nd ? nd : depth;
        int64_t *nb = nd ? realloc(beg, sizeof(int64_t) * (n_inner + 1)) : NULL;
        beg = nb ? nb : beg;
        float *nm = nb ? realloc(dom, sizeof(float) * (6 * n_inner + 1)) : NULL;
        dom = nm ? nm : dom;
        if (!nm) {
            rc = 3;
            goto pass_end;
        }
        int64_t j = 0;
        for (int64_t o = 0; o < K6; ++o)
            if (inner[o]) {
                count[j] = ocount[o];
                depth[j] = out_depth[o];
                beg[j] = obeg[o];
                for (int r = 0; r < 6; ++r)
                    dom[r * n_inner + j] = odom[r * K6 + o];
                ++j;
            }
        K = n_inner;
    pass_end:
        free(cap);
        free(fl);
        free(i32);
        free(u8);
    }
out:
    made[0] = n_rec;
    made[1] = n_rows;
    made[2] = n_leaves;
    made[3] = n_tids;
    free(idx);
    free(tmp);
    free(part);
    free(count);
    free(depth);
    free(beg);
    free(dom);
    return rc;
}

/* pack._step_down: the float32 next to x towards -inf, on the bits (inf and NaN as they are). */
static float step_down(float x)
{
    int32_t u;
    memcpy(&u, &x, 4);
    if ((u & 0x7F800000) != 0x7F800000)
        u = u > 0 ? u - 1 : u == 0 ? INT32_MIN + 1 : u + 1;
    memcpy(&x, &u, 4);
    return x;
}

/* pack.finish for n_rec records (rows[r] rows each; child and rec (N, 2) all records' rows in order, N the node
 * count): the nodes in depth-first order, packed as NODE_DTYPE's 16 words each into out (widened by step_down
 * where `widen`), the root's box (six-row form) into root_box, and each child slot's SAH term (its box's half area
 * times its triangles, 1 for a node, 0 for an empty leaf) into terms (N, 2), for numpy's sums. Leaves: boxes (L, 6)
 * six-row form, first slot, size. Returns 0, or -1 for a record, node or leaf reference out of range. */
int64_t hybrid_finish(const int64_t *child, const int64_t *rec, const int64_t *rows, int64_t n_rec,
                      const float *leaf_box, const int64_t *leaf_first, const int64_t *leaf_size, int64_t n_leaves,
                      int64_t widen, uint32_t *out, float *root_box, double *terms)
{
    int64_t n = 0, rc = -1;
    int64_t *base = malloc(sizeof(int64_t) * (n_rec + 1));
    if (!base)
        return -1;
    for (int64_t r = 0; r < n_rec; ++r) {
        base[r] = n;
        n += rows[r];
    }
    base[n_rec] = n;
    int64_t *nid = malloc(sizeof(int64_t) * (2 * n + 1)), *size = malloc(sizeof(int64_t) * (n + 1));
    int64_t *pos = malloc(sizeof(int64_t) * (n + 1));
    float *box = malloc(sizeof(float) * (6 * n + 1));
    if (!nid || !size || !pos || !box)
        goto done;
    for (int64_t q = 0; q < 2 * n; ++q) {   /* child node ids in build order, -1 for a leaf */
        const int64_t r = rec[q], c = child[q];
        if (r >= 0 ? r >= n_rec || c < 0 || c >= rows[r] || base[r] + c <= q / 2 : c < 0 || c >= n_leaves)
            goto done;
        nid[q] = r >= 0 ? base[r] + c : -1;
    }
    for (int64_t i = n - 1; i >= 0; --i)   /* subtree sizes bottom up (children have larger ids) */
        size[i] = (nid[2 * i] >= 0 ? size[nid[2 * i]] : 0) + (nid[2 * i + 1] >= 0 ? size[nid[2 * i + 1]] : 0) + 1;
    if (n)
        pos[0] = 0;
    for (int64_t i = 0; i < n; ++i) {   /* pre-order positions top down: the right child after the left subtree */
        int64_t p = pos[i] + 1;
        if (nid[2 * i] >= 0) {
            pos[nid[2 * i]] = p;
            p += size[nid[2 * i]];
        }
        if (nid[2 * i + 1] >= 0)
            pos[nid[2 * i + 1]] = p;
    }
    for (int64_t i = n - 1; i >= 0; --i) {   /* exact boxes bottom up; each node packed at its position */
        const float *cb[2];
        uint32_t word[2], count[2];
        for (int s = 0; s < 2; ++s) {
            const int64_t j = nid[2 * i + s], lid = child[2 * i + s];
            cb[s] = j >= 0 ? box + 6 * j : leaf_box + 6 * lid;
            word[s] = j >= 0 ? (uint32_t)pos[j] : ((uint32_t)leaf_first[lid] | 0x80000000u);
            count[s] = j >= 0 ? 0 : (uint32_t)leaf_size[lid];
            const int64_t wt = j >= 0 ? 1 : leaf_size[lid];
            terms[2 * i + s] = wt > 0 ? (double)half_area(cb[s]) * (double)wt : 0.0;
        }
        for (int r = 0; r < 6; ++r)
            box[6 * i + r] = min_np(cb[0][r], cb[1][r]);
        float *row = (float *)(out + 16 * pos[i]);
        for (int s = 0; s < 2; ++s)
            for (int a = 0; a < 3; ++a) {
                const float lo = cb[s][a], hi = cb[s][3 + a];
                row[8 * s + a] = widen ? step_down(lo) : lo;
                row[8 * s + 4 + a] = -(widen ? step_down(hi) : hi);
            }
        out[16 * pos[i] + 3] = word[0];
        out[16 * pos[i] + 7] = word[1];
        out[16 * pos[i] + 11] = count[0];
        out[16 * pos[i] + 15] = count[1];
    }
    if (n)
        memcpy(root_box, box, sizeof(float) * 6);
    rc = 0;
done:
    free(base);
    free(nid);
    free(size);
    free(pos);
    free(box);
    return rc;
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
 * offsets[axis] (origin i at o[i * o_stride]); then, unless `up` is null, bit 0 set where up[i * up_stride] > 0
 * (the direction's y). */
#if defined(__GNUC__) && defined(__x86_64__) && defined(__GLIBC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))   /* (AVX2's gathers vectorize the table lookups) */
#endif
void hybrid_ray_keys(const float *o, int64_t o_stride, int64_t n, const float *lo, const float *scale,
                     const float *top, const uint32_t *table, const uint32_t *offsets, const float *up, int64_t up_stride,
                     int64_t first, uint64_t *words)
{
    for (int64_t i = 0; i < n; ++i) {
        uint32_t key = 0;
        for (int a = 0; a < 3; ++a) {
            float q = o[o_stride * i + a] - lo[a];
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

/* hybrid_gather_rows from source rows `stride` bytes apart (a view of some columns of wider rows: the origins or
 * directions of Open3D's (N, 6) rays). */
void hybrid_gather_strided(const uint8_t *src, int64_t stride, const int64_t *rows, int64_t n, int64_t size,
                           uint8_t *dst)
{
    const int64_t ahead = 64;
    if (size == 12) {
        for (int64_t i = 0; i < n; ++i) {
            if (i + ahead < n)
                __builtin_prefetch(src + rows[i + ahead] * stride);
            memcpy(dst + i * 12, src + rows[i] * stride, 12);
        }
        return;
    }
    for (int64_t i = 0; i < n; ++i) {
        if (i + ahead < n)
            __builtin_prefetch(src + rows[i + ahead] * stride);
        memcpy(dst + i * size, src + rows[i] * stride, (size_t)size);
    }
}

/* out[rows[i]] = words[i] != 0 (occlusion results back into the caller's order). */
void hybrid_scatter_flags(const uint32_t *words, const int64_t *rows, int64_t n, uint8_t *out)
{
    for (int64_t i = 0; i < n; ++i)
        out[rows[i]] = words[i] != 0;
}

/* ---- closest points: the point walk of shaders/glsl/include/bvh_point.glsl on the host ----------------------------- */

#define CLOSEST_STACK 256 /* entries: a tree of depth D pushes at most D + 1 (build_bvh caps D at 32) */
#define LEAF_FLAG 0x80000000u

static double box_d2(const float *lo, const float *hi, const double *p)
{
    double d2 = 0.0;
    for (int k = 0; k < 3; k++) {
        double below = (double)lo[k] - p[k], above = p[k] - (double)hi[k];
        double e = below > 0.0 ? below : (above > 0.0 ? above : 0.0);
        d2 += e * e; /* an empty slot's inverted box: +inf, never visited */
    }
    return d2;
}

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* The nearest point of segment a + t (b - a), t in [0, 1], to p: its squared distance and t. */
static double segment_d2(const double *p, const double *a, const double *b, double *t)
{
    double ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]};
    double len2 = dot3(ab, ab), s = len2 > 0.0 ? dot3(ap, ab) / len2 : 0.0;
    s = s < 0.0 ? 0.0 : (s > 1.0 ? 1.0 : s);
    double q[3] = {ap[0] - s * ab[0], ap[1] - s * ab[1], ap[2] - s * ab[2]};
    *t = s;
    return dot3(q, q);
}

/* The nearest point of triangle (a, b, c) to p as barycentric weights (wb, wc) of b and c, and its squared distance
   (Ericson, Real-Time Collision Detection 5.1.5); a zero-area triangle is measured as its three edges. */
static double triangle_d2(const double *p, const double *a, const double *b, const double *c, double *wb, double *wc)
{
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; k++) {
        ab[k] = b[k] - a[k], ac[k] = c[k] - a[k], ap[k] = p[k] - a[k], bp[k] = p[k] - b[k], cp[k] = p[k] - c[k];
    }
    double d1 = dot3(ab, ap), d2 = dot3(ac, ap), d3 = dot3(ab, bp), d4 = dot3(ac, bp), d5 = dot3(ab, cp);
    double d6 = dot3(ac, cp), vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
    double v, w;
    if (d1 <= 0.0 && d2 <= 0.0) {
        v = 0.0, w = 0.0;
    } else if (d3 >= 0.0 && d4 <= d3) {
        v = 1.0, w = 0.0;
    } else if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        v = d1 / (d1 - d3), w = 0.0;
    } else if (d6 >= 0.0 && d5 <= d6) {
        v = 0.0, w = 1.0;
    } else if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        v = 0.0, w = d2 / (d2 - d6);
    } else if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0) {
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6)), v = 1.0 - w;
    } else if (va + vb + vc > 0.0) {
        double inv = 1.0 / (va + vb + vc);
        v = vb * inv, w = vc * inv;
    } else { /* zero area: the nearest of its edges */
        double t, best = segment_d2(p, a, b, &t);
        v = t, w = 0.0;
        double d = segment_d2(p, a, c, &t);
        if (d < best) best = d, v = 0.0, w = t;
        d = segment_d2(p, b, c, &t);
        if (d < best) best = d, v = 1.0 - t, w = t;
        *wb = v, *wc = w;
        return best;
    }
    double q[3];
    for (int k = 0; k < 3; k++) q[k] = ap[k] - v * ab[k] - w * ac[k];
    *wb = v, *wc = w;
    return dot3(q, q);
}

void hybrid_closest_points(const float *nodes, const float *tris, const double *points, int64_t n, float *dist,
                           int32_t *prim, float *u, float *v)
{
    const uint32_t *words = (const uint32_t *)nodes;
    const int32_t *tri_words = (const int32_t *)tris;
    uint32_t stack_word[CLOSEST_STACK], stack_count[CLOSEST_STACK];
    double stack_d2[CLOSEST_STACK];
    for (int64_t i = 0; i < n; i++) {
        const double *p = points + 3 * i;
        double best = INFINITY, bu = 0.0, bv = 0.0;
        int32_t slot = -1;
        int sp = 0;
        stack_word[sp] = 0, stack_count[sp] = 0, stack_d2[sp++] = 0.0; /* the root: interior node 0 */
        while (sp) {
            sp--;
            uint32_t word = stack_word[sp], count = stack_count[sp];
            if (stack_d2[sp] >= best) continue;
            if (word & LEAF_FLAG) {
                for (uint32_t t = word & ~LEAF_FLAG, end = t + count; t < end; t++) {
                    const float *r = tris + 12 * (int64_t)t;
                    double a[3] = {r[0], r[1], r[2]}, b[3] = {r[4], r[5], r[6]}, c[3] = {r[8], r[9], r[10]};
                    double wb, wc, d2 = triangle_d2(p, a, b, c, &wb, &wc);
                    if (d2 < best) best = d2, bu = wb, bv = wc, slot = tri_words[12 * (int64_t)t + 3];
                }
                continue;
            }
            const float *nd = nodes + 16 * (int64_t)word;
            const uint32_t *nw = words + 16 * (int64_t)word;
            double dl = box_d2(nd, nd + 4, p), dr = box_d2(nd + 8, nd + 12, p);
            /* the nearer child on top, walked first; a child no nearer than the best so far is not pushed */
            int left_first = dl <= dr;
            for (int side = 0; side < 2; side++) {
                int left = side == 0 ? !left_first : left_first;
                double d2 = left ? dl : dr;
                if (d2 >= best || sp >= CLOSEST_STACK) continue;
                stack_word[sp] = left ? nw[3] : nw[7], stack_count[sp] = left ? nw[11] : nw[15], stack_d2[sp++] = d2;
            }
        }
        dist[i] = (float)sqrt(best), prim[i] = slot, u[i] = (float)bu, v[i] = (float)bv;
    }
}

/* The front ends' answers (engine/rt/raycasting.py, raymesh.py, closest.py) from n hit records (t, prim as int
 * bits, u, v), hit i written to row r = rows[i] (rows NULL: r = i) of each output that is not NULL. A hit (0 <= prim
 * < n_tri): t_out[r] = t; gid_out[r] = geometry[prim] (geometry NULL: 0); pid_out[r] = primitive[prim] (primitive
 * NULL: prim); prim_out[r] = prim; uv_out[2r..] = (u, v); normal_out[3r..] = normal[3 prim..]; point_out[3r..] =
 * float32 of a + u (b - a) + v (c - a) in double (a, b, c: the corners verts[faces[prim]]; numpy's order of
 * operations), plus center where given (the sum rounded to float32 again, as numpy's float32 + float64 assigned to
 * float32). A miss: t = +inf, ids 0xFFFFFFFF, prim -1, uv, normal and point 0. */
void hybrid_scene_hits(const float *rec, int64_t n, const int64_t *rows, const uint32_t *geometry,
                       const uint32_t *primitive, const float *normal, int64_t n_tri, const float *verts,
                       const int64_t *faces, const double *center, float *t_out, uint32_t *gid_out,
                       uint32_t *pid_out, int64_t *prim_out, float *uv_out, float *normal_out, float *point_out)
{
    if (!rows && !geometry && !primitive && t_out && gid_out && pid_out && !prim_out && uv_out && normal_out &&
        !point_out) {   /* (cast_rays of one geometry: the same answers in a loop without the tests) */
        for (int64_t i = 0; i < n; ++i) {
            const float *h = rec + 4 * i;
            int32_t prim;
            memcpy(&prim, h + 1, 4);
            const int hit = prim >= 0 && prim < n_tri;
            const int64_t p = hit ? prim : 0;
            t_out[i] = hit ? h[0] : INFINITY;
            gid_out[i] = hit ? 0u : 0xFFFFFFFFu;
            pid_out[i] = hit ? (uint32_t)prim : 0xFFFFFFFFu;
            uv_out[2 * i] = hit ? h[2] : 0.0f;
            uv_out[2 * i + 1] = hit ? h[3] : 0.0f;
            normal_out[3 * i] = hit ? normal[3 * p] : 0.0f;
            normal_out[3 * i + 1] = hit ? normal[3 * p + 1] : 0.0f;
            normal_out[3 * i + 2] = hit ? normal[3 * p + 2] : 0.0f;
        }
        return;
    }
    for (int64_t i = 0; i < n; ++i) {
        const float *h = rec + 4 * i;
        int32_t prim;
        memcpy(&prim, h + 1, 4);
        const int64_t r = rows ? rows[i] : i;
        const int hit = prim >= 0 && prim < n_tri;
        if (t_out)
            t_out[r] = hit ? h[0] : INFINITY;
        if (gid_out)
            gid_out[r] = hit ? (geometry ? geometry[prim] : 0u) : 0xFFFFFFFFu;
        if (pid_out)
            pid_out[r] = hit ? (primitive ? primitive[prim] : (uint32_t)prim) : 0xFFFFFFFFu;
        if (prim_out)
            prim_out[r] = hit ? prim : -1;
        if (uv_out) {
            uv_out[2 * r] = hit ? h[2] : 0.0f;
            uv_out[2 * r + 1] = hit ? h[3] : 0.0f;
        }
        if (normal_out) {
            for (int k = 0; k < 3; ++k)
                normal_out[3 * r + k] = hit ? normal[3 * prim + k] : 0.0f;
        }
        if (point_out) {
            for (int k = 0; k < 3; ++k) {
                float p = 0.0f;
                if (hit) {
                    const double a = verts[3 * faces[3 * prim] + k], b = verts[3 * faces[3 * prim + 1] + k];
                    const double c = verts[3 * faces[3 * prim + 2] + k];
                    p = (float)((a + (double)h[2] * (b - a)) + (double)h[3] * (c - a));
                }
                point_out[3 * r + k] = center ? (float)((double)p + center[k]) : p;
            }
        }
    }
}

/* hybrid_frame_rays for one element type. */
#define FRAME_RAYS(T)                                                                                              \
    for (int64_t i = 0; i < n; ++i) {                                                                              \
        const T *oi = (const T *)o + i * stride, *di = (const T *)d + i * stride;                                 \
        const double dx = di[0], dy = di[1], dz = di[2];                                                           \
        const double len = sqrt(dx * dx + dy * dy + dz * dz);                                                      \
        if (!(len > 0.0) || !(len <= DBL_MAX))                                                                     \
            return i;                                                                                              \
        for (int k = 0; k < 3; ++k) {                                                                              \
            const double x = ((double)oi[k] - center[k]) * factor;                                                 \
            if (!(fabs(x) <= bound) || !isfinite((double)oi[k]) || !isfinite((double)di[k]))                      \
                return i;                                                                                          \
            o_out[3 * i + k] = (float)x;                                                                           \
            d_out[3 * i + k] = (float)((double)di[k] / len);                                                       \
        }                                                                                                          \
    }                                                                                                              \
    return -1;

/* RayMeshIntersector's rays in the frame it traces: float32 of (o - center) * factor and of d / |d| (|d| =
 * sqrt((x^2 + y^2) + z^2)), computed in double as its numpy steps do, for n rays of float32 (f32 != 0) or double
 * values, rows `stride` elements apart. Returns the first ray with a value not finite, a zero length, or an origin
 * beyond +-bound in the frame (the caller's checks then name it), or -1 (outputs written up to that ray only). */
int64_t hybrid_frame_rays(const void *o, const void *d, int64_t n, int64_t stride, int64_t f32, const double *center,
                          double factor, double bound, float *o_out, float *d_out)
{
    if (f32) {
        FRAME_RAYS(float)
    }
    FRAME_RAYS(double)
}

/* The first of n float32 points (rows `stride` floats apart) with a coordinate not finite or beyond +-bound, or
 * -1. */
int64_t hybrid_first_bad_point(const float *p, int64_t n, int64_t stride, double bound)
{
    for (int64_t i = 0; i < n; ++i) {
        const float *q = p + i * stride;
        if (!(fabs((double)q[0]) <= bound) || !(fabs((double)q[1]) <= bound) || !(fabs((double)q[2]) <= bound))
            return i;
    }
    return -1;
}

/* One round of RaycastingScene._all_hits: for the m live rays r = live[j] of float64 rays (origin at o + stride r,
 * direction at d + stride r), o_out[j] = float32 of o + d * start[r] (in double, numpy's order of operations) and
 * d_out[j] = float32 of d: what numpy's o[live] + d[live] * start[live, None] gives the Tracer. */
void hybrid_walk_rays(const double *o, const double *d, int64_t stride, const int64_t *live, int64_t m,
                      const double *start, float *o_out, float *d_out)
{
    for (int64_t j = 0; j < m; ++j) {
        const int64_t r = live[j];
        const double *oi = o + stride * r, *di = d + stride * r;
        for (int k = 0; k < 3; ++k) {
            o_out[3 * j + k] = (float)(oi[k] + di[k] * start[r]);
            d_out[3 * j + k] = (float)di[k];
        }
    }
}

/* The hits of one round of RaycastingScene._all_hits, in live order (rec[j]: t, prim bits, u, v of ray live[j]): a
 * ray that hit a triangle other than its last one records the hit (ray, prim, t = start + t_hit, u, v), takes it as
 * its last and starts again base past it; a ray that hit its last triangle again doubles its step and moves on by
 * it; both stay live (live_out), the others drop out. counts[0]: hits recorded, counts[1]: rays still live. */
void hybrid_walk_hits(const float *rec, const int64_t *live, int64_t m, double *start, double *step,
                      const double *base, int64_t *last, int64_t *ray_out, int64_t *prim_out, double *t_out,
                      float *u_out, float *v_out, int64_t *live_out, int64_t *counts)
{
    int64_t found = 0, going = 0;
    for (int64_t j = 0; j < m; ++j) {
        const float *h = rec + 4 * j;
        int32_t prim;
        memcpy(&prim, h + 1, 4);
        if (prim < 0)
            continue;
        const int64_t r = live[j];
        const double t = start[r] + (double)h[0];
        if (last[r] != prim) {
            ray_out[found] = r;
            prim_out[found] = prim;
            t_out[found] = t;
            u_out[found] = h[2];
            v_out[found] = h[3];
            ++found;
            last[r] = prim;
            step[r] = base[r];
            start[r] = t + step[r];
        } else {
            step[r] *= 2.0;
            start[r] += step[r];
        }
        live_out[going++] = r;
    }
    counts[0] = found;
    counts[1] = going;
}
