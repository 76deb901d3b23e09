<%namespace name="common" file="/primitives/common.cl.mako"/>\
<%
    serial = work_group_size == 1
    segments = work_group_size // max(wavefront, 1)
%>\
/* ${"Inclusive" if inclusive else "Exclusive"} prefix sum of ${dtype} values in ONE launch: chained scan
 * with decoupled look-back (opt-in, or chosen by the tuner where its guard
 * passes; reduce-then-scan is always available).
 *
 * Tiles of TILE = WG * ITEMS elements.
% if order == "ticket":
 * Work groups take tiles in the order they start, by drawing a ticket from
 * an atomic counter, so every tile's predecessors have already started (and
 * the last ticket drawn resets the counter for the next call).
% else:
 * A work group takes the tile of its group id (no ticket atomic and no
 * barrier delay its loads). This relies on work groups starting in id
 * order, as NVIDIA and AMD GPUs do; OpenCL does not promise it (see Guard).
% endif
 * A tile sums itself and publishes its sum
 * (AGGREGATE), then looks back over its predecessors, LOOKBACK at a time
 * (one per work-item, read in parallel), adding their sums up to the nearest
 * one that knows its inclusive prefix (INCLUSIVE); it publishes its own
 * inclusive prefix and writes its scan. The input is read once and the
 * output written once.
 *
 * Tile words: each tile publishes one 64-bit word, so a single 64-bit read
 * sees a consistent status and value: the value's bits in the high half,
 * (epoch << 2) | status in the low half. The host passes a new epoch to
 * every call, so words left by earlier calls read as empty: nothing is
 * zeroed between calls (the host zeroes the state once, when it allocates
 * it, and again when the epoch wraps after 2^30 calls).
 *
 * Guard: this relies on started work groups making progress while others
 * spin, which OpenCL does not promise. The wait is bounded: a tile that polls
 * more than MAX_SPINS times sets the failure flag and goes on with a wrong
 * prefix instead of hanging. The host checks the scheme once per device and
 * parameters against numpy and otherwise falls back to reduce-then-scan.
 *
 * state: ulong [0] = ticket counter (low uint) and failure flag (high uint),
 * then one word per tile. Words are published with an atomic exchange and
 * polled with plain volatile 64-bit loads: a poll is one cheap read that
 * other pollers of the same word do not queue behind (an atomic
 * read-modify-write would), and the value travels inside the word, so no
 * ordering between different addresses is needed.
 */
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
#define STATUS_AGGREGATE 1u
#define STATUS_INCLUSIVE 2u
#define MAX_SPINS (1u << 26)
% if not serial:
/* each work-item holds VECTORS vectors of 4 elements in registers: vector v
 * of work-item l is vector v * WG + l of its tile (coalesced loads) */
#define VECTORS (ITEMS / 4)
#define WAVEFRONT ${wavefront}
#define SEGMENTS ${segments}
/* predecessors read at once by one look-back step, one per work-item */
#define LOOKBACK ${lookback}
/* one padding slot every 32 values: strided walks over local memory hit
 * distinct banks */
#define PADDED(i) ((i) + ((i) >> 5))
% endif
typedef ${dtype} T;
typedef ${dtype}4 T4;
${common.element_count()}

/* The published word of a tile: value bits high, epoch and status low. */
inline ulong tile_word(uint status, uint epoch, T value)
{
    return ((ulong)as_uint(value) << 32) | (ulong)((epoch << 2) | status);
}

/* The status a word announces in this epoch: 0 (empty) for words of other epochs. */
inline uint word_status(ulong word, uint epoch)
{
    return ((uint)word >> 2) == epoch ? ((uint)word & 3u) : 0u;
}

/* Publish a tile's word for the other work groups (one atomic store). */
inline void publish(__global ulong* words, uint tile, uint status, uint epoch, T value)
{
    atom_xchg(&words[tile], tile_word(status, epoch, value));
}

/* Wait (bounded) until tile t has published in this call; return its value
 * (aggregate or inclusive prefix) and its status in *status. Each poll is
 * one volatile load (it reads the word where atomics land, not a cached copy). */
inline T wait_for_tile(volatile __global const ulong* words, __global uint* failed, uint t,
                       uint epoch, uint* status)
{
    ulong word;
    uint spins = 0;
    do {
        word = words[t];
        *status = word_status(word, epoch);
    } while (*status == 0u && ++spins < MAX_SPINS);
    if (*status == 0u) {
        atomic_xchg(failed, 1u);  /* no progress: report, don't hang */
        *status = STATUS_INCLUSIVE;  /* and stop looking back */
        return 0;
    }
    return as_${dtype}((uint)(word >> 32));
}

