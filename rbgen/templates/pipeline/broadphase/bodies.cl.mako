/* Per-body preparation shared by the broadphases: validation and sizes.
 *
 * One work-item per body; a work group is responsible for ${work_group_size}
 * consecutive bodies.
 */
${cl_constants()}

${cl_structs("Aabb", "BroadphaseStatus")}

<%include file="/pipeline/broadphase/common.cl.mako"/>

/* Checks each AABB (a NaN bound or lower > upper records the lowest such body
 * in status->bad_body) and writes its clamped log2 size, which Reduce sums
 * into the geometric mean that sets the grid cell and the large-body limit. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void measure_bodies(__global const Aabb* aabbs,
                    const uint body_count,
                    __global float* log_sizes,
                    __global BroadphaseStatus* status)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    float3 lower = aabbs[i].lower.xyz;
    float3 upper = aabbs[i].upper.xyz;
    /* Comparisons with NaN are false, so this also catches NaN bounds. */
    if (!all(lower <= upper))
        atomic_min(&status->bad_body, i);
    float size = box_size(lower, upper);
    float log_size = isfinite(size) ? log2(fmax(size, 1e-30f)) : LOG_SIZE_LIMIT;
    log_sizes[i] = clamp(log_size, -LOG_SIZE_LIMIT, LOG_SIZE_LIMIT);
}
