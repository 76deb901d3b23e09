<%namespace name="group" file="/primitives/common.cl.mako"/>\
/* Uniform-grid broadphase, owner emission: the whole query in six launches
 * (the status reset included), over a grid of two levels.
 *
 * Pair (a, b), a < b, is written by its owner a into a's slice of the pair
 * buffer, and the slices are in body order, so the list comes out sorted by
 * (a, b) with no global sort. The query, one kernel per global dependency:
 *
 *   measure_grid_bodies   the status reset, per-group sums of log2 sizes, and
 *                         the reset of the bucket lists and size statistics;
 *   classify_grid_bodies  validation; the geometric mean g from those sums
 *                         sorts each body into a level (below); the largest
 *                         body of each grid level (an atomic max) sets that
 *                         level's cell;
 *   link_bucket_bodies    each grid body joins the linked list of its lower
 *                         corner's bucket in its level (cells.cl.mako), a fine
 *                         body also a list of the coarse cells: no sort, no
 *                         scan;
 *   count_owned_pairs     per body (index order): the pairs it owns, their
 *                         prefix sum inside the work group and its total;
 *   place_owner_slices    one work group: the group totals become group
 *                         offsets, and the pair count is published;
 *   write_owned_pairs     the same visit again, storing each owner's pairs
 *                         from its offset and sorting its short slice.
 *
 * Levels (size: the largest side of the AABB, SMALL_SLACK as in is_small):
 *   fine    size * SMALL_SLACK <= fine_factor * g: cells of side
 *           SMALL_SLACK x the largest fine size;
 *   coarse  the other bodies with size * SMALL_SLACK <= large_factor * g:
 *           cells of side SMALL_SLACK x the largest coarse size (empty when
 *           every body is fine, e.g. equal sizes: then the query is the
 *           one-level grid's, with no coarse list filled or read);
 *   large   the rest and shared static geometry: the large-body list.
 * Three bucket tables (the same folding, grid_dim^3 buckets each) hold lists:
 *   FINE_TABLE    fine bodies by fine cell      (links in next_body);
 *   COARSE_TABLE  coarse bodies by coarse cell  (links in next_body);
 *   SPLIT_TABLE   fine bodies by coarse cell    (links in next_split; filled
 *                 only when the coarse level is not empty).
 *
 * Contract: the owner finds every pair it owns exactly once.
 *   - A fine owner walks FINE_TABLE in fine cells (fine partners) and
 *     COARSE_TABLE in coarse cells (coarse partners).
 *   - A coarse owner walks COARSE_TABLE and SPLIT_TABLE in coarse cells
 *     (coarse and fine partners).
 *   - Every grid owner tests the large bodies of higher index.
 *   - The cells walked in a table are those from one below the cell of the
 *     owner's lower corner to the cell of its upper corner on each axis:
 *     the partners filed there are no larger than a cell, so an overlapping
 *     one has its lower corner at most one cell below the owner's and none
 *     above the owner's upper corner; the owner is no larger than a cell
 *     either, so that is 2 or 3 cells a side.
 * Each body is filed once in each table it appears in, and each pair kind
 * (fine-fine, fine-coarse, coarse-fine, coarse-coarse) is read from exactly
 * one table by exactly one side, its lower body: the owner takes partners of
 * higher index only. With grid_dim >= 3 the at most 3 cells a side fall in
 * distinct buckets, so no list is walked twice.
 *
 * A large body (at most LARGE_ROWS, else status->retry asks for slot
 * emission) owns its pairs with every body of higher index: each such body
 * sets bit t of its "row mask" when large body t owns a pair with it, and its
 * rank in the owner's slice is the prefix count of bit t over the bodies
 * (work-group scans plus group offsets). The order inside the bucket lists
 * varies between runs; the pair list does not.
 *
 * Environments (a WorldBatch: static_flags holds collision words, env << 1 |
 * static) overlap in space, so each files its grid bodies, in both levels, in
 * cells displaced by a hash of its index (env_cell): overlapping environments
 * then share few buckets, and pairs across them are rarely even visited.
 * Shared static geometry is always large (every environment's bodies meet it
 * in the large list).
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
/* A body's level (body_levels). */
#define FINE 0u
#define COARSE 1u
#define LARGE 2u
/* The bucket tables, one after the other in bucket_heads (see the header). */
#define FINE_TABLE 0u
#define COARSE_TABLE 1u
#define SPLIT_TABLE 2u
/* The size statistics (grid_sizes): the bits of the largest fine and coarse
 * sizes (0: the level is empty). */
