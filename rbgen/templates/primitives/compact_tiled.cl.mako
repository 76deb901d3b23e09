<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* Stream compaction, GPU shape: the ${"values" if gather_values else "indices"} of the elements whose flag is
 * nonzero, in input order, and their count, left on the device. Tiles of
 * TILE = WG * ITEMS flags, one per work group; three launches:
 *   count_tiles        every work group counts the set flags of its tile;
 *   scan_tile_counts   one work group turns the counts into exclusive offsets
 *                      and writes the total to out_count[0];
 *   scatter_tiles      every work group ranks its set flags (serial per item,
 *                      then a work-group scan), gathers the kept elements in
 *                      local memory and writes them from its offset, coalesced.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define WAVEFRONT ${wavefront}
/* one padding slot every 32 flags: the serial per-item walk (stride ITEMS) hits distinct banks */
#define PADDED(i) ((i) + ((i) >> 5))
${common.element_count()}
${common.work_group_reduce("uint", "sum", "{a} + {b}", work_group_size)}
${common.work_group_exclusive_scan("uint", work_group_size, wavefront)}

/* A work group is responsible for counting the set flags of one tile. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void count_tiles(__global const uint* flags, const uint capacity,
                 __global const uint* device_count, __global uint* tile_counts)
{
    __local uint scratch[WG];
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together */
    uint count = 0;
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = tile_start + j * WG + get_local_id(0);
        count += (i < n && flags[i] != 0u) ? 1u : 0u;
    }
    count = work_group_sum_uint(count, scratch);
    if (get_local_id(0) == 0)
        tile_counts[get_group_id(0)] = count;
}

/* One work group is responsible for all tile counts: each work-item takes a
 * contiguous run of them, the work group scans the runs' sums, then each
 * work-item rewrites its run as exclusive offsets; the total goes to out_count[0]. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scan_tile_counts(__global uint* tile_counts, const uint capacity,
                      __global const uint* device_count, __global uint* out_count)
{
    __local uint scratch[2 * WG];
    __local uint segment_sums[WG / WAVEFRONT + 1];
    const uint n = element_count(capacity, device_count);
    const uint tiles = (n + TILE - 1) / TILE;
    const uint run = (tiles + WG - 1) / WG;
    const uint first = min((uint)get_local_id(0) * run, tiles);
    const uint end = min(first + run, tiles);
    uint run_count = 0;
    for (uint i = first; i < end; ++i)
        run_count += tile_counts[i];
    uint kept;
    uint running = work_group_exclusive_scan_uint(run_count, scratch, segment_sums, &kept);
    for (uint i = first; i < end; ++i) {
        uint count = tile_counts[i];
        tile_counts[i] = running;
        running += count;
    }
    if (get_local_id(0) == 0)
        out_count[0] = kept;
}

/* A work group is responsible for writing the kept elements of one tile.
 * Flags are read coalesced into local memory, ranked (serial per work-item
 * over ITEMS consecutive flags, then a work-group scan), the kept elements
 * gathered in rank order in local memory and written out coalesced. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scatter_tiles(__global const uint* flags,
% if gather_values:
                   __global const uint* values,
% endif
                   __global uint* out, const uint capacity,
                   __global const uint* device_count, __global const uint* tile_offsets)
{
    __local uint keep[PADDED(TILE)];   /* 1 if the element is kept */
    __local uint kept[TILE];           /* kept elements in rank order */
    __local uint scratch[2 * WG];
    __local uint segment_sums[WG / WAVEFRONT + 1];
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together */
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        keep[PADDED(i)] = (tile_start + i < n && flags[tile_start + i] != 0u) ? 1u : 0u;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* work-item lid ranks the ITEMS consecutive flags from `first` */
    const uint first = lid * ITEMS;
    uint item_kept = 0;
    for (uint j = 0; j < ITEMS; ++j)
        item_kept += keep[PADDED(first + j)];
    uint tile_kept;
    uint rank = work_group_exclusive_scan_uint(item_kept, scratch, segment_sums, &tile_kept);
    for (uint j = 0; j < ITEMS; ++j)
        if (keep[PADDED(first + j)])
% if gather_values:
            kept[rank++] = values[tile_start + first + j];
% else:
            kept[rank++] = tile_start + first + j;
% endif
    barrier(CLK_LOCAL_MEM_FENCE);

    const uint offset = tile_offsets[get_group_id(0)];
    for (uint j = 0; j < ITEMS; ++j) {
        uint r = j * WG + lid;
        if (r < tile_kept)
            out[offset + r] = kept[r];
    }
}
