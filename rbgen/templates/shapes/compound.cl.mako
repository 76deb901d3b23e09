/* ---- Compound (rbgen.compound.Compound): world AABB ---- */

/* The box of the children in the compound's frame (lower and upper corners at
 * hull_vertices[vertex_offset]), rotated: centre +- |R| half size. */
inline void compound_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                                __global const float4* hull_vertices, float3* lower, float3* upper)
{
    float3 lo = hull_vertices[shape.vertex_offset].xyz, hi = hull_vertices[shape.vertex_offset + 1].xyz;
    float3 middle = 0.5f * (lo + hi);
    float3 half_size = abs_rotate(r0, r1, r2, 0.5f * (hi - lo));
    centre += (float3)(dot3(r0, middle), dot3(r1, middle), dot3(r2, middle));
    *lower = centre - half_size;
    *upper = centre + half_size;
}