#define LARGEST_FINE 0
#define LARGEST_COARSE 1
#define GRID_SIZES 2
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

/* The first bucket of table `table` in bucket_heads. */
inline uint table_start(uint table, int grid_dim)
{
    return table * (uint)(grid_dim * grid_dim * grid_dim);
}

/* Exclusive prefix sum of one uint per work-item over the group (the group's
 * sum in *total); every work-item of the group must call it. */
inline uint group_exclusive_scan(uint value, __local uint* scratch, uint* total)
{
    return work_group_exclusive_scan_uint(value, scratch, scratch + 2 * WG, total);
}

/* Starts the query: resets the status, sums the clamped log2 sizes (one
 * partial sum per work group), empties the bucket lists of every table
 * (bucket_count buckets in all) and resets the statistics the next kernel
 * gathers. The launch has at most as many work
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
                         __global uint* grid_sizes,
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
        for (int k = 0; k < GRID_SIZES; ++k)
            grid_sizes[k] = 0;  /* the bits of 0.0f */
    }
}

/* Validates every AABB (a NaN bound or lower > upper records the lowest such
 * body in status->bad_body) and sorts the bodies into levels (see the header)
 * by the geometric mean size, which every work group sums from the same
 * partials in the same order: body_levels[i] is FINE, COARSE or LARGE; large
 * bodies join the large-body list (status->retry past LARGE_ROWS of them);
 * the largest size of each grid level reaches grid_sizes by one atomic max
 * per work group (non-negative floats order like their bits). A work group
 * is responsible for WG consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void classify_grid_bodies(__global const Aabb* aabbs,
                          __global const uint* static_flags,
                          const uint body_count,
                          __global const float* log_size_partials,
                          const uint partial_count,
                          const float fine_factor,
                          const float large_factor,
                          __global uint* body_levels,
                          __global uint* large_count,
                          __global uint* large_bodies,
                          __global uint* grid_sizes,
                          __global BroadphaseStatus* status)
{
    __local float scratch[WG];
    float log_sum = 0.0f;
    for (uint k = get_local_id(0); k < partial_count; k += WG)
        log_sum += log_size_partials[k];
    log_sum = work_group_sum_float(log_sum, scratch);
    float scale = size_scale(log_sum, body_count, large_factor);
    float fine_scale = size_scale(log_sum, body_count, fine_factor);

    uint i = get_global_id(0);
    float fine_size = 0.0f, coarse_size = 0.0f;
    if (i < body_count) {
        float3 lower = aabbs[i].lower.xyz, upper = aabbs[i].upper.xyz;
        /* Comparisons with NaN are false, so this also catches NaN bounds. */
        if (!all(lower <= upper))
            atomic_min(&status->bad_body, i);
        float size = box_size(lower, upper);
        bool small = is_small(size, scale) && static_flags[i] != RB_SHARED_STATIC;
        bool fine = small && is_small(size, fine_scale);
        body_levels[i] = fine ? FINE : small ? COARSE : LARGE;
        if (fine) {
            fine_size = fmax(size, 0.0f);  /* an inverted box is reported, not sized */
        } else if (small) {
            coarse_size = size;
        } else {
            uint row = atomic_inc(large_count);
            if (row < LARGE_ROWS)
                large_bodies[row] = i;
            else
                status->retry = RB_BP_RETRY_LARGE;
        }
    }
    fine_size = work_group_max_float(fine_size, scratch);
    coarse_size = work_group_max_float(coarse_size, scratch);
    if (get_local_id(0) == 0) {
        atomic_max(&grid_sizes[LARGEST_FINE], as_uint(fine_size));
        if (coarse_size > 0.0f)
            atomic_max(&grid_sizes[LARGEST_COARSE], as_uint(coarse_size));
    }
}

