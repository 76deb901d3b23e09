/* Uniform-grid broadphase.
 *
 * Small bodies live in the cell of their lower corner. The cell side is at
 * least the size of every small body (SMALL_SLACK times the largest), so two
 * overlapping small bodies sit in the same or adjacent cells. A body pairs
 * with the bodies of higher index in its own cell and with every body in the
 * 13 "forward" neighbour cells (offsets after (0, 0, 0) in z, y, x order):
 * of two bodies in different adjacent cells exactly one sees the other's
 * cell as forward, so each pair is met once.
 *
 * Cells are folded into a table of grid_dim^3 buckets (coordinates modulo
 * grid_dim >= 3), so the buckets around a cell are distinct; a body of a far
 * cell folded into a visited bucket cannot overlap (its true cell would be a
 * neighbour with the same bucket) and fails the box test. Large bodies (see
 * common.cl.mako) sort after every bucket and are tested as a list (visit.mako).
 *
 * Counting and writing are two kernels over the same visit: a scan of the
 * counts gives every body its slice of the pair buffer, so the output order
 * depends only on the input, and a full buffer never loses a count.
% if emission == "owner":
 *
 * Owner emission: pair (a, b) is written by its owner a into a's slice (slices
 * in body order), so the list comes out sorted by (a, b) with no global sort.
 * A small owner visits all 27 cells around its own for partners of higher
 * index and sorts its short slice. The slices of the large owners (at most
 * ${large_rows}) come from one row of flags per large body, set in parallel
 * over all partners and scanned; with more large bodies the query asks to be
 * redone with slot emission.
% else:
 *
 * Slot emission: the pairs of each body in bucket order (own cell: partners
 * of higher index, forward cells: all), ordered afterwards by a global sort.
% endif
 */
${cl_constants()}

