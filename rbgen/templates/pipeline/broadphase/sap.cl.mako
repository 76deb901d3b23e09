/* One-axis sweep and prune (${shape} shape).
 *
 * Small bodies are sorted by their lower bound on the axis along which their
 * centres vary most; body p then sweeps forward through the sorted list while
 * the next lower bound is not above its own upper bound, testing the full box
 * of each body met. Large bodies (see common.cl.mako) stay out of the sweep
 * and are tested through the large-body list. Sorted boxes are stored with
 * the sweep axis rotated into x and the body index in lower.w, so the sweep
 * reads one contiguous array.
% if shape == "gpu":
 *
 * GPU shape: a work group sweeps ${work_group_size} consecutive sorted bodies
 * together, staging tiles of the following sorted boxes in local memory until
 * every sweep of the group has ended.
% else:
 *
 * CPU shape: every work-item sweeps through global memory on its own (the
 * cache holds the neighbourhood); no barriers.
% endif
 */
${cl_constants()}

${cl_structs("Aabb", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>
<%namespace name="visit" file="/pipeline/broadphase/visit.mako"/>

/* Order-preserving map of a float to a uint (negative values reversed). */
inline uint sortable_float(float value)
{
    uint bits = as_uint(value);
    return bits ^ ((bits >> 31) ? 0xFFFFFFFFu : 0x80000000u);
}

/* The box's coordinates with the sweep axis first (a rotation, so overlap
 * tests are unchanged). */
inline float4 sweep_frame(float4 v, uint axis)
{
    return axis == 0 ? v : axis == 1 ? (float4)(v.y, v.z, v.x, 0.0f) : (float4)(v.z, v.x, v.y, 0.0f);
}

/* Centres of small bodies and their squares (zero for large bodies), summed
 * by Reduce into the variance per axis; large bodies are flagged for the
 * large-body list. A work group is responsible for ${work_group_size} bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void measure_centres(__global const Aabb* aabbs,
                     const uint body_count,
                     __global const float* log_size_sum,
                     const float large_factor,
                     __global float* centre_x, __global float* centre_y, __global float* centre_z,
                     __global float* square_x, __global float* square_y, __global float* square_z,
                     __global uint* large_flags)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    float3 lower = aabbs[i].lower.xyz, upper = aabbs[i].upper.xyz;
    float scale = size_scale(log_size_sum[0], body_count, large_factor);
    bool small = is_small(box_size(lower, upper), scale);
    float3 centre = small ? 0.5f * (lower + upper) : (float3)(0.0f);
    centre_x[i] = centre.x; centre_y[i] = centre.y; centre_z[i] = centre.z;
    square_x[i] = centre.x * centre.x; square_y[i] = centre.y * centre.y;
    square_z[i] = centre.z * centre.z;
    large_flags[i] = small ? 0u : 1u;
}

/* Picks the axis of largest centre variance (written to sweep_axis[0] by
 * work-item 0) and writes the sort key of every body: its sortable lower
 * bound on that axis, or 0xFFFFFFFF for large bodies, which thus sort last.
 * A work group is responsible for ${work_group_size} bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sweep_keys(__global const Aabb* aabbs,
                const uint body_count,
                __global const uint* large_flags,
                __global const uint* large_count,
                __global const float* sum_x, __global const float* sum_y,
                __global const float* sum_z, __global const float* sum_xx,
                __global const float* sum_yy, __global const float* sum_zz,
                __global uint* sweep_axis,
                __global uint* keys,
                __global uint* bodies)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    float small_count = (float)max(body_count - large_count[0], 1u);
    float3 mean = (float3)(sum_x[0], sum_y[0], sum_z[0]) / small_count;
    float3 variance = (float3)(sum_xx[0], sum_yy[0], sum_zz[0]) / small_count - mean * mean;
    uint axis = variance.x >= variance.y && variance.x >= variance.z ? 0u
              : variance.y >= variance.z ? 1u : 2u;
    if (i == 0)
        sweep_axis[0] = axis;
    keys[i] = large_flags[i] ? 0xFFFFFFFFu : sortable_float(sweep_frame(aabbs[i].lower, axis).x);
    bodies[i] = i;
}

/* Sorted boxes in the sweep frame, body index in lower.w. A work group is
 * responsible for ${work_group_size} sorted positions. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void gather_sorted(__global const Aabb* aabbs,
                   const uint body_count,
                   __global const uint* sweep_axis,
                   __global const uint* sorted_bodies,
                   __global Aabb* sorted_boxes)
{
    uint p = get_global_id(0);
    if (p >= body_count)
        return;
    uint body = sorted_bodies[p], axis = sweep_axis[0];
    Aabb box;
    box.lower = sweep_frame(aabbs[body].lower, axis);
    box.upper = sweep_frame(aabbs[body].upper, axis);
    box.lower.w = as_float(body);
    sorted_boxes[p] = box;
}

<%def name="sweep_kernel(mode)">\
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void ${mode}_sweep_pairs(
        __global const Aabb* aabbs,
        __global const uint* static_flags,
        const uint body_count,
        __global const Aabb* sorted_boxes,
        __global const uint* large_bodies,
        __global const uint* large_count,
% if mode == "count":
${visit.count_arguments()})
% else:
${visit.write_arguments()})
% endif
{
% if mode == "write":
${visit.publish_totals()}
% endif
% if shape == "gpu":
    __local float4 tile_lower[${work_group_size}];
    __local float4 tile_upper[${work_group_size}];
    __local int tile_needed;
    uint lane = get_local_id(0);
    uint group_first = get_group_id(0) * ${work_group_size};
    /* Work-items past the end stay for the barriers, on a valid position. */
    uint slot = min((uint)get_global_id(0), body_count - 1);
% else:
    uint slot = get_global_id(0);
    if (slot >= body_count)
        return;
% endif
    ${visit.start(mode)}
    uint small_count = body_count - large_count[0];
    Aabb me = sorted_boxes[slot];
    uint self_index = as_uint(me.lower.w);
% if shape == "cpu":
    bool small = slot < small_count;
    if (small) {
        for (uint q = slot + 1; q < small_count; ++q) {
            Aabb next_box = sorted_boxes[q];
            if (next_box.lower.x > me.upper.x)
                break;
            uint other = as_uint(next_box.lower.w);
            if (boxes_overlap(me.lower.xyz, me.upper.xyz, next_box.lower.xyz, next_box.upper.xyz)
                && pair_allowed(static_flags, self_index, other))
                ${visit.emit(mode, "self_index", "other")}
        }
    }
% else:
    bool small = get_global_id(0) < small_count;
    /* Tiles of sorted boxes from the group's first body on, until no sweep
     * of the group needs more. Barriers keep every lane in the loop. */
    bool sweeping = small;
    for (uint tile = group_first; ; tile += ${work_group_size}) {
        if (lane == 0)
            tile_needed = 0;
        barrier(CLK_LOCAL_MEM_FENCE);
        if (sweeping)
            tile_needed = 1;
        if (tile + lane < small_count) {
            tile_lower[lane] = sorted_boxes[tile + lane].lower;
            tile_upper[lane] = sorted_boxes[tile + lane].upper;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        if (tile_needed == 0)
            break;
        if (sweeping) {
            uint tile_end = min((uint)${work_group_size}, small_count - tile);
            for (uint k = slot >= tile ? slot - tile + 1 : 0; k < tile_end; ++k) {
                if (tile_lower[k].x > me.upper.x) {
                    sweeping = false;
                    break;
                }
                uint other = as_uint(tile_lower[k].w);
                if (boxes_overlap(me.lower.xyz, me.upper.xyz, tile_lower[k].xyz, tile_upper[k].xyz)
                    && pair_allowed(static_flags, self_index, other))
                    ${visit.emit(mode, "self_index", "other")}
            }
            if (tile + ${work_group_size} >= small_count)
                sweeping = false;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (get_global_id(0) >= body_count)
        return;
% endif

    /* Large bodies, in world coordinates. */
    float3 lower = aabbs[self_index].lower.xyz, upper = aabbs[self_index].upper.xyz;
${visit.visit_large_bodies(mode, "0", "large_count[0]", "uint other = large_bodies[k];\n        Aabb other_box = aabbs[other];")}\
% if mode == "count":
    pair_counts[slot] = found;
% endif
}
</%def>

/* Counts the pairs each sorted body owns (those it meets sweeping forward,
 * and its large-body pairs). A work group is responsible for
 * ${work_group_size} consecutive sorted bodies. */
${sweep_kernel("count")}

/* Writes the pairs each sorted body owns from its scanned offset. A work
 * group is responsible for ${work_group_size} consecutive sorted bodies. */
${sweep_kernel("write")}
