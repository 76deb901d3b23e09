<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* ${"Inclusive" if inclusive else "Exclusive"} prefix sum of ${dtype} values in a single pass: chained
 * scan with decoupled look-back (opt-in; reduce-then-scan is the default).
 *
 * Work groups take tiles of TILE = WG * ITEMS elements in the order they
 * start, by drawing a ticket from an atomic counter, so every tile's
 * predecessors have already started. A tile sums itself, publishes its sum
 * (AGGREGATE), then looks back over its predecessors, WINDOW at a time (one
 * per work-item), adding their sums until it meets one that knows its
 * inclusive prefix (INCLUSIVE); the tile publishes its own inclusive prefix
 * and scans itself from its exclusive prefix. The input is read once from memory: the tile is kept in
 * local memory between its sum and its scan.
 *
 * Guard: this relies on started work groups making progress while others
 * spin, which OpenCL does not promise. The wait is bounded: a tile that waits
 * more than MAX_SPINS polls sets state[1] (the failure flag) and goes on with
 * a wrong prefix instead of hanging. The host checks the scheme once per
 * device against numpy and otherwise falls back to reduce-then-scan.
 *
 * state: [0] ticket counter, [1] failure flag, then per tile a status word
 * (EMPTY, AGGREGATE or INCLUSIVE), its aggregate and its inclusive prefix.
 * The host zeroes the ticket, the flag and the status words before each scan.
 */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define WAVEFRONT ${wavefront}
#define PADDED(i) ((i) + ((i) >> 5))
#define TILE_EMPTY 0u
#define TILE_AGGREGATE 1u
#define TILE_INCLUSIVE 2u
#define MAX_SPINS (1u << 26)
/* predecessors examined at once by the look-back, one per work-item */
#define WINDOW ${min(work_group_size, max(wavefront, 1))}
typedef ${dtype} T;
${common.element_count()}
${common.work_group_exclusive_scan(dtype, work_group_size, wavefront)}

/* Publish a value for other work groups: the value first, then (after a
 * fence) the status that announces it. */
inline void publish(__global uint* status, __global uint* slot, uint flag, T value)
{
    atomic_xchg(slot, as_uint(value));
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    atomic_xchg(status, flag);
}

/* Wait (bounded) until tile t has published something; return its status,
 * and its inclusive prefix or aggregate in *value. */
inline uint wait_for_tile(__global uint* state, uint tiles, uint t, T* value)
{
    __global uint* status = state + 2;
    __global uint* aggregates = status + tiles;
    __global uint* inclusives = aggregates + tiles;
    uint flag, spins = 0;
    do {
        flag = atomic_or(&status[t], 0u);
    } while (flag == TILE_EMPTY && ++spins < MAX_SPINS);
    if (flag == TILE_EMPTY) {
        atomic_xchg(&state[1], 1u);  /* no progress: report, don't hang */
        *value = 0;
        return TILE_INCLUSIVE;       /* and stop looking back */
    }
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    *value = as_${dtype}(atomic_or(flag == TILE_INCLUSIVE ? &inclusives[t] : &aggregates[t], 0u));
    return flag;
}

/* A work group is responsible for the tile whose ticket it draws. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scan_chained(__global const T* src, __global T* dst, const uint capacity,
                  __global const uint* device_count, __global uint* state, __global T* total)
{
    __local T tile_values[PADDED(TILE)];
    __local T scratch[2 * WG];
    __local T segment_sums[WG / WAVEFRONT + 1];
    __local uint ticket;
    __local T tile_prefix;
    __local uint window_flags[WINDOW];
    __local T window_values[WINDOW];
    __local uint look_from;  /* predecessors below this index are still to be read */
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
    const uint tiles = (capacity + TILE - 1) / TILE;  /* state is sized by capacity */
    if (lid == 0)
        ticket = atomic_inc(&state[0]);
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint tile = ticket;
    const uint tile_start = tile * TILE;
    if (tile_start >= n) {
        if (n == 0 && tile == 0 && lid == 0 && total)
            total[0] = 0;
        return;  /* the whole group leaves together */
    }

    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        tile_values[PADDED(i)] = tile_start + i < n ? src[tile_start + i] : (T)0;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    T item_sum = 0;
    for (uint j = 0; j < ITEMS; ++j)
        item_sum += tile_values[PADDED(lid * ITEMS + j)];
    T tile_sum;
    T running = work_group_exclusive_scan_${dtype}(item_sum, scratch, segment_sums, &tile_sum);

    /* publish this tile's sum: tile 0 knows its inclusive prefix already */
    __global uint* status = state + 2;
    __global uint* aggregates = status + tiles;
    __global uint* inclusives = aggregates + tiles;
    if (lid == 0) {
        if (tile == 0)
            publish(&status[0], &inclusives[0], TILE_INCLUSIVE, tile_sum);
        else
            publish(&status[tile], &aggregates[tile], TILE_AGGREGATE, tile_sum);
        tile_prefix = 0;
        look_from = tile;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* decoupled look-back, WINDOW predecessors at a time: work-item k reads
     * tile look_from - 1 - k; then one work-item adds the window's values up
     * to the nearest tile that knows its inclusive prefix. The loop condition
     * is read from local memory after a barrier, so it is uniform. */
    while (look_from > 0) {
        const uint base = look_from;
        if (lid < WINDOW && lid < base) {
            T value;
            window_flags[lid] = wait_for_tile(state, tiles, base - 1 - lid, &value);
            window_values[lid] = value;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid == 0) {
            const uint width = min((uint)WINDOW, base);
            T sum = 0;
            uint next = base - width;
            for (uint k = 0; k < width; ++k) {
                sum += window_values[k];
                if (window_flags[k] == TILE_INCLUSIVE) {
                    next = 0;
                    break;
                }
            }
            tile_prefix += sum;
            look_from = next;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }

    if (lid == 0) {
        if (tile > 0)
            publish(&status[tile], &inclusives[tile], TILE_INCLUSIVE, tile_prefix + tile_sum);
        if (total && tile_start + TILE >= n)
            total[0] = tile_prefix + tile_sum;
    }

    running += tile_prefix;
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = PADDED(lid * ITEMS + j);
        T x = tile_values[i];
% if inclusive:
        running += x;
        tile_values[i] = running;
% else:
        tile_values[i] = running;
        running += x;
% endif
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = j * WG + lid;
        if (tile_start + i < n)
            dst[tile_start + i] = tile_values[PADDED(i)];
    }
}