${cl_structs("Aabb", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>
<%namespace name="visit" file="/pipeline/broadphase/visit.mako"/>
<%!
    def dedent(text):
        """Shift generated lines one level (4 spaces) left."""
        return "\n".join(line[4:] if line.startswith("    ") else line for line in text.split("\n"))
%>

/* Neighbour m of the 27 cells around a cell, m = 9 (dz + 1) + 3 (dy + 1) + (dx + 1):
 * m = 13 is the cell itself, m > 13 the 13 cells after it in (z, y, x) order. */
inline int3 neighbour_offset(int m)
{
    return (int3)(m % 3 - 1, m / 3 % 3 - 1, m / 9 - 1);
}

% if emission == "owner":
/* Rows of the large-owner flag matrix: the most large bodies handled. */
#define LARGE_ROWS ${large_rows}

% endif
/* Side of the grid cells: a little more than the largest small body. */
inline float grid_cell_size(float largest_small_size)
{
    return fmax(SMALL_SLACK * largest_small_size, FLT_MIN);
}

/* Cell of a point; saturating, so far-away points share the border cells
 * (which keeps neighbours neighbours). */
inline int3 cell_of(float3 point, float cell_size)
{
    return convert_int3_sat_rtn(floor(point / cell_size));
}

/* Bucket of a cell: its coordinates modulo grid_dim, linearised. */
inline uint bucket_of(int3 cell, int grid_dim)
{
    int3 folded = (cell % grid_dim + grid_dim) % grid_dim;
    return ((uint)folded.z * (uint)grid_dim + (uint)folded.y) * (uint)grid_dim + (uint)folded.x;
}

/* Flags large bodies (larger than large_factor times the geometric mean
 * size) and writes the size of each small body (0 for large ones), which
 * Reduce turns into the cell size. Large bodies sort after every bucket, so
 * the sorted list ends with the large-body list. A work group is responsible for
 * ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void classify_sizes(__global const Aabb* aabbs,
                    const uint body_count,
                    __global const float* log_size_sum,
                    const float large_factor,
                    __global float* small_sizes,
                    __global uint* large_flags)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    float size = box_size(aabbs[i].lower.xyz, aabbs[i].upper.xyz);
    bool small = is_small(size, size_scale(log_size_sum[0], body_count, large_factor));
    small_sizes[i] = small ? size : 0.0f;
    large_flags[i] = small ? 0u : 1u;
}

/* The bucket of a body: that of its lower corner's cell, or bucket_count
 * (past every bucket) for a large body. */
inline uint bucket_key(float3 lower, bool large, float cell_size, int grid_dim)
{
    return large ? (uint)(grid_dim * grid_dim * grid_dim)
                 : bucket_of(cell_of(lower, cell_size), grid_dim);
}

% if bucketing == "sort":
/* Sort keys (buckets) and values (body indices) for the radix sort. A work
 * group is responsible for ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void bucket_bodies(__global const Aabb* aabbs,
                   const uint body_count,
                   __global const uint* large_flags,
                   __global const float* largest_small_size,
                   const int grid_dim,
                   __global uint* bucket_keys,
                   __global uint* bucket_bodies)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    bucket_keys[i] = bucket_key(aabbs[i].lower.xyz, large_flags[i] != 0,
                                grid_cell_size(largest_small_size[0]), grid_dim);
    bucket_bodies[i] = i;
}

/* Boxes in bucket order, body index in lower.w, so that a bucket's boxes are
 * contiguous. A work group is responsible for ${work_group_size} positions. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void gather_sorted(__global const Aabb* aabbs,
                   const uint body_count,
                   __global const uint* sorted_bodies,
                   __global Aabb* sorted_boxes)
{
    uint p = get_global_id(0);
    if (p >= body_count)
        return;
    uint body = sorted_bodies[p];
    Aabb box = aabbs[body];
    box.lower.w = as_float(body);
    sorted_boxes[p] = box;
}
% else:
/* Counting sort, first pass: the bucket of each body and the size of every
 * bucket (bucket_sizes must be zero before). A work group is responsible for
 * ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void count_bucket_bodies(__global const Aabb* aabbs,
                         const uint body_count,
                         __global const uint* large_flags,
                         __global const float* largest_small_size,
                         const int grid_dim,
                         __global uint* bucket_keys,
                         __global uint* bucket_sizes)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    uint key = bucket_key(aabbs[i].lower.xyz, large_flags[i] != 0,
                          grid_cell_size(largest_small_size[0]), grid_dim);
    bucket_keys[i] = key;
    atomic_inc(&bucket_sizes[key]);
}

/* Counting sort, second pass: each body takes the next free position of its
 * bucket (cursors start at the scanned bucket starts), writing its key and
 * its box with the body index in lower.w. The order inside a bucket varies
 * between runs; the pairs do not, since they are ordered afterwards. A work
 * group is responsible for ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void scatter_bucket_bodies(__global const Aabb* aabbs,
                           const uint body_count,
                           __global const uint* bucket_keys,
                           __global uint* bucket_cursors,
                           __global uint* sorted_keys,
                           __global Aabb* sorted_boxes)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    uint key = bucket_keys[i];
    uint position = atomic_inc(&bucket_cursors[key]);
    Aabb box = aabbs[i];
    box.lower.w = as_float(i);
    sorted_keys[position] = key;
    sorted_boxes[position] = box;
}
% endif

/* The bodies of one bucket that pair with the visiting body: those passing
 * `accept` (a condition on `other`) whose boxes overlap. */
<%def name="visit_bucket(mode, accept)">\
            for (uint k = bucket_start[bucket]; k < bucket_start[bucket + 1]; ++k) {
                float4 other_lower = sorted_boxes[k].lower;
                uint other = as_uint(other_lower.w);
                if (${accept}pair_allowed(static_flags, self_index, other)
                    && boxes_overlap(lower, upper, other_lower.xyz, sorted_boxes[k].upper.xyz))
                    ${visit.emit(mode, "self_index", "other")}
            }
</%def>

<%def name="grid_arguments()">\
        __global const Aabb* aabbs,
        __global const uint* static_flags,
        const uint body_count,
        __global const float* largest_small_size,
        const int grid_dim,
        __global const uint* sorted_keys,
        __global const Aabb* sorted_boxes,
        __global const uint* bucket_start,\
</%def>

% if emission == "slot":
<%def name="grid_kernel(mode)">\
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void ${mode}_grid_pairs(
${grid_arguments()}
% if mode == "count":
${visit.count_arguments()})
% else:
${visit.write_arguments()})
% endif
{
% if mode == "write":
${visit.publish_totals()}
% endif
    uint slot = get_global_id(0);
    if (slot >= body_count)
        return;
    ${visit.start(mode)}
    Aabb self_box = sorted_boxes[slot];
    uint self_index = as_uint(self_box.lower.w);
    float3 lower = self_box.lower.xyz, upper = self_box.upper.xyz;
    uint bucket_count = (uint)(grid_dim * grid_dim * grid_dim);
    bool small = sorted_keys[slot] < bucket_count;

    if (small) {
        int3 home = cell_of(lower, grid_cell_size(largest_small_size[0]));
        /* Own cell: bodies of higher index. */
        {
            uint bucket = bucket_of(home, grid_dim);
${visit_bucket(mode, "other > self_index && ")}\
        }
        /* Forward neighbour cells: every body. */
        for (int neighbour = 14; neighbour < 27; ++neighbour) {
            uint bucket = bucket_of(home + neighbour_offset(neighbour), grid_dim);
${visit_bucket(mode, "")}\
        }
    }

    /* Large bodies: sorted after every bucket, in index order. */
${visit.visit_large_bodies(mode, "bucket_start[bucket_count]", "body_count", "Aabb other_box = sorted_boxes[k];\n        uint other = as_uint(other_box.lower.w);")}\
% if mode == "count":
    pair_counts[slot] = found;
% endif
}
</%def>

/* Counts the pairs each body owns, one work-item per body in bucket order;
 * a work group is responsible for ${work_group_size} consecutive sorted bodies. */
${grid_kernel("count")}

/* Writes the pairs each body owns from its scanned offset; a work group is
 * responsible for ${work_group_size} consecutive sorted bodies. */
${grid_kernel("write")}
% else:
/* Sorts the partners b of one owner in slots [first, end) (insertion sort:
 * the slices of small owners are short). */
inline void sort_owner_slice(__global uint* pairs_b, uint first, uint end, uint capacity)
{
    end = min(end, capacity);
    for (uint k = first + 1; k < end; ++k) {
        uint partner = pairs_b[k];
        uint m = k;
        for (; m > first && pairs_b[m - 1] > partner; --m)
            pairs_b[m] = pairs_b[m - 1];
        pairs_b[m] = partner;
    }
}

<%def name="owner_kernel(mode)">\
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void ${mode}_owned_pairs(
${grid_arguments()}
% if mode == "count":
${visit.count_arguments()})
% else:
${visit.write_arguments()})
% endif
{
% if mode == "write":
${visit.publish_totals()}
% endif
    uint slot = get_global_id(0);
    if (slot >= body_count)
        return;
    Aabb self_box = sorted_boxes[slot];
    uint self_index = as_uint(self_box.lower.w);
    uint bucket_count = (uint)(grid_dim * grid_dim * grid_dim);
    bool small = sorted_keys[slot] < bucket_count;
    if (!small) {
% if mode == "count":
        pair_counts[self_index] = 0;  /* counted from its flag row */
% endif
        return;
    }
    ${visit.start(mode, "self_index")}
    float3 lower = self_box.lower.xyz, upper = self_box.upper.xyz;
    int3 home = cell_of(lower, grid_cell_size(largest_small_size[0]));
    for (int neighbour = 0; neighbour < 27; ++neighbour) {
        uint bucket = bucket_of(home + neighbour_offset(neighbour), grid_dim);
${dedent(capture(visit_bucket, mode, "other > self_index && "))}\
    }

    /* Large partners of higher index (those of lower index own the pair). */
${visit.visit_large_bodies(mode, "bucket_start[bucket_count]", "body_count", "Aabb other_box = sorted_boxes[k];\n        uint other = as_uint(other_box.lower.w);", "other > self_index")}\
% if mode == "count":
    pair_counts[self_index] = found;
% else:
    sort_owner_slice(pairs_b, pair_offsets[self_index], next, capacity);
% endif
}
</%def>