/* Puts each grid body at the head of its bucket's list in its level's table
 * (next_body links the rest), and a fine body also at the head of its coarse
 * cell's list in SPLIT_TABLE (next_split) when the coarse level is not empty.
 * A work group is responsible for WG consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void link_bucket_bodies(__global const Aabb* aabbs,
                        __global const uint* static_flags,
                        const uint body_count,
                        const int grid_dim,
                        __global const uint* body_levels,
                        __global const uint* grid_sizes,
                        __global uint* bucket_heads,
                        __global uint* next_body,
                        __global uint* next_split)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    uint level = body_levels[i];
    if (level == LARGE)
        return;
    float3 lower = aabbs[i].lower.xyz;
    uint word = static_flags[i];
    uint coarse_bits = grid_sizes[LARGEST_COARSE];
    float coarse_cell = grid_cell_size(as_float(coarse_bits));
    float own_cell = level == FINE ? grid_cell_size(as_float(grid_sizes[LARGEST_FINE]))
                                   : coarse_cell;
    uint table = level == FINE ? FINE_TABLE : COARSE_TABLE;
    uint bucket = bucket_of(env_cell(cell_of(lower, own_cell), word), grid_dim);
    next_body[i] = atomic_xchg(&bucket_heads[table_start(table, grid_dim) + bucket], i);
    if (level == FINE && coarse_bits != 0) {
        bucket = bucket_of(env_cell(cell_of(lower, coarse_cell), word), grid_dim);
        next_split[i] = atomic_xchg(&bucket_heads[table_start(SPLIT_TABLE, grid_dim) + bucket], i);
    }
}

<%def name="visit_arguments()">\
                       __global const Aabb* aabbs,
                       __global const uint* static_flags,
                       const uint body_count,
                       const int grid_dim,
                       __global const uint* body_levels,
                       __global const uint* grid_sizes,
                       __global const uint* bucket_heads,
                       __global const uint* next_body,
                       __global const uint* next_split,
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

/* Walks the bucket list from `head` (links in `next`) for the partners of
 * `self` (box lower..upper): higher index, boxes overlapping, pair allowed.
 * Returns their number; with `pairs` (not null) also stores them from slot
 * `at` on. */
inline uint walk_bucket_list(__global const Aabb* aabbs,
                             __global const uint* static_flags,
                             __global const uint* next,
                             uint head,
                             uint self,
                             float3 lower,
                             float3 upper,
                             __global Pair* pairs,
                             uint at,
                             uint capacity)
{
    uint found = 0;
    for (uint other = head; other != NO_BODY; other = next[other]) {
        if (other > self && pair_allowed(static_flags, self, other)
            && boxes_overlap(lower, upper, aabbs[other].lower.xyz, aabbs[other].upper.xyz)) {
            if (pairs)
                store_owned_pair(pairs, capacity, at + found, self, other);
            ++found;
        }
    }
    return found;
}

/* The cells, in a grid of side `side`, that can hold the lower corner of a
 * body of that grid's level overlapping box lower..upper (of a body filed in
 * that grid or a finer one): from one below the lower corner's cell to the
 * upper corner's on each axis, 2 or 3 a side. Returns the first, folded
 * (the env_cell of a body of collision word `word`); *span is 0 or 1 a side:
 * the cells after it. */
inline int3 cells_to_visit(float3 lower, float3 upper, float side, uint word, int grid_dim,
                           int3* span)
{
    int3 low = env_cell(cell_of(lower, side), word);
    *span = clamp(env_cell(cell_of(upper, side), word) - low, (int3)(0), (int3)(1));
    return folded_cell(low, grid_dim);
}

/* Walks the lists of one bucket table (links in `next`) in the cells from
 * one below folded cell `home` to `home` + `span` on each axis (see
 * cells_to_visit); as walk_bucket_list. */
