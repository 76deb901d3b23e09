<%
    # Branches are emitted only for the shape types this world contains.
    emit = set(shape_types)
%>/* ---- World-space AABB of one body (compute_world_aabbs, prepare_bodies) ----
 *
 * The box of a shape centred on the body is centre +- |R| e, where |R| is the
 * element-wise absolute rotation matrix and e the local half extents (exact
 * for boxes, spheres and capsules). Hulls take the exact support along each
 * world axis from their vertices. The box is grown by `margin` on all sides.
 * Shape types handled: ${", ".join(shape_types)}.
 */

/* Bound used for the unbounded sides of planes. */
#define UNBOUNDED 1e30f

inline float3 abs_rotate(float3 r0, float3 r1, float3 r2, float3 e)
{
    return (float3)(dot3(abs3(r0), e), dot3(abs3(r1), e), dot3(abs3(r2), e));
}

/* r0, r1, r2: the rows of the body's rotation. */
inline void write_world_aabb(Body body, Shape shape, float3 r0, float3 r1, float3 r2,
                             __global const float4* hull_vertices, float margin, __global Aabb* out)
{
    float3 centre = body.position.xyz;
    float3 lower, upper;

    switch (shape.type) {
% if "sphere" in emit:
    case RB_SHAPE_SPHERE:
        lower = centre - shape.extents.x;
        upper = centre + shape.extents.x;
        break;
% endif
% if "box" in emit:
    case RB_SHAPE_BOX: {
        float3 half_size = abs_rotate(r0, r1, r2, shape.extents.xyz);
        lower = centre - half_size;
        upper = centre + half_size;
        break;
    }
% endif
% if "capsule" in emit:
    case RB_SHAPE_CAPSULE: {
        /* segment along local y of half length extents.y, swept by radius extents.x */
        float3 half_size = abs_rotate(r0, r1, r2, (float3)(0.0f, shape.extents.y, 0.0f)) + shape.extents.x;
        lower = centre - half_size;
        upper = centre + half_size;
        break;
    }
% endif
% if "hull" in emit:
    case RB_SHAPE_HULL: {
        lower = (float3)(UNBOUNDED);
        upper = (float3)(-UNBOUNDED);
        for (uint v = 0; v < shape.vertex_count; ++v) {
            float3 p = hull_vertices[shape.vertex_offset + v].xyz;
            float3 world = (float3)(dot3(r0, p), dot3(r1, p), dot3(r2, p));
            lower = (float3)(min1(lower.x, world.x), min1(lower.y, world.y), min1(lower.z, world.z));
            upper = (float3)(max1(upper.x, world.x), max1(upper.y, world.y), max1(upper.z, world.z));
        }
        lower += centre;
        upper += centre;
        break;
    }
% endif
% if "plane" in emit:
    case RB_SHAPE_PLANE: {
        /* Half-space n.x <= d (world frame): bounded only along an axis-aligned normal. */
        float3 n = shape.extents.xyz;
        float d = shape.extents.w;
        lower = (float3)(-UNBOUNDED);
        upper = (float3)(UNBOUNDED);
        if (n.x > 0.99999f) upper.x = d;
        if (n.y > 0.99999f) upper.y = d;
        if (n.z > 0.99999f) upper.z = d;
        if (n.x < -0.99999f) lower.x = -d;
        if (n.y < -0.99999f) lower.y = -d;
        if (n.z < -0.99999f) lower.z = -d;
        break;
    }
% endif
    default:
        /* unknown type: an inverted box, which the broadphase reports as an error */
        lower = (float3)(UNBOUNDED);
        upper = (float3)(-UNBOUNDED);
        break;
    }
    out->lower = (float4)(lower - margin, 0.0f);
    out->upper = (float4)(upper + margin, 0.0f);
}
