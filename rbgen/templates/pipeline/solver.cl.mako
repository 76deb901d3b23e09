/* Projected Gauss-Seidel over batched contact constraints.
 *
 * One launch per iteration (per cell colour in the cells batching mode): a
 * work group is responsible for one level-1 group (no dynamic body is shared
 * with a group of the same launch) and walks its batches in order,
 * with a barrier between batches; the lanes of a batch solve constraints that
 * share no dynamic body, so they may write body velocities without atomics.
 * The last batch slot (${max_batches - 1}) holds any remainder and is solved by lane 0 alone.
 *
 * Rows: per contact point a normal row (impulse >= 0, drives the normal
 * velocity to its target),
% if normal_solve == "block":
 * all points' normal rows of a manifold solved together as one block
 * (solve_normal_block: exact for the points that stay pushing, so that the
 * result does not depend on the order of the points: solving them one after
 * another leaves a residual torque that tips a symmetric column from its
 * first step and makes it lean or walk), then once more one after another
 * (forwards and backwards on alternate sweeps) for the points it released, then
% else:
 * all points' normal rows first, one after another, forwards and backwards
 * on alternate sweeps (always solving point 0 first biases a heavy stack's
 * base and makes the whole column wobble), then
% endif
% if friction == "point":
 * per point a friction pair clamped to the disc |f| <= mu * its normal impulse.
% else:
 * one friction pair at the centre of the points, clamped to the disc
 * |f| <= mu * the total normal impulse, and a twist row about the normal.
% endif
 * Impulses are accumulated, so warm starting applies last step's
 * totals once, for every constraint, before the first iteration's sweep.
% if split_impulse:
 * The split-impulse position pass solves the same normal rows on separate
 * push velocities, which apply_split_velocities turns into a displacement
 * after integration and then forgets.
% endif
 */
${cl_constants()}

% if split_impulse:
${cl_structs("Body", "BodyInertia", "ContactConstraint", "SplitVelocity")}
% else:
${cl_structs("Body", "BodyInertia", "ContactConstraint")}
% endif

#define MAX_BATCHES ${max_batches}
#define SERIAL_BATCH (MAX_BATCHES - 1)
/* what one solve_contacts launch does (bit flags of its `passes` argument) */
#define WARM_START_PASS 1u
#define SOLVE_PASS 2u
#define REVERSE_PASS 4u

inline float3 mul_rows(const float3 row[3], float3 v)
{
    return (float3)(dot(row[0], v), dot(row[1], v), dot(row[2], v));
}

inline void load_inertia(__global const BodyInertia* inertia, uint body, float3 rows[3])
{
    for (int r = 0; r < 3; ++r)
        rows[r] = inertia[body].inv_inertia_world[r].xyz;
}

/* Impulse p at lever arms ra (on A, as -p) and rb (on B, as +p). */
inline void apply_impulse(float3 p, float3 ra, float3 rb,
                          float inv_mass_a, const float3 inv_inertia_a[3], float3* va, float3* wa,
                          float inv_mass_b, const float3 inv_inertia_b[3], float3* vb, float3* wb)
{
    *va -= p * inv_mass_a;
    *wa -= mul_rows(inv_inertia_a, cross(ra, p));
    *vb += p * inv_mass_b;
    *wb += mul_rows(inv_inertia_b, cross(rb, p));
}

inline float3 relative_velocity(float3 ra, float3 rb, float3 va, float3 wa, float3 vb, float3 wb)
{
    return vb + cross(wb, rb) - va - cross(wa, ra);
}

% if normal_solve == "block":
/* a pushing point counts as separating beyond its target above this fraction of the
 * largest right-hand side (float32 round-off of an exact solve stays far below) */
