<%namespace name="common" file="/primitives/common.cl.mako"/>\
<%namespace name="tiles" file="/primitives/radix_sort_tiles.cl.mako"/>\
/* Stable LSD radix sort of uint keys${" with uint values" if with_values else ""}, GPU shape with split ranking:
 * one pass per RADIX_BITS-bit digit over tiles of TILE = WG * ITEMS keys, one
 * tile per work group. Per pass:
 *   count_digits    every work group builds its tile's digit histogram in local
 *                   memory (local atomics) and writes it to column `group` of the
 *                   digit table, laid out digit-major: table[digit * tiles + group];
 *   (host)          an exclusive scan of the whole table (Scan primitive) gives
 *                   every (digit, tile) pair its first output position;
 *   scatter_digits  every work group sorts its tile stably by the digit in
 *                   local memory, ${"with two 4-bit splits (low nibble, then high nibble)" if radix_bits == 8 else "with one 4-bit split"},
 *                   then writes it out: the key at tile position r with digit d
 *                   goes to the digit's first output position for this tile plus
 *                   (r - the tile position of the first key with digit d), so
 *                   consecutive work-items write consecutive addresses.
 * A split ranks keys by one nibble with 16 counters per work-item, packed as
 * 16-bit halves into 8 uints: local memory stays small whatever RADIX_BITS is.
 * Work-item `lid` ranks the ITEMS consecutive keys lid * ITEMS ... of the tile,
 * so ordering (nibble, work-item, item) keeps the tile order within a nibble:
 * every split, hence the pass, is stable.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define WAVEFRONT ${wavefront}
#define RADIX_BITS ${radix_bits}
#define RADIX (1u << RADIX_BITS)
/* rows of packed nibble counters: row r holds nibbles r (low half) and r + 8 (high half) */
#define COUNTER_ROWS 8u
/* keys past the element count: every nibble is the largest, so they sort
 * after all real keys (they come last in the tile, and splits are stable) */
#define PAST_END_KEY 0xFFFFFFFFu
/* one padding slot every 32 words: walks with a stride of ITEMS or COUNTER_ROWS
 * words hit distinct banks */
#define PADDED(i) ((i) + ((i) >> 5))
${common.element_count()}
${common.work_group_exclusive_scan("uint", work_group_size, wavefront)}
${tiles.count_digits()}

${tiles.split_tile(with_values)}
/* A work group is responsible for moving the keys of one tile to their sorted
 * positions for this pass's digit: it sorts the tile by the digit in local
 * memory, then writes it out in tile order, which is coalesced within each
 * digit's run. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scatter_digits(__global const uint* keys_in, __global uint* keys_out,
% if with_values:
                    __global const uint* values_in, __global uint* values_out,
% endif
                    const uint capacity, __global const uint* device_count,
                    const uint shift, const uint digit_mask, __global const uint* table)
{
    __local uint tile_keys[PADDED(TILE)];
% if with_values:
    __local uint tile_values[PADDED(TILE)];
% endif
    __local uint counters[PADDED(COUNTER_ROWS * WG)];
    __local uint tile_base[RADIX];              /* output position - tile position, per digit */
    __local uint scratch[2 * WG];
    __local uint segment_sums[WG / WAVEFRONT + 1];
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint tile_start = get_group_id(0) * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together: no barrier is skipped */
    const uint valid = min((uint)TILE, n - tile_start);

    /* coalesced load of the tile, padded with PAST_END_KEY */
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        tile_keys[PADDED(i)] = i < valid ? keys_in[tile_start + i] : PAST_END_KEY;
% if with_values:
        if (i < valid)
            tile_values[PADDED(i)] = values_in[tile_start + i];
% endif
    }
    barrier(CLK_LOCAL_MEM_FENCE);

% if radix_bits == 8:
    /* sort the tile by the digit: low nibble, then high nibble unless this
     * pass's digit has 4 bits or fewer (the same for the whole work group:
     * no work-item skips a barrier the others wait at) */
% else:
    /* sort the tile by the digit (one nibble) */
% endif
    split_tile(tile_keys, ${"tile_values, " if with_values else ""}shift, min(digit_mask, 15u), counters, scratch, segment_sums);
% if radix_bits == 8:
    if (digit_mask > 15u)
        split_tile(tile_keys, ${"tile_values, " if with_values else ""}shift + 4u, digit_mask >> 4, counters, scratch,
                   segment_sums);
% endif

    /* the tile is sorted by digit: where a digit's run starts, note the
     * output position of tile position 0 for that digit (digits absent from
     * the tile are never looked up) */
    const uint groups = get_num_groups(0);
    uint keys[ITEMS];
    for (uint j = 0; j < ITEMS; ++j) {
        uint r = j * WG + lid;
        keys[j] = tile_keys[PADDED(r)];
        uint digit = (keys[j] >> shift) & digit_mask;
        if (r < valid && (r == 0 || digit != ((tile_keys[PADDED(r - 1)] >> shift) & digit_mask)))
            tile_base[digit] = table[digit * groups + get_group_id(0)] - r;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* write in tile order: position r of digit d goes to tile_base[d] + r */
    for (uint j = 0; j < ITEMS; ++j) {
        uint r = j * WG + lid;
        if (r < valid) {
            uint position = tile_base[(keys[j] >> shift) & digit_mask] + r;
            keys_out[position] = keys[j];
% if with_values:
            values_out[position] = tile_values[PADDED(r)];
% endif
        }
    }
}

${tiles.copy_back(with_values)}
