<%!
    from rbgen.pipeline.prepare import FAST_FRACTION
%>\
/* Per-body preparation before the contact solver.
 *
 * One work-item per body; a work group is responsible for ${work_group_size}
 * consecutive bodies.
% if backup:
 * First every body, as it is, goes to `backup` (the World's copy of the
 * step's start, from which a step whose buffers overflowed is redone: here
 * rather than in a copy command of its own, which costs a GPU's queue as
 * much as a launch).
% endif
 * For every dynamic body:
% if gravity:
 *   - gravity, v += g dt (here rather than in a launch of its own);
% endif
% if gyroscopic:
 *   - the implicit gyroscopic term: one Newton step (from w) of the implicit
 *     midpoint rule I (w' - w) + dt m x (I m) = 0, m = (w + w') / 2, in the
 *     body frame. Bullet 2.x solves implicit Euler (w' in place of m), which
 *     bleeds angular momentum (16% in 10 s for a box tumbling near its
 *     middle axis at 5 rad/s); the midpoint rule keeps |L| to 1e-5 and its
 *     direction to 0.5% there, and costs the same;
% endif
 *   - the world inverse inertia tensor R diag(I^-1) R^T, which the solver
 *     reads for every contact row;
% if external_forces:
 *   - the step's external forces (rbgen.forces), for the first substep of h:
 *     v += F h / m, w += I^-1 (M - x cross F_lever) h, with x the centre of mass
 *     at the step's start (the host never reads x to turn a force at a point
 *     into a torque); the same changes go to `kicks` (2 float4 a body: linear,
 *     angular; zero for a static body), which every later substep adds as it
 *     adds g h, so that a force acts through the step as gravity does.
 *     force_terms says which of the three arrays were given (bits RB_FORCE_*),
 *     the others being zero and unread; with none, `kicks` is not written (the
 *     substeps are told not to read it). The arrays are read, not cleared: a
 *     redone step reads the same forces again.
% endif
 * Static bodies get a zero tensor.
% if shape_types:
 * Every body, static or not, also gets its world AABB for the broadphase
 * (the step's positions and orientations, which this kernel does not change:
 * one launch instead of a compute_world_aabbs of its own), and its
 * speculative distance (continuous collision, below).
% endif
 */
${cl_constants()}

${cl_structs("Body", "BodyInertia", *(("Shape", "Aabb") if shape_types else ()))}

<%include file="/common/quaternion.cl.mako"/>
% if shape_types:
<%include file="/pipeline/world_aabb.cl.mako"/>

/* Continuous collision by speculative contacts. A dynamic body is fast when
 * one step's travel |v| dt exceeds FAST_FRACTION of its inner radius (the
 * shape's extents.w; Box2D v3's test): its speculative distance, kept in
 * linear_velocity.w for this step, is then that travel, and its AABB is
 * swept along it, so that the broadphase pairs it with what lies ahead and
 * the narrowphase keeps the pair's points up to margin + the two bodies'
 * speculative distances apart. The solver lets a point apart close its gap
 * this step and no more, so a fast body stops at the surface it would have
 * passed. Every other body gets 0: its AABB and its pairs' margin are those
 * of a world without continuous collision. */
#define FAST_FRACTION ${FAST_FRACTION}f

inline float speculative_distance(Body body, float inner_radius, float3 travel)
{
    float reach = length3(travel);
    return body.inv_mass > 0.0f && reach > FAST_FRACTION * inner_radius ? reach : 0.0f;
}
% endif

% if gyroscopic:
/* Solve J x = f for a 3x3 matrix given by rows (Cramer's rule); J is the
 * Jacobian of the gyroscopic residual, diagonally dominant for dt small. */
inline float3 solve3(float3 j0, float3 j1, float3 j2, float3 f)
{
    float3 c0 = cross3(j1, j2), c1 = cross3(j2, j0), c2 = cross3(j0, j1);
    float det = dot3(j0, c0);
    if (abs1(det) < 1e-30f)
        return (float3)(0.0f);
    /* inverse = [c0 c1 c2] / det (columns are the cofactor rows) */
    return (c0 * f.x + c1 * f.y + c2 * f.z) / det;
}

/* One Newton step of the implicit-midpoint gyroscopic update, started at
 * w' = w; w_body in the body frame, inertia the principal moments. */
