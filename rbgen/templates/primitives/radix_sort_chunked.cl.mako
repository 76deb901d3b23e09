<%namespace name="common" file="/primitives/common.cl.mako"/>\
/* Stable LSD radix sort of uint keys${" with uint values" if with_values else ""}, CPU shape: one pass per
 * RADIX_BITS-bit digit.
 *
 * CHUNKS work-items (work groups of one) each own one long contiguous chunk.
 * Per pass:
 *   count_digits    each work-item counts the digits of its chunk in a private
 *                   histogram and writes it to column c of the digit table,
 *                   laid out digit-major: table[digit * CHUNKS + c];
 *   (host)          an exclusive scan of the whole table (Scan primitive) gives
 *                   every (digit, chunk) pair its first output position;
 *   scatter_digits  each work-item walks its chunk in order and moves every key
 *                   to the next position of its digit. Chunks are in input order
 *                   and walked in order, so equal digits keep their order: stable.
 */
#define CHUNKS ${work_items}
#define RADIX_BITS ${radix_bits}
#define RADIX (1u << RADIX_BITS)
${common.element_count()}
${common.chunk_range()}

/* A work group (one work-item) is responsible for the digit histogram of one chunk. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void count_digits(__global const uint* keys, const uint capacity,
                  __global const uint* device_count, const uint shift, const uint digit_mask,
                  __global uint* table)
{
    const uint chunk = get_global_id(0);
    uint begin, end;
    chunk_range(element_count(capacity, device_count), chunk, &begin, &end);
    uint histogram[RADIX];
    for (uint d = 0; d < RADIX; ++d)
        histogram[d] = 0;
    for (uint i = begin; i < end; ++i)
        ++histogram[(keys[i] >> shift) & digit_mask];
    for (uint d = 0; d < RADIX; ++d)
        table[d * CHUNKS + chunk] = histogram[d];
}

/* A work group (one work-item) is responsible for moving one chunk's keys
 * to the positions the scanned digit table assigns them. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void scatter_digits(__global const uint* keys_in, __global uint* keys_out,
% if with_values:
                    __global const uint* values_in, __global uint* values_out,
% endif
                    const uint capacity, __global const uint* device_count,
                    const uint shift, const uint digit_mask, __global const uint* table)
{
    const uint chunk = get_global_id(0);
    uint begin, end;
    chunk_range(element_count(capacity, device_count), chunk, &begin, &end);
    uint next[RADIX];
    for (uint d = 0; d < RADIX; ++d)
        next[d] = table[d * CHUNKS + chunk];
    for (uint i = begin; i < end; ++i) {
        uint key = keys_in[i];
        uint position = next[(key >> shift) & digit_mask]++;
        keys_out[position] = key;
% if with_values:
        values_out[position] = values_in[i];
% endif
    }
}

/* A work group (one work-item) is responsible for copying one chunk back
 * after an odd number of passes. */
__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void copy_back(__global const uint* keys_in, __global uint* keys_out,
% if with_values:
               __global const uint* values_in, __global uint* values_out,
% endif
               const uint capacity, __global const uint* device_count)
{
    uint begin, end;
    chunk_range(element_count(capacity, device_count), get_global_id(0), &begin, &end);
    for (uint i = begin; i < end; ++i) {
        keys_out[i] = keys_in[i];
% if with_values:
        values_out[i] = values_in[i];
% endif
    }
}
