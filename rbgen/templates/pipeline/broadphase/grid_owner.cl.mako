<%namespace name="group" file="/primitives/common.cl.mako"/>\
/* Uniform-grid broadphase, owner emission: the whole query in six launches
 * (the status reset included).
 *
 * Pair (a, b), a < b, is written by its owner a into a's slice of the pair
 * buffer, and the slices are in body order, so the list comes out sorted by
 * (a, b) with no global sort. The query, one kernel per global dependency:
 *
 *   measure_grid_bodies   the status reset, per-group sums of log2 sizes, and
 *                         the reset of the bucket lists and size statistics;
 *   classify_grid_bodies  validation; the geometric mean from those sums:
 *                         large bodies (the ground, big boxes) go to the
 *                         large-body list, the largest small one (an atomic
 *                         max) sets the cell;
 *   link_bucket_bodies    each small body joins the linked list of its lower
 *                         corner's bucket (cells.cl.mako): no sort, no scan;
 *   count_owned_pairs     per body (index order): the pairs it owns, their
 *                         prefix sum inside the work group and its total;
 *   place_owner_slices    one work group: the group totals become group
 *                         offsets, and the pair count is published;
 *   write_owned_pairs     the same visit again, storing each owner's pairs
 *                         from its offset and sorting its short slice.
 *
 * A small owner visits all 27 cells around its own for partners of higher
 * index, and the large bodies of higher index. A large body (at most
 * LARGE_ROWS, else status->retry asks for slot emission) owns its pairs with
 * every body of higher index: each such body sets bit t of its "row mask"
 * when large body t owns a pair with it, and its rank in the owner's slice is
 * the prefix count of bit t over the bodies (work-group scans plus group
 * offsets). The order inside the bucket lists varies between runs; the pair
 * list does not.
 *
 * Environments (a WorldBatch: static_flags holds collision words, env << 1 |
 * static) overlap in space, so each files its small bodies in cells displaced
 * by a hash of its index (env_cell): overlapping environments then share few
 * buckets, and pairs across them are rarely even visited. Shared static
 * geometry is always large (every environment's bodies meet it in the large
 * list).
 */
${cl_constants()}

${cl_structs("Aabb", "Pair", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>
<%include file="/pipeline/broadphase/cells.cl.mako"/>
<%include file="/common/hash.cl.mako"/>

#define WG ${work_group_size}
/* Most large bodies owner emission handles (one row of masks each). */
#define LARGE_ROWS ${large_rows}
/* End of a bucket list. */
#define NO_BODY 0xFFFFFFFFu
${group.work_group_reduce("float", "sum", "{a} + {b}", work_group_size)}
${group.work_group_reduce("float", "max", "fmax({a}, {b})", work_group_size)}
${group.work_group_exclusive_scan("uint", work_group_size, min(32, work_group_size))}

/* Local memory of one group scan: two rows of WG values, the segment sums. */
#define SCAN_SCRATCH (2 * WG + WG / ${min(32, work_group_size)} + 1)

/* The cell a body of collision word `word` is filed in: its own for
 * environment 0 (every World), else displaced by whole cells (no rounding)
 * by a hash of the environment, so that environments sharing a region of
 * space fall into different buckets. */
inline int3 env_cell(int3 cell, uint word)
{
    uint env = word >> 1;
    if (env == 0)
        return cell;
    uint h = mix32(env);
    int3 shift = 3 * (int3)((int)(h & 1023u), (int)((h >> 10) & 1023u), (int)((h >> 20) & 1023u));
    return add_sat(cell, shift);
}

/* Exclusive prefix sum of one uint per work-item over the group (the group's
 * sum in *total); every work-item of the group must call it. */
inline uint group_exclusive_scan(uint value, __local uint* scratch, uint* total)
{
    return work_group_exclusive_scan_uint(value, scratch, scratch + 2 * WG, total);
}

/* Starts the query: resets the status, sums the clamped log2 sizes (one
 * partial sum per work group), empties the bucket lists and resets the
 * statistics the next kernel gathers. The launch has at most as many work
 * groups as the partial sums the classification reads, so a work group is
 * responsible for the bodies and buckets at every global-size stride from its
 * work-items. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void measure_grid_bodies(__global const Aabb* aabbs,
                         const uint body_count,
                         const uint bucket_count,
                         __global float* log_size_partials,
                         __global uint* bucket_heads,
                         __global uint* large_count,
                         __global uint* largest_small_bits,
                         __global BroadphaseStatus* status)
{
    __local float scratch[WG];
    const uint stride = get_global_size(0);
    float log_sum = 0.0f;
    for (uint i = get_global_id(0); i < body_count; i += stride) {
        float size = box_size(aabbs[i].lower.xyz, aabbs[i].upper.xyz);
        float log_size = isfinite(size) ? log2(fmax(size, 1e-30f)) : LOG_SIZE_LIMIT;
        log_sum += clamp(log_size, -LOG_SIZE_LIMIT, LOG_SIZE_LIMIT);
    }
    log_sum = work_group_sum_float(log_sum, scratch);
    if (get_local_id(0) == 0)
        log_size_partials[get_group_id(0)] = log_sum;
    for (uint b = get_global_id(0); b < bucket_count; b += stride)
        bucket_heads[b] = NO_BODY;
    if (get_global_id(0) == 0) {
        status->pair_count = 0;
        status->pairs_found = 0;
        status->bad_body = RB_BP_NO_BODY;
        status->crossings = 0;
        status->retry = 0;
        *large_count = 0;
        *largest_small_bits = 0;  /* the bits of 0.0f */
    }
}

