<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* Stream compaction, CPU shape: the ${"values" if gather_values else "indices"} of the elements whose flag is
 * nonzero, in input order, and their count, left on the device. CHUNKS
 * work-items (work groups of one) each own one long contiguous chunk:
 *   count_chunks        chunk_counts[c] = set flags in chunk c;
 *   scan_chunk_counts   one work-item: exclusive offsets, total to out_count[0];
 *   scatter_chunks      every work-item writes its kept elements in order
 *                       (branch-free: a random 25% keep rate defeats branch
 *                       prediction).
 */
#define CHUNKS ${work_items}
${common.element_count()}
${common.chunk_range()}

/* A work group (one work-item) is responsible for counting one chunk's set flags. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void count_chunks(__global const uint* flags, const uint capacity,
                  __global const uint* device_count, __global uint* chunk_counts)
{
    uint begin, end;
    chunk_range(element_count(capacity, device_count), get_global_id(0), &begin, &end);
    /* chunks start on 64-byte boundaries: count eight flags at a time */
    __global const uint8* vectors = (__global const uint8*)(flags + begin);
    const uint vector_count = (end - begin) / 8;
    uint8 counts = 0;
    for (uint k = 0; k < vector_count; ++k)
        counts += select((uint8)0u, (uint8)1u, vectors[k] != (uint8)0u);
    uint count = counts.s0 + counts.s1 + counts.s2 + counts.s3
               + counts.s4 + counts.s5 + counts.s6 + counts.s7;
    for (uint i = begin + 8 * vector_count; i < end; ++i)
        count += flags[i] != 0u ? 1u : 0u;
    chunk_counts[get_global_id(0)] = count;
}

/* One work-item is responsible for all chunk counts. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scan_chunk_counts(__global uint* chunk_counts, __global uint* out_count)
{
    uint running = 0;
    for (uint c = 0; c < CHUNKS; ++c) {
        uint count = chunk_counts[c];
        chunk_counts[c] = running;
        running += count;
    }
    out_count[0] = running;
}

/* A work group (one work-item) is responsible for writing one chunk's kept
 * elements. Branch-free: every element is written to the next free slot and
 * the slot advances only when the element is kept, so a dropped element is
 * overwritten by the next kept one; the walk stops when the chunk's slots
 * (up to the next chunk's offset, or the total) are full, so nothing is
 * written outside them. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scatter_chunks(__global const uint* flags,
% if gather_values:
                    __global const uint* values,
% endif
                    __global uint* out, const uint capacity,
                    __global const uint* device_count, __global const uint* chunk_offsets,
                    __global const uint* out_count)
{
    const uint chunk = get_global_id(0);
    uint begin, end;
    chunk_range(element_count(capacity, device_count), chunk, &begin, &end);
    uint position = chunk_offsets[chunk];
    const uint limit = chunk + 1 < CHUNKS ? chunk_offsets[chunk + 1] : out_count[0];
    for (uint i = begin; i < end && position < limit; ++i) {
% if gather_values:
        out[position] = values[i];
% else:
        out[position] = i;
% endif
        position += flags[i] != 0u ? 1u : 0u;
    }
}
