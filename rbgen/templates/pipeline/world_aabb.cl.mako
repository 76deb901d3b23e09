<%!
    from rbgen.shapes import shape_type
%>\
<%
    # the registry entries of this world's shape types (rbgen.shapes)
    types = [shape_type(name) for name in shape_types]
%>/* ---- World-space AABB of one body (compute_world_aabbs, prepare_bodies) ----
 *
 * Each shape type writes its box with its own function, <type>_world_aabb
 * (rbgen/templates/shapes/), from the body's centre and the rows of its
 * rotation; the box is then grown by `margin` on all sides. A shape of
 * another type gets an inverted box, which the broadphase reports.
 * Shape types handled: ${", ".join(shape_types)}.
 */

/* Bound used for the unbounded sides of planes. */
#define UNBOUNDED 1e30f

/* Half extents of a box with half extents e rotated by the rows r0, r1, r2:
 * |R| e, R's entries taken by absolute value. */
inline float3 abs_rotate(float3 r0, float3 r1, float3 r2, float3 e)
{
    return (float3)(dot3(abs3(r0), e), dot3(abs3(r1), e), dot3(abs3(r2), e));
}

% for path in dict.fromkeys(t.aabb_template for t in types):
<%include file="/${path}"/>

% endfor
/* r0, r1, r2: the rows of the body's rotation. */
inline void write_world_aabb(Body body, Shape shape, float3 r0, float3 r1, float3 r2,
                             __global const float4* hull_vertices, float margin, __global Aabb* out)
{
    float3 centre = body.position.xyz;
    float3 lower, upper;

    switch (shape.type) {
% for t in types:
    case ${t.type_constant}:
        ${t.type_name}_world_aabb(shape, centre, r0, r1, r2, hull_vertices, &lower, &upper);
        break;
% endfor
    default:
        /* unknown type: an inverted box, which the broadphase reports as an error */
        lower = (float3)(UNBOUNDED);
        upper = (float3)(-UNBOUNDED);
        break;
    }
    out->lower = (float4)(lower - margin, 0.0f);
    out->upper = (float4)(upper + margin, 0.0f);
}

/* A fast body's box swept along its travel this step: its speculative distance
 * (linear_velocity.w, prepare_bodies: |v| dt, or 0 for a body that is not fast)
 * along its velocity. Boxes of other bodies are left as they are. */
inline void sweep_world_aabb(Body body, __global Aabb* out)
{
    float reach = body.linear_velocity.w;
    if (reach > 0.0f) {
        float3 travel = body.linear_velocity.xyz * (reach / length3(body.linear_velocity.xyz));
        out->lower.xyz += fmin(travel, (float3)(0.0f));
        out->upper.xyz += fmax(travel, (float3)(0.0f));
    }
}
