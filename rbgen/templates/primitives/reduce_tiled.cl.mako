<%namespace name="common" file="/primitives/common.cl.mako"/>\
<%
    identity = {("sum", "uint"): "0u", ("sum", "int"): "0", ("sum", "float"): "0.0f",
                ("min", "uint"): "UINT_MAX", ("min", "int"): "INT_MAX", ("min", "float"): "INFINITY",
                ("max", "uint"): "0u", ("max", "int"): "INT_MIN", ("max", "float"): "-INFINITY"}[(op, dtype)]
    combine = {"sum": "{a} + {b}", "min": "min({a}, {b})", "max": "max({a}, {b})"}[op]
%>\
/* ${op} of ${dtype} values, GPU shape: two launches.
 *   reduce_tiles     every work group combines one tile of TILE = WG * ITEMS
 *                    elements into partials[group];
 *   reduce_partials  one work group combines the partials into out[0].
 * The ${op} of no elements is ${identity}.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define IDENTITY ${identity}
typedef ${dtype} T;
${common.element_count()}
${common.work_group_reduce(dtype, op, combine, work_group_size)}

inline T combine(T a, T b)
{
    return ${combine.format(a="a", b="b")};
}

/* A work group is responsible for one tile of the input. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void reduce_tiles(__global const T* src, const uint capacity,
                  __global const uint* device_count, __global T* partials)
{
    __local T scratch[WG];
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together */
    T acc = IDENTITY;
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = tile_start + j * WG + get_local_id(0);
        if (i < n)
            acc = combine(acc, src[i]);
    }
    acc = work_group_${op}_${dtype}(acc, scratch);
    if (get_local_id(0) == 0)
        partials[get_group_id(0)] = acc;
}

/* One work group is responsible for combining the partials of all tiles
 * that hold elements. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void reduce_partials(__global const T* partials, const uint capacity,
                     __global const uint* device_count, __global T* out)
{
    __local T scratch[WG];
    const uint n = element_count(capacity, device_count);
    const uint tiles = (n + TILE - 1) / TILE;
    T acc = IDENTITY;
    for (uint i = get_local_id(0); i < tiles; i += WG)
        acc = combine(acc, partials[i]);
    acc = work_group_${op}_${dtype}(acc, scratch);
    if (get_local_id(0) == 0)
        out[0] = acc;
}
