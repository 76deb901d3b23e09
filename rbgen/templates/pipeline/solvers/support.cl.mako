/* Support chains as launches of their own (solvers/support_chains.cl.mako says what
 * they compute): a solve that does not run its substeps itself takes them between its
 * sweeps and the integrator, each substep: offer_supports (`supports` is zero, no support,
 * everywhere before; `flip`: 0 on even substeps, RB_SUPPORT_INDEX on odd ones), link_supports (`up`: against gravity, a unit vector; `slack`: RB_SUPPORT_SLACK |g| h), `rounds` jump_supports (round r from links' half
 * r % 2 to the other: links holds 2 body_count records) and apply_supports (from the
 * half the last round wrote; it clears `supports` again). One work-item per constraint or
 * body; a work group is responsible for ${work_group_size} consecutive ones. The
 * constraint count stays on the device.
 */
${cl_constants()}

${cl_structs("Body", "ContactConstraint")}

<%include file="/common/inline_math.cl.mako"/>

<%include file="/pipeline/solvers/support_chains.cl.mako"/>

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void offer_supports(__global const ContactConstraint* constraints,
                    __global const uint* constraint_count, const uint capacity,
                    const uint flip, volatile __global uint* supports)
{
    const uint i = get_global_id(0);
    if (i < min(constraint_count[0], capacity))
        offer_support(constraints, i, flip, supports);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void link_supports(__global const ContactConstraint* constraints,
                   __global const Body* bodies, volatile __global const uint* supports,
                   const uint flip, volatile __global float4* links, const uint body_count,
                   const float4 up, const float slack)
{
    const uint k = get_global_id(0);
    if (k < body_count)
        links[k] = support_link(constraints, bodies, supports, flip, up.xyz, slack, k);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jump_supports(volatile __global float4* links, const uint body_count, const uint round)
{
    const uint k = get_global_id(0);
    const uint from = (round & 1u) * body_count, to = body_count - from;
    if (k < body_count)
        links[to + k] = support_jump(links + from, k);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void apply_supports(__global Body* bodies, volatile __global uint* supports,
                    volatile __global const float4* links, const uint body_count,
                    const float4 up, const uint rounds)
{
    const uint k = get_global_id(0);
    if (k < body_count)
        support_apply(bodies, supports, up.xyz, links[(rounds & 1u) * body_count + k], k);
}