/* Draw this work group's ticket (its tile); the last ticket of the launch
 * resets the counter, since every other ticket has been drawn by then. */
inline uint draw_ticket(__global uint* counter)
{
    uint ticket = atomic_inc(counter);
    if (ticket == get_num_groups(0) - 1)
        atomic_xchg(counter, 0u);
    return ticket;
}

/* Exclusive or inclusive scan of one vector from the sum of everything before it. */
inline T4 scan_vector(T4 x, T before)
{
    T4 y;
% if inclusive:
    y.s0 = before + x.s0;
    y.s1 = y.s0 + x.s1;
    y.s2 = y.s1 + x.s2;
    y.s3 = y.s2 + x.s3;
% else:
    y.s0 = before;
    y.s1 = before + x.s0;
    y.s2 = y.s1 + x.s1;
    y.s3 = y.s2 + x.s2;
% endif
    return y;
}

/* Vector i of a tile that holds only count < TILE elements: zeros past the end. */
inline T4 load_partial(__global const T* tile, uint i, uint count)
{
    uint e = 4 * i;
    return (T4)(e < count ? tile[e] : (T)0, e + 1 < count ? tile[e + 1] : (T)0,
                e + 2 < count ? tile[e + 2] : (T)0, e + 3 < count ? tile[e + 3] : (T)0);
}

inline void store_partial(__global T* tile, uint i, uint count, T4 y)
{
    uint e = 4 * i;
    if (e < count) tile[e] = y.s0;
    if (e + 1 < count) tile[e + 1] = y.s1;
    if (e + 2 < count) tile[e + 2] = y.s2;
    if (e + 3 < count) tile[e + 3] = y.s3;
}
% if serial:

/* Sum of the count elements of a tile (one work-item walks it). */
inline T sum_tile(__global const T* tile, uint count)
{
    __global const T4* vectors = (__global const T4*)tile;
    T4 sums = 0;
    for (uint i = 0; i < count / 4; ++i)
        sums += vectors[i];
    if (count % 4)
        sums += load_partial(tile, count / 4, count);
    return sums.s0 + sums.s1 + sums.s2 + sums.s3;
}

/* Scan of a tile from the sum of everything before it (src and dst may be one buffer). */
inline void scan_tile(__global const T* in, __global T* out, uint count, T running)
{
    __global const T4* vectors = (__global const T4*)in;
    __global T4* results = (__global T4*)out;
    for (uint i = 0; i < count / 4; ++i) {
        T4 x = vectors[i];
        results[i] = scan_vector(x, running);
        running += x.s0 + x.s1 + x.s2 + x.s3;
    }
    if (count % 4)
        store_partial(out, count / 4, count, scan_vector(load_partial(in, count / 4, count), running));
}

/* A work group (one work-item, CPU shape) is responsible for the tile whose
 * ticket it draws (or of its group id, ORDER group): it sums the tile, looks
 * back one predecessor at a time, then scans the tile (still in cache). */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scan_chained(__global const T* src, __global T* dst, const uint capacity,
                  __global const uint* device_count, __global ulong* state, const uint epoch,
                  __global T* total)
{
    __global uint* counters = (__global uint*)state;  /* [0] tickets, [1] failure flag */
    __global ulong* words = state + 1;
    const uint n = element_count(capacity, device_count);
% if order == "ticket":
    const uint tile = draw_ticket(&counters[0]);
% else:
    const uint tile = get_group_id(0);
% endif
    const uint tile_start = tile * TILE;
    if (tile_start >= n) {
        if (n == 0 && tile == 0 && total)
            total[0] = 0;
        return;
    }
    const uint count = min(n - tile_start, (uint)TILE);
    const T tile_sum = sum_tile(src + tile_start, count);
    publish(words, tile, tile == 0 ? STATUS_INCLUSIVE : STATUS_AGGREGATE, epoch, tile_sum);

    T before = 0;
    for (uint t = tile; t > 0; --t) {
        uint status;
        before += wait_for_tile(words, &counters[1], t - 1, epoch, &status);
        if (status == STATUS_INCLUSIVE)
            break;
    }
    if (tile > 0)
        publish(words, tile, STATUS_INCLUSIVE, epoch, before + tile_sum);
    if (total && tile_start + TILE >= n)
        total[0] = before + tile_sum;
    scan_tile(src + tile_start, dst + tile_start, count, before);
}
% else:

