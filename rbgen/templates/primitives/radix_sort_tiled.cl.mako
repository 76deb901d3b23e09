<%namespace name="common" file="/primitives/common.cl.mako"/>\
<%namespace name="tiles" file="/primitives/radix_sort_tiles.cl.mako"/>\
/* Stable LSD radix sort of uint keys${" with uint values" if with_values else ""}, GPU shape: one pass per
 * RADIX_BITS-bit digit over tiles of TILE = WG * ITEMS keys, one tile per work group.
 * Per pass:
 *   count_digits    every work group builds its tile's digit histogram in local
 *                   memory (local atomics) and writes it to column `group` of the
 *                   digit table, laid out digit-major: table[digit * tiles + group];
 *   (host)          an exclusive scan of the whole table (Scan primitive) gives
 *                   every (digit, tile) pair its first output position;
 *   scatter_digits  every work group ranks its keys stably inside the tile
 *                   (per-work-item digit counters in local memory, scanned
 *                   digit-major), reorders the tile by rank in local memory
 *                   and writes it out coalesced: rank r of digit d goes to the
 *                   tile's first position for d plus (r - the digit's first rank).
 * Work-item `lid` owns the ITEMS consecutive keys lid * ITEMS ... of its tile,
 * so ordering (digit, work-item, item) is the input order within a digit: stable.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define WAVEFRONT ${wavefront}
#define RADIX_BITS ${radix_bits}
#define RADIX (1u << RADIX_BITS)
/* per-(digit, work-item) counters stay below TILE <= 65535: ${counter_type} suffices
 * and keeps RADIX * WG of them within local memory */
typedef ${counter_type} counter_t;
/* one padding slot every 32 keys: the serial per-item walk (stride ITEMS) hits distinct banks */
#define PADDED(i) ((i) + ((i) >> 5))
${common.element_count()}
${common.work_group_exclusive_scan("uint", work_group_size, wavefront)}

${tiles.count_digits()}

/* A work group is responsible for moving the keys of one tile to their
 * sorted positions for this pass's digit. The tile is reordered by rank in
 * local memory first, so that consecutive work-items write consecutive
 * output positions (coalesced) within each digit's run. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scatter_digits(__global const uint* keys_in, __global uint* keys_out,
% if with_values:
                    __global const uint* values_in, __global uint* values_out,
% endif
                    const uint capacity, __global const uint* device_count,
                    const uint shift, const uint digit_mask, __global const uint* table)
{
    __local uint tile_keys[PADDED(TILE)];      /* input order, then rank order */
% if with_values:
    __local uint tile_values[PADDED(TILE)];
% endif
    __local counter_t counters[RADIX * WG];      /* [digit * WG + lid] */
    __local uint tile_base[RADIX];              /* output position - tile rank, per digit */
    __local uint scratch[2 * WG];
    __local uint segment_sums[WG / WAVEFRONT + 1];
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together: no barrier is skipped */
    const uint valid = min((uint)TILE, n - tile_start);

    /* coalesced load of the tile; clear this work-item's counters */
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        if (i < valid) {
            tile_keys[PADDED(i)] = keys_in[tile_start + i];
% if with_values:
            tile_values[PADDED(i)] = values_in[tile_start + i];
% endif
        }
    }
    for (uint d = 0; d < RADIX; ++d)
        counters[d * WG + lid] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);

    /* take this work-item's consecutive keys and count their digits */
    const uint first = lid * ITEMS;
    uint keys[ITEMS];
% if with_values:
    uint values[ITEMS];
% endif
    for (uint j = 0; j < ITEMS; ++j) {
        keys[j] = tile_keys[PADDED(first + j)];
% if with_values:
        values[j] = tile_values[PADDED(first + j)];
% endif
        if (first + j < valid)
            ++counters[((keys[j] >> shift) & digit_mask) * WG + lid];
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* exclusive scan of the counters in digit-major order: work-item lid walks
     * the RADIX consecutive counters lid * RADIX ... serially, then the work
     * group scans the per-item sums */
    uint item_sum = 0;
    for (uint d = 0; d < RADIX; ++d)
        item_sum += counters[lid * RADIX + d];
    uint tile_count;
    uint running = work_group_exclusive_scan_uint(item_sum, scratch, segment_sums, &tile_count);
    for (uint d = 0; d < RADIX; ++d) {
        uint c = counters[lid * RADIX + d];
        counters[lid * RADIX + d] = (counter_t)running;
        running += c;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* counters[d * WG] is now the tile rank of the first key with digit d */
    for (uint d = lid; d < RADIX; d += WG)
        tile_base[d] = table[d * get_num_groups(0) + get_group_id(0)] - counters[d * WG];
    barrier(CLK_LOCAL_MEM_FENCE);  /* counters[d * WG] is read above and advanced below */

    /* put every key at its tile rank (the tile's own slots are free now) */
    for (uint j = 0; j < ITEMS; ++j) {
        if (first + j < valid) {
            uint rank = counters[((keys[j] >> shift) & digit_mask) * WG + lid]++;
            tile_keys[PADDED(rank)] = keys[j];
% if with_values:
            tile_values[PADDED(rank)] = values[j];
% endif
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* write in rank order: rank r of digit d goes to tile_base[d] + r */
    for (uint j = 0; j < ITEMS; ++j) {
        uint rank = j * WG + lid;
        if (rank < valid) {
            uint key = tile_keys[PADDED(rank)];
            uint position = tile_base[(key >> shift) & digit_mask] + rank;
            keys_out[position] = key;
% if with_values:
            values_out[position] = tile_values[PADDED(rank)];
% endif
        }
    }
}

${tiles.copy_back(with_values)}