#define OVERSHOOT_TOLERANCE 1e-4f
/* The normal rows of one manifold as a block: the accumulated impulses
 * lambda[k] (>= 0) of its `count` points are replaced by totals with which
 * every point that keeps a positive impulse reaches its normal velocity
 * target at once, K (total - lambda) = target - vn, with K[j][k] = the normal
 * velocity change at point j per unit impulse at point k. Points whose
 * impulse would turn negative are released (impulse 0) and the rest is
 * solved again, at most `count` rounds. K is singular for four points on one
 * face (only three of their motions are independent), so the totals are
 * found by conjugate gradients started from zero: they converge to the
 * smallest such totals, the evenly spread ones (no drift of the split
 * between the points from step to step, which would skew the per-point
 * friction limits), and stop once the remaining residual lies in K's null
 * space (no velocity left to fix).
 * Targets that no rigid motion meets together (a corner still apart, target
 * -gap/dt, beside touching corners at 0; the kink of the split-impulse slop)
 * leave conjugate gradients at a least-squares compromise with every impulse
 * positive: it moves the apart corner down and lifts the opposite one, i.e.
 * tilts the box towards the gap on every sweep, which kept stacks of a
 * dropped pile rocking for ever. Such a compromise shows as a pushing point
 * that would separate faster than its target (complementarity violated): the
 * one of those with the lowest target (farthest apart) is released and the
 * rest solved exactly, as the contact problem demands. Updates the
 * velocities in place. */
void solve_normal_block(const uint count, const float3 n, __global const float4* r_a,
                        __global const float4* r_b, const float relaxation,
                        float inv_mass_a, const float3 inv_inertia_a[3], float3* va, float3* wa,
                        float inv_mass_b, const float3 inv_inertia_b[3], float3* vb, float3* wb,
                        const float target[4], float lambda[4])
{
    /* Loops run to the constant RB_MAX_MANIFOLD_POINTS and test `count` inside, so
     * that compilers unroll them and keep these small arrays in registers (with a
     * runtime trip count NVIDIA's compiler put them in slow private memory). */
    /* per point: the torque arms of its normal row on A and B */
    float3 arm_a[4], arm_b[4];
    float residual[4], total[4], k_matrix[4][4];
    float largest = 0.0f;
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        float3 ra = r_a[k].xyz, rb = r_b[k].xyz;
        arm_a[k] = cross(ra, n);
        arm_b[k] = cross(rb, n);
        residual[k] = target[k] - dot(relative_velocity(ra, rb, *va, *wa, *vb, *wb), n);
    }
    for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count)
        for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
            k_matrix[j][k] = inv_mass_a + inv_mass_b
                           + dot(arm_a[j], mul_rows(inv_inertia_a, arm_a[k]))
                           + dot(arm_b[j], mul_rows(inv_inertia_b, arm_b[k]));
            largest = fmax(largest, k_matrix[j][k]);
        }
    bool active[4];
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        active[k] = true;
    /* the velocity the current impulses produce: residual + K lambda */
    float rhs[4], tolerance = 0.0f;
    for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count) {
        rhs[j] = residual[j];
        for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
            rhs[j] += k_matrix[j][k] * lambda[k];
        tolerance = fmax(tolerance, OVERSHOOT_TOLERANCE * fabs(rhs[j]));
    }
    for (uint attempt = 0; attempt < RB_MAX_MANIFOLD_POINTS; ++attempt) if (attempt < count) {
        /* new totals: 0 for released points; for the others, four points
         * (K singular) start from 0 so that they end as the smallest, evenly
         * spread totals that reach the targets; fewer points (K regular, but
         * ill-conditioned when two lie close) start from the current ones so
         * that a direction the iteration gives up on keeps what earlier
         * sweeps built */
        float gradient[4], direction[4], rr = 0.0f;
        for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count)
            total[j] = active[j] && count < 4 ? lambda[j] : 0.0f;
        for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count) {
            gradient[j] = rhs[j];
            for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
                gradient[j] -= k_matrix[j][k] * total[k];
            gradient[j] = direction[j] = active[j] ? gradient[j] : 0.0f;
            rr += gradient[j] * gradient[j];
        }
        for (uint iteration = 0; iteration < RB_MAX_MANIFOLD_POINTS; ++iteration) if (iteration < count) {
            float k_direction[4], dkd = 0.0f, dd = 0.0f;
            for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count) {
                k_direction[j] = 0.0f;
                for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
                    k_direction[j] += k_matrix[j][k] * direction[k];
                k_direction[j] = active[j] ? k_direction[j] : 0.0f;
                dkd += direction[j] * k_direction[j];
                dd += direction[j] * direction[j];
            }
            /* nothing left but directions K (almost) does not move: its null
             * space, blurred by a slightly tilted face; a step along them would
             * be huge impulses that cancel each other */
            if (dkd <= 1e-3f * largest * dd)
                break;
            float distance = rr / dkd, next_rr = 0.0f;
            for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count) {
                total[j] += active[j] ? distance * direction[j] : 0.0f;
                gradient[j] -= distance * k_direction[j];
                next_rr += gradient[j] * gradient[j];
            }
            for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) if (j < count)
                direction[j] = gradient[j] + next_rr / rr * direction[j];
            rr = next_rr;
        }
        bool released = false;
        for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
            if (active[k] && lambda[k] + relaxation * (total[k] - lambda[k]) < 0.0f)
                active[k] = false, released = true;
        /* none negative: release the pushing point that overshoots its target
         * (gradient = target - velocity reached < 0) and has the lowest target */
        uint overshoot = RB_MAX_MANIFOLD_POINTS;
        for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
            if (active[k] && gradient[k] < -tolerance
                && (overshoot == RB_MAX_MANIFOLD_POINTS || target[k] < target[overshoot]))
                overshoot = k;
        if (!released && overshoot < RB_MAX_MANIFOLD_POINTS)
            active[overshoot] = false, released = true;
        if (!released)
            break;
    }
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        /* a point released in the last round keeps no impulse */
        float change = fmax(lambda[k] + relaxation * ((active[k] ? total[k] : 0.0f) - lambda[k]),
                            0.0f) - lambda[k];
        lambda[k] += change;
        *va -= n * (change * inv_mass_a);
        *wa -= mul_rows(inv_inertia_a, arm_a[k] * change);
        *vb += n * (change * inv_mass_b);
        *wb += mul_rows(inv_inertia_b, arm_b[k] * change);
    }
}