/* Exclusive scan of the WG run sums in run_sums[0..WG) (this work-item's is
 * `mine`): every work-item adds the sums before its own in its segment of
 * WAVEFRONT work-items (vector reads all work-items of a segment share), the
 * last of each segment publishes the segment's sum, then every work-item adds
 * the sums of the segments before its own. Two barriers, no serial chain.
 * Returns this work-item's prefix; *tile_sum gets the total. */
inline T scan_run_sums(__local T* run_sums, T mine, __local T* segment_sums, T* tile_sum)
{
    const uint lid = get_local_id(0);
    const uint segment = lid / WAVEFRONT, lane = lid % WAVEFRONT;
    __local const T* own_segment = run_sums + segment * WAVEFRONT;
    barrier(CLK_LOCAL_MEM_FENCE);
    T prefix = 0;
    #pragma unroll
    for (uint j = 0; j < WAVEFRONT / 4; ++j) {
        const T4 x = vload4(j, own_segment);
        const uint k = 4 * j;
        prefix += (k < lane ? x.s0 : (T)0) + (k + 1 < lane ? x.s1 : (T)0)
                + (k + 2 < lane ? x.s2 : (T)0) + (k + 3 < lane ? x.s3 : (T)0);
    }
    if (lane == WAVEFRONT - 1)
        segment_sums[segment] = prefix + mine;
    barrier(CLK_LOCAL_MEM_FENCE);
    T sum = 0;
    #pragma unroll
    for (uint s = 0; s < SEGMENTS; ++s) {
        T x = segment_sums[s];
        prefix += s < segment ? x : (T)0;
        sum += x;
    }
    *tile_sum = sum;
    return prefix;
}

/* The look-back's mark of an INCLUSIVE predecessor k (k-th nearest) in step
 * `step`: atomic_max over the marks of one step keeps the nearest one, and a
 * mark left by an earlier step is smaller than every mark of a later one, so
 * the two marks words never need to be cleared. 22 bits of step (a tile
 * takes at most 2^25 / LOOKBACK steps), 10 bits of position. */
inline uint inclusive_mark(uint step, uint k)
{
    return ((step + 1u) << 10) | (1023u - k);
}

/* Sum of values[0..last] (last < LOOKBACK), read as vectors of 4. */
inline T sum_window(__local const T* values, uint last)
{
    T4 sums = 0;
    uint j = 0;
    for (; 4 * j + 4 <= last; ++j)
        sums += vload4(j, values);
    const T4 x = vload4(j, values);  /* 4 * j <= last: in bounds (LOOKBACK is a multiple of 4) */
    const uint k = 4 * j;
    sums += (T4)(k <= last ? x.s0 : (T)0, k + 1 <= last ? x.s1 : (T)0,
                 k + 2 <= last ? x.s2 : (T)0, k + 3 <= last ? x.s3 : (T)0);
    return sums.s0 + sums.s1 + sums.s2 + sums.s3;
}

/* The sum of every tile before `tile` (called by the whole work group; the
 * result is the same in every work-item). Each step polls the LOOKBACK
 * nearest predecessors not yet read, work-item k the k-th nearest; the
 * INCLUSIVE ones mark themselves, and after one barrier every work-item adds
 * up the window up to the nearest mark (or the whole window, and goes on).
 * window_values holds two buffers of LOOKBACK values; they alternate, so a
 * fast work-item's next step never overwrites what a slow one still reads. */
