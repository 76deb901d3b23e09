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

<%def name="work_group_exclusive_scan(type_name, wg, wavefront)">
/* Exclusive prefix sum of one ${type_name} per work-item over the work group,
 * returning this work-item's prefix and the group's sum in *group_sum.
 * Two levels: a Hillis-Steele scan inside each segment of ${wavefront} work-items
 * (steps unrolled, ping-pong between the halves of scratch), then a serial
 * scan of the ${wg // wavefront} segment sums by one work-item. A barrier separates every
 * step, so nothing relies on lock-step execution; no barrier sits in a loop.
 * scratch holds 2 * ${wg} values, segment_sums ${wg // wavefront} + 1. */
inline ${type_name} work_group_exclusive_scan_${type_name}(${type_name} value,
                                                __local ${type_name}* scratch,
                                                __local ${type_name}* segment_sums,
                                                ${type_name}* group_sum)
{
    const uint lid = get_local_id(0);
    const uint lane = lid % ${wavefront};
    __local ${type_name}* ping = scratch;
    __local ${type_name}* pong = scratch + ${wg};
    ${type_name} x = value;
    ping[lid] = x;
    barrier(CLK_LOCAL_MEM_FENCE);
<%
    steps = []
    offset = 1
    while offset < wavefront:
        steps.append(offset)
        offset *= 2
%>\
% for k, offset in enumerate(steps):
    if (lane >= ${offset}u)
        x += ${"ping" if k % 2 == 0 else "pong"}[lid - ${offset}u];
    ${"pong" if k % 2 == 0 else "ping"}[lid] = x;
    barrier(CLK_LOCAL_MEM_FENCE);
% endfor
<% last = "pong" if len(steps) % 2 == 1 else "ping" %>\
    /* ${last}[] and x now hold inclusive scans within each segment */
    if (lid == 0) {
        ${type_name} running = 0;
        for (uint s = 0; s < ${wg // wavefront}u; ++s) {
            ${type_name} segment = ${last}[s * ${wavefront}u + ${wavefront - 1}u];
            segment_sums[s] = running;
            running += segment;
        }
        segment_sums[${wg // wavefront}] = running;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    ${type_name} prefix = segment_sums[lid / ${wavefront}u] + (lane > 0u ? ${last}[lid - 1] : (${type_name})0);
    *group_sum = segment_sums[${wg // wavefront}];
    barrier(CLK_LOCAL_MEM_FENCE);  /* scratch may be reused by the caller */
    return prefix;
}
</%def>

<%def name="work_group_reduce(type_name, op_name, combine, wg)">
## combine: a C expression of {a} and {b}, e.g. "{a} + {b}" or "min({a}, {b})"
/* ${op_name} of one ${type_name} per work-item over the work group: a tree in local
 * memory, one unrolled level per halving with a barrier after each (no barrier
 * in a loop); every work-item gets the result. scratch: ${wg} values. */
inline ${type_name} work_group_${op_name}_${type_name}(${type_name} value, __local ${type_name}* scratch)
{
    const uint lid = get_local_id(0);
    scratch[lid] = value;
    barrier(CLK_LOCAL_MEM_FENCE);
<%
    strides = []
    stride = wg // 2
    while stride >= 1:
        strides.append(stride)
        stride //= 2
%>\
% for stride in strides:
    if (lid < ${stride}u) {
        ${type_name} a = scratch[lid], b = scratch[lid + ${stride}u];
        scratch[lid] = ${combine.format(a="a", b="b")};
    }
    barrier(CLK_LOCAL_MEM_FENCE);
% endfor
    ${type_name} result = scratch[0];
    barrier(CLK_LOCAL_MEM_FENCE);  /* scratch may be reused by the caller */
    return result;
}
</%def>