inline uint walk_cells(__global const Aabb* aabbs,
                       __global const uint* static_flags,
                       const int grid_dim,
                       __global const uint* table_heads,
                       __global const uint* next,
                       int3 home,
                       int3 span,
                       uint self,
                       float3 lower,
                       float3 upper,
                       __global Pair* pairs,
                       uint at,
                       uint capacity)
{
    /* The list heads first: independent loads, in flight together. */
    uint heads[27];
    for (int neighbour = 0; neighbour < 27; ++neighbour)
        heads[neighbour] = all(neighbour_offset(neighbour) <= span)
                               ? table_heads[neighbour_bucket(home, neighbour, grid_dim)]
                               : NO_BODY;
    uint found = 0;
    for (int neighbour = 0; neighbour < 27; ++neighbour)
        found += walk_bucket_list(aabbs, static_flags, next, heads[neighbour], self, lower, upper,
                                  pairs, at + found, capacity);
    return found;
}

/* The pairs grid body `self` owns (the header's contract): partners of higher
 * index in the cells of its level and the other level, and among the large
 * bodies, boxes overlapping, not both static. Returns their number; with
 * `pairs` (not null) also stores them from slot `first` on, in visiting
 * order. */
inline uint visit_owned_partners(__global const Aabb* aabbs,
                                 __global const uint* static_flags,
                                 const int grid_dim,
                                 uint level,
                                 __global const uint* grid_sizes,
                                 __global const uint* bucket_heads,
                                 __global const uint* next_body,
                                 __global const uint* next_split,
                                 uint large_total,
                                 __global const uint* large_bodies,
                                 uint self,
                                 __global Pair* pairs,
                                 uint first,
                                 uint capacity)
{
    float3 lower = aabbs[self].lower.xyz, upper = aabbs[self].upper.xyz;
    uint word = static_flags[self];
    uint coarse_bits = grid_sizes[LARGEST_COARSE];
    float coarse_cell = grid_cell_size(as_float(coarse_bits));
    uint found = 0;
    int3 span;
    if (level == FINE) {
        float fine_cell = grid_cell_size(as_float(grid_sizes[LARGEST_FINE]));
        int3 home = cells_to_visit(lower, upper, fine_cell, word, grid_dim, &span);
        found += walk_cells(aabbs, static_flags, grid_dim,
                            bucket_heads + table_start(FINE_TABLE, grid_dim), next_body, home,
                            span, self, lower, upper, pairs, first, capacity);
        if (coarse_bits != 0) {
            home = cells_to_visit(lower, upper, coarse_cell, word, grid_dim, &span);
            found += walk_cells(aabbs, static_flags, grid_dim,
                                bucket_heads + table_start(COARSE_TABLE, grid_dim), next_body,
                                home, span, self, lower, upper, pairs, first + found, capacity);
        }
    } else {
        int3 home = cells_to_visit(lower, upper, coarse_cell, word, grid_dim, &span);
        found += walk_cells(aabbs, static_flags, grid_dim,
                            bucket_heads + table_start(COARSE_TABLE, grid_dim), next_body, home,
                            span, self, lower, upper, pairs, first, capacity);
        found += walk_cells(aabbs, static_flags, grid_dim,
                            bucket_heads + table_start(SPLIT_TABLE, grid_dim), next_split, home,
                            span, self, lower, upper, pairs, first + found, capacity);
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
 * sort: the slices of grid owners are short). */
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

/* Counts the pairs each grid body owns and their exclusive prefix sum inside
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
        uint level = body_levels[i];
        if (level != LARGE)
            found = visit_owned_partners(aabbs, static_flags, grid_dim, level, grid_sizes,
                                         bucket_heads, next_body, next_split, large_total,
                                         large_bodies, i, 0, 0, 0);
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
 * become the first slot of each counting group (grid owners) and each row
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

/* Writes the pairs each grid body owns into its slice and sorts the slice,
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
        uint level = body_levels[i];
        if (level != LARGE) {
            uint first = group_starts[group] + in_group_offsets[i];
            for (uint row = 0; row < large_total; ++row)
                if (large_bodies[row] < i)
                    first += owner_counts[row];
            uint found = visit_owned_partners(aabbs, static_flags, grid_dim, level, grid_sizes,
                                              bucket_heads, next_body, next_split, large_total,
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
