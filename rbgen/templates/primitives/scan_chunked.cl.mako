<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* ${"Inclusive" if inclusive else "Exclusive"} prefix sum of ${dtype} values, CPU shape.
 *
 * CHUNKS work-items (work groups of one) each own one long contiguous chunk
 * and walk it sequentially with private running sums; no local memory and no
 * barriers. Three launches:
 *   reduce_chunks     chunk_sums[c] = sum of chunk c;
 *   scan_chunk_sums   one work-item turns chunk_sums into exclusive offsets
 *                     (and writes the grand total when asked);
 *   scan_chunks       every work-item scans its chunk from its offset.
 * Integer sums are associative, so the compiler vectorises the plain loops
 * itself (on PoCL twice as fast as hand-written vectors); float sums it must
 * not reassociate, so for floats both walks take eight elements at a time as
 * one vector and the running sum (a serial dependency) advances once per eight.
 * src and dst may be the same buffer.
 */
#define CHUNKS ${work_items}
typedef ${dtype} T;
<% vector = dtype == "float" %>\
% if vector:
typedef ${dtype}8 V;  /* eight consecutive elements, scanned in registers */
% endif
${common.element_count()}
${common.chunk_range()}

% if vector:
/* Inclusive scan of the eight lanes of v, in three shifted additions. */
inline V inclusive_scan8(V v)
{
    v.s1357 += v.s0246;
    v.s2367 += v.s1155;
    v.s4567 += v.s3333;
    return v;
}
% endif

/* A work group (one work-item) is responsible for summing one chunk. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void reduce_chunks(__global const T* src, const uint capacity,
                   __global const uint* device_count, __global T* chunk_sums)
{
    uint begin, end;
    chunk_range(element_count(capacity, device_count), get_global_id(0), &begin, &end);
    uint i = begin;
% if vector:
    /* chunks start on 64-byte boundaries: read them as aligned vectors */
    __global const V* vectors = (__global const V*)(src + begin);
    V lanes = 0, more_lanes = 0;
    for (; i + 16 <= end; i += 16, vectors += 2) {
        lanes += vectors[0];
        more_lanes += vectors[1];
    }
    T sum = inclusive_scan8(lanes + more_lanes).s7;
% else:
    T sum = 0;
% endif
    for (; i < end; ++i)
        sum += src[i];
    chunk_sums[get_global_id(0)] = sum;
}

/* One work-item is responsible for all CHUNKS chunk sums: exclusive prefix
 * sums in place, and the total if asked. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scan_chunk_sums(__global T* chunk_sums, __global T* total)
{
    T running = 0;
    for (uint c = 0; c < CHUNKS; ++c) {
        T sum = chunk_sums[c];
        chunk_sums[c] = running;
        running += sum;
    }
    if (total)
        total[0] = running;
}

/* A work group (one work-item) is responsible for scanning one chunk from
 * the chunk's offset. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scan_chunks(__global const T* src, __global T* dst, const uint capacity,
                 __global const uint* device_count, __global const T* chunk_offsets)
{
    uint begin, end;
    chunk_range(element_count(capacity, device_count), get_global_id(0), &begin, &end);
    T running = chunk_offsets[get_global_id(0)];
    uint i = begin;
% if vector:
    for (; i + 8 <= end; i += 8) {
        V inclusive = inclusive_scan8(*(__global const V*)(src + i)) + running;
% if inclusive:
        *(__global V*)(dst + i) = inclusive;
% else:
        *(__global V*)(dst + i) = (V)(running, inclusive.s012, inclusive.s3456);
% endif
        running = inclusive.s7;
    }
% endif
    for (; i < end; ++i) {
        T x = src[i];
% if inclusive:
        running += x;
        dst[i] = running;
% else:
        dst[i] = running;
        running += x;
% endif
    }
}
