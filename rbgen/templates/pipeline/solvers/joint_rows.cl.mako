<%doc>
  The rows of a joint (layouts: JointConstraint) and how one joint is solved, for the
  Gauss-Seidel solver (pgs.cl.mako). The including template supplies the structs
  JointConstraint and Body, common/quaternion.cl.mako, and contact_rows.cl.mako (the
  Row type, point_row, twist_row, row_speed, apply_row and ContactBodies).
</%doc>
/* Joint rows. Every joint kind is a few rows between body A and body B (the
 * world, static, when RB_JOINT_WORLD is set):
 *   ball:     3 point rows (the anchors coincide), solved as one 3x3 block,
 *             and with RB_JOINT_MOTOR a friction block: 3 angular rows that
 *             stop the relative rotation, their impulse within the maximum
 *             torque times the substep;
 *   fixed:    the point block and 3 angular rows (the relative orientation of
 *             creation), a 3x3 block;
 *   hinge:    the point block, 2 swing rows across the axis (a 2x2 block), and
 *             on the axis a motor row (speed, impulse within the maximum torque
 *             times the substep) and limit rows on the twist angle;
 *   slider:   3 angular rows, 2 rows across the axis at B's anchor (a 2x2
 *             block), limit rows on the offset along the axis;
 *   distance: one row along the anchors' line, rigid when min == max, else a
 *             lower and an upper limit row.
 * Order within a joint: motor, limits, angular rows, linear rows (the rows that
 * must hold exactly last).
 *
 * Stabilisation: the velocity rows are rigid (target 0: no bias, so no energy
 * is added to the motion); the joint's error (anchors apart, axes or
 * orientation turned, a limit crossed) is removed by the same rows solved on
 * the push velocities of the split-impulse sweeps, with the target
 * -recovery * error / h, which move the bodies over the substep and are then
 * thrown away. The errors are measured from the bodies' poses of this
 * substep, so that they follow the motion within a step. Limit rows are
 * unilateral (accumulated impulse >= 0) and speculative: a limit still apart
 * by a gap lets the bodies approach by gap / h within the substep. Push rows
 * keep no accumulated impulse (each sweep's change is clamped alone).
 *
 * The axial rows (motor, limits, a distance's rows) measure A relative to B:
 * the hinge angle A turned about the axis since creation, the slider offset of
 * A's anchor from B's along the axis, the distance between the anchors.
 *
 * Accumulated impulses (for the warm start and world.joint_impulses): the
 * unclamped blocks' as world totals on B (linear, at the lever arms ra, rb, and
 * angular), the axial rows' as scalars (lower limit, upper limit, motor) along
 * the axis of the moment, so that a clamped row's old impulse never acts
 * across its turned direction. */

/* A joint's geometry this substep: lever arms of its linear rows (A's anchor,
 * or B's for a slider, relative to A's centre; B's anchor relative to B's), the
 * anchors' separation pb - pa, and the orientations. */
typedef struct {
    float3 ra, rb, separation;
    float4 qa, qb;
} JointFrame;

inline void joint_frame(__global const JointConstraint* j, float3 xa, float4 qa, float3 xb,
                        float4 qb, JointFrame* f)
{
    float3 pa = xa + quat_rotate(qa, j->anchor_a.xyz);
    float3 pb = xb + quat_rotate(qb, j->anchor_b.xyz);
    f->qa = qa;
    f->qb = qb;
    f->separation = pb - pa;
    f->ra = (j->kind == RB_JOINT_SLIDER ? pb : pa) - xa;
    f->rb = pb - xb;
}

/* B's rotation from its pose of creation relative to A, in A's frame:
 * conj(qa) qb conj(reference), with w >= 0 (the shorter way round). */
inline float4 joint_deviation(__global const JointConstraint* j, const JointFrame* f)
{
    float4 d = quat_mul(quat_mul(quat_conjugate(f->qa), f->qb), quat_conjugate(j->reference));
    return d.w < 0.0f ? -d : d;
}

/* The angle (rad, in (-pi, pi]) B turned about A's axis (A's frame) since creation. */
inline float twist_angle(float4 d, float3 axis)
{
    return 2.0f * atan2(dot3(d.xyz, axis), d.w);
}

