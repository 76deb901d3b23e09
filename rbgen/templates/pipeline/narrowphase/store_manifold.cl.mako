/* ---- Writing a pair's manifold slot (pair kernels and clip_incident_face) ---- */

/* Pairs per placement tile: scatter_manifolds places one tile per work group
 * and needs the number of manifolds in every earlier tile (tile_counts). */
#define PLACEMENT_TILE ${placement_tile}u

/* Store up to four points computed in the kernel's order (normal from first to
 * second, points on second) into the pair's slot in the pair's order (normal
 * from a to b, points on b), flag the slot and count it in its placement
 * tile. A point on the second body moves
 * to the first body's surface by -separation along the normal. */
inline void store_manifold(__global ContactManifold* slots, __global uint* contact_flags,
                           __global uint* tile_counts,
                           QueuedPair q, float3 normal, const float4* points,
                           const uint* features, uint count)
{
    __global ContactManifold* m = &slots[q.index];
    for (uint k = 0; k < count; ++k) {
        float4 p = points[k];
        if (q.swapped)
            p.xyz -= normal * p.w;
        m->points[k] = p;
        m->features[k] = features[k];
    }
    m->normal = (float4)(q.swapped ? -normal : normal, 0.0f);
    m->body_a = q.swapped ? q.second : q.first;
    m->body_b = q.swapped ? q.first : q.second;
    m->sub = q.sub;
    m->point_count = count;
    contact_flags[q.index] = 1u;
    atomic_inc(&tile_counts[q.index / PLACEMENT_TILE]);
}
