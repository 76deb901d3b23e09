<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* Stream compaction, CPU shape: the ${"values" if gather_values else "indices"} of the elements whose flag is
 * nonzero, in input order, and their count, left on the device. CHUNKS
 * work-items (work groups of one) each own one long contiguous chunk:
 *   count_chunks        chunk_counts[c] = set flags in chunk c;
 *   scan_chunk_counts   one work-item: exclusive offsets, total to out_count[0];
 *   scatter_chunks      every work-item writes its kept elements in order.
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
    uint count = 0;
    for (uint i = begin; i < end; ++i)
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

/* A work group (one work-item) is responsible for writing one chunk's kept elements. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scatter_chunks(__global const uint* flags,
% if gather_values:
                    __global const uint* values,
% endif
                    __global uint* out, const uint capacity,
                    __global const uint* device_count, __global const uint* chunk_offsets)
{
    uint begin, end;
    chunk_range(element_count(capacity, device_count), get_global_id(0), &begin, &end);
    uint position = chunk_offsets[get_global_id(0)];
    for (uint i = begin; i < end; ++i)
        if (flags[i] != 0u)
% if gather_values:
            out[position++] = values[i];
% else:
            out[position++] = i;
% endif
}
