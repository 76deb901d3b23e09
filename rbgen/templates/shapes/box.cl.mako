/* ---- Box (rbgen.shapes.Box): world AABB ---- */

/* Exact: centre +- |R| e, e the half extents (extents.xyz). */
inline void box_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                           __global const float4* hull_vertices, float3* lower, float3* upper)
{
    float3 half_size = abs_rotate(r0, r1, r2, shape.extents.xyz);
    *lower = centre - half_size;
    *upper = centre + half_size;
}
