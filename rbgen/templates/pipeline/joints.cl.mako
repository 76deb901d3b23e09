/* The joints' part of a step's constraint-edge list (layouts: ConstraintEdge):
 * edge i is joint i's (joints come first in the list, contacts after them), so
 * that batching colours joints and contacts together and the solver finds a
 * joint through its edge's item. Before that, a joint whose reaction of the
 * last step exceeded its break impulse breaks: it is marked broken, its
 * impulses are cleared, and the solver skips it from now on.
 */
${cl_constants()}

${cl_structs("Body", "JointConstraint", "ConstraintEdge")}

<%include file="/common/quaternion.cl.mako"/>

/* One work-item per joint: first the joint, as the step found it, goes to
 * `backup` (the World's copy of its step slot: a redone step starts again from
 * it, impulses and broken flag), then the break test, then its edge (bodies,
 * item, B's anchor as its point, and the colour of the previous step's edge i
 * when that edge was this joint's: the same item and bodies, among the
 * `previous_count` joint edges the previous step wrote).
 * A work group is responsible for ${work_group_size} consecutive joints. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void prepare_joints(__global JointConstraint* joints,
                    __global JointConstraint* backup,
                    const uint joint_count,
                    __global const Body* bodies,
                    __global ConstraintEdge* edges,
                    __global const ConstraintEdge* previous_edges,
                    const uint previous_count,
                    const float substeps)
{
    uint i = get_global_id(0);
    if (i >= joint_count)
        return;
    __global JointConstraint* j = &joints[i];
    backup[i] = *j;
    uint flags = j->flags;
    /* the last substep's linear impulse (the block's and, across it, a slider's or
     * distance joint's axial rows'), times the substeps: the reaction over a step */
    float axial = 0.0f;
    if (j->kind == RB_JOINT_SLIDER || j->kind == RB_JOINT_DISTANCE)
        axial = j->axial_impulse.x - j->axial_impulse.y;
    float3 block = j->linear_impulse.xyz;
    float reaction = sqrt(dot(block, block) + axial * axial) * substeps;
    if (!(flags & RB_JOINT_BROKEN) && reaction > j->motor.z) {
        flags |= RB_JOINT_BROKEN;
        j->flags = flags;
        j->linear_impulse = j->angular_impulse = j->axial_impulse = (float4)(0.0f);
    }
    uint a = j->body_a, b = j->body_b;
    float3 anchor = j->anchor_b.xyz;
    if (!(flags & RB_JOINT_WORLD))
        anchor = bodies[b].position.xyz + quat_rotate(bodies[b].orientation, anchor);
    ConstraintEdge edge;
    edge.body_a = a;
    edge.body_b = b;
    edge.item = RB_EDGE_JOINT << RB_EDGE_KIND_SHIFT | i;
    edge.colour = RB_SOLVER_NONE;
    if (i < previous_count) {
        ConstraintEdge before = previous_edges[i];
        if (before.item == edge.item && before.body_a == a && before.body_b == b)
            edge.colour = before.colour;
    }
    edge.point = (float4)(anchor, 0.0f);
    edges[i] = edge;
}
