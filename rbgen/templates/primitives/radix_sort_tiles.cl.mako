## Code shared by the tile-shaped radix sorts (radix_sort_tiled, radix_sort_split,
## radix_sort_onesweep), as Mako defs. The including template defines WG, ITEMS,
## TILE and RADIX (and for split_tile COUNTER_ROWS and PADDED) and renders
## common.element_count() (and for split_tile common.work_group_exclusive_scan) first.

<%def name="count_digits()">
/* A work group is responsible for the digit histogram of one tile (all zeros
 * past the element count, so the table always covers every tile). */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void count_digits(__global const uint* keys, const uint capacity,
                  __global const uint* device_count, const uint shift, const uint digit_mask,
                  __global uint* table)
{
    __local uint histogram[RADIX];
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    for (uint d = lid; d < RADIX; d += WG)
        histogram[d] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = tile_start + j * WG + lid;
        if (i < n)
            atomic_inc(&histogram[(keys[i] >> shift) & digit_mask]);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint d = lid; d < RADIX; d += WG)
        table[d * get_num_groups(0) + get_group_id(0)] = histogram[d];
}
</%def>

<%def name="copy_back(with_values)">
/* A work group is responsible for copying one tile back after an odd
 * number of passes. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void copy_back(__global const uint* keys_in, __global uint* keys_out,
% if with_values:
               __global const uint* values_in, __global uint* values_out,
% endif
               const uint capacity, __global const uint* device_count)
{
    const uint n = element_count(capacity, device_count);
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = get_group_id(0) * TILE + j * WG + get_local_id(0);
        if (i < n) {
            keys_out[i] = keys_in[i];
% if with_values:
            values_out[i] = values_in[i];
% endif
        }
    }
}
</%def>

<%def name="split_tile(with_values)">
/* Ranks of this work-item's ITEMS keys (tile positions lid * ITEMS + j) in the
 * tile ordered stably by the nibble (key >> nibble_shift) & nibble_mask.
 * counters[PADDED(row * WG + lid)] packs this work-item's counts of nibbles
 * row and row + 8; scanned in that (row, work-item) order, low halves give the
 * first rank of every (nibble < 8, work-item) pair and high halves, plus the
 * count of all nibbles below 8, that of every (nibble >= 8, work-item) pair.
 * Halves never carry: a tile holds fewer than 65536 keys.
 * Callers put a barrier between this and their previous use of counters. */
inline void rank_by_nibble(const uint* keys, uint nibble_shift, uint nibble_mask,
                           __local uint* counters, __local uint* scratch,
                           __local uint* segment_sums, uint* ranks)
{
    const uint lid = get_local_id(0);
    for (uint row = 0; row < COUNTER_ROWS; ++row)
        counters[PADDED(row * WG + lid)] = 0;
    /* count; a key's rank among this work-item's keys of its nibble is the count before it */
    for (uint j = 0; j < ITEMS; ++j) {
        uint nibble = (keys[j] >> nibble_shift) & nibble_mask;
        uint slot = PADDED((nibble % COUNTER_ROWS) * WG + lid);
        uint half_shift = (nibble / COUNTER_ROWS) * 16u;
        uint packed = counters[slot];
        ranks[j] = (packed >> half_shift) & 0xFFFFu;
        counters[slot] = packed + (1u << half_shift);
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* exclusive scan of the counters in (row, work-item) order: work-item lid
     * walks COUNTER_ROWS consecutive counters serially, the work group scans
     * the per-item sums */
    uint mine[COUNTER_ROWS];
    uint item_sum = 0;
    for (uint k = 0; k < COUNTER_ROWS; ++k) {
        mine[k] = counters[PADDED(lid * COUNTER_ROWS + k)];
        item_sum += mine[k];
    }
    uint packed_total;
    uint running = work_group_exclusive_scan_uint(item_sum, scratch, segment_sums, &packed_total);
    running += (packed_total & 0xFFFFu) << 16;  /* nibbles >= 8 follow all nibbles < 8 */
    for (uint k = 0; k < COUNTER_ROWS; ++k) {
        counters[PADDED(lid * COUNTER_ROWS + k)] = running;
        running += mine[k];
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    for (uint j = 0; j < ITEMS; ++j) {
        uint nibble = (keys[j] >> nibble_shift) & nibble_mask;
        uint packed = counters[PADDED((nibble % COUNTER_ROWS) * WG + lid)];
        ranks[j] += (packed >> ((nibble / COUNTER_ROWS) * 16u)) & 0xFFFFu;
    }
}

/* Reorders the tile (TILE keys in local memory${", and their values" if with_values else ""}) stably by the
 * nibble (key >> nibble_shift) & nibble_mask; ends with a barrier. */
inline void split_tile(__local uint* tile_keys,
% if with_values:
                       __local uint* tile_values,
% endif
                       uint nibble_shift, uint nibble_mask, __local uint* counters,
                       __local uint* scratch, __local uint* segment_sums)
{
    const uint first = get_local_id(0) * ITEMS;
    uint keys[ITEMS], ranks[ITEMS];
% if with_values:
    uint values[ITEMS];
% endif
    for (uint j = 0; j < ITEMS; ++j) {
        keys[j] = tile_keys[PADDED(first + j)];
% if with_values:
        values[j] = tile_values[PADDED(first + j)];
% endif
    }
    /* the barriers in here follow every work-item's reads above: the tile's
     * slots are free to take the keys in their new order below */
    rank_by_nibble(keys, nibble_shift, nibble_mask, counters, scratch, segment_sums, ranks);
    for (uint j = 0; j < ITEMS; ++j) {
        tile_keys[PADDED(ranks[j])] = keys[j];
% if with_values:
        tile_values[PADDED(ranks[j])] = values[j];
% endif
    }
    barrier(CLK_LOCAL_MEM_FENCE);
}
</%def>
