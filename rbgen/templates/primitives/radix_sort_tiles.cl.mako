## Kernels shared by the tile-shaped radix sorts (radix_sort_tiled, radix_sort_split),
## as Mako defs. The including template defines WG, ITEMS, TILE and RADIX and
## renders common.element_count() first.

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
