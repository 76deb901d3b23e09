<%doc>
  A contact's row targets for a substep from how far its bodies moved since the
  step began, shared by the substeps' refresh kernel (solvers/substeps.cl.mako)
  and the persistent PGS launch that runs its substeps itself (solvers/pgs.cl.mako).
  The including template supplies the struct ContactConstraint and
  common/inline_math.cl.mako.
</%doc>
/* Constraint *c's targets for a substep of h: each point's separation from the
 * bodies' motion (moved: B's displacement less A's; turned_a, turned_b: their
 * rotations), then its velocity target (when `velocity`) and its push target
 * with the push impulse cleared (when `push`); see solvers/substeps.cl.mako. */
inline void refresh_targets(__global ContactConstraint* c, float3 moved, float3 turned_a,
                            float3 turned_b, const float h, const float penetration_slop,
                            const float penetration_recovery, const bool velocity,
                            const bool push)
{
    uint count = c->point_count;
    float3 n = c->normal.xyz;
    float velocity_target[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    float position_target[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        float4 ra = c->r_a[k], rb = c->r_b[k];
        float separation = ra.w + dot3(n, moved) + dot3(turned_b, cross3(rb.xyz, n))
                         - dot3(turned_a, cross3(ra.xyz, n));
        velocity_target[k] = separation > 0.0f ? -separation / h : 0.0f;
        float push_out = penetration_recovery / h * max1(-separation - penetration_slop, 0.0f);
        position_target[k] = separation > 0.0f ? -penetration_recovery / h * separation
                                               : push_out;
    }
    if (velocity)
        c->velocity_target = (float4)(velocity_target[0], velocity_target[1],
                                      velocity_target[2], velocity_target[3]);
    if (push) {
        c->position_target = (float4)(position_target[0], position_target[1],
                                      position_target[2], position_target[3]);
        c->push_impulse = (float4)(0.0f);
    }
}
