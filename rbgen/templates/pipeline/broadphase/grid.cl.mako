/* Uniform-grid broadphase, slot emission over buckets in sorted order.
 *
 * Cells and buckets: see cells.cl.mako. A body pairs with the bodies of
 * higher index in its own cell and with every body in the 13 "forward"
 * neighbour cells (offsets after (0, 0, 0) in z, y, x order): of two bodies
 * in different adjacent cells exactly one sees the other's cell as forward,
 * so each pair is met once. Large bodies (see common.cl.mako) sort after
 * every bucket and are tested as a list (visit.mako).
 *
 * Counting and writing are two kernels over the same visit: a scan of the
 * counts gives every body slot its slice of the pair buffer, and a full
 * buffer never loses a count; the pair buffer then sorts the pairs by (a, b).
 * (The owner emission of GPUs is grid_owner.cl.mako.)
 */
${cl_constants()}

${cl_structs("Aabb", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>
<%include file="/pipeline/broadphase/cells.cl.mako"/>
<%namespace name="visit" file="/pipeline/broadphase/visit.mako"/>

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
