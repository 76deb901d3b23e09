## Device helpers shared by the primitives' templates, as Mako defs.
## Import with <%namespace name="common" file="/primitives/common.cl.mako"/>
## and call e.g. ${common.element_count()} where the helper is needed.

<%def name="element_count()">
/* Elements to process: the device count when one is given (clamped to the
 * buffers' capacity), else the capacity itself (the host count). */
inline uint element_count(uint capacity, __global const uint* device_count)
{
    return device_count ? min(device_count[0], capacity) : capacity;
}
</%def>

<%def name="chunk_range()">
/* The contiguous range [*begin, *end) of n elements owned by one of
 * CHUNKS work-items; chunk lengths are multiples of 16 elements so that
 * neighbouring chunks never share a cache line. */
inline void chunk_range(uint n, uint chunk, uint* begin, uint* end)
{
    uint length = ((n + CHUNKS - 1) / CHUNKS + 15u) & ~15u;
    *begin = min(chunk * length, n);
    *end = min(*begin + length, n);
}
</%def>

<%def name="work_group_exclusive_scan(type_name)">
/* Exclusive prefix sum of one ${type_name} per work-item over the work group,
 * returning this work-item's prefix and the group's sum in *group_sum.
 * Two levels: a Hillis-Steele scan inside each segment of WAVEFRONT work-items,
 * then a serial scan of the WG / WAVEFRONT segment sums by one work-item. A
 * barrier separates every step, so nothing relies on lock-step execution.
 * scratch holds 2 * WG values (ping-pong), segment_sums WG / WAVEFRONT + 1. */
inline ${type_name} work_group_exclusive_scan_${type_name}(${type_name} value,
                                                __local ${type_name}* scratch,
                                                __local ${type_name}* segment_sums,
                                                ${type_name}* group_sum)
{
    const uint lid = get_local_id(0);
    const uint lane = lid % WAVEFRONT;
    __local ${type_name}* from = scratch;
    __local ${type_name}* to = scratch + WG;
    from[lid] = value;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint offset = 1; offset < WAVEFRONT; offset <<= 1) {
        ${type_name} x = from[lid];
        if (lane >= offset)
            x += from[lid - offset];
        to[lid] = x;
        barrier(CLK_LOCAL_MEM_FENCE);
        __local ${type_name}* swap = from;
        from = to;
        to = swap;
    }
    /* from[] now holds inclusive scans within each segment */
    if (lid == 0) {
        ${type_name} running = 0;
        for (uint s = 0; s < WG / WAVEFRONT; ++s) {
            ${type_name} segment = from[s * WAVEFRONT + WAVEFRONT - 1];
            segment_sums[s] = running;
            running += segment;
        }
        segment_sums[WG / WAVEFRONT] = running;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    ${type_name} prefix = segment_sums[lid / WAVEFRONT] + (lane > 0 ? from[lid - 1] : (${type_name})0);
    *group_sum = segment_sums[WG / WAVEFRONT];
    barrier(CLK_LOCAL_MEM_FENCE);  /* scratch may be reused by the caller */
    return prefix;
}
</%def>

<%def name="work_group_reduce(type_name, op_name, combine)">
## combine: a C expression of {a} and {b}, e.g. "{a} + {b}" or "min({a}, {b})"
/* ${op_name} of one ${type_name} per work-item over the work group (tree in local
 * memory, a barrier per level); every work-item gets the result. scratch: WG values. */
inline ${type_name} work_group_${op_name}_${type_name}(${type_name} value, __local ${type_name}* scratch)
{
    const uint lid = get_local_id(0);
    scratch[lid] = value;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint stride = WG / 2; stride > 0; stride >>= 1) {
        if (lid < stride) {
            ${type_name} a = scratch[lid], b = scratch[lid + stride];
            scratch[lid] = ${combine.format(a="a", b="b")};
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    ${type_name} result = scratch[0];
    barrier(CLK_LOCAL_MEM_FENCE);  /* scratch may be reused by the caller */
    return result;
}
</%def>
