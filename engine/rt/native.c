/* The host steps of ray reordering (engine/rt/order.py) in C: the key of each ray, and the gathers and scatters
 * of rows in the keys' order (the sort itself stays numpy's, vectorized and in place). numpy's versions of these
 * steps are the reference (the same keys and the same order, bit for bit); engine/rt/native.py compiles this file
 * with the system's C compiler on first use and falls back to numpy where there is none. Plain C99, no Python
 * headers: loaded with ctypes. */
#include <stdint.h>
#include <string.h>

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
