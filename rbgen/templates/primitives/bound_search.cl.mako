/* ${"Lower" if side == "lower" else "Upper"} bound of each query in an ascending uint key array: the
 * first index i in [0, n_keys) with keys[i] ${">=" if side == "lower" else ">"} query, or n_keys if none.
 * One binary search per work-item; a work group is responsible for WG
 * consecutive queries. */
#define WG ${work_group_size}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void bound_search(__global const uint* keys, const uint key_capacity,
                  __global const uint* device_key_count,
                  __global const uint* queries, const uint query_capacity,
                  __global const uint* device_query_count, __global uint* out)
{
    const uint q = get_global_id(0);
    const uint n_queries = device_query_count ? min(device_query_count[0], query_capacity)
                                              : query_capacity;
    if (q >= n_queries)
        return;
    const uint n_keys = device_key_count ? min(device_key_count[0], key_capacity) : key_capacity;
    const uint query = queries[q];
    uint lo = 0, hi = n_keys;  /* the answer lies in [lo, hi] */
    while (lo < hi) {
        uint mid = lo + (hi - lo) / 2;
% if side == "lower":
        if (keys[mid] < query)
% else:
        if (keys[mid] <= query)
% endif
            lo = mid + 1;
        else
            hi = mid;
    }
    out[q] = lo;
}