/* Counts the pairs each small body owns (partners of higher index); one
 * work-item per body in bucket order, a work group is responsible for
 * ${work_group_size} consecutive sorted bodies. */
${owner_kernel("count")}

/* Writes the pairs each small body owns into its slice and sorts the slice;
 * a work group is responsible for ${work_group_size} consecutive sorted
 * bodies. */
${owner_kernel("write")}

/* Row t, entry j of the large-owner flags: whether the t-th large body owns
 * a pair with body j (j of higher index, boxes overlap, not both static).
 * Rows past the large-body count are zero; more large bodies than rows sets
 * status->retry. One work-item per entry; a work group is responsible for
 * ${work_group_size} entries of a row. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void flag_large_owner_pairs(__global const Aabb* aabbs,
                            __global const uint* static_flags,
                            const uint body_count,
                            const int grid_dim,
                            __global const Aabb* sorted_boxes,
                            __global const uint* bucket_start,
                            __global uint* flags,
                            __global BroadphaseStatus* status)
{
    uint entry = get_global_id(0);
    uint large_first = bucket_start[grid_dim * grid_dim * grid_dim];
    uint large_total = body_count - large_first;
    if (entry == 0 && large_total > LARGE_ROWS)
        status->retry = RB_BP_RETRY_LARGE;
    if (entry >= LARGE_ROWS * body_count)
        return;
    uint row = entry / body_count, partner = entry % body_count;
    bool owned = false;
    if (row < large_total) {
        Aabb owner_box = sorted_boxes[large_first + row];
        uint owner = as_uint(owner_box.lower.w);
        owned = partner > owner && pair_allowed(static_flags, owner, partner)
                && boxes_overlap(owner_box.lower.xyz, owner_box.upper.xyz,
                                 aabbs[partner].lower.xyz, aabbs[partner].upper.xyz);
    }
    flags[entry] = owned ? 1u : 0u;
}

/* The pair count of each large owner: its row's flag total (from the
 * exclusive scan of the flags). A work group is responsible for
 * ${work_group_size} rows. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void count_large_owner_pairs(const uint body_count,
                             const int grid_dim,
                             __global const Aabb* sorted_boxes,
                             __global const uint* bucket_start,
                             __global const uint* flags,
                             __global const uint* flag_ranks,
                             __global uint* pair_counts)
{
    uint row = get_global_id(0);
    uint large_first = bucket_start[grid_dim * grid_dim * grid_dim];
    if (row >= min(body_count - large_first, (uint)LARGE_ROWS))
        return;
    uint first = row * body_count, last = first + body_count - 1;
    uint owner = as_uint(sorted_boxes[large_first + row].lower.w);
    pair_counts[owner] = flag_ranks[last] + flags[last] - flag_ranks[first];
}

/* Writes the flagged pairs of the large owners into their slices, in partner
 * order (the scanned flags rank them). One work-item per flag; a work group
 * is responsible for ${work_group_size} entries of a row. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void write_large_owner_pairs(const uint body_count,
                             const int grid_dim,
                             __global const Aabb* sorted_boxes,
                             __global const uint* bucket_start,
                             __global const uint* flags,
                             __global const uint* flag_ranks,
                             __global const uint* pair_offsets,
                             const uint capacity,
                             __global uint* pairs_a,
                             __global uint* pairs_b)
{
    uint entry = get_global_id(0);
    if (entry >= LARGE_ROWS * body_count || !flags[entry])
        return;
    uint row = entry / body_count, partner = entry % body_count;
    uint large_first = bucket_start[grid_dim * grid_dim * grid_dim];
    uint owner = as_uint(sorted_boxes[large_first + row].lower.w);
    uint at = pair_offsets[owner] + flag_ranks[entry] - flag_ranks[row * body_count];
    store_pair(pairs_a, pairs_b, capacity, at, owner, partner);
}
% endif
