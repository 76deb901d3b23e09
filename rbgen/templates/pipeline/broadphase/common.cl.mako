/* Broadphase helpers shared by every algorithm (included, not compiled alone).
 *
 * Touching rule: boxes are closed, so two AABBs that share only a face, an
 * edge or a corner overlap (resting boxes touch exactly). A pair joins two
 * different bodies, not both static, and is stored as (a, b) with a < b.
 */

/* Bodies larger than cell / SMALL_SLACK are "large": kept out of the grid or
 * the sweep and tested against everything separately. The slack keeps the
 * grid's one-cell reach exact despite float rounding of lower / cell. */
#define SMALL_SLACK 1.01f
/* log2 sizes are clamped to this range so that points and infinite slabs do
 * not dominate the mean. */
#define LOG_SIZE_LIMIT 40.0f

inline bool boxes_overlap(float3 lower_a, float3 upper_a, float3 lower_b, float3 upper_b)
{
    return all(lower_a <= upper_b) && all(lower_b <= upper_a);
}

/* Largest side of a box; NaN or infinity for degenerate boxes. */
inline float box_size(float3 lower, float3 upper)
{
    float3 side = upper - lower;
    return fmax(side.x, fmax(side.y, side.z));
}

/* The scale used to tell small from large bodies: factor times the geometric
 * mean of the body sizes (the mean of their clamped log2 sizes). */
inline float size_scale(float log_size_sum, uint body_count, float factor)
{
    return factor * exp2(log_size_sum / (float)max(body_count, 1u));
}

/* NaN and infinite sizes compare false: such bodies are large. */
inline bool is_small(float size, float scale)
{
    return size * SMALL_SLACK <= scale;
}

/* A pair is kept unless both of its bodies are static, or they are in different
 * environments (a WorldBatch) and neither is shared static geometry. static_flags
 * holds each body's collision word, env << 1 | static (layouts: RB_SHARED_STATIC):
 * the test costs no load beyond the static flags it always read. */
inline bool pair_allowed(__global const uint* static_flags, uint a, uint b)
{
    uint ga = static_flags[a], gb = static_flags[b];
    return (ga & gb & RB_GROUP_STATIC) == 0
           && ((ga >> 1) == (gb >> 1) || ga == RB_SHARED_STATIC || gb == RB_SHARED_STATIC);
}

/* Stores pair {first, second} as (a, b), a < b, at slot `at` of the pair
 * arrays; past the capacity it is only counted (by the caller's offsets). */
inline void store_pair(__global uint* pairs_a, __global uint* pairs_b, uint capacity, uint at,
                       uint first, uint second)
{
    if (at < capacity) {
        pairs_a[at] = min(first, second);
        pairs_b[at] = max(first, second);
    }
}
