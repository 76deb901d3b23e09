/* ---- Capsule (rbgen.shapes.Capsule): world AABB ---- */

/* Exact: the segment along local y of half length extents.y, swept by the
 * radius extents.x. */
inline void capsule_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                               __global const float4* hull_vertices, float3* lower, float3* upper)
{
    float3 half_size = abs_rotate(r0, r1, r2, (float3)(0.0f, shape.extents.y, 0.0f)) + shape.extents.x;
    *lower = centre - half_size;
    *upper = centre + half_size;
}