% endif
/* Apply last step's accumulated impulses of one constraint (warm start). */
void warm_start_contact(__global const ContactConstraint* c, __global Body* bodies,
                        __global const BodyInertia* inertia)
{
    uint a = c->body_a, b = c->body_b;
    float inv_mass_a = bodies[a].inv_mass, inv_mass_b = bodies[b].inv_mass;
    float3 va = bodies[a].linear_velocity.xyz, wa = bodies[a].angular_velocity.xyz;
    float3 vb = bodies[b].linear_velocity.xyz, wb = bodies[b].angular_velocity.xyz;
    float3 inv_inertia_a[3], inv_inertia_b[3];
    load_inertia(inertia, a, inv_inertia_a);
    load_inertia(inertia, b, inv_inertia_b);
    float normal_impulse[4], tangent1_impulse[4], tangent2_impulse[4];
    vstore4(c->normal_impulse, 0, normal_impulse);
    vstore4(c->tangent1_impulse, 0, tangent1_impulse);
    vstore4(c->tangent2_impulse, 0, tangent2_impulse);
% if friction == "point":
    for (uint k = 0; k < c->point_count; ++k) {
        float3 p = c->normal.xyz * normal_impulse[k] + c->tangent1.xyz * tangent1_impulse[k]
                 + c->tangent2.xyz * tangent2_impulse[k];
        apply_impulse(p, c->r_a[k].xyz, c->r_b[k].xyz, inv_mass_a, inv_inertia_a, &va, &wa,
                      inv_mass_b, inv_inertia_b, &vb, &wb);
    }
% else:
    float3 ra = (float3)(0.0f), rb = (float3)(0.0f);
    for (uint k = 0; k < c->point_count; ++k) {
        apply_impulse(c->normal.xyz * normal_impulse[k], c->r_a[k].xyz, c->r_b[k].xyz,
                      inv_mass_a, inv_inertia_a, &va, &wa, inv_mass_b, inv_inertia_b, &vb, &wb);
        ra += c->r_a[k].xyz, rb += c->r_b[k].xyz;
    }
    float share = c->point_count > 0 ? 1.0f / (float)c->point_count : 0.0f;
    float3 p = c->tangent1.xyz * tangent1_impulse[0] + c->tangent2.xyz * tangent2_impulse[0];
    apply_impulse(p, ra * share, rb * share, inv_mass_a, inv_inertia_a, &va, &wa,
                  inv_mass_b, inv_inertia_b, &vb, &wb);
    wa -= mul_rows(inv_inertia_a, c->normal.xyz * tangent1_impulse[1]);
    wb += mul_rows(inv_inertia_b, c->normal.xyz * tangent1_impulse[1]);
% endif
    if (inv_mass_a > 0.0f) {
        bodies[a].linear_velocity.xyz = va;
        bodies[a].angular_velocity.xyz = wa;
    }
    if (inv_mass_b > 0.0f) {
        bodies[b].linear_velocity.xyz = vb;
        bodies[b].angular_velocity.xyz = wb;
    }
}

