<%namespace name="common" file="/primitives/common.cl.mako"/>\
<%
    identity = {("sum", "uint"): "0u", ("sum", "int"): "0", ("sum", "float"): "0.0f",
                ("min", "uint"): "UINT_MAX", ("min", "int"): "INT_MAX", ("min", "float"): "INFINITY",
                ("max", "uint"): "0u", ("max", "int"): "INT_MIN", ("max", "float"): "-INFINITY"}[(op, dtype)]
    combine = {"sum": "{a} + {b}", "min": "min({a}, {b})", "max": "max({a}, {b})"}[op]
%>\
/* ${op} of ${dtype} values, CPU shape: CHUNKS work-items (work groups of one)
 * each combine one long contiguous chunk with LANES independent accumulators
 * held in one vector, then
 * one work-item combines the chunk results into out[0].
 * The ${op} of no elements is ${identity}.
 */
#define CHUNKS ${work_items}
<% lanes = 8 %>\
#define LANES ${lanes}
#define IDENTITY ${identity}
typedef ${dtype} T;
typedef ${dtype}${lanes} V;
${common.element_count()}
${common.chunk_range()}

inline T combine(T a, T b)
{
    return ${combine.format(a="a", b="b")};
}

inline V combine_lanes(V a, V b)
{
    return ${combine.format(a="a", b="b")};
}

/* A work group (one work-item) is responsible for one chunk. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void reduce_chunks(__global const T* src, const uint capacity,
                   __global const uint* device_count, __global T* partials)
{
    uint begin, end;
    chunk_range(element_count(capacity, device_count), get_global_id(0), &begin, &end);
    /* two vectors of LANES independent accumulators: no loop-carried chain
     * through a single register. Chunks start on 64-byte boundaries, so the
     * chunk can be read as aligned vectors (much faster on PoCL than vload). */
    __global const V* vectors = (__global const V*)(src + begin);
    const uint vector_count = (end - begin) / LANES;
    V lanes = (V)(IDENTITY), more_lanes = (V)(IDENTITY);
    uint k = 0;
    for (; k + 2 <= vector_count; k += 2) {
        lanes = combine_lanes(lanes, vectors[k]);
        more_lanes = combine_lanes(more_lanes, vectors[k + 1]);
    }
    if (k < vector_count)
        lanes = combine_lanes(lanes, vectors[k]);
    lanes = combine_lanes(lanes, more_lanes);
    T acc = IDENTITY;
    for (uint i = begin + vector_count * LANES; i < end; ++i)
        acc = combine(acc, src[i]);
% for k in range(lanes):
    acc = combine(acc, lanes.s${"%x" % k});
% endfor
    partials[get_global_id(0)] = acc;
}

/* One work-item is responsible for combining the CHUNKS chunk results. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void reduce_partials(__global const T* partials, __global T* out)
{
    T acc = IDENTITY;
    for (uint c = 0; c < CHUNKS; ++c)
        acc = combine(acc, partials[c]);
    out[0] = acc;
}