/* Validates every AABB (a NaN bound or lower > upper records the lowest such
 * body in status->bad_body) and tells small from large bodies (larger than
 * large_factor times the geometric mean size, which every work group sums
 * from the same partials in the same order): large ones get large_flags[i] = 1
 * and join the large-body list (status->retry past LARGE_ROWS of them); the
 * largest small size reaches *largest_small_bits by one atomic max per work
 * group (non-negative floats order like their bits). A work group is
 * responsible for WG consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void classify_grid_bodies(__global const Aabb* aabbs,
                          __global const uint* static_flags,
                          const uint body_count,
                          __global const float* log_size_partials,
                          const uint partial_count,
                          const float large_factor,
                          __global uint* large_flags,
                          __global uint* large_count,
                          __global uint* large_bodies,
                          __global uint* largest_small_bits,
                          __global BroadphaseStatus* status)
{
    __local float scratch[WG];
    float log_sum = 0.0f;
    for (uint k = get_local_id(0); k < partial_count; k += WG)
        log_sum += log_size_partials[k];
    float scale = size_scale(work_group_sum_float(log_sum, scratch), body_count, large_factor);

    uint i = get_global_id(0);
    float small_size = 0.0f;
    if (i < body_count) {
        float3 lower = aabbs[i].lower.xyz, upper = aabbs[i].upper.xyz;
        /* Comparisons with NaN are false, so this also catches NaN bounds. */
        if (!all(lower <= upper))
            atomic_min(&status->bad_body, i);
        float size = box_size(lower, upper);
        bool small = is_small(size, scale) && static_flags[i] != RB_SHARED_STATIC;
        large_flags[i] = small ? 0u : 1u;
        if (small) {
            small_size = fmax(size, 0.0f);  /* an inverted box is reported, not sized */
        } else {
            uint row = atomic_inc(large_count);
            if (row < LARGE_ROWS)
                large_bodies[row] = i;
            else
                status->retry = RB_BP_RETRY_LARGE;
        }
    }
    small_size = work_group_max_float(small_size, scratch);
    if (get_local_id(0) == 0)
        atomic_max(largest_small_bits, as_uint(small_size));
}

/* Puts each small body at the head of its bucket's list (next_body links the
 * rest). A work group is responsible for WG consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void link_bucket_bodies(__global const Aabb* aabbs,
                        __global const uint* static_flags,
                        const uint body_count,
                        const int grid_dim,
                        __global const uint* large_flags,
                        __global const uint* largest_small_bits,
                        __global uint* bucket_heads,
                        __global uint* next_body)
{
    uint i = get_global_id(0);
    if (i >= body_count || large_flags[i])
        return;
    float cell_size = grid_cell_size(as_float(*largest_small_bits));
    uint bucket = bucket_of(env_cell(cell_of(aabbs[i].lower.xyz, cell_size), static_flags[i]),
                            grid_dim);
    next_body[i] = atomic_xchg(&bucket_heads[bucket], i);
}

<%def name="visit_arguments()">\
                       __global const Aabb* aabbs,
                       __global const uint* static_flags,
                       const uint body_count,
                       const int grid_dim,
                       __global const uint* large_flags,
                       __global const uint* largest_small_bits,
                       __global const uint* bucket_heads,
                       __global const uint* next_body,
                       __global const uint* large_count,
                       __global const uint* large_bodies,\
</%def>
/* Pair (owner, partner) with a partner of higher index is stored at slot `at`
 * of the pair buffer (when within the capacity). */
inline void store_owned_pair(__global Pair* pairs, uint capacity, uint at, uint owner,
                             uint partner)
{
    if (at < capacity) {
        Pair pair;
        pair.a = owner;
        pair.b = partner;
        pair.sub = RB_WHOLE_BODY;  /* the broadphase pairs whole bodies */
        pairs[at] = pair;
    }
}

/* The pairs small body `self` owns: partners of higher index in the 27 cells
 * around its own and among the large bodies, boxes overlapping, not both
 * static. Returns their number; with `pairs` (not null) also stores them from
 * slot `first` on, in visiting order. */
