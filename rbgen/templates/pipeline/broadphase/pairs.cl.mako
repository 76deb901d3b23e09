/* Ordering the pairs found by a broadphase by (a, b).
 *
 * Broadphases write pair halves into two uint arrays (a[k], b[k]). When a*n+b
 * fits 32 bits, combine_pair_keys folds each pair into one key for a single
 * keys-only radix sort and split_pair_keys unfolds it; otherwise two stable
 * key-value sorts (by b, then by a) precede interleave_pairs. One work-item
 * per stored pair; a work group is responsible for ${work_group_size}
 * consecutive pairs. Work-items past status->pair_count exit at once, so the
 * host launches over the capacity without reading the count.
 */
${cl_constants()}

${cl_structs("Pair", "BroadphaseStatus")}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void combine_pair_keys(__global uint* pairs_a,
                       __global const uint* pairs_b,
                       __global const BroadphaseStatus* status,
                       const uint body_count)
{
    uint k = get_global_id(0);
    if (k >= status->pair_count)
        return;
    pairs_a[k] = pairs_a[k] * body_count + pairs_b[k];
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void split_pair_keys(__global const uint* keys,
                     __global const BroadphaseStatus* status,
                     const uint body_count,
                     __global Pair* pairs)
{
    uint k = get_global_id(0);
    if (k >= status->pair_count)
        return;
    Pair pair;
    pair.a = keys[k] / body_count;
    pair.b = keys[k] % body_count;
    pair.sub = RB_WHOLE_BODY;  /* the broadphase pairs whole bodies */
    pairs[k] = pair;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void interleave_pairs(__global const uint* pairs_a,
                      __global const uint* pairs_b,
                      __global const BroadphaseStatus* status,
                      __global Pair* pairs)
{
    uint k = get_global_id(0);
    if (k >= status->pair_count)
        return;
    Pair pair;
    pair.a = pairs_a[k];
    pair.b = pairs_b[k];
    pair.sub = RB_WHOLE_BODY;  /* the broadphase pairs whole bodies */
    pairs[k] = pair;
}