/* An orthonormal pair across unit axis n. */
inline void joint_basis(float3 n, float3* p1, float3* p2)
{
    if (abs1(n.x) > 0.57735f)
        *p1 = normalize3((float3)(n.y, -n.x, 0.0f));
    else
        *p1 = normalize3((float3)(0.0f, n.z, -n.y));
    *p2 = cross3(n, *p1);
}

/* K[r][s] = J_r M^-1 J_s^T of two rows. */
inline float row_coupling(const Row* r, const Row* s, const __private ContactBodies* p)
{
    return (p->inv_mass_a + p->inv_mass_b) * dot3(r->linear, s->linear)
         + dot3(r->arm_a, s->turn_a) + dot3(r->arm_b, s->turn_b);
}

inline Row reversed_row(Row r)
{
    r.linear = -r.linear, r.arm_a = -r.arm_a, r.arm_b = -r.arm_b;
    r.turn_a = -r.turn_a, r.turn_b = -r.turn_b;
    return r;
}

/* One row driven to speed `target`, its accumulated impulse *total kept in
 * [lo, hi]; returns the impulse applied. */
inline float solve_joint_row(const Row* row, float target, float* total, float lo, float hi,
                             __private ContactBodies* p)
{
    float k = row_coupling(row, row, p);
    float mass = k > 0.0f ? 1.0f / k : 0.0f;
    float old = *total;
    float next = clamp1(old - mass * (row_speed(row, p) - target), lo, hi);
    apply_row(row, next - old, p);
    *total = next;
    return next - old;
}

/* A limit row (impulse >= 0) whose constraint is `gap` >= 0. Velocity sweep:
 * approach by at most gap / h this substep; push sweep: only a crossed limit
 * (gap < 0) is pushed back by recovery of the crossing. */
inline float solve_limit_row(const Row* row, float gap, float inv_h, float bias, bool push,
                             float* total, __private ContactBodies* p)
{
    if (push) {
        float alone = 0.0f;
        return gap < 0.0f ? solve_joint_row(row, -bias * gap, &alone, 0.0f, FLT_MAX, p) : 0.0f;
    }
    return solve_joint_row(row, gap > 0.0f ? -gap * inv_h : 0.0f, total, 0.0f, FLT_MAX, p);
}

/* Two rows solved together (a 2x2 block, no clamp) to speeds `target`;
 * returns the impulses applied. */
inline float2 solve_joint_pair(const Row* r1, const Row* r2, float2 target,
                               __private ContactBodies* p)
{
    float k11 = row_coupling(r1, r1, p), k12 = row_coupling(r1, r2, p);
    float k22 = row_coupling(r2, r2, p);
    float det = k11 * k22 - k12 * k12;
    if (!(det > 1e-12f * (k11 * k22 + 1e-30f)))
        return (float2)(0.0f);
    float2 rhs = target - (float2)(row_speed(r1, p), row_speed(r2, p));
    float2 change = (float2)(k22 * rhs.x - k12 * rhs.y, k11 * rhs.y - k12 * rhs.x) / det;
    apply_row(r1, change.x, p);
    apply_row(r2, change.y, p);
    return change;
}

/* Three rows solved together (a 3x3 block by Cramer's rule, no clamp) to
 * speeds `target`; returns the impulses applied. */
inline float3 solve_joint_block(const Row rows[3], float3 target, __private ContactBodies* p)
{
    float3 c0 = (float3)(row_coupling(&rows[0], &rows[0], p), row_coupling(&rows[1], &rows[0], p),
                         row_coupling(&rows[2], &rows[0], p));
    float3 c1 = (float3)(c0.y, row_coupling(&rows[1], &rows[1], p),
                         row_coupling(&rows[2], &rows[1], p));
    float3 c2 = (float3)(c0.z, c1.z, row_coupling(&rows[2], &rows[2], p));
    float det = dot3(c0, cross3(c1, c2));
    if (!(det > 1e-18f * c0.x * c1.y * c2.z + 1e-30f))
        return (float3)(0.0f);
    float3 rhs = target - (float3)(row_speed(&rows[0], p), row_speed(&rows[1], p),
                                   row_speed(&rows[2], p));
    float3 change = (float3)(dot3(rhs, cross3(c1, c2)), dot3(c0, cross3(rhs, c2)),
                             dot3(c0, cross3(c1, rhs))) / det;
    apply_row(&rows[0], change.x, p);
    apply_row(&rows[1], change.y, p);
    apply_row(&rows[2], change.z, p);
    return change;
}

