<%namespace name="common" file="/primitives/common.cl.mako"/>\
<%namespace name="tiles" file="/primitives/radix_sort_tiles.cl.mako"/>\
/* Stable LSD radix sort of uint keys${" with uint values" if with_values else ""} in one launch per pass
 * ("onesweep"): RADIX_BITS-bit digits, tiles of TILE = WG * ITEMS keys.
 *   count_all_digits  once per sort: the histograms of every pass's digit
 *                     over all keys (the digit totals don't change between
 *                     passes, only the order of the keys does);
 *   sort_pass         per pass: a work group draws a tile by ticket, counts
 *                     its digits and publishes the counts, sorts the tile by
 *                     the digit in local memory (4-bit splits, as in
 *                     radix_sort_split), then finds, per digit, how many keys
 *                     of earlier tiles have that digit by decoupled look-back
 *                     over their published counts, and writes the tile out.
 * The output position of the key at sorted tile position r with digit d is
 * (keys with a digit < d) + (keys with digit d in earlier tiles) + (r - the
 * tile position of the first key with digit d): consecutive work-items write
 * consecutive addresses within a digit's run.
 *
 * Guard: the look-back relies on started work groups making progress while
 * others wait, which OpenCL does not promise (tickets make every awaited tile
 * one that started earlier). A wait longer than MAX_SPINS polls sets the
 * failure flag and goes on with a wrong result instead of hanging; the host
 * checks the scheme once per device against numpy and otherwise falls back.
 *
 * state (zeroed by the host before each sort): [0] failure flag, [1 + p] the
 * tile ticket of pass p, then STATE_TOTALS: the digit totals of every pass,
 * [p * RADIX + d], then STATE_STATUS: per pass, tile and digit one status
 * word, the tile's count of the digit or the count of all tiles up to it
 * (COUNT_BITS bits) under a flag saying which.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define WAVEFRONT ${wavefront}
#define RADIX_BITS ${radix_bits}
#define RADIX (1u << RADIX_BITS)
#define MAX_PASSES ${-(-32 // radix_bits)}u
#define COUNTER_ROWS 8u
#define PAST_END_KEY 0xFFFFFFFFu
#define PADDED(i) ((i) + ((i) >> 5))
#define STATE_TOTALS (1u + MAX_PASSES)
#define STATE_STATUS (STATE_TOTALS + MAX_PASSES * RADIX)
/* status words: counts below 2^30 (the host refuses larger arrays) under a 2-bit flag */
#define COUNT_BITS 30u
#define COUNT_MASK ((1u << COUNT_BITS) - 1u)
#define TILE_AGGREGATE (1u << COUNT_BITS)   /* the tile's own count */
#define TILE_INCLUSIVE (2u << COUNT_BITS)   /* the count over tiles 0 .. this one */
#define MAX_SPINS (1u << 26)
${common.element_count()}
${common.work_group_exclusive_scan("uint", work_group_size, wavefront)}
${tiles.split_tile(with_values)}

/* The digit of `key` in the pass that starts at bit `shift` of `key_bits`. */
inline uint pass_digit(uint key, uint shift, uint key_bits)
{
    uint bits = min((uint)RADIX_BITS, key_bits - shift);
    return (key >> shift) & ((1u << bits) - 1u);
}

/* A work group is responsible for a strided share of the keys (work-item
 * lid of group g reads keys (k * groups + g) * WG + lid): it counts every
 * pass's digits in local memory and adds its counts to the totals. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void count_all_digits(__global const uint* keys, const uint capacity,
                      __global const uint* device_count, const uint key_bits,
                      __global uint* state)
{
    __local uint histograms[MAX_PASSES * RADIX];
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint passes = (key_bits + RADIX_BITS - 1) / RADIX_BITS;
    for (uint i = lid; i < MAX_PASSES * RADIX; i += WG)
        histograms[i] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint i = get_group_id(0) * WG + lid; i < n; i += get_num_groups(0) * WG) {
        uint key = keys[i];
        for (uint p = 0; p < passes; ++p)
            atomic_inc(&histograms[p * RADIX + pass_digit(key, p * RADIX_BITS, key_bits)]);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint i = lid; i < passes * RADIX; i += WG)
        if (histograms[i])
            atomic_add(&state[STATE_TOTALS + i], histograms[i]);
}

/* Bounded wait for tile `tile`'s status of digit `digit` in this pass (0 if
 * the wait failed, after setting the failure flag). */
inline uint wait_for_status(__global uint* state, __global uint* status, uint tile, uint digit)
{
    uint word, spins = 0;
    do {
        word = atomic_or(&status[tile * RADIX + digit], 0u);
    } while (word == 0u && ++spins < MAX_SPINS);
    if (word == 0u)
        atomic_xchg(&state[0], 1u);  /* no progress: report, don't hang */
    return word;
}

