/* Integrate rigid bodies over one time step (semi-implicit Euler).
 *
 * One work-item per body; a work group is responsible for ${work_group_size}
 * consecutive bodies. Static bodies (inv_mass == 0) are left untouched.
% if gravity:
 *   v  += g dt                     (gravity, dynamic bodies only)
% else:
 *   (gravity is applied before the solver by apply_gravity, not here)
% endif
% if damping:
 *   v  *= linear_damping_factor,  w *= angular_damping_factor
 *         (the factors (1 - damping)^dt are the same for every body: the host
 *         computes them once)
% endif
 *   x  += v dt
 *   q   = dq(w dt) q, renormalised, where dq is the axis-angle quaternion of
 *         the rotation w dt; sin(a/2)/a uses its Taylor series for small a so
 *         that slow spins keep full precision. The rotation per step is
 *         clamped to max_angular_step radians (the stored w is not changed).
% if split:
 *   then the split-impulse push (the solver's position sweeps' velocities),
 *   which moves the body and is cleared:
 *   x  += v_push dt,  q += (w_push dt / 2, 0) q (first order), renormalised
 *   (the solver's apply_split_velocities, fused here: one launch less).
% endif
% if deltas:
 *   and, for the substeps of a step, how far the body moved since the step
 *   began (BodyDelta: restarted by the first substep), from which contacts
 *   update their separations (solvers/substeps.cl.mako).
% endif
 */
${cl_constants()}

${cl_structs("Body", *(("SplitVelocity",) if split else ()), *(("BodyDelta",) if deltas else ()))}

<%include file="/common/quaternion.cl.mako"/>

<%include file="/common/body_motion.cl.mako"/>

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void integrate_bodies(__global Body* bodies,
                      const uint body_count,
                      const float dt,
% if gravity:
                      const float4 gravity,
% endif
% if damping:
                      const float linear_damping_factor,
                      const float angular_damping_factor,
% endif
% if split:
                      __global SplitVelocity* split,
% endif
% if deltas:
                      __global BodyDelta* deltas,
                      const uint first_substep,
% endif
                      const float max_angular_step)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    __global Body* body = &bodies[i];
    if (body->inv_mass == 0.0f)
        return;

% if gravity:
    float3 v = body->linear_velocity.xyz + gravity.xyz * dt;
% else:
    float3 v = body->linear_velocity.xyz;
% endif
    float3 w = body->angular_velocity.xyz;
% if damping:
    v *= linear_damping_factor;
    w *= angular_damping_factor;
% endif
    body->linear_velocity.xyz = v;
    body->angular_velocity.xyz = w;
    body->position.xyz += v * dt;
    body->orientation = rotate_by_angular_velocity(body->orientation, w, dt, max_angular_step);
% if deltas:
    float3 moved = v * dt, turned = turn_of(w, dt, max_angular_step);
% endif
% if split:
    /* the arithmetic of the solver's apply_split_velocities, term for term (the same
     * roundings: a World steps exactly as with that kernel) */
    float3 push = split[i].linear.xyz, h = 0.5f * dt * split[i].angular.xyz;
    body->position.xyz += push * dt;
    body->orientation = push_orientation(body->orientation, h);
    split[i].linear = (float4)(0.0f);
    split[i].angular = (float4)(0.0f);
% if deltas:
    moved += push * dt, turned += 2.0f * h;
% endif
% endif
% if deltas:
    if (first_substep) {
        deltas[i].linear = (float4)(moved, 0.0f);
        deltas[i].angular = (float4)(turned, 0.0f);
    } else {
        deltas[i].linear.xyz += moved;
        deltas[i].angular.xyz += turned;
    }
% endif
}
% if not gravity:

/* v += g dt for every dynamic body, and with `kicked` the step's external forces for
 * a substep (`kicks`: the prepare kernel's, 2 float4 a body): run before the contact
 * solver so that resting contacts see (and cancel) them. A work group is
 * responsible for ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void apply_gravity(__global Body* bodies, const uint body_count, const float dt, const float4 gravity,
                   __global const float4* kicks, const uint kicked)
{
    uint i = get_global_id(0);
    if (i >= body_count || bodies[i].inv_mass == 0.0f)
        return;
    bodies[i].linear_velocity.xyz += gravity.xyz * dt;
    if (kicked) {  /* the step's external forces, for this substep (prepare.cl.mako) */
        bodies[i].linear_velocity.xyz += kicks[2 * i].xyz;
        bodies[i].angular_velocity.xyz += kicks[2 * i + 1].xyz;
    }
}
% endif