/* Solve all rows of one constraint and write back its impulses and the
 * velocities of its dynamic bodies. */
void solve_contact(__global ContactConstraint* c, __global Body* bodies,
                   __global const BodyInertia* inertia, const float relaxation,
                   const bool reverse)
{
    uint a = c->body_a, b = c->body_b, count = c->point_count;
    float inv_mass_a = bodies[a].inv_mass, inv_mass_b = bodies[b].inv_mass;
    float3 va = bodies[a].linear_velocity.xyz, wa = bodies[a].angular_velocity.xyz;
    float3 vb = bodies[b].linear_velocity.xyz, wb = bodies[b].angular_velocity.xyz;
    float3 inv_inertia_a[3], inv_inertia_b[3];
    load_inertia(inertia, a, inv_inertia_a);
    load_inertia(inertia, b, inv_inertia_b);
    float3 n = c->normal.xyz, t1 = c->tangent1.xyz, t2 = c->tangent2.xyz;
    float friction = c->normal.w;
    float normal_impulse[4], tangent1_impulse[4], tangent2_impulse[4];
    float normal_mass[4], tangent1_mass[4], tangent2_mass[4], target[4];
    vstore4(c->normal_impulse, 0, normal_impulse);
    vstore4(c->tangent1_impulse, 0, tangent1_impulse);
    vstore4(c->tangent2_impulse, 0, tangent2_impulse);
    vstore4(c->normal_mass, 0, normal_mass);
    vstore4(c->tangent1_mass, 0, tangent1_mass);
    vstore4(c->tangent2_mass, 0, tangent2_mass);
    vstore4(c->velocity_target, 0, target);

% if normal_solve == "block":
    solve_normal_block(count, n, c->r_a, c->r_b, relaxation, inv_mass_a, inv_inertia_a, &va, &wa,
                       inv_mass_b, inv_inertia_b, &vb, &wb, target, normal_impulse);
    /* then the rows one after another: no change where the block was exact;
     * completes a point the block released while it still approaches */
% endif
    for (uint step = 0; step < count; ++step) {
        /* alternate the point order between sweeps, so that no point is always first */
        uint k = reverse ? count - 1 - step : step;
        float3 ra = c->r_a[k].xyz, rb = c->r_b[k].xyz;
        /* normal row: impulse >= 0 */
        float vn = dot(relative_velocity(ra, rb, va, wa, vb, wb), n);
        float total = fmax(normal_impulse[k] + relaxation * normal_mass[k] * (target[k] - vn), 0.0f);
        float delta = total - normal_impulse[k];
        normal_impulse[k] = total;
        apply_impulse(n * delta, ra, rb, inv_mass_a, inv_inertia_a, &va, &wa,
                      inv_mass_b, inv_inertia_b, &vb, &wb);
    }
% if friction == "point":
    for (uint step = 0; step < count; ++step) {
        /* friction pair: |(f1, f2)| <= mu * normal impulse (same point order) */
        uint k = reverse ? count - 1 - step : step;
        float3 ra = c->r_a[k].xyz, rb = c->r_b[k].xyz;
        float3 dv = relative_velocity(ra, rb, va, wa, vb, wb);
        float f1 = tangent1_impulse[k] - relaxation * tangent1_mass[k] * dot(dv, t1);
        float f2 = tangent2_impulse[k] - relaxation * tangent2_mass[k] * dot(dv, t2);
        float limit = friction * normal_impulse[k];
        float length_sq = f1 * f1 + f2 * f2;
        if (length_sq > limit * limit) {
            float scale = limit * rsqrt(length_sq);
            f1 *= scale;
            f2 *= scale;
        }
        float3 p = t1 * (f1 - tangent1_impulse[k]) + t2 * (f2 - tangent2_impulse[k]);
        tangent1_impulse[k] = f1;
        tangent2_impulse[k] = f2;
        apply_impulse(p, ra, rb, inv_mass_a, inv_inertia_a, &va, &wa,
                      inv_mass_b, inv_inertia_b, &vb, &wb);
    }
% else:
    /* one friction pair at the centre of the points: |(f1, f2)| <= mu * total normal
     * impulse, and a twist row about n: |f| <= mu * total * mean point distance */
    float3 ra = (float3)(0.0f), rb = (float3)(0.0f);
    float total = 0.0f;
    for (uint k = 0; k < count; ++k)
        ra += c->r_a[k].xyz, rb += c->r_b[k].xyz, total += normal_impulse[k];
    float share = count > 0 ? 1.0f / (float)count : 0.0f;
    ra *= share;
    rb *= share;
    float3 dv = relative_velocity(ra, rb, va, wa, vb, wb);
    float f1 = tangent1_impulse[0] - relaxation * tangent1_mass[0] * dot(dv, t1);
    float f2 = tangent2_impulse[0] - relaxation * tangent2_mass[0] * dot(dv, t2);
    float limit = friction * total;
    float length_sq = f1 * f1 + f2 * f2;
    if (length_sq > limit * limit) {
        float scale = limit * rsqrt(length_sq);
        f1 *= scale;
        f2 *= scale;
    }
    float3 p = t1 * (f1 - tangent1_impulse[0]) + t2 * (f2 - tangent2_impulse[0]);
    tangent1_impulse[0] = f1;
    tangent2_impulse[0] = f2;
    apply_impulse(p, ra, rb, inv_mass_a, inv_inertia_a, &va, &wa, inv_mass_b, inv_inertia_b,
                  &vb, &wb);
    float radius = 0.0f;
    for (uint k = 0; k < count; ++k)
        radius += length(c->r_b[k].xyz - rb);
    float twist_limit = limit * radius * share;
    float twist = clamp(tangent1_impulse[1] - relaxation * tangent1_mass[1] * dot(wb - wa, n),
                        -twist_limit, twist_limit);
    float twist_delta = twist - tangent1_impulse[1];
    tangent1_impulse[1] = twist;
    wa -= mul_rows(inv_inertia_a, n * twist_delta);
    wb += mul_rows(inv_inertia_b, n * twist_delta);
% endif
    c->normal_impulse = vload4(0, normal_impulse);
    c->tangent1_impulse = vload4(0, tangent1_impulse);
    c->tangent2_impulse = vload4(0, tangent2_impulse);
    if (inv_mass_a > 0.0f) {
        bodies[a].linear_velocity.xyz = va;
        bodies[a].angular_velocity.xyz = wa;
    }
    if (inv_mass_b > 0.0f) {
        bodies[b].linear_velocity.xyz = vb;
        bodies[b].angular_velocity.xyz = wb;
    }
}

