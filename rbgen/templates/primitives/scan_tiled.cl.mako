<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* ${"Inclusive" if inclusive else "Exclusive"} prefix sum of ${dtype} values, GPU shape (reduce-then-scan).
 *
 * The input is cut into tiles of TILE = WG * ITEMS elements, one per work group:
 *   reduce_tiles     every work group sums its tile into tile_sums[group];
 *   scan_tile_sums   one work group turns tile_sums into exclusive offsets
 *                    (and writes the grand total when asked);
 *   scan_tiles       every work group scans its tile from its offset.
 * src and dst may be the same buffer. Loads and stores are coalesced through
 * local memory; each work-item scans ITEMS consecutive elements serially.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define WAVEFRONT ${wavefront}
/* one padding slot every 32 elements: the serial per-item walk over local
 * memory (stride ITEMS) then hits distinct banks */
#define PADDED(i) ((i) + ((i) >> 5))
typedef ${dtype} T;
${common.element_count()}
${common.work_group_reduce(dtype, "sum", "{a} + {b}", work_group_size)}
${common.work_group_exclusive_scan(dtype, work_group_size, wavefront)}

/* A work group is responsible for summing one tile of the input. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void reduce_tiles(__global const T* src, const uint capacity,
                  __global const uint* device_count, __global T* tile_sums)
{
    __local T scratch[WG];
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together: no barrier is skipped */
    T sum = 0;
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = tile_start + j * WG + get_local_id(0);
        if (i < n)
            sum += src[i];
    }
    sum = work_group_sum_${dtype}(sum, scratch);
    if (get_local_id(0) == 0)
        tile_sums[get_group_id(0)] = sum;
}

/* One work group is responsible for all tile sums: each work-item takes a
 * contiguous run of them, the work group scans the runs' sums, then each
 * work-item rewrites its run as exclusive offsets. The total is written if asked. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scan_tile_sums(__global T* tile_sums, const uint capacity,
                    __global const uint* device_count, __global T* total)
{
    __local T scratch[2 * WG];
    __local T segment_sums[WG / WAVEFRONT + 1];
    const uint n = element_count(capacity, device_count);
    const uint tiles = (n + TILE - 1) / TILE;
    const uint run = (tiles + WG - 1) / WG;
    const uint first = min((uint)get_local_id(0) * run, tiles);
    const uint end = min(first + run, tiles);
    T run_sum = 0;
    for (uint i = first; i < end; ++i)
        run_sum += tile_sums[i];
    T all_tiles;
    T running = work_group_exclusive_scan_${dtype}(run_sum, scratch, segment_sums, &all_tiles);
    for (uint i = first; i < end; ++i) {
        T sum = tile_sums[i];
        tile_sums[i] = running;
        running += sum;
    }
    if (total && get_local_id(0) == 0)
        total[0] = all_tiles;
}

/* A work group is responsible for scanning one tile, starting from the
 * tile's offset computed by scan_tile_sums. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scan_tiles(__global const T* src, __global T* dst, const uint capacity,
                __global const uint* device_count, __global const T* tile_offsets)
{
    __local T tile[PADDED(TILE)];
    __local T scratch[2 * WG];
    __local T segment_sums[WG / WAVEFRONT + 1];
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together */
    const uint lid = get_local_id(0);

    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        tile[PADDED(i)] = tile_start + i < n ? src[tile_start + i] : (T)0;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    T item_sum = 0;
    for (uint j = 0; j < ITEMS; ++j)
        item_sum += tile[PADDED(lid * ITEMS + j)];
    T tile_sum;
    T running = tile_offsets[get_group_id(0)]
              + work_group_exclusive_scan_${dtype}(item_sum, scratch, segment_sums, &tile_sum);
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = PADDED(lid * ITEMS + j);
        T x = tile[i];
% if inclusive:
        running += x;
        tile[i] = running;
% else:
        tile[i] = running;
        running += x;
% endif
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        if (tile_start + i < n)
            dst[tile_start + i] = tile[PADDED(i)];
    }
}
