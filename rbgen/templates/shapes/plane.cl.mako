/* ---- Plane (rbgen.shapes.Plane): world AABB ---- */

/* The half-space n.x <= d (extents: n, d in the body's frame), placed by the
 * body's pose as the narrowphase places it (plane_to_world): bounded only
 * along an axis-aligned world normal, UNBOUNDED elsewhere. */
inline void plane_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                             __global const float4* hull_vertices, float3* lower, float3* upper)
{
    float3 n = (float3)(dot3(r0, shape.extents.xyz), dot3(r1, shape.extents.xyz),
                        dot3(r2, shape.extents.xyz));
    float d = shape.extents.w + dot3(n, centre);
    float3 lo = (float3)(-UNBOUNDED), hi = (float3)(UNBOUNDED);
    if (n.x > 0.99999f) hi.x = d;
    if (n.y > 0.99999f) hi.y = d;
    if (n.z > 0.99999f) hi.z = d;
    if (n.x < -0.99999f) lo.x = -d;
    if (n.y < -0.99999f) lo.y = -d;
    if (n.z < -0.99999f) lo.z = -d;
    *lower = lo;
    *upper = hi;
}