inline uint visit_owned_partners(__global const Aabb* aabbs,
                                 __global const uint* static_flags,
                                 const int grid_dim,
                                 float cell_size,
                                 __global const uint* bucket_heads,
                                 __global const uint* next_body,
                                 uint large_total,
                                 __global const uint* large_bodies,
                                 uint self,
                                 __global Pair* pairs,
                                 uint first,
                                 uint capacity)
{
    float3 lower = aabbs[self].lower.xyz, upper = aabbs[self].upper.xyz;
    int3 home = folded_cell(env_cell(cell_of(lower, cell_size), static_flags[self]), grid_dim);
    /* The 27 list heads first: independent loads, in flight together. */
    uint heads[27];
    for (int neighbour = 0; neighbour < 27; ++neighbour)
        heads[neighbour] = bucket_heads[neighbour_bucket(home, neighbour, grid_dim)];
    uint found = 0;
    for (int neighbour = 0; neighbour < 27; ++neighbour) {
        for (uint other = heads[neighbour]; other != NO_BODY; other = next_body[other]) {
            if (other > self && pair_allowed(static_flags, self, other)
                && boxes_overlap(lower, upper, aabbs[other].lower.xyz, aabbs[other].upper.xyz)) {
                if (pairs)
                    store_owned_pair(pairs, capacity, first + found, self, other);
                ++found;
            }
        }
    }
    for (uint row = 0; row < large_total; ++row) {
        uint other = large_bodies[row];
        if (other > self && pair_allowed(static_flags, self, other)
            && boxes_overlap(lower, upper, aabbs[other].lower.xyz, aabbs[other].upper.xyz)) {
            if (pairs)
                store_owned_pair(pairs, capacity, first + found, self, other);
            ++found;
        }
    }
    return found;
}

/* Bit `row` set when large body `row` owns a pair with body `self`: it has
 * the lower index, the boxes overlap, not both are static. */
inline uint large_owner_mask(__global const Aabb* aabbs,
                             __global const uint* static_flags,
                             uint large_total,
                             __global const uint* large_bodies,
                             uint self)
{
    float3 lower = aabbs[self].lower.xyz, upper = aabbs[self].upper.xyz;
    uint mask = 0;
    for (uint row = 0; row < large_total; ++row) {
        uint owner = large_bodies[row];
        if (owner < self && pair_allowed(static_flags, owner, self)
            && boxes_overlap(aabbs[owner].lower.xyz, aabbs[owner].upper.xyz, lower, upper))
            mask |= 1u << row;
    }
    return mask;
}

/* Sorts the partners of one owner in slots [first, end) by b (insertion
 * sort: the slices of small owners are short). */
inline void sort_owner_slice(__global Pair* pairs, uint first, uint end, uint capacity)
{
    end = min(end, capacity);
    for (uint k = first + 1; k < end; ++k) {
        Pair pair = pairs[k];
        uint m = k;
        for (; m > first && pairs[m - 1].b > pair.b; --m)
            pairs[m] = pairs[m - 1];
        pairs[m] = pair;
    }
}

/* Counts the pairs each small body owns and their exclusive prefix sum inside
 * the work group (in_group_offsets), the group's total (group_pairs[group])
 * and, per large body t, how many bodies of the group it owns a pair with
 * (group_rows[t * group_count + group]). A work group is responsible for WG
 * consecutive bodies in index order. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void count_owned_pairs(
${visit_arguments()}
                       __global uint* in_group_offsets,
                       __global uint* group_pairs,
                       __global uint* group_rows)
{
    __local uint scan_scratch[SCAN_SCRATCH];
    __local uint row_counts[LARGE_ROWS];
    const uint i = get_global_id(0), lid = get_local_id(0), group = get_group_id(0);
    const uint group_count = get_num_groups(0);
    const uint large_total = min(*large_count, (uint)LARGE_ROWS);
    for (uint row = lid; row < LARGE_ROWS; row += WG)
        row_counts[row] = 0;
    uint found = 0, mask = 0;
    if (i < body_count) {
        mask = large_owner_mask(aabbs, static_flags, large_total, large_bodies, i);
        if (!large_flags[i])
            found = visit_owned_partners(aabbs, static_flags, grid_dim,
                                         grid_cell_size(as_float(*largest_small_bits)),
                                         bucket_heads, next_body, large_total, large_bodies, i,
                                         0, 0, 0);
    }
    barrier(CLK_LOCAL_MEM_FENCE);  /* row_counts zeroed */
    for (uint row = 0; row < large_total; ++row)
        if (mask & (1u << row))
            atomic_inc(&row_counts[row]);
    uint total;
    /* the scan's barriers also order the row_counts increments before their reads */
    uint offset = group_exclusive_scan(found, scan_scratch, &total);
    if (i < body_count)
        in_group_offsets[i] = offset;
    if (lid == 0)
        group_pairs[group] = total;
    for (uint row = lid; row < large_total; row += WG)
        group_rows[row * group_count + group] = row_counts[row];
}