/* The direction of a joint's axial rows on B (A relative to B: minus A's
 * axis; a distance joint's: along the anchors' separation). */
inline float3 joint_axial_direction(__global const JointConstraint* j, const JointFrame* f)
{
    float3 axis = quat_rotate(f->qa, j->axis_a.xyz);
    if (j->kind != RB_JOINT_DISTANCE)
        return -axis;
    float length = length3(f->separation);
    return length > 1e-6f ? f->separation * (1.0f / length) : axis;
}

/* The warm start of a joint: its accumulated impulses applied to *p. */
inline void warm_start_joint_rows(__global const JointConstraint* j, const JointFrame* f,
                                  __private ContactBodies* p)
{
    float3 impulse = j->linear_impulse.xyz, angular = j->angular_impulse.xyz;
    float3 along = joint_axial_direction(j, f);
    float4 axial = j->axial_impulse;
    if (j->kind == RB_JOINT_HINGE)
        angular += along * (axial.x - axial.y + axial.z);
    else if (j->kind == RB_JOINT_BALL)
        angular += axial.xyz;  /* the friction block's (world) */
    else if (j->kind == RB_JOINT_SLIDER || j->kind == RB_JOINT_DISTANCE)
        impulse += along * (axial.x - axial.y);
    p->va -= impulse * p->inv_mass_a;
    p->wa -= mul_rows(p->inv_inertia_a, cross3(f->ra, impulse) + angular);
    p->vb += impulse * p->inv_mass_b;
    p->wb += mul_rows(p->inv_inertia_b, cross3(f->rb, impulse) + angular);
}

/* One sweep's rows of joint j on the velocities in *p: the velocity rows
 * (push false: rigid targets, accumulated impulses updated) or the push rows
 * (push true: targets -recovery * error / h, nothing accumulated). */
