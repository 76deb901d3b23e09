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
 *   velocity target: -s/h while apart (close the gap, no further: a point
 *     lands exactly), 0 once it touches (the bounce, r_b[k].w, comes once,
 *     after the rows of the step's last velocity sweep: contact_rows.cl.mako's
 *     apply_restitution, for the points that push);
 *   push target: recovery/h of the penetration beyond the slop, or -recovery/h
 *     of the gap of a point still apart.
 * The push impulses start again from zero, as the push velocities do.
 * One work-item per constraint; a work group is responsible for
 * ${work_group_size} consecutive constraints. The count stays on the device.
 */
${cl_constants()}

${cl_structs("ContactConstraint", "BodyDelta")}

<%include file="/common/inline_math.cl.mako"/>

<%include file="/pipeline/solvers/contact_targets.cl.mako"/>

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
    uint a = constraints[i].body_a, b = constraints[i].body_b;
    refresh_targets(&constraints[i], deltas[b].linear.xyz - deltas[a].linear.xyz,
                    deltas[a].angular.xyz, deltas[b].angular.xyz, h, penetration_slop,
                    penetration_recovery, true, true);
}
