/* Between the substeps of a step: each contact's separations from its bodies'
 * motion so far, and the targets of its rows for the next substep.
 *
 * Contacts are found once a step; within the step a point keeps its lever
 * arms r_a, r_b and normal n, and its separation follows the bodies: a body
 * that moved by dx and turned by dtheta (BodyDelta, first order) moved the
 * point by dx + dtheta x r, so
 *   s = s0 + n . (dx_b - dx_a) + dtheta_b . (r_b x n) - dtheta_a . (r_a x n)
 * with s0 the separation at setup (r_a[k].w). From it, as the setup did for the
 * first substep (constraints.cl.mako), over the substep h:
 *   velocity target: -s/h while apart (close the gap, no further); the bounce
 *     (r_b[k].w) of a point that touches; of one whose gap would be crossed
 *     within the substep, the velocity that lands it and bounces it within the
 *     substep, bounce - (1 + e) s / h;
 *   push target: recovery/h of the penetration beyond the slop, or -recovery/h
 *     of the gap of a point still apart.
 * The push impulses start again from zero, as the push velocities do.
 * One work-item per constraint; a work group is responsible for
 * ${work_group_size} consecutive constraints. The count stays on the device.
 */
${cl_constants()}

${cl_structs("ContactConstraint", "BodyDelta")}

<%include file="/common/inline_math.cl.mako"/>

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void refresh_contact_targets(__global ContactConstraint* constraints,
                             __global const uint* constraint_count,
                             const uint capacity,
                             __global const BodyDelta* deltas,
                             const float h,
                             const float penetration_slop,
                             const float penetration_recovery)
{
    uint i = get_global_id(0);
    if (i >= min(constraint_count[0], capacity))
        return;
    __global ContactConstraint* c = &constraints[i];
    uint a = c->body_a, b = c->body_b, count = c->point_count;
    float3 n = c->normal.xyz;
    float restitution = c->tangent2.w;
    float3 moved = deltas[b].linear.xyz - deltas[a].linear.xyz;
    float3 turned_a = deltas[a].angular.xyz, turned_b = deltas[b].angular.xyz;
    float velocity_target[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    float position_target[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        float4 ra = c->r_a[k], rb = c->r_b[k];
        float separation = ra.w + dot3(n, moved) + dot3(turned_b, cross3(rb.xyz, n))
                         - dot3(turned_a, cross3(ra.xyz, n));
        float bounce = rb.w;
        if (separation > 0.0f)
            velocity_target[k] = (bounce > 0.0f && bounce * h > restitution * separation)
                                 ? bounce - (1.0f + restitution) * separation / h
                                 : -separation / h;
        else
            velocity_target[k] = bounce;
        float push = penetration_recovery / h * max1(-separation - penetration_slop, 0.0f);
        position_target[k] = separation > 0.0f ? -penetration_recovery / h * separation : push;
    }
    c->velocity_target = (float4)(velocity_target[0], velocity_target[1], velocity_target[2],
                                  velocity_target[3]);
    c->position_target = (float4)(position_target[0], position_target[1], position_target[2],
                                  position_target[3]);
    c->push_impulse = (float4)(0.0f);
}
