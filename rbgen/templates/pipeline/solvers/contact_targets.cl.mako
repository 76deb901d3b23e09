<%doc>
  A contact's row targets for a substep from how far its bodies moved since the
  step began, shared by the substeps' refresh kernel (solvers/substeps.cl.mako)
  and the persistent PGS launch that runs its substeps itself (solvers/pgs.cl.mako),
  and the share of the impulses a warm start carries (the constraint setup's too,
  constraints.cl.mako).
  The including template supplies the struct ContactConstraint and
  common/inline_math.cl.mako. With `private_copies` it also gets carry_impulses_private
  and refresh_targets_private, the same arithmetic on a lane's private copy of a
  constraint (the persistent launch's sweeps solve such copies).
</%doc>
<%page args="private_copies=False"/>\
/* A warm start carries a manifold's impulses from one substep into the next (and
 * from a step's last substep into the next step's first) only up to a cap on
 * their total normal impulse: CARRY_GROWTH times the total it carried the time
 * before (tangent2_impulse slot 2), plus one substep of gravity (the world's, at
 * least CARRY_ACCELERATION's) on the bodies' reduced mass at the face (slot 3, set
 * up with the constraint; layouts: ContactConstraint). A load at rest is held substep after substep, and a load
 * put on a contact grows from one substep to the next by at most a factor (its
 * share of the weight above), so it is carried whole; the impulse that stops an
 * impact is many times what the contact held before, and the part above the cap
 * is not carried: re-applied in the next substep it pushed the bodies apart
 * again, and the few sweeps after could not take it back from a stack (a box
 * dropped on a resting stack threw the stack up, with restitution 0, and the
 * columns of a dropped pile kept rocking). A new contact carries at most the
 * floor at first. Friction is carried in the same share. The manifold's total,
 * not each point's impulse: the sweeps move a face's load between its points
 * from substep to substep, and that is no impact. */
#define CARRY_GROWTH 1.5f
/* (so that contacts in a world without gravity, pressed by joints or forces, still
 * carry their loads: standard gravity) */
#define CARRY_ACCELERATION 9.81f

/* The share of its impulses a warm start carries from a manifold whose rows
 * accumulated a total normal impulse `total`, having carried `carried` the time
 * before, a carry adding at most `allowance` (see CARRY_GROWTH). */
inline float carried_share(const float total, const float carried, const float allowance)
{
    float cap = CARRY_GROWTH * carried + allowance;
    return total > cap ? cap / total : 1.0f;
}

<%def name="target_functions(space, suffix, carries)">\
/* Scale the impulses of *c that a warm start carries (see CARRY_GROWTH), and keep
 * their total for the next carry. */
inline void carry_impulses${suffix}(${space} ContactConstraint* c)
{
    float4 impulse = c->normal_impulse;
    float total = impulse.x + impulse.y + impulse.z + impulse.w;
    float4 t2 = c->tangent2_impulse;
    float share = carried_share(total, t2.z, t2.w);
    c->normal_impulse = impulse * share;
    /* the friction pair (slot 0) and the twist (tangent1 slot 1) in the same share */
    float4 t1 = c->tangent1_impulse;
    c->tangent1_impulse = (float4)(t1.x * share, t1.y * share, t1.z, t1.w);
    c->tangent2_impulse = (float4)(t2.x * share, t2.y, total * share, t2.w);
}

/* Constraint *c's targets for a substep of h: each point's separation from the
 * bodies' motion (moved: B's displacement less A's; turned_a, turned_b: their
 * rotations), then its velocity target (when `velocity`) and its push target
 * with the push impulse cleared (when `push`); see solvers/substeps.cl.mako.
% if carries:
 * With the velocity targets, the impulses the next substep's warm start carries
 * (carry_impulses). */
% else:
 * (The impulses it carries were carried by the sweep that solved them last.) */
% endif
inline void refresh_targets${suffix}(${space} ContactConstraint* c, float3 moved, float3 turned_a,
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
    if (velocity) {
        c->velocity_target = (float4)(velocity_target[0], velocity_target[1],
                                      velocity_target[2], velocity_target[3]);
% if carries:
        carry_impulses${suffix}(c);  /* (into the next substep's warm start) */
% endif
    }
    if (push) {
        c->position_target = (float4)(position_target[0], position_target[1],
                                      position_target[2], position_target[3]);
        c->push_impulse = (float4)(0.0f);
    }
}
</%def>\
${target_functions("__global", "", True)}
% if private_copies:
/* (on a private copy; its velocity targets do not carry: the sweep that solved the
 * copy last carried its impulses, pgs.cl.mako) */
${target_functions("__private", "_private", False)}
% endif