/* A work group is responsible for the tile whose ticket it draws: it moves
 * the tile's keys to their sorted positions for this pass's digit. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void sort_pass(__global const uint* keys_in, __global uint* keys_out,
% if with_values:
               __global const uint* values_in, __global uint* values_out,
% endif
               const uint capacity, __global const uint* device_count,
               const uint key_bits, const uint pass, __global uint* state)
{
    __local uint tile_keys[PADDED(TILE)];
% if with_values:
    __local uint tile_values[PADDED(TILE)];
% endif
    __local uint counters[PADDED(COUNTER_ROWS * WG)];
    __local uint histogram[RADIX];
    __local uint tile_base[RADIX];          /* output position - tile position, per digit */
    __local uint scratch[2 * WG];
    __local uint segment_sums[WG / WAVEFRONT + 1];
    __local uint ticket;
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint shift = pass * RADIX_BITS;
    const uint digit_mask = (1u << min((uint)RADIX_BITS, key_bits - shift)) - 1u;
    const uint tiles = (capacity + TILE - 1) / TILE;  /* state is sized by capacity */
    __global uint* status = state + STATE_STATUS + pass * tiles * RADIX;
    if (lid == 0)
        ticket = atomic_inc(&state[1 + pass]);
    if (lid < RADIX)
        histogram[lid] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint tile = ticket;
    const uint tile_start = tile * TILE;
    if (tile_start >= n)
        return;  /* the whole group leaves together: no barrier is skipped */
    const uint valid = min((uint)TILE, n - tile_start);

    /* coalesced load of the tile, padded with PAST_END_KEY; count its digits */
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        uint key = PAST_END_KEY;
        if (i < valid) {
            key = keys_in[tile_start + i];
            atomic_inc(&histogram[(key >> shift) & digit_mask]);
% if with_values:
            tile_values[PADDED(i)] = values_in[tile_start + i];
% endif
        }
        tile_keys[PADDED(i)] = key;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* publish the tile's counts early, so that later tiles' look-backs find
     * them; tile 0 knows its inclusive counts already (WG >= RADIX: work-item
     * d handles digit d here and in the look-back) */
    if (lid < RADIX)
        atomic_xchg(&status[tile * RADIX + lid],
                    (tile == 0 ? TILE_INCLUSIVE : TILE_AGGREGATE) | histogram[lid]);

    /* the first output position of every digit: keys of smaller digits */
    uint total = lid < RADIX ? state[STATE_TOTALS + pass * RADIX + lid] : 0u;
    uint unused;
    uint digit_start = work_group_exclusive_scan_uint(total, scratch, segment_sums, &unused);

% if radix_bits == 8:
    /* sort the tile by the digit: low nibble, then high nibble unless this
     * pass's digit has 4 bits or fewer (the same for the whole work group) */
% else:
    /* sort the tile by the digit (one nibble) */
% endif
    split_tile(tile_keys, ${"tile_values, " if with_values else ""}shift, min(digit_mask, 15u), counters, scratch, segment_sums);
% if radix_bits == 8:
    if (digit_mask > 15u)
        split_tile(tile_keys, ${"tile_values, " if with_values else ""}shift + 4u, digit_mask >> 4, counters, scratch,
                   segment_sums);
% endif

    /* decoupled look-back, one work-item per digit: add the earlier tiles'
     * counts of the digit, back to the nearest tile that knows its inclusive
     * count; then publish this tile's inclusive count */
    if (lid < RADIX) {
        uint before = 0;
        for (uint t = tile; t > 0; --t) {
            uint word = wait_for_status(state, status, t - 1, lid);
            before += word & COUNT_MASK;
            if (word & TILE_INCLUSIVE || word == 0u)
                break;
        }
        if (tile > 0)
            atomic_xchg(&status[tile * RADIX + lid], TILE_INCLUSIVE | (before + histogram[lid]));
        tile_base[lid] = digit_start + before;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* where a digit's run starts in the sorted tile, make tile_base[d] the
     * output position of tile position 0 for that digit (one work-item per
     * digit present; absent digits are never looked up) */
    uint keys[ITEMS];
    for (uint j = 0; j < ITEMS; ++j) {
        uint r = j * WG + lid;
        keys[j] = tile_keys[PADDED(r)];
        uint digit = (keys[j] >> shift) & digit_mask;
        if (r < valid && (r == 0 || digit != ((tile_keys[PADDED(r - 1)] >> shift) & digit_mask)))
            tile_base[digit] -= r;
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