inline float3 implicit_gyroscopic(float3 w_body, float3 inertia, float dt)
{
    float3 momentum = inertia * w_body;
    float3 residual = dt * cross3(w_body, momentum);
    /* J = I + (dt / 2) (skew(w) I - skew(I w)), written row by row */
    float h = 0.5f * dt;
    float3 w = w_body, m = momentum, d = inertia;
    float3 j0 = (float3)(d.x, h * (-w.z * d.y + m.z), h * (w.y * d.z - m.y));
    float3 j1 = (float3)(h * (w.z * d.x - m.z), d.y, h * (-w.x * d.z + m.x));
    float3 j2 = (float3)(h * (-w.y * d.x + m.y), h * (w.x * d.y - m.x), d.z);
    return w_body - solve3(j0, j1, j2, residual);
}
% endif

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void prepare_bodies(__global Body* bodies,
                    __global BodyInertia* inertia,
                    const uint body_count,
% if backup:
                    __global Body* backup,
% endif
% if gravity:
                    const float4 gravity,
% endif
% if external_forces:
                    __global const float4* forces,
                    __global const float4* lever_forces,
                    __global const float4* moments,
                    const uint force_terms,
                    __global float4* kicks,
                    const float h,
% endif
% if shape_types:
                    __global const Shape* shapes,
                    __global const float4* hull_vertices,
                    __global Aabb* aabbs,
                    const float margin,
% endif
                    const float dt)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
% if backup:
    backup[i] = bodies[i];
% endif
    float4 q = bodies[i].orientation;
% if sleeping:
    /* a sleeping body (inv_mass 0 while asleep) is static to the solver: no inverse
     * inertia either (a static body's is 0 already) */
    float3 inv_local = bodies[i].inv_mass > 0.0f ? inertia[i].inv_inertia_local.xyz
                                                 : (float3)(0.0f);
% else:
    float3 inv_local = inertia[i].inv_inertia_local.xyz;
% endif
% if gravity:
    /* gravity before the solver, so that resting contacts cancel this step's */
    if (bodies[i].inv_mass > 0.0f)
        bodies[i].linear_velocity.xyz += gravity.xyz * dt;
% endif
% if gyroscopic:
    if (bodies[i].inv_mass > 0.0f && all(inv_local > 0.0f)) {
        float3 w_body = quat_rotate(quat_conjugate(q), bodies[i].angular_velocity.xyz);
        w_body = implicit_gyroscopic(w_body, 1.0f / inv_local, dt);
        bodies[i].angular_velocity.xyz = quat_rotate(q, w_body);
    }
% endif
    float3 r0, r1, r2;
    quat_to_rows(q, &r0, &r1, &r2);
    /* (R D R^T)_jk = sum_m R_jm D_m R_km */
    inertia[i].inv_inertia_world[0] = (float4)(dot3(r0 * inv_local, r0), dot3(r0 * inv_local, r1),
                                                dot3(r0 * inv_local, r2), 0.0f);
    inertia[i].inv_inertia_world[1] = (float4)(dot3(r1 * inv_local, r0), dot3(r1 * inv_local, r1),
                                                dot3(r1 * inv_local, r2), 0.0f);
    inertia[i].inv_inertia_world[2] = (float4)(dot3(r2 * inv_local, r0), dot3(r2 * inv_local, r1),
                                                dot3(r2 * inv_local, r2), 0.0f);
% if external_forces:
    if (force_terms != 0) {
        float3 linear = (float3)(0.0f), angular = (float3)(0.0f);
        if (bodies[i].inv_mass > 0.0f) {
            float3 torque = (float3)(0.0f);
            if (force_terms & RB_FORCE_FORCE)
                linear = forces[i].xyz * (bodies[i].inv_mass * h);
            if (force_terms & RB_FORCE_MOMENT)
                torque = moments[i].xyz;
            if (force_terms & RB_FORCE_LEVER)
                torque -= cross3(bodies[i].position.xyz, lever_forces[i].xyz);
            angular = (float3)(dot3(inertia[i].inv_inertia_world[0].xyz, torque),
                               dot3(inertia[i].inv_inertia_world[1].xyz, torque),
                               dot3(inertia[i].inv_inertia_world[2].xyz, torque)) * h;
            bodies[i].linear_velocity.xyz += linear;
            bodies[i].angular_velocity.xyz += angular;
        }
        kicks[2 * i] = (float4)(linear, 0.0f);
        kicks[2 * i + 1] = (float4)(angular, 0.0f);
    }
% endif
% if shape_types:
    Body body = bodies[i];
    Shape shape = shapes[body.shape];
    write_world_aabb(body, shape, r0, r1, r2, hull_vertices, margin, &aabbs[i]);
    body.linear_velocity.w = speculative_distance(body, shape.extents.w,
                                                  body.linear_velocity.xyz * dt);
    bodies[i].linear_velocity.w = body.linear_velocity.w;
    sweep_world_aabb(body, &aabbs[i]);
% endif
}
