/* ---- Convex hull (rbgen.shapes.ConvexHull): world AABB ---- */

/* Exact: the support along each world axis, over the hull's vertices. */
inline void hull_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                            __global const float4* hull_vertices, float3* lower, float3* upper)
{
    float3 lo = (float3)(UNBOUNDED), hi = (float3)(-UNBOUNDED);
    for (uint v = 0; v < shape.vertex_count; ++v) {
        float3 p = hull_vertices[shape.vertex_offset + v].xyz;
        float3 world = (float3)(dot3(r0, p), dot3(r1, p), dot3(r2, p));
        lo = (float3)(min1(lo.x, world.x), min1(lo.y, world.y), min1(lo.z, world.z));
        hi = (float3)(max1(hi.x, world.x), max1(hi.y, world.y), max1(hi.z, world.z));
    }
    *lower = lo + centre;
    *upper = hi + centre;
}
