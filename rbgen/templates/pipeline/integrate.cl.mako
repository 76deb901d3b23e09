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

/* Below this angular speed * dt, sin(a/2)/a and cos(a/2) are replaced by their
 * series (the next terms are below float precision). */
#define SMALL_ROTATION 0.001f

inline float4 quat_normalized(float4 q)
{
    return q * (1.0f / sqrt1(dot3(q.xyz, q.xyz) + q.w * q.w));
}

inline float4 rotate_by_angular_velocity(float4 q, float3 w, float dt, float max_angular_step)
{
    float speed = length3(w);
    if (speed * dt > max_angular_step)
        w *= max_angular_step / (dt * speed), speed = max_angular_step / dt;
    float half_angle = 0.5f * speed * dt;
    float4 dq;
    if (speed * dt < SMALL_ROTATION) {
        /* sin(s dt / 2) / s = dt/2 - dt^3 s^2 / 48 + O(s^4); cos(a) = 1 - a^2/2 + O(a^4) */
        dq.xyz = w * (0.5f * dt - dt * dt * dt * (1.0f / 48.0f) * speed * speed);
        dq.w = 1.0f - 0.5f * half_angle * half_angle;
    } else {
        dq.xyz = w * (sin(half_angle) / speed);
        dq.w = cos(half_angle);
    }
    float4 turned = quat_mul(dq, q);
    return quat_normalized(turned);
}

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
    float3 moved = v * dt, turned = w * dt;
    float speed = length3(w);
    if (speed * dt > max_angular_step)  /* (the clamp rotate_by_angular_velocity applied) */
        turned *= max_angular_step / (dt * speed);
% endif
% if split:
    /* the arithmetic of the solver's apply_split_velocities, term for term (the same
     * roundings: a World steps exactly as with that kernel) */
    float3 push = split[i].linear.xyz, h = 0.5f * dt * split[i].angular.xyz;
    body->position.xyz += push * dt;
    float4 q = body->orientation;
    float3 hq = h * q.xyz;
    float4 dq = (float4)(q.w * h + (h.yzx * q.zxy - h.zxy * q.yzx), -(hq.x + hq.y + hq.z));
    body->orientation = normalize(q + dq);
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

/* v += g dt for every dynamic body: run before the contact solver so that
 * resting contacts see (and cancel) this step's gravity. A work group is
 * responsible for ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void apply_gravity(__global Body* bodies, const uint body_count, const float dt, const float4 gravity)
{
    uint i = get_global_id(0);
    if (i >= body_count || bodies[i].inv_mass == 0.0f)
        return;
    bodies[i].linear_velocity.xyz += gravity.xyz * dt;
}
% endif
