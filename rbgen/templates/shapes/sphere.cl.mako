/* ---- Sphere (rbgen.shapes.Sphere): world AABB ---- */

/* extents.x is the radius. */
inline void sphere_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                              __global const float4* hull_vertices, float3* lower, float3* upper)
{
    *lower = centre - shape.extents.x;
    *upper = centre + shape.extents.x;
}
