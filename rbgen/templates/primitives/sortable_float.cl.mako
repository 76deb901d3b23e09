/* Order-preserving bit flip between float32 and uint32 sort keys.
 * Negative floats get every bit flipped, the others only the sign bit: then
 * unsigned integer order equals float order. One work-item per element. */
#define WG ${work_group_size}

/* A work group is responsible for WG consecutive floats: float bits -> key. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void float_to_sortable(__global const uint* float_bits, __global uint* keys, const uint count)
{
    const uint i = get_global_id(0);
    if (i >= count)
        return;
    uint bits = float_bits[i];
    keys[i] = bits ^ ((bits >> 31) ? 0xFFFFFFFFu : 0x80000000u);
}

/* A work group is responsible for WG consecutive keys: key -> float bits. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void sortable_to_float(__global const uint* keys, __global uint* float_bits, const uint count)
{
    const uint i = get_global_id(0);
    if (i >= count)
        return;
    uint key = keys[i];
    float_bits[i] = key ^ ((key >> 31) ? 0x80000000u : 0xFFFFFFFFu);
}