void solve_joint_rows(__global JointConstraint* j, const JointFrame* f,
                      __private ContactBodies* p, const float inv_h, const float recovery,
                      const bool push)
{
    const uint kind = j->kind, flags = j->flags;
    /* target speed per unit of error */
    const float bias = push ? recovery * inv_h : 0.0f;
    float3 linear = (float3)(0.0f), angular = (float3)(0.0f);
    /* accumulated impulses of the lower limit, upper limit and motor rows */
    /* (a ball joint's friction block keeps its world impulse in the three) */
    float4 axial = push ? (float4)(0.0f) : j->axial_impulse;
    float lower = axial.x, upper = axial.y, motor = axial.z;
    const float3 axis = quat_rotate(f->qa, j->axis_a.xyz);
    const float4 d = joint_deviation(j, f);
    /* the axial rows' direction on B (A relative to B) */
    const float3 along = -axis;

    if (kind == RB_JOINT_HINGE && (flags & RB_JOINT_MOTOR) && !push) {
        Row row = twist_row(along, p);
        float most = j->motor.y / inv_h;
        solve_joint_row(&row, j->motor.x, &motor, -most, most, p);
    }
    if (kind == RB_JOINT_BALL && (flags & RB_JOINT_MOTOR) && !push) {
        /* friction: the relative rotation stopped, the impulse within the torque */
        Row rows[3] = {twist_row((float3)(1.0f, 0.0f, 0.0f), p),
                       twist_row((float3)(0.0f, 1.0f, 0.0f), p),
                       twist_row((float3)(0.0f, 0.0f, 1.0f), p)};
        float3 old = (float3)(lower, upper, motor);
        float3 free = old + solve_joint_block(rows, (float3)(0.0f), p);
        float most = j->motor.y / inv_h, size = length3(free);
        float3 total = size > most ? free * (most / size) : free;
        /* (the block applied its whole change: take back what the clamp removed) */
        apply_row(&rows[0], total.x - free.x, p);
        apply_row(&rows[1], total.y - free.y, p);
        apply_row(&rows[2], total.z - free.z, p);
        lower = total.x, upper = total.y, motor = total.z;
    }
    if ((flags & RB_JOINT_LIMITS) && (kind == RB_JOINT_HINGE || kind == RB_JOINT_SLIDER)) {
        const bool hinge = kind == RB_JOINT_HINGE;
        float position = hinge ? -twist_angle(d, j->axis_a.xyz) : dot3(f->separation, along);
        Row row = hinge ? twist_row(along, p) : point_row(along, f->ra, f->rb, p);
        Row back = reversed_row(row);
        solve_limit_row(&row, position - j->axis_a.w, inv_h, bias, push, &lower, p);
        solve_limit_row(&back, j->axis_b.w - position, inv_h, bias, push, &upper, p);
    }

    if (kind == RB_JOINT_FIXED || kind == RB_JOINT_SLIDER) {
        Row rows[3] = {twist_row((float3)(1.0f, 0.0f, 0.0f), p),
                       twist_row((float3)(0.0f, 1.0f, 0.0f), p),
                       twist_row((float3)(0.0f, 0.0f, 1.0f), p)};
        float3 error = quat_rotate(f->qa, 2.0f * d.xyz);
        angular += solve_joint_block(rows, -bias * error, p);
    } else if (kind == RB_JOINT_HINGE) {
        float3 p1, p2;
        joint_basis(axis, &p1, &p2);
        float3 swing = cross3(axis, quat_rotate(f->qb, j->axis_b.xyz));
        Row r1 = twist_row(p1, p), r2 = twist_row(p2, p);
        float2 change = solve_joint_pair(&r1, &r2,
                                         -bias * (float2)(dot3(swing, p1), dot3(swing, p2)), p);
        angular += p1 * change.x + p2 * change.y;
    }

    if (kind == RB_JOINT_BALL || kind == RB_JOINT_FIXED || kind == RB_JOINT_HINGE) {
        Row rows[3] = {point_row((float3)(1.0f, 0.0f, 0.0f), f->ra, f->rb, p),
                       point_row((float3)(0.0f, 1.0f, 0.0f), f->ra, f->rb, p),
                       point_row((float3)(0.0f, 0.0f, 1.0f), f->ra, f->rb, p)};
        linear += solve_joint_block(rows, -bias * f->separation, p);
    } else if (kind == RB_JOINT_SLIDER) {
        float3 p1, p2;
        joint_basis(axis, &p1, &p2);
        Row r1 = point_row(p1, f->ra, f->rb, p), r2 = point_row(p2, f->ra, f->rb, p);
        float2 error = (float2)(dot3(f->separation, p1), dot3(f->separation, p2));
        float2 change = solve_joint_pair(&r1, &r2, -bias * error, p);
        linear += p1 * change.x + p2 * change.y;
    } else if (kind == RB_JOINT_DISTANCE) {
        float length = length3(f->separation);
        float3 n = length > 1e-6f ? f->separation * (1.0f / length) : axis;
        float shortest = j->anchor_a.w, longest = j->anchor_b.w;
        Row row = point_row(n, f->ra, f->rb, p);
        if (longest - shortest <= 1e-6f) {  /* a rod: one two-sided row */
            solve_joint_row(&row, -bias * (length - shortest), &lower, -FLT_MAX, FLT_MAX, p);
        } else {
            Row back = reversed_row(row);
            solve_limit_row(&row, length - shortest, inv_h, bias, push, &lower, p);
            solve_limit_row(&back, longest - length, inv_h, bias, push, &upper, p);
        }
    }
    if (!push) {
        j->linear_impulse = (float4)(j->linear_impulse.xyz + linear, 0.0f);
        j->angular_impulse = (float4)(j->angular_impulse.xyz + angular, 0.0f);
        j->axial_impulse = (float4)(lower, upper, motor, 0.0f);
    }
}
