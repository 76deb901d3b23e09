<%
    # Branches are emitted only for the shape types this world contains.
    emit = set(shape_types)
%>/* World-space AABB of every body.
 *
 * One work-item per body; a work group is responsible for ${work_group_size}
 * consecutive bodies. The box of a shape centred on the body is
 * centre +- |R| e, where |R| is the element-wise absolute rotation matrix and
 * e the local half extents (exact for boxes, spheres and capsules). Hulls take
 * the exact support along each world axis from their vertices. Every box is
 * grown by `margin` on all sides. Shape types handled: ${", ".join(shape_types)}.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Aabb")}

<%include file="/common/quaternion.cl.mako"/>

/* Bound used for the unbounded sides of planes. */
#define UNBOUNDED 1e30f

inline float3 abs_rotate(float3 r0, float3 r1, float3 r2, float3 e)
{
    return (float3)(dot(fabs(r0), e), dot(fabs(r1), e), dot(fabs(r2), e));
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void compute_world_aabbs(__global const Body* bodies,
                         __global const Shape* shapes,
                         __global const float4* hull_vertices,
                         __global Aabb* aabbs,
                         const uint body_count,
                         const float margin)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    Body body = bodies[i];
    Shape shape = shapes[body.shape];
    float3 centre = body.position.xyz;
    float3 r0, r1, r2;
    quat_to_rows(body.orientation, &r0, &r1, &r2);
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
            float3 world = (float3)(dot(r0, p), dot(r1, p), dot(r2, p));
            lower = fmin(lower, world);
            upper = fmax(upper, world);
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
    aabbs[i].lower = (float4)(lower - margin, 0.0f);
    aabbs[i].upper = (float4)(upper + margin, 0.0f);
}