/* One velocity iteration over the groups that may run concurrently (all of
 * them, or one cell colour). A work group is responsible for one level-1
 * group (group_offset + its id): its batches in order, a barrier after each. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void solve_contacts(__global ContactConstraint* constraints,
                    __global const uint* order,
                    __global const uint* group_batches,
                    __global const uint* group_batch_count,
                    __global Body* bodies,
                    __global const BodyInertia* inertia,
                    const float relaxation,
                    const uint group_offset,
                    const uint passes)
{
    const uint lane = get_local_id(0), group = group_offset + get_group_id(0);
    const bool apply_warm_start = passes & WARM_START_PASS, solve = passes & SOLVE_PASS;
    const bool reverse = passes & REVERSE_PASS;
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint batch_count = group_batch_count[group];
    /* warm start (before the first sweep): old impulses, batch by batch */
    for (uint batch = 0; apply_warm_start && batch < batch_count; ++batch) {
        uint begin = offsets[batch], end = offsets[batch + 1];
        uint stride = ${work_group_size};
        if (batch == SERIAL_BATCH)
            stride = lane == 0 ? 1 : 0, begin = lane == 0 ? begin : end;
        for (uint i = begin + lane; i < end; i += stride)
            warm_start_contact(&constraints[order[i]], bodies, inertia);
        barrier(CLK_GLOBAL_MEM_FENCE);
    }
    for (uint batch = 0; solve && batch < batch_count; ++batch) {
        uint begin = offsets[batch], end = offsets[batch + 1];
        uint stride = ${work_group_size};
        if (batch == SERIAL_BATCH)
            stride = lane == 0 ? 1 : 0, begin = lane == 0 ? begin : end;
        for (uint i = begin + lane; i < end; i += stride)
            solve_contact(&constraints[order[i]], bodies, inertia, relaxation, reverse);
        barrier(CLK_GLOBAL_MEM_FENCE);
    }
}
% if split_impulse:

