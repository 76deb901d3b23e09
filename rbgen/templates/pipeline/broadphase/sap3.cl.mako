/* Incremental three-axis sweep and prune: pairs updated from the changes of
 * the sorted endpoint arrays between two steps.
 *
 * Endpoint e < n is the lower bound of body e, endpoint n + e its upper
 * bound. On each axis the endpoints are sorted by value with a stable sort
 * from that canonical order, so equal values put lower bounds first: rank
 * order then agrees exactly with the closed overlap test (lower_a <= upper_b),
 * and two boxes overlap iff on every axis each lower endpoint ranks before the
 * other's upper endpoint.
 *
 * A pair changes overlap only if two of its endpoints swapped order on some
 * axis. For endpoints e, f that swapped, f's old rank lies between e's old and
 * new ranks, or e's new rank between f's old and new ranks; so each endpoint
 * scans the previous and the current sorted arrays between its old and new
 * rank (read-only) and tests every body met with the old and the new boxes.
 * The changes (found once or more) are sorted and made distinct; the new
 * pair set is the symmetric difference of the old set and the changes,
 * written in (a, b) order by a merge (binary search of each list in the
 * other), so the old set is never sorted again.
 */
${cl_constants()}

${cl_structs("Aabb", "Pair", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>

/* status->crossings when the step cannot be done incrementally (too many
 * crossings, or the change buffer overflowed): the host redoes it in full. */
#define INCREMENTAL_FAILED 0xFFFFFFFFu

/* Order-preserving map of a float to a uint; -0 is first made +0, because
 * they compare equal and the order must agree with the overlap test. */
inline uint sortable_float(float value)
{
    uint bits = as_uint(value == 0.0f ? 0.0f : value);
    return bits ^ ((bits >> 31) ? 0xFFFFFFFFu : 0x80000000u);
}

inline float axis_value(float4 v, uint axis)
{
    return axis == 0 ? v.x : axis == 1 ? v.y : v.z;
}

/* Sort keys of the 2n endpoints on the three axes, values the endpoint ids.
 * A work group is responsible for ${work_group_size} endpoints. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void endpoint_keys(__global const Aabb* aabbs,
                   const uint body_count,
                   __global uint* keys_x, __global uint* keys_y, __global uint* keys_z,
                   __global uint* ends_x, __global uint* ends_y, __global uint* ends_z)
{
    uint e = get_global_id(0);
    if (e >= 2 * body_count)
        return;
    float4 bound = e < body_count ? aabbs[e].lower : aabbs[e - body_count].upper;
    keys_x[e] = sortable_float(bound.x);
    keys_y[e] = sortable_float(bound.y);
    keys_z[e] = sortable_float(bound.z);
    ends_x[e] = e; ends_y[e] = e; ends_z[e] = e;
}

/* Inverse permutations: ranks[axis * 2n + e] is the position of endpoint e in
 * the sorted array of that axis. A work group is responsible for
 * ${work_group_size} sorted positions. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void endpoint_ranks(const uint body_count,
                    __global const uint* sorted_x, __global const uint* sorted_y,
                    __global const uint* sorted_z,
                    __global uint* ranks)
{
    uint p = get_global_id(0), m = 2 * body_count;
    if (p >= m)
        return;
    ranks[sorted_x[p]] = p;
    ranks[m + sorted_y[p]] = p;
    ranks[2 * m + sorted_z[p]] = p;
}

/* How far each endpoint moved in rank (summed by Reduce to decide whether
 * the step is incremental). A work group is responsible for
 * ${work_group_size} (axis, endpoint) entries. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void rank_moves(const uint body_count,
                __global const uint* old_ranks,
                __global const uint* new_ranks,
                __global float* moves)
{
    uint k = get_global_id(0);
    if (k >= 6 * body_count)
        return;
    moves[k] = (float)abs_diff(old_ranks[k], new_ranks[k]);
}

/* Records pair (i, j) when its overlap differs between the old and new boxes. */
inline void test_change(uint i, uint j,
                        __global const Aabb* old_boxes, __global const Aabb* aabbs,
                        __global const uint* static_flags,
                        __global uint* change_count, const uint change_capacity,
                        __global uint* changes_a, __global uint* changes_b)
{
    if (i == j || !pair_allowed(static_flags, i, j))
        return;
    bool was = boxes_overlap(old_boxes[i].lower.xyz, old_boxes[i].upper.xyz,
                             old_boxes[j].lower.xyz, old_boxes[j].upper.xyz);
    bool now = boxes_overlap(aabbs[i].lower.xyz, aabbs[i].upper.xyz,
                             aabbs[j].lower.xyz, aabbs[j].upper.xyz);
    if (was == now)
        return;
    uint slot = atomic_inc(change_count);
    if (slot < change_capacity) {
        changes_a[slot] = min(i, j);
        changes_b[slot] = max(i, j);
    }
}

/* One work-item per (axis, endpoint): scans the old and new sorted arrays
 * between its old and new rank. Nothing is scanned when the moves exceed the
 * budget; work-item 0 records the crossings in the status. A work group is
 * responsible for ${work_group_size} (axis, endpoint) entries. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void find_changes(__global const Aabb* aabbs,
                  __global const Aabb* old_boxes,
                  __global const uint* static_flags,
                  const uint body_count,
                  __global const uint* old_ranks, __global const uint* new_ranks,
                  __global const uint* old_x, __global const uint* old_y, __global const uint* old_z,
                  __global const uint* new_x, __global const uint* new_y, __global const uint* new_z,
                  __global const float* total_moves,
                  const float move_budget,
                  __global uint* change_count,
                  const uint change_capacity,
                  __global uint* changes_a,
                  __global uint* changes_b,
                  __global BroadphaseStatus* status)
{
    uint k = get_global_id(0), m = 2 * body_count;
    bool within_budget = total_moves[0] <= move_budget;
    if (k == 0)
        status->crossings = within_budget ? (uint)total_moves[0] : INCREMENTAL_FAILED;
    if (k >= 3 * m || !within_budget)
        return;
    uint axis = k / m, endpoint = k % m;
    uint from = min(old_ranks[k], new_ranks[k]), to = max(old_ranks[k], new_ranks[k]);
    if (from == to)
        return;
    __global const uint* old_sorted = axis == 0 ? old_x : axis == 1 ? old_y : old_z;
    __global const uint* new_sorted = axis == 0 ? new_x : axis == 1 ? new_y : new_z;
    uint body = endpoint % body_count;
    for (uint p = from; p <= to; ++p) {
        test_change(body, old_sorted[p] % body_count, old_boxes, aabbs, static_flags,
                    change_count, change_capacity, changes_a, changes_b);
        test_change(body, new_sorted[p] % body_count, old_boxes, aabbs, static_flags,
                    change_count, change_capacity, changes_a, changes_b);
    }
}

/* Number of pairs of sorted[0, count) ordered before (a, b). */
inline uint pairs_before(__global const Pair* sorted, uint count, uint a, uint b)
{
    uint first = 0, last = count;
    while (first < last) {
        uint middle = first + (last - first) / 2;
        Pair probe = sorted[middle];
        if (probe.a < a || (probe.a == a && probe.b < b))
            first = middle + 1;
        else
            last = middle;
    }
    return first;
}

inline bool pair_at(__global const Pair* sorted, uint count, uint index, uint a, uint b)
{
    return index < count && sorted[index].a == a && sorted[index].b == b;
}

/* Changes sorted by (a, b) may repeat (a change is found from several
 * endpoints): flags the first of each run. Work-item 0 marks the step failed
 * when the change buffer overflowed. A work group is responsible for
 * ${work_group_size} changes. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void mark_unique_changes(__global const uint* changes_a,
                         __global const uint* changes_b,
                         __global const uint* change_count,
                         const uint change_capacity,
                         __global uint* first_flags,
                         __global BroadphaseStatus* status)
{
    uint k = get_global_id(0), count = min(change_count[0], change_capacity);
    if (k == 0 && change_count[0] > change_capacity)
        status->crossings = INCREMENTAL_FAILED;
    if (k >= count)
        return;
    first_flags[k] = k == 0 || changes_a[k - 1] != changes_a[k] || changes_b[k - 1] != changes_b[k];
}

/* The distinct changes as Pair records. A work group is responsible for
 * ${work_group_size} distinct changes. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void gather_unique_changes(__global const uint* changes_a,
                           __global const uint* changes_b,
                           __global const uint* unique_index,
                           __global const uint* unique_count,
                           __global Pair* unique_changes)
{
    uint m = get_global_id(0);
    if (m >= unique_count[0])
        return;
    Pair change;
    change.a = changes_a[unique_index[m]];
    change.b = changes_b[unique_index[m]];
    change.sub = RB_WHOLE_BODY;  /* the broadphase pairs whole bodies */
    unique_changes[m] = change;
}

/* The new set is the symmetric difference of the old set and the changes:
 * an old pair survives unless it changed (keep_old), a change is a new pair
 * unless it was in the old set (keep_change). A work group is responsible for
 * ${work_group_size} old pairs. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void mark_old_pairs(__global const Pair* old_pairs,
                    __global const BroadphaseStatus* old_status,
                    __global const Pair* unique_changes,
                    __global const uint* unique_count,
                    __global uint* keep_old)
{
    uint k = get_global_id(0);
    if (k >= old_status->pair_count)
        return;
    Pair pair = old_pairs[k];
    uint u = unique_count[0];
    keep_old[k] = !pair_at(unique_changes, u, pairs_before(unique_changes, u, pair.a, pair.b),
                           pair.a, pair.b);
}

/* See mark_old_pairs. A work group is responsible for ${work_group_size}
 * distinct changes. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void mark_new_pairs(__global const Pair* old_pairs,
                    __global const BroadphaseStatus* old_status,
                    __global const Pair* unique_changes,
                    __global const uint* unique_count,
                    __global uint* keep_change)
{
    uint m = get_global_id(0);
    if (m >= unique_count[0])
        return;
    Pair change = unique_changes[m];
    uint o = old_status->pair_count;
    keep_change[m] = !pair_at(old_pairs, o, pairs_before(old_pairs, o, change.a, change.b),
                              change.a, change.b);
}

/* Kept entries before position `index` of a list, from its exclusive scan. */
inline uint kept_before(__global const uint* ranks, uint count, uint total, uint index)
{
    return index < count ? ranks[index] : total;
}

/* Merge: a kept old pair goes after the kept old pairs and the new pairs
 * ordered before it. Past the capacity pairs are counted, not stored. A work
 * group is responsible for ${work_group_size} old pairs. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void place_old_pairs(__global const Pair* old_pairs,
                     __global const BroadphaseStatus* old_status,
                     __global const uint* keep_old,
                     __global const uint* old_ranks,
                     __global const Pair* unique_changes,
                     __global const uint* unique_count,
                     __global const uint* change_ranks,
                     __global const uint* added_total,
                     const uint capacity,
                     __global Pair* pairs)
{
    uint k = get_global_id(0);
    if (k >= old_status->pair_count || !keep_old[k])
        return;
    Pair pair = old_pairs[k];
    uint u = unique_count[0];
    uint slot = old_ranks[k] + kept_before(change_ranks, u, added_total[0],
                                           pairs_before(unique_changes, u, pair.a, pair.b));
    if (slot < capacity)
        pairs[slot] = pair;
}

/* Merge: a new pair goes after the new pairs and the kept old pairs ordered
 * before it. Work-item 0 publishes the totals. A work group is responsible
 * for ${work_group_size} distinct changes. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void place_new_pairs(__global const Pair* old_pairs,
                     __global const BroadphaseStatus* old_status,
                     __global const uint* old_ranks,
                     __global const uint* kept_total,
                     __global const Pair* unique_changes,
                     __global const uint* unique_count,
                     __global const uint* keep_change,
                     __global const uint* change_ranks,
                     __global const uint* added_total,
                     const uint capacity,
                     __global Pair* pairs,
                     __global BroadphaseStatus* status)
{
    uint m = get_global_id(0);
    if (m == 0) {
        uint total = kept_total[0] + added_total[0];
        status->pairs_found = total;
        status->pair_count = min(total, capacity);
    }
    if (m >= unique_count[0] || !keep_change[m])
        return;
    Pair change = unique_changes[m];
    uint o = old_status->pair_count;
    uint slot = change_ranks[m] + kept_before(old_ranks, o, kept_total[0],
                                              pairs_before(old_pairs, o, change.a, change.b));
    if (slot < capacity)
        pairs[slot] = change;
}
