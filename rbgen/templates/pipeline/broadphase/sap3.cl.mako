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
 * The changes (found once or more) are merged with the previous pair set:
 * after sorting both together, a pair survives iff it was in the old set or
 * changed, but not both.
 */
${cl_constants()}

${cl_structs("Aabb", "Pair", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>

/* Merge records store b as (b << 1) | tag, tag 1 for this step's changes:
 * sorting by that keeps records of one pair adjacent, old record first. */
#define CHANGE_TAG 1u
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

/* Concatenates the previous pair set and the changes (tagged) for sorting;
 * work-item 0 writes their total, or 0 and INCREMENTAL_FAILED when the step
 * must be redone in full. A work group is responsible for ${work_group_size}
 * records. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void stage_merge(__global const Pair* old_pairs,
                 __global const BroadphaseStatus* old_status,
                 __global const uint* changes_a,
                 __global const uint* changes_b,
                 __global const uint* change_count,
                 const uint change_capacity,
                 __global uint* merged_a,
                 __global uint* merged_b,
                 __global uint* merged_count,
                 __global BroadphaseStatus* status)
{
    uint k = get_global_id(0);
    uint old_count = old_status->pair_count;
    bool failed = status->crossings == INCREMENTAL_FAILED || change_count[0] > change_capacity;
    uint total = failed ? 0u : old_count + change_count[0];
    if (k == 0) {
        merged_count[0] = total;
        if (failed)
            status->crossings = INCREMENTAL_FAILED;
    }
    if (k >= total)
        return;
    if (k < old_count) {
        merged_a[k] = old_pairs[k].a;
        merged_b[k] = old_pairs[k].b << 1;
    } else {
        merged_a[k] = changes_a[k - old_count];
        merged_b[k] = (changes_b[k - old_count] << 1) | CHANGE_TAG;
    }
}

/* After sorting, equal pairs are adjacent. The first record of each run keeps
 * the pair iff the run holds an old record or a change, but not both. A work
 * group is responsible for ${work_group_size} records. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void mark_survivors(__global const uint* merged_a,
                    __global const uint* merged_b,
                    __global const uint* merged_count,
                    __global uint* keep)
{
    uint k = get_global_id(0), total = merged_count[0];
    if (k >= total)
        return;
    uint a = merged_a[k], b = merged_b[k] >> 1;
    bool first = k == 0 || merged_a[k - 1] != a || merged_b[k - 1] >> 1 != b;
    bool has_old = false, has_change = false;
    for (uint q = k; first && q < total && merged_a[q] == a && merged_b[q] >> 1 == b; ++q) {
        has_change |= (merged_b[q] & CHANGE_TAG) != 0;
        has_old |= (merged_b[q] & CHANGE_TAG) == 0;
    }
    keep[k] = first && has_old != has_change ? 1u : 0u;
}

/* Writes the surviving pairs (already in (a, b) order) and publishes the
 * totals (work-item 0); past the capacity they are counted, not stored. A
 * work group is responsible for ${work_group_size} surviving pairs. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void gather_survivors(__global const uint* merged_a,
                      __global const uint* merged_b,
                      __global const uint* survivors,
                      __global const uint* survivor_count,
                      const uint capacity,
                      __global Pair* pairs,
                      __global BroadphaseStatus* status)
{
    uint k = get_global_id(0), total = survivor_count[0];
    if (k == 0) {
        status->pairs_found = total;
        status->pair_count = min(total, capacity);
    }
    if (k >= min(total, capacity))
        return;
    Pair pair;
    pair.a = merged_a[survivors[k]];
    pair.b = merged_b[survivors[k]] >> 1;
    pairs[k] = pair;
}