/* Exclusive prefix sums of values[0, count) in place, by one work group: each
 * work-item sums a contiguous run (independent loads), one group scan of the
 * run sums, then each work-item rewrites its run. Returns the total. */
inline uint scan_in_place(__global uint* values, uint count, __local uint* scratch)
{
    const uint run = (count + WG - 1) / WG;
    const uint first = min((uint)get_local_id(0) * run, count), end = min(first + run, count);
    uint run_sum = 0, total;
    for (uint k = first; k < end; ++k)
        run_sum += values[k];
    uint prefix = group_exclusive_scan(run_sum, scratch, &total);
    for (uint k = first; k < end; ++k) {
        uint value = values[k];
        values[k] = prefix;
        prefix += value;
    }
    return total;
}

/* One work group is responsible for the whole query's slices: group_pairs
 * become the first slot of each counting group (small owners) and each row
 * of group_rows the rank offsets of one large owner's partners per group;
 * owner_starts / owner_counts give each large owner's slice, and the pair
 * totals reach the status (at most `capacity` pairs are stored; the host
 * grows the buffer and redoes the query). */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void place_owner_slices(const uint group_count,
                        __global const uint* large_count,
                        __global const uint* large_bodies,
                        __global const uint* in_group_offsets,
                        __global uint* group_pairs,
                        __global uint* group_rows,
                        __global uint* owner_starts,
                        __global uint* owner_counts,
                        const uint capacity,
                        __global BroadphaseStatus* status)
{
    __local uint scan_scratch[SCAN_SCRATCH];
    __local uint row_totals[LARGE_ROWS];
    const uint lid = get_local_id(0);
    const uint large_total = min(*large_count, (uint)LARGE_ROWS);
    uint found = scan_in_place(group_pairs, group_count, scan_scratch);
    for (uint row = 0; row < large_total; ++row) {
        uint total = scan_in_place(group_rows + row * group_count, group_count,
                                   scan_scratch);
        if (lid == 0)
            row_totals[row] = total;
        found += total;
    }
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    for (uint owner_row = lid; owner_row < large_total; owner_row += WG) {
        /* A large owner's slice follows those of every body of lower index. */
        uint owner = large_bodies[owner_row];
        uint start = group_pairs[owner / WG] + in_group_offsets[owner];
        for (uint row = 0; row < large_total; ++row)
            if (large_bodies[row] < owner)
                start += row_totals[row];
        owner_starts[owner_row] = start;
        owner_counts[owner_row] = row_totals[owner_row];
    }
    if (lid == 0) {
        status->pairs_found = found;
        status->pair_count = min(found, capacity);
    }
}

/* Writes the pairs each small body owns into its slice and sorts the slice,
 * and the pairs large owners have with each body at their ranks. A work
 * group is responsible for WG consecutive bodies in index order (the groups
 * of count_owned_pairs). */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void write_owned_pairs(
${visit_arguments()}
                       __global const uint* in_group_offsets,
                       __global const uint* group_starts,
                       __global const uint* group_row_ranks,
                       __global const uint* owner_starts,
                       __global const uint* owner_counts,
                       const uint capacity,
                       __global Pair* pairs)
{
    __local uint scan_scratch[SCAN_SCRATCH];
    const uint i = get_global_id(0), group = get_group_id(0);
    const uint group_count = get_num_groups(0);
    const uint large_total = min(*large_count, (uint)LARGE_ROWS);
    uint mask = 0;
    if (i < body_count) {
        mask = large_owner_mask(aabbs, static_flags, large_total, large_bodies, i);
        if (!large_flags[i]) {
            uint first = group_starts[group] + in_group_offsets[i];
            for (uint row = 0; row < large_total; ++row)
                if (large_bodies[row] < i)
                    first += owner_counts[row];
            uint found = visit_owned_partners(aabbs, static_flags, grid_dim,
                                              grid_cell_size(as_float(*largest_small_bits)),
                                              bucket_heads, next_body, large_total,
                                              large_bodies, i, pairs, first, capacity);
            sort_owner_slice(pairs, first, first + found, capacity);
        }
    }
    /* Pairs of the large owners: body i's rank among the partners of owner t
     * is the number of bodies before it with bit t set. */
    for (uint row = 0; row < large_total; ++row) {
        uint bit = (mask >> row) & 1u, unused;
        uint rank = group_exclusive_scan(bit, scan_scratch, &unused);
        if (bit)
            store_owned_pair(pairs, capacity,
                             owner_starts[row] + group_row_ranks[row * group_count + group] + rank,
                             large_bodies[row], i);
    }
}
