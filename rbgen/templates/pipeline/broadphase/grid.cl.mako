/* Uniform-grid broadphase.
 *
 * Small bodies live in the cell of their lower corner. The cell side is at
 * least the size of every small body, so two overlapping small bodies sit in
 * the same or adjacent cells: each body visits the 27 cells around its own
 * and pairs with the bodies of higher index found there. Cells are folded
 * into a table of grid_dim^3 buckets (coordinates modulo grid_dim >= 3), so
 * the 27 buckets visited are distinct and each candidate is met once;
 * bodies of far cells folded into the same bucket fail the box test. Large
 * bodies (see common.cl.mako) are tested separately: every small body tests
 * each large one, and a large body tests the large ones of higher index.
 *
 * Counting and writing are two kernels over the same visit: a scan of the
 * counts gives every body its slice of the pair buffer, so the output order
 * depends only on the input, and a full buffer never loses a count.
 */
${cl_constants()}

${cl_structs("Aabb", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>
<%namespace name="large" file="/pipeline/broadphase/large.mako"/>

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

/* Sort keys: the bucket of each small body, bucket_count (past every bucket)
 * for large bodies, which also get a flag for the large-body list. A work
 * group is responsible for ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void bucket_bodies(__global const Aabb* aabbs,
                   const uint body_count,
                   __global const float* log_size_sum,
                   const float cell_factor,
                   const int grid_dim,
                   __global uint* bucket_keys,
                   __global uint* bucket_bodies,
                   __global uint* large_flags)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    float cell_size = size_scale(log_size_sum[0], body_count, cell_factor);
    float3 lower = aabbs[i].lower.xyz;
    bool small = is_small(box_size(lower, aabbs[i].upper.xyz), cell_size);
    uint bucket_count = (uint)(grid_dim * grid_dim * grid_dim);
    bucket_keys[i] = small ? bucket_of(cell_of(lower, cell_size), grid_dim) : bucket_count;
    bucket_bodies[i] = i;
    large_flags[i] = small ? 0u : 1u;
}

<%def name="visit_pairs(setup)">\
    uint slot = get_global_id(0);
    if (slot >= body_count)
        return;
    ${setup}
    uint self_index = sorted_bodies[slot];
    float3 lower = aabbs[self_index].lower.xyz;
    float3 upper = aabbs[self_index].upper.xyz;
    bool small = sorted_keys[slot] < (uint)(grid_dim * grid_dim * grid_dim);

    if (small) {
        /* Small neighbours: the 27 buckets around this body's cell. */
        float cell_size = size_scale(log_size_sum[0], body_count, cell_factor);
        int3 home = cell_of(lower, cell_size);
        for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            uint bucket = bucket_of(home + (int3)(dx, dy, dz), grid_dim);
            uint last = bucket_start[bucket + 1];
            for (uint k = bucket_start[bucket]; k < last; ++k) {
                uint other = sorted_bodies[k];
                if (other > self_index && pair_allowed(static_flags, self_index, other)
                    && boxes_overlap(lower, upper, aabbs[other].lower.xyz, aabbs[other].upper.xyz)) {
                    uint a = self_index, b = other;
                    ${caller.body()}
                }
            }
        }
    }

    /* Large bodies (see large.mako). */
<%large:visit_large_bodies>
${caller.body()}
</%large:visit_large_bodies>
</%def>

<%def name="visit_arguments()">\
__global const Aabb* aabbs,
                     __global const uint* static_flags,
                     const uint body_count,
                     __global const float* log_size_sum,
                     const float cell_factor,
                     const int grid_dim,
                     __global const uint* sorted_keys,
                     __global const uint* sorted_bodies,
                     __global const uint* bucket_start,
                     __global const uint* large_bodies,
                     __global const uint* large_count\
</%def>

/* Counts the pairs each body owns; one work-item per body in bucket order, a
 * work group is responsible for ${work_group_size} consecutive sorted bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void count_grid_pairs(${visit_arguments()},
                      __global uint* pair_counts)
{
<%self:visit_pairs setup="uint found = 0;">
                    ++found;
</%self:visit_pairs>
    pair_counts[slot] = found;
}

/* Writes the pairs each body owns from its scanned offset; pairs past the
 * capacity are counted but not stored (the host grows the buffer and runs the
 * query again). Work item 0 publishes the totals. A work group is responsible
 * for ${work_group_size} consecutive sorted bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void write_grid_pairs(${visit_arguments()},
                      __global const uint* pair_offsets,
                      __global const uint* pairs_found,
                      const uint capacity,
                      __global uint* pairs_a,
                      __global uint* pairs_b,
                      __global BroadphaseStatus* status)
{
    if (get_global_id(0) == 0) {
        status->pairs_found = pairs_found[0];
        status->pair_count = min(pairs_found[0], capacity);
    }
<%self:visit_pairs setup="uint next = pair_offsets[slot];">
                    if (next < capacity) {
                        pairs_a[next] = a;
                        pairs_b[next] = b;
                    }
                    ++next;
</%self:visit_pairs>
}