/* Normal rows on the push velocities of one constraint (split impulse). */
void solve_push(__global ContactConstraint* c, __global SplitVelocity* split,
                __global const Body* bodies, __global const BodyInertia* inertia,
                const float relaxation)
{
    uint a = c->body_a, b = c->body_b, count = c->point_count;
    float inv_mass_a = bodies[a].inv_mass, inv_mass_b = bodies[b].inv_mass;
    float3 va = split[a].linear.xyz, wa = split[a].angular.xyz;
    float3 vb = split[b].linear.xyz, wb = split[b].angular.xyz;
    float3 inv_inertia_a[3], inv_inertia_b[3];
    load_inertia(inertia, a, inv_inertia_a);
    load_inertia(inertia, b, inv_inertia_b);
    float3 n = c->normal.xyz;
    float push_impulse[4], normal_mass[4], target[4];
    vstore4(c->push_impulse, 0, push_impulse);
    vstore4(c->normal_mass, 0, normal_mass);
    vstore4(c->position_target, 0, target);
% if normal_solve == "block":
    solve_normal_block(count, n, c->r_a, c->r_b, relaxation, inv_mass_a, inv_inertia_a, &va, &wa,
                       inv_mass_b, inv_inertia_b, &vb, &wb, target, push_impulse);
% else:
    for (uint k = 0; k < count; ++k) {
        float3 ra = c->r_a[k].xyz, rb = c->r_b[k].xyz;
        float vn = dot(relative_velocity(ra, rb, va, wa, vb, wb), n);
        float total = fmax(push_impulse[k] + relaxation * normal_mass[k] * (target[k] - vn), 0.0f);
        float delta = total - push_impulse[k];
        push_impulse[k] = total;
        apply_impulse(n * delta, ra, rb, inv_mass_a, inv_inertia_a, &va, &wa,
                      inv_mass_b, inv_inertia_b, &vb, &wb);
    }
% endif
    c->push_impulse = vload4(0, push_impulse);
    if (inv_mass_a > 0.0f) {
        split[a].linear.xyz = va;
        split[a].angular.xyz = wa;
    }
    if (inv_mass_b > 0.0f) {
        split[b].linear.xyz = vb;
        split[b].angular.xyz = wb;
    }
}

/* One position (split-impulse) iteration. A work group is responsible for
 * one level-1 group: its batches in order, a barrier after each. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void solve_penetration(__global ContactConstraint* constraints,
                       __global const uint* order,
                       __global const uint* group_batches,
                       __global const uint* group_batch_count,
                       __global SplitVelocity* split,
                       __global const Body* bodies,
                       __global const BodyInertia* inertia,
                       const float relaxation,
                       const uint group_offset)
{
    const uint lane = get_local_id(0), group = group_offset + get_group_id(0);
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint batch_count = group_batch_count[group];
    for (uint batch = 0; batch < batch_count; ++batch) {
        uint begin = offsets[batch], end = offsets[batch + 1];
        uint stride = ${work_group_size};
        if (batch == SERIAL_BATCH)
            stride = lane == 0 ? 1 : 0, begin = lane == 0 ? begin : end;
        for (uint i = begin + lane; i < end; i += stride)
            solve_push(&constraints[order[i]], split, bodies, inertia, relaxation);
        barrier(CLK_GLOBAL_MEM_FENCE);
    }
}

/* One work-item per body: move it by its push velocity over dt, then clear
 * the push. A work group is responsible for ${work_group_size} consecutive bodies. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void apply_split_velocities(__global Body* bodies, __global SplitVelocity* split,
                            const uint body_count, const float dt)
{
    uint i = get_global_id(0);
    if (i >= body_count || bodies[i].inv_mass == 0.0f)
        return;
    float3 v = split[i].linear.xyz, w = split[i].angular.xyz;
    bodies[i].position.xyz += v * dt;
    float4 q = bodies[i].orientation;
    float3 h = 0.5f * dt * w;  /* q += (h, 0) q: first order, renormalised */
    float4 dq = (float4)(q.w * h + cross(h, q.xyz), -dot(h, q.xyz));
    bodies[i].orientation = normalize(q + dq);
    split[i].linear = (float4)(0.0f);
    split[i].angular = (float4)(0.0f);
}
% endif
