/* Fill the first n elements of a ${dtype} array with one value. A work group is
 * responsible for TILE = WG * ITEMS consecutive elements; work-item lid writes
 * elements lid, lid + WG, ... of the tile (coalesced on GPUs, contiguous
 * across the vector lanes of a CPU). */
#define WG ${work_group_size}
#define ITEMS ${items_per_thread}
#define TILE (WG * ITEMS)
typedef ${dtype} T;

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void fill(__global T* array, const T value, const uint capacity, __global const uint* device_count)
{
    const uint n = device_count ? min(device_count[0], capacity) : capacity;
    const uint tile_start = get_group_id(0) * TILE;
    for (uint j = 0; j < ITEMS; ++j) {
        uint i = tile_start + j * WG + get_local_id(0);
        if (i < n)
            array[i] = value;
    }
}