inline T look_back(volatile __global const ulong* words, __global uint* failed, uint tile,
                   uint epoch, __local T* window_values, __local uint* marks)
{
    const uint lid = get_local_id(0);
    T before = 0;
    uint look_from = tile;  /* predecessors below this index are still to be read */
    uint step = 0;
    do {
        const uint w = step & 1u;
        __local T* values = window_values + w * LOOKBACK;
        const uint width = min((uint)LOOKBACK, look_from);
        if (lid < width) {
            uint status;
            values[lid] = wait_for_tile(words, failed, look_from - 1 - lid, epoch, &status);
            if (status == STATUS_INCLUSIVE)
                atomic_max(&marks[w], inclusive_mark(step, lid));
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        const uint mark = marks[w];
        const bool found = (mark >> 10) == step + 1u;
        if (width > 0)
            before += sum_window(values, found ? 1023u - (mark & 1023u) : width - 1);
        look_from = found ? 0 : look_from - width;
        ++step;
    } while (look_from > 0);
    return before;
}

/* A work group is responsible for the tile whose ticket it draws (or, with
 * ORDER group, the tile of its group id).
 *  1. load the tile: VECTORS vectors per work-item, coalesced;
 *  2. scan the vectors' sums in local memory (vector_sums, in tile order):
 *     work-item l sums the run of VECTORS consecutive vectors l * VECTORS..,
 *     the work group scans the run sums, work-item l writes its run's
 *     exclusive prefixes back;
 *  3. publish the tile's sum and look back over the predecessors;
 *  4. each work-item scans its vectors from their prefixes and stores them. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void scan_chained(__global const T* src, __global T* dst, const uint capacity,
                  __global const uint* device_count, __global ulong* state, const uint epoch,
                  __global T* total)
{
    __local T vector_sums[PADDED(VECTORS * WG)];
    __local T run_sums[WG];
    __local T segment_sums[SEGMENTS];
    __local T window_values[2 * LOOKBACK];  /* two buffers of one look-back step */
    __local uint marks[2];
% if order == "ticket":
    __local uint ticket;
% endif
    __global uint* counters = (__global uint*)state;  /* [0] tickets, [1] failure flag */
    __global ulong* words = state + 1;
    const uint lid = get_local_id(0);
    const uint n = element_count(capacity, device_count);
% if order == "ticket":
    if (lid == 0) {
        ticket = draw_ticket(&counters[0]);
        marks[0] = marks[1] = 0;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint tile = ticket;
% else:
    /* tile = group id: no atomic and no barrier before the loads (the marks
     * are made visible by the barrier after step 1) */
    if (lid == 0)
        marks[0] = marks[1] = 0;
    const uint tile = get_group_id(0);
% endif
    const uint tile_start = tile * TILE;
    if (tile_start >= n) {
        if (n == 0 && tile == 0 && lid == 0 && total)
            total[0] = 0;
        return;  /* the whole group leaves together */
    }
    const uint count = min(n - tile_start, (uint)TILE);

    /* 1. load */
    T4 x[VECTORS];
    if (count == TILE) {
        __global const T4* vectors = (__global const T4*)(src + tile_start);
        #pragma unroll
        for (uint v = 0; v < VECTORS; ++v)
            x[v] = vectors[v * WG + lid];
    } else {
        #pragma unroll
        for (uint v = 0; v < VECTORS; ++v)
            x[v] = load_partial(src + tile_start, v * WG + lid, count);
    }
    #pragma unroll
    for (uint v = 0; v < VECTORS; ++v)
        vector_sums[PADDED(v * WG + lid)] = x[v].s0 + x[v].s1 + x[v].s2 + x[v].s3;
    barrier(CLK_LOCAL_MEM_FENCE);

    /* 2. scan the vector sums */
    T run[VECTORS];
    T run_sum = 0;
    #pragma unroll
    for (uint k = 0; k < VECTORS; ++k) {
        run[k] = vector_sums[PADDED(lid * VECTORS + k)];
        run_sum += run[k];
    }
    run_sums[lid] = run_sum;
    T tile_sum;
    T running = scan_run_sums(run_sums, run_sum, segment_sums, &tile_sum);
    #pragma unroll
    for (uint k = 0; k < VECTORS; ++k) {
        vector_sums[PADDED(lid * VECTORS + k)] = running;
        running += run[k];
    }

    /* 3. publish, then look back (its first barrier also makes vector_sums'
     * prefixes visible to step 4) */
    if (lid == 0)
        publish(words, tile, tile == 0 ? STATUS_INCLUSIVE : STATUS_AGGREGATE, epoch, tile_sum);
    const T before = look_back(words, &counters[1], tile, epoch, window_values, marks);
    if (lid == 0) {
        if (tile > 0)
            publish(words, tile, STATUS_INCLUSIVE, epoch, before + tile_sum);
        if (total && tile_start + TILE >= n)
            total[0] = before + tile_sum;
    }

    /* 4. scan and store */
    if (count == TILE) {
        __global T4* results = (__global T4*)(dst + tile_start);
        #pragma unroll
        for (uint v = 0; v < VECTORS; ++v)
            results[v * WG + lid] = scan_vector(x[v], before + vector_sums[PADDED(v * WG + lid)]);
    } else {
        #pragma unroll
        for (uint v = 0; v < VECTORS; ++v)
            store_partial(dst + tile_start, v * WG + lid, count,
                          scan_vector(x[v], before + vector_sums[PADDED(v * WG + lid)]));
    }
}
% endif
