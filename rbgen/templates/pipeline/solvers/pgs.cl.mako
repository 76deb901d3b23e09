<%
    serial = solve_form == "serial"
    summed = warm_start_mode == "summed"
    # where the velocities live: other work groups of a persistent launch write them
    # between batches, so it reads them through volatile pointers
    # (common/device_barrier.cl.mako)
    velocity_space = "volatile __global" if persistent else "__global"
    # the serial form solves each constraint in place; the lanes forms solve a private
    # copy, whose loads are all issued at once (in place, PoCL reads the fields back
    # through failed store forwarding; a copy there is a memcpy a visit)
    constraint_space = "__global" if serial else "__private"
    # what the visits of joint items take besides a contact's arguments (joints only)
    joint_params = (", __global JointConstraint* joints, const float inv_h, "
                    "const float joint_recovery") if joints else ""
    joint_args = ", joints, inv_h, joint_recovery" if joints else ""
    # the block solve derives each contact's ContactGeometry once a step (the launches
    # with GEOMETRY_PASS) and its sweeps read it (contact_rows.cl.mako; the template
    # parameter contact_geometry: serial or persistent solves)
    geometry_cache = contact_geometry
    # a persistent launch folds each substep's refresh, carry and warm-start sums into
    # its sweeps (Sweep; pgs.py: fold_substeps); with joints, the joints' warm start
    # stays a pass of its own (it measures the bodies' poses of the substep it starts)
    fused = fold_substeps and persistent
    # what a fused sweep's constraint visits take besides solve_copy's arguments
    fused_params = (", volatile __global const BodyDelta* deltas, const float h, "
                    "const float penetration_slop, const float penetration_recovery"
                    + (", volatile __global long* warm_sums" if summed else "")) if fused else ""
    fused_args = (", deltas, h, penetration_slop, penetration_recovery"
                  + (", warm_sums" if summed else "")) if fused else ""
%>\
/* Projected Gauss-Seidel over batched constraints. solve_groups runs the
 * warm start and the sweeps of one launch over the groups it is given, as
 * the batcher laid them out (rbgen.pipeline.batching): every sweep of a step
 * when one group holds all constraints, one sweep a launch per colour
 * otherwise. apply_split_velocities moves the bodies by their push
 * velocities after integration.
 *
% if serial:
 * Serial form: a work-item is responsible for one level-1 group (a group
 * shares no dynamic body with another group of the same launch) and solves
 * its constraints one after another, in place: plain Gauss-Seidel, no
 * batches, no barriers, every row sees every earlier row's result.
% if geometry_cache:
 * What the rows of a contact derive from its lever arms, normal and the
 * bodies' inertias alone (contact_rows.cl.mako: FaceBlock, FrictionRows)
 * holds over a step: the launches with GEOMETRY_PASS (a step's first)
 * write it to the contact's ContactGeometry record, which every sweep of
 * the step reads (the last one's restitution too: it changes velocities only),
 * prefetching the next contact's records as it solves one.
% endif
% elif not persistent:
 * Lanes form: a work group is responsible for one level-1 group (a group
 * shares no dynamic body with another group of the same launch) and walks
 * its level-2 batches with a barrier after each; its lanes solve a batch's
 * constraints, which share no dynamic body, so they write the velocities
 * without atomics.
% else:
 * Persistent launch: every work group of the launch (as many as the device
 * runs at once) takes part in each batch of the one group of all
 * constraints, a batch's constraints spread over all their lanes, with a
 * device-wide barrier after each batch (common/device_barrier.cl.mako): the
 * whole solve is one launch, and every compute unit takes part.
% if geometry_cache:
 * What the rows of a contact derive from its lever arms, normal and the
 * bodies' inertias alone (contact_rows.cl.mako: FaceBlock, FrictionRows)
 * holds over the step: a launch with GEOMETRY_PASS first writes it to each
 * contact's ContactGeometry record (every lane a share of all contacts), and
 * its sweeps, behind at least one device-wide barrier, read it instead of
 * deriving it (a shock sweep's face block of the held bodies too). No lane has read a
 * record before the launch writes it, so no compute unit's cache holds a
 * stale copy.
% endif
% endif
% if not serial:
 *
 * Batches are walked from the highest colour to the lowest: first-fit
 * colourings give the lowest colours to the constraints of the lowest-indexed
 * bodies, so a ground added first has all its contacts in batch 0, which
 * then comes after the weight above has been passed down. The last batch
 * slot (${max_batches - 1}) holds any remainder and is solved by one lane alone, in
 * order. A lane solves a private copy of its constraint.
% endif
 *
% if summed:
 * The warm start applies the previous step's accumulated impulses once,
 * before the first sweep, summed rather than batched: every lane turns its
 * constraints' impulses into velocity changes at once and adds them to
 * per-body sums of 64-bit fixed-point integers with atomics (integer sums do
 * not depend on the order of the additions: the same bits at every run);
 * after one device-wide barrier every body takes its sum.
% else:
 * The warm start applies the previous step's accumulated impulses once,
 * before the first sweep, visiting the constraints as a sweep does.
% endif
 *
 * A sweep solves the velocity rows (contact_rows.cl.mako) and, in the same
 * batch steps, the split-impulse push rows on the push velocities: the two
 * touch disjoint velocities and impulses, so sweep s of each sees what it
 * would see alone. Odd sweeps visit a manifold's points backwards.
 *
 *
% if persistent:
 * The launch runs the step's substeps itself (`substeps` of h each; 0: only
 * the warm start and the sweeps, for callers that move the bodies): between
 * substeps every body moves over h (the integrator's arithmetic,
 * common/body_motion.cl.mako: damping, rotation, the push, and the motion
 * since the step began in `deltas`) and takes gravity, every constraint's
 * targets follow its bodies' motion (solvers/substeps.cl.mako's rule), then
 * the warm start and the sweeps run again; after the last substep the bodies
 * move over its h, so no integrator launch follows. A constraint is refreshed
 * and summed by the lanes that solve its rows, so that no lane reads a field
 * another work group wrote through its compute unit's cache.
% if fused:
 * Between substeps there is no pass over the constraints: a substep's last
 * velocity sweep carries each constraint's impulses and sums their warm
 * start as it solves it, the bodies take the sums as they move, and the next
 * substep's first sweep refreshes each constraint's targets before its rows
 * (solve_copy): one device-wide barrier between substeps.
% endif
 *
% endif
 * `order` lists constraint-edge items (layouts: ConstraintEdge). A contact's
 * item is its index in `constraints` (the contact kind is 0)${";" if joints else ", and contacts"}
% if joints:
 * a joint's is RB_EDGE_JOINT << RB_EDGE_KIND_SHIFT | its index in `joints`
 * (joint_rows.cl.mako): joints are solved in the same batches and sweeps as
 * contacts, their rows on the velocities and their error on the push
 * velocities, and need no refresh between substeps (their rows measure the
 * bodies' poses of the substep). The program may be built with
% else:
 * are the only kind this solver visits. The program may be built with
% endif
 * -cl-fast-relaxed-math: nothing here relies on an infinity or a NaN.
 */
${cl_constants()}

${cl_structs("Body", "BodyInertia", "ContactConstraint", "SplitVelocity",
             *(("ContactGeometry",) if geometry_cache else ()),
             *(("BodyDelta",) if persistent else ()), *(("JointConstraint",) if joints else ()))}

#define MAX_BATCHES ${max_batches}
/* what one solve_groups launch does before its sweeps (bit flags of `passes`) */
#define WARM_START_PASS 1u
#define FIRST_REVERSED 2u
/* the launch's last velocity sweep is the step's: it applies the restitution
 * (contact_rows.cl.mako: apply_restitution; in a persistent launch, in the
 * last substep only) */
#define RESTITUTION_PASS 4u
/* the launch's last velocity sweep (each substep's, in a persistent launch) is
 * a shock sweep (contact_rows.cl.mako: solve_contact's `shock`); then the
 * restitution goes with the sweep before it */
#define SHOCK_PASS 16u
% if geometry_cache:
/* the launch first derives its contacts' ContactGeometry records (a step's
 * first launch over a group; the sweeps of the step read them) */
#define GEOMETRY_PASS 8u
/* prefetch_constraint's hints, for CPU targets only (the serial form is the CPU's;
 * a GPU compiler may have the builtin but refuse a __global pointer for its
 * generic argument, as NVIDIA's does): a cache line at a time where the compiler
 * has the builtin, else OpenCL's prefetch */
#if defined(__x86_64__) || defined(__aarch64__)
#define PREFETCH_HINTS 1
#if defined(__has_builtin)
#if __has_builtin(__builtin_prefetch)
#define PREFETCH_LINES 1
#endif
#endif
#endif
% endif
% if not serial:
/* the remainder's batch slot, solved by one lane in order */
#define SERIAL_BATCH (MAX_BATCHES - 1)
% endif
% if summed:
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
/* the summed warm start's fixed point: units of 2^-32 m/s (rad/s) */
#define WARM_SUM_ONE 4294967296.0f
% endif

% if persistent:
<%include file="/common/quaternion.cl.mako"/>
<%include file="/common/device_barrier.cl.mako"/>
<%include file="/common/body_motion.cl.mako"/>
% if support_chains:
<%include file="/pipeline/solvers/support_chains.cl.mako" args="velocity_space=velocity_space"/>
% endif
% elif joints:
<%include file="/common/quaternion.cl.mako"/>
% else:
<%include file="/common/inline_math.cl.mako"/>
% endif
<%include file="/pipeline/solvers/contact_masses.cl.mako"/>
<%include file="/pipeline/solvers/contact_rows.cl.mako" args="constraint_space=constraint_space, geometry_cache=geometry_cache, cpu_hints=serial"/>

inline void load_bodies(__private ContactBodies* p, ${velocity_space} const Body* bodies,
                        __global const BodyInertia* inertia, uint a, uint b)
{
    p->inv_mass_a = bodies[a].inv_mass;
    p->inv_mass_b = bodies[b].inv_mass;
    load_inertia(inertia, a, p->inv_inertia_a);
    load_inertia(inertia, b, p->inv_inertia_b);
}

/* The velocities a sweep solves for, in global memory; only dynamic bodies
 * are written back. */
inline void load_velocities(__private ContactBodies* p, ${velocity_space} const Body* bodies,
                            uint a, uint b)
{
    p->va = bodies[a].linear_velocity.xyz, p->wa = bodies[a].angular_velocity.xyz;
    p->vb = bodies[b].linear_velocity.xyz, p->wb = bodies[b].angular_velocity.xyz;
}

/* (whole float4s, w = 0 as unused: a store of .xyz alone through a volatile
 * pointer is a read-modify-write, a round trip more per batch step) */
inline void store_velocities(const __private ContactBodies* p, ${velocity_space} Body* bodies,
                             uint a, uint b)
{
    if (p->inv_mass_a > 0.0f) {
        bodies[a].linear_velocity = (float4)(p->va, 0.0f);
        bodies[a].angular_velocity = (float4)(p->wa, 0.0f);
    }
    if (p->inv_mass_b > 0.0f) {
        bodies[b].linear_velocity = (float4)(p->vb, 0.0f);
        bodies[b].angular_velocity = (float4)(p->wb, 0.0f);
    }
}

inline void load_push(__private ContactBodies* p, ${velocity_space} const SplitVelocity* split,
                      uint a, uint b)
{
    p->va = split[a].linear.xyz, p->wa = split[a].angular.xyz;
    p->vb = split[b].linear.xyz, p->wb = split[b].angular.xyz;
}

inline void store_push(const __private ContactBodies* p, ${velocity_space} SplitVelocity* split,
                       uint a, uint b)
{
    if (p->inv_mass_a > 0.0f) {
        split[a].linear = (float4)(p->va, 0.0f);
        split[a].angular = (float4)(p->wa, 0.0f);
    }
    if (p->inv_mass_b > 0.0f) {
        split[b].linear = (float4)(p->vb, 0.0f);
        split[b].angular = (float4)(p->wb, 0.0f);
    }
}

/* What one sweep solves of each constraint. */
typedef struct {
    bool velocity;           /* its velocity rows (a velocity sweep) */
    bool push;               /* its push rows (a position sweep) */
    bool reverse;            /* a manifold's points backwards */
    bool velocity_releases;  /* the block normal solve may release points */
    bool push_releases;
    bool restitution;        /* then the restitution (the step's last velocity sweep) */
    bool shock;              /* a shock sweep (SHOCK_PASS) */
% if fused:
    /* what a persistent launch's substeps fold into the sweep (set by solve_groups) */
    bool refresh_velocity;   /* the velocity targets refreshed before the rows */
    bool refresh_push;       /* the push targets refreshed (and the push cleared) */
    bool carry;              /* after the rows, the impulses carried (carry_impulses) */
    bool sum;                /* and their warm start added to the bodies' sums */
% endif
} Sweep;

/* Sweep `sweep` of a launch with solve_groups' scalars. */
inline Sweep sweep_of(uint sweep, uint passes, uint velocity_sweeps, uint position_sweeps,
                      uint velocity_release_from, uint position_release_from)
{
    Sweep s;
    s.velocity = sweep < velocity_sweeps;
    s.push = sweep < position_sweeps;
    s.reverse = ((passes & FIRST_REVERSED) != 0) != ((sweep & 1) != 0);
    s.velocity_releases = sweep >= velocity_release_from;
    s.push_releases = sweep >= position_release_from;
    s.shock = (passes & SHOCK_PASS) != 0 && sweep + 1 == velocity_sweeps;
    /* (the last of the sweeps before a shock sweep) */
    const uint shock_sweeps = (passes & SHOCK_PASS) != 0 && velocity_sweeps > 1 ? 1u : 0u;
    s.restitution = (passes & RESTITUTION_PASS) != 0
                    && sweep + 1 + shock_sweeps == velocity_sweeps;
% if fused:
    s.refresh_velocity = s.refresh_push = s.carry = s.sum = false;
% endif
    return s;
}

/* The warm start of one constraint: its accumulated impulses of the previous
 * step applied to its bodies' velocities. */
inline void warm_start_rows(${constraint_space} const ContactConstraint* c,
                            ${velocity_space} Body* bodies, __global const BodyInertia* inertia)
{
    uint a = c->body_a, b = c->body_b;
    ContactBodies state;
    load_bodies(&state, bodies, inertia, a, b);
    load_velocities(&state, bodies, a, b);
    warm_start_contact(c, &state);
    store_velocities(&state, bodies, a, b);
}

% if persistent:
/* One sweep's rows of one constraint: its velocity rows or its push rows, one
 * kind a visit (s.velocity or s.push: solve_batch_persistent), picked at run
 * time through one solve_contact, so that the launch carries one copy of the
 * rows' code. */
inline void solve_rows(${constraint_space} ContactConstraint* c,${" __global const ContactGeometry* g," if geometry_cache else ""}
                       ${velocity_space} Body* bodies,
                       __global const BodyInertia* inertia,
                       ${velocity_space} SplitVelocity* split, const float relaxation,
                       const Sweep s)
{
    const uint a = c->body_a, b = c->body_b;
    const bool push = s.push;
    ContactBodies state;
    load_bodies(&state, bodies, inertia, a, b);
    if (push)
        load_push(&state, split, a, b);
    else
        load_velocities(&state, bodies, a, b);
    solve_contact(c${", g" if geometry_cache else ""}, &state, relaxation, s.reverse,
                  push ? s.push_releases : s.velocity_releases, s.restitution, s.shock, push);
    if (push)
        store_push(&state, split, a, b);
    else
        store_velocities(&state, bodies, a, b);
}
% else:
/* One sweep's rows of one constraint. The velocity and the push rows are
 * loaded first, then solved, then stored: they touch disjoint velocities, so
 * their chains overlap instead of queueing behind each other's stores. */
inline void solve_rows(${constraint_space} ContactConstraint* c,${" __global const ContactGeometry* g," if geometry_cache else ""}
                       ${velocity_space} Body* bodies,
                       __global const BodyInertia* inertia,
                       ${velocity_space} SplitVelocity* split, const float relaxation,
                       const Sweep s)
{
    uint a = c->body_a, b = c->body_b;
    ContactBodies state;
    load_bodies(&state, bodies, inertia, a, b);
    ContactBodies push_state;  /* (a copy only for a sweep with push rows) */
    if (s.push)
        push_state = state;
    if (s.velocity)
        load_velocities(&state, bodies, a, b);
    if (s.push)
        load_push(&push_state, split, a, b);
    if (s.velocity)
        solve_contact(c${", g" if geometry_cache else ""}, &state, relaxation, s.reverse, s.velocity_releases,
                      s.restitution, s.shock, false);
    if (s.push)
        solve_push(c${", g" if geometry_cache else ""}, &push_state, relaxation, s.push_releases);
    if (s.velocity)
        store_velocities(&state, bodies, a, b);
    if (s.push)
        store_push(&push_state, split, a, b);
}
% endif
% if joints:

<%include file="/pipeline/solvers/joint_rows.cl.mako"/>

/* Is this item of `order` a joint's? */
inline bool is_joint(uint item)
{
    return item >> RB_EDGE_KIND_SHIFT == RB_EDGE_JOINT;
}

/* A joint's bodies (B static when it is the world) and its geometry this
 * substep, from the bodies' poses. */
inline void load_joint(__global const JointConstraint* j, ${velocity_space} const Body* bodies,
                       __global const BodyInertia* inertia, __private ContactBodies* p,
                       JointFrame* f)
{
    uint a = j->body_a, b = j->body_b;
    load_bodies(p, bodies, inertia, a, b);
    float3 xb = (float3)(0.0f);
    float4 qb = (float4)(0.0f, 0.0f, 0.0f, 1.0f);
    if (j->flags & RB_JOINT_WORLD) {
        p->inv_mass_b = 0.0f;
        p->inv_inertia_b[0] = p->inv_inertia_b[1] = p->inv_inertia_b[2] = (float3)(0.0f);
    } else {
        xb = bodies[b].position.xyz;
        qb = bodies[b].orientation;
    }
    joint_frame(j, bodies[a].position.xyz, bodies[a].orientation, xb, qb, f);
}

/* The world does not move: B's velocities of a joint to the world are zero. */
inline void still_world(__global const JointConstraint* j, __private ContactBodies* p)
{
    if (j->flags & RB_JOINT_WORLD)
        p->vb = p->wb = (float3)(0.0f);
}

/* The warm start of joint `index`: its accumulated impulses applied to its
 * bodies' velocities (a broken joint acts no more). */
inline void warm_start_joint(__global const JointConstraint* joints, uint index,
                             ${velocity_space} Body* bodies, __global const BodyInertia* inertia)
{
    __global const JointConstraint* j = &joints[index];
    if (j->flags & RB_JOINT_BROKEN)
        return;
    ContactBodies state;
    JointFrame f;
    load_joint(j, bodies, inertia, &state, &f);
    load_velocities(&state, bodies, j->body_a, j->body_b);
    still_world(j, &state);
    warm_start_joint_rows(j, &f, &state);
    store_velocities(&state, bodies, j->body_a, j->body_b);
}

/* One sweep's rows of joint `index`, in place (joint_rows.cl.mako): its
 * velocity rows on the velocities, its push rows on the push velocities. */
inline void solve_joint(__global JointConstraint* joints, uint index,
                        ${velocity_space} Body* bodies, __global const BodyInertia* inertia,
                        ${velocity_space} SplitVelocity* split, const float inv_h,
                        const float joint_recovery, const Sweep s)
{
    __global JointConstraint* j = &joints[index];
    if (j->flags & RB_JOINT_BROKEN)
        return;
    uint a = j->body_a, b = j->body_b;
    ContactBodies state;
    JointFrame f;
    load_joint(j, bodies, inertia, &state, &f);
    if (s.velocity) {
        ContactBodies velocity_state = state;
        load_velocities(&velocity_state, bodies, a, b);
        still_world(j, &velocity_state);
        solve_joint_rows(j, &f, &velocity_state, inv_h, joint_recovery, false);
        store_velocities(&velocity_state, bodies, a, b);
    }
    if (s.push) {
        load_push(&state, split, a, b);
        still_world(j, &state);
        solve_joint_rows(j, &f, &state, inv_h, joint_recovery, true);
        store_push(&state, split, a, b);
    }
}
% endif
% if geometry_cache:

/* The ContactGeometry records of the contacts order[begin], order[begin +
 * stride], ... below `end` (joint items have none), for the sweeps of the
 * step: a serial group's all (stride 1), or a persistent launch lane's share
 * of them (every lanes-th item from its lane, whatever its batch). */
inline void store_geometry_share(__global const ContactConstraint* constraints,
                                 __global const uint* order, uint begin, uint end, uint stride,
                                 ${velocity_space} const Body* bodies,
                                 __global const BodyInertia* inertia,
                                 __global ContactGeometry* geometry)
{
    for (uint i = begin; i < end; i += stride) {
        const uint item = order[i];
% if joints:
        if (is_joint(item))
            continue;
% endif
% if constraint_space == "__private":
        const ContactConstraint copy = constraints[item];  /* (as the sweeps read it) */
        __private const ContactConstraint* c = &copy;
% else:
        __global const ContactConstraint* c = &constraints[item];
% endif
        ContactBodies state;
        load_bodies(&state, bodies, inertia, c->body_a, c->body_b);
        store_geometry(c, &state, &geometry[item]);
    }
}
% endif
% if serial:

% if geometry_cache:
/* Ask for the cache lines of constraint `index` and of its geometry before
 * they are read: a serial sweep reads every constraint's records once, and
 * the solve of the one before gives the loads time to arrive. (A hint only, on
 * CPU targets: see PREFETCH_HINTS; elsewhere nothing.) */
inline void prefetch_constraint(__global const ContactConstraint* constraints,
                                __global const ContactGeometry* geometry, uint index)
{
    __global const char* c = (__global const char*)&constraints[index];
    __global const char* g = (__global const char*)&geometry[index];
#if defined(PREFETCH_LINES)
    for (uint line = 0; line < sizeof(ContactConstraint); line += 64)
        __builtin_prefetch(c + line);
    for (uint line = 0; line < sizeof(ContactGeometry); line += 64)
        __builtin_prefetch(g + line);
#elif defined(PREFETCH_HINTS)
    prefetch(c, sizeof(ContactConstraint));
    prefetch(g, sizeof(ContactGeometry));
#endif
}

/* Ask for the cache lines of constraint c's bodies (their records, inertias and,
 * for a sweep with push rows, push velocities) before its rows read them: the
 * bodies of a slab do not stay cached while a sweep streams its constraints'
 * records through, and each row's chain starts with their velocities. (A hint
 * only, as prefetch_constraint's.) */
inline void prefetch_bodies(__global const ContactConstraint* c, __global const Body* bodies,
                            __global const BodyInertia* inertia,
                            __global const SplitVelocity* split, const bool push)
{
#if defined(PREFETCH_HINTS)
    const uint body[2] = {c->body_a, c->body_b};
    for (uint k = 0; k < 2; ++k) {
        __global const char* record = (__global const char*)&bodies[body[k]];
#if defined(PREFETCH_LINES)
        /* (a Body spans two cache lines at most: its first and last byte) */
        __builtin_prefetch(record);
        __builtin_prefetch(record + sizeof(Body) - 1);
        __builtin_prefetch(&inertia[body[k]]);
        if (push)
            __builtin_prefetch(&split[body[k]]);
#else
        prefetch(record, sizeof(Body));
        prefetch(&inertia[body[k]], 1);
        if (push)
            prefetch(&split[body[k]], 1);
#endif
    }
#endif
}
% endif

/* The warm start of a group's constraints order[begin .. end - 1], in order. */
inline void warm_start_group_serial(__global ContactConstraint* constraints,
                                    __global const uint* order, uint begin, uint end,
                                    __global Body* bodies, __global const BodyInertia* inertia${joint_params})
{
    for (uint i = begin; i < end; ++i) {
% if joints:
        if (is_joint(order[i])) {
            warm_start_joint(joints, order[i] & RB_EDGE_INDEX_MASK, bodies, inertia);
            continue;
        }
% endif
        warm_start_rows(&constraints[order[i]], bodies, inertia);
    }
}

/* One sweep over a group's constraints order[begin .. end - 1], in order. */
inline void solve_group_serial(__global ContactConstraint* constraints,
% if geometry_cache:
                               __global const ContactGeometry* geometry,
% endif
                               __global const uint* order, uint begin, uint end,
                               __global Body* bodies, __global const BodyInertia* inertia,
                               __global SplitVelocity* split, const float relaxation,
                               const Sweep s${joint_params})
{
% if geometry_cache:
    if (begin + 1 < end)
        prefetch_constraint(constraints, geometry, order[begin + 1]);
% endif
    for (uint i = begin; i < end; ++i) {
% if joints:
        if (is_joint(order[i])) {
            solve_joint(joints, order[i] & RB_EDGE_INDEX_MASK, bodies, inertia, split, inv_h,
                        joint_recovery, s);
            continue;
        }
% endif
% if geometry_cache:
        /* (the records two constraints ahead, the bodies of the next: its
         * record, prefetched a constraint earlier, names them; a joint item's
         * index is no constraint's, and its prefetch a harmless hint) */
        if (i + 2 < end)
            prefetch_constraint(constraints, geometry, order[i + 2]);
        if (i + 1 < end${" && !is_joint(order[i + 1])" if joints else ""})
            prefetch_bodies(&constraints[order[i + 1]], bodies, inertia, split, s.push);
% endif
        solve_rows(&constraints[order[i]],${" &geometry[order[i]]," if geometry_cache else ""} bodies, inertia, split, relaxation, s);
    }
}
% else:

/* The constraints order[begin], order[begin + stride], ... below `end` that
 * lane `lane` of `lanes` solves of batch `batch` (order[first .. end - 1]):
 * (begin, stride). The serial slot is lane 0's alone, in order. */
inline uint2 batch_share(uint first, uint end, uint batch, uint lane, uint lanes)
{
    if (batch == SERIAL_BATCH)
        return lane == 0 ? (uint2)(first, 1u) : (uint2)(end, 0u);
    return (uint2)(first + lane, lanes);
}
% endif
% if not serial and not summed:

/* Lane `lane`'s share of the warm start of one batch. */
inline void warm_start_batch(__global const ContactConstraint* constraints,
                             __global const uint* order, uint first, uint end, uint batch,
                             uint lane, uint lanes, ${velocity_space} Body* bodies,
                             __global const BodyInertia* inertia${joint_params})
{
    const uint2 share = batch_share(first, end, batch, lane, lanes);
    for (uint i = share.x; i < end; i += share.y) {
% if joints:
        if (is_joint(order[i])) {
            warm_start_joint(joints, order[i] & RB_EDGE_INDEX_MASK, bodies, inertia);
            continue;
        }
% endif
        ContactConstraint c = constraints[order[i]];  /* a private copy */
        warm_start_rows(&c, bodies, inertia);
    }
}
% endif
% if summed:

/* Add a velocity change to a body's fixed-point sums (linear, then angular). */
inline void add_warm_sum(volatile __global long* sums, float3 linear, float3 angular)
{
    atom_add(&sums[0], convert_long_rte(linear.x * WARM_SUM_ONE));
    atom_add(&sums[1], convert_long_rte(linear.y * WARM_SUM_ONE));
    atom_add(&sums[2], convert_long_rte(linear.z * WARM_SUM_ONE));
    atom_add(&sums[3], convert_long_rte(angular.x * WARM_SUM_ONE));
    atom_add(&sums[4], convert_long_rte(angular.y * WARM_SUM_ONE));
    atom_add(&sums[5], convert_long_rte(angular.z * WARM_SUM_ONE));
}

inline float3 warm_sum_vector(volatile __global const long* sums)
{
    return (float3)(convert_float(sums[0]), convert_float(sums[1]), convert_float(sums[2]))
           * (1.0f / WARM_SUM_ONE);
}

/* Body sums `sums` taken into its velocities *v, *w, and cleared for the next warm
 * start. */
inline void take_warm_sum(volatile __global long* sums, float3* v, float3* w)
{
    *v += warm_sum_vector(sums);
    *w += warm_sum_vector(sums + 3);
    for (uint k = 0; k < RB_WARM_SUM_WORDS; ++k)
        sums[k] = 0;
}

/* A constraint's velocity changes (`state`'s velocities, from rest), added to
 * the sums of its dynamic bodies a and b. */
inline void add_warm_sums(const __private ContactBodies* state, uint a, uint b,
                          volatile __global long* warm_sums)
{
    if (state->inv_mass_a > 0.0f)
        add_warm_sum(warm_sums + RB_WARM_SUM_WORDS * a, state->va, state->wa);
    if (state->inv_mass_b > 0.0f)
        add_warm_sum(warm_sums + RB_WARM_SUM_WORDS * b, state->vb, state->wb);
}

/* The velocity changes of contact *c's warm start (its impulses applied to its
 * bodies at rest), added to its dynamic bodies' sums. */
inline void sum_contact_warm_start(const __private ContactConstraint* c,
                                   volatile __global Body* bodies,
                                   __global const BodyInertia* inertia,
                                   volatile __global long* warm_sums)
{
    const uint a = c->body_a, b = c->body_b;
    ContactBodies state;
    load_bodies(&state, bodies, inertia, a, b);
    state.va = state.wa = state.vb = state.wb = (float3)(0.0f);
    warm_start_contact(c, &state);
    add_warm_sums(&state, a, b, warm_sums);
}

/* Summed warm start, phase 1: the velocity changes of the constraints lane
 * `lane` solves (its share of every batch: it wrote their impulses), added to
 * their dynamic bodies' sums. */
inline void sum_warm_starts(__global const ContactConstraint* constraints,
                            __global const uint* order, __global const uint* offsets,
                            uint batch_count, uint lane,
                            volatile __global Body* bodies, __global const BodyInertia* inertia,
                            volatile __global long* warm_sums,${" const bool contacts," if joints else ""} const bool ok${joint_params})
{
    const uint lanes = get_global_size(0);
    for (uint batch = 0; ok && batch < batch_count; ++batch) {
      const uint first = offsets[batch], end = offsets[batch + 1];
      const uint2 share = batch_share(first, end, batch, lane, lanes);
      for (uint i = share.x; i < end; i += share.y) {
% if joints:
        if (is_joint(order[i])) {
            __global const JointConstraint* j = &joints[order[i] & RB_EDGE_INDEX_MASK];
            if (j->flags & RB_JOINT_BROKEN)
                continue;
            ContactBodies state;
            JointFrame f;
            const uint a = j->body_a, b = j->body_b;
            load_joint(j, bodies, inertia, &state, &f);
            state.va = state.wa = state.vb = state.wb = (float3)(0.0f);
            warm_start_joint_rows(j, &f, &state);
            add_warm_sums(&state, a, b, warm_sums);
            continue;
        }
        if (!contacts)  /* (the sweep that carried them summed them) */
            continue;
% endif
        ContactConstraint c = constraints[order[i]];  /* a private copy */
        sum_contact_warm_start(&c, bodies, inertia, warm_sums);
      }
    }
}

/* Summed warm start, phase 2: every lanes-th body from `lane` takes its sums
 * and clears them for the next step. */
inline void take_warm_sums(volatile __global Body* bodies, volatile __global long* warm_sums,
                           uint body_count, uint lane, const bool ok)
{
    const uint lanes = get_global_size(0);
    for (uint body = lane; ok && body < body_count; body += lanes) {
        if (bodies[body].inv_mass > 0.0f) {
            float3 v = bodies[body].linear_velocity.xyz, w = bodies[body].angular_velocity.xyz;
            take_warm_sum(warm_sums + RB_WARM_SUM_WORDS * body, &v, &w);
            bodies[body].linear_velocity = (float4)(v, 0.0f);
            bodies[body].angular_velocity = (float4)(w, 0.0f);
        }
    }
}
% endif
% if persistent:
<%include file="/pipeline/solvers/contact_targets.cl.mako" args="private_copies=fused"/>

<%
    # group_slot's shape: two halves of the work group (velocity rows, push rows of
    # a small batch), each of `slot_warps` warps of `warp_lanes` lanes (32: NVIDIA's warp),
    # filled in pairs of slots
    warp_lanes = min(32, max(work_group_size // 2, 1))
    slot_warps = max(work_group_size // 2 // warp_lanes, 1)
    slot_pair = min(2, warp_lanes)
%>\
/* The slot of local lane `local_lane` in the order a batch's constraints fill a
 * work group (solve_groups: lane = slot * groups + group). The first half of
 * the slots is the first half of the lanes, the second the second (a small
 * batch's push rows, push_offset). Within a half, pairs of consecutive slots
 * go round its warps (slot s: warp (s / 2) % warps, lanes 2 (s / (2 warps))
 * and the next), so that a compute unit's few constraints of a small batch run
 * as a few warps, which its schedulers (four on NVIDIA's, a work group's warps
 * dealt to them in turn) issue side by side, rather than as lanes of one warp
 * that one scheduler issues, each load for every lane's bodies; the second
 * half's warps start half-way round, so that the push rows run on other
 * schedulers than the velocity rows beside them (without it, small scenes
 * were slower; README: where a GPU step's time goes). A permutation of the
 * lanes for any work-group size. */
inline uint group_slot(const uint local_lane)
{
% if work_group_size >= 2:
    const uint part = local_lane / ${work_group_size // 2}u;
    const uint in_part = local_lane % ${work_group_size // 2}u;
    const uint lane = in_part % ${warp_lanes}u;
    uint warp = in_part / ${warp_lanes}u;
    if (part == 1u)
        warp = (warp + ${slot_warps - slot_warps // 2}u) % ${slot_warps}u;
    return part * ${work_group_size // 2}u
           + ((lane / ${slot_pair}u) * ${slot_warps}u + warp) * ${slot_pair}u + lane % ${slot_pair}u;
% else:
    return local_lane;
% endif
}

/* The lane that solves the push rows of batch order[first .. end - 1] for
 * lane `lane` (see solve_groups). */
inline uint push_owner_of(uint first, uint end, uint lane, uint push_lane, uint push_offset)
{
    return end - first <= push_offset ? push_lane : lane;
}

/* Refresh constraint order[i]'s targets: its velocity targets when `velocity`,
 * its push targets when `push` (the lanes that solve those rows). */
inline void refresh_item(__global ContactConstraint* constraints, uint item,
                         volatile __global const BodyDelta* deltas, const float h,
                         const float penetration_slop, const float penetration_recovery,
                         const bool velocity, const bool push)
{
    __global ContactConstraint* c = &constraints[item];
    uint a = c->body_a, b = c->body_b;
    float3 moved = deltas[b].linear.xyz - deltas[a].linear.xyz;
    refresh_targets(c, moved, deltas[a].angular.xyz, deltas[b].angular.xyz, h,
                    penetration_slop, penetration_recovery, velocity, push);
}

/* Every batch's targets for the next substep, each constraint by the lanes
 * that solve its rows (its velocity rows' lane and its push rows' lane). */
inline void refresh_batches(__global ContactConstraint* constraints, __global const uint* order,
                            __global const uint* offsets, uint batch_count, uint lane,
                            uint push_lane, uint push_offset,
                            volatile __global const BodyDelta* deltas, const float h,
                            const float penetration_slop, const float penetration_recovery)
{
    const uint lanes = get_global_size(0);
    for (uint batch = 0; batch < batch_count; ++batch) {
        const uint first = offsets[batch], end = offsets[batch + 1];
        const uint2 share = batch_share(first, end, batch, lane, lanes);
        for (uint i = share.x; i < end; i += share.y)
% if joints:
            if (!is_joint(order[i]))  /* (a joint measures the poses itself) */
% endif
            refresh_item(constraints, order[i], deltas, h, penetration_slop,
                         penetration_recovery, true, false);
        const uint owner = push_owner_of(first, end, lane, push_lane, push_offset);
        const uint2 push_share = batch_share(first, end, batch, owner, lanes);
        for (uint i = push_share.x; i < end; i += push_share.y)
% if joints:
            if (!is_joint(order[i]))
% endif
            refresh_item(constraints, order[i], deltas, h, penetration_slop,
                         penetration_recovery, false, true);
    }
}

% if support_chains:
/* After a substep's sweeps, the support chains (support_chains.cl.mako), by every
 * lane of the launch, in rounds + 2 phases with a device-wide barrier after each: every
 * constraint of the batches (order[first .. end - 1]) offers its support (`flip`:
 * offer_support); every body's link; `rounds` rounds of pointer jumping between the two
 * halves of `links` (body_count records each). Then every body takes its gain along `up`
 * (against gravity), with no barrier after it: what follows is move_bodies, whose lane
 * for body k is this one's (the same lanes-th bodies from `lane`), so it reads the
 * velocity this lane wrote. `run` false (a solve without substeps, which moves
 * nothing): none of it. One loop over the phases, so that the kernel has one more
 * barrier site, not four: PoCL's compile time grows with the sites. */
inline void propagate_supports(__global const ContactConstraint* constraints,
                               __global const uint* order, uint first, uint end,
                               volatile __global Body* bodies, volatile __global uint* supports,
                               volatile __global float4* links, uint body_count, uint lane,
                               const bool run, const uint rounds, const uint flip, const float3 up,
                               const float slack, volatile __global uint* sync,
                               __local uint* barrier_ok)
{
    const uint lanes = get_global_size(0);
    const uint phases = run ? rounds + 2u : 0u;
    for (uint phase = 0; phase < phases; ++phase) {
        if (phase == 0u) {
            for (uint j = first + lane; *barrier_ok && j < end; j += lanes)
                offer_support(constraints, order[j], flip, supports);
        } else if (phase == 1u) {
            for (uint k = lane; *barrier_ok && k < body_count; k += lanes)
                links[k] = support_link(constraints, bodies, supports, flip, up, slack, k);
        } else {
            const uint r = phase - 2u;
            const uint from = (r & 1u) * body_count, to = body_count - from;
            for (uint k = lane; *barrier_ok && k < body_count; k += lanes)
                links[to + k] = support_jump(links + from, k);
        }
        device_barrier(sync, barrier_ok);
    }
    const uint last = (rounds & 1u) * body_count;
    for (uint k = lane; run && *barrier_ok && k < body_count; k += lanes)
        support_apply(bodies, supports, up, links[last + k], k);
}

% endif
/* Every lanes-th body from `lane` moves over the substep h that just ended (the
 * integrator's arithmetic: damping, rotation, the push applied and cleared,
 * the motion since the step began added to `deltas`, restarted when `first`),
 * then takes the next substep's gravity g h (`gravity_h`; zero after the last),
 * with `kick` its share of the step's external forces (`kicks`, 2 float4 a body:
 * the prepare kernel's)${" and, with `take`, its warm-start sums (take_warm_sums)" if summed else ""}. */
inline void move_bodies(volatile __global Body* bodies, volatile __global SplitVelocity* split,
                        volatile __global BodyDelta* deltas, uint body_count, uint lane,
                        const float h, const float linear_damping_factor,
                        const float angular_damping_factor, const float max_angular_step,
                        const bool first, const float3 gravity_h,
                        __global const float4* kicks, const bool kick,${" volatile __global long* warm_sums, const bool take," if summed else ""} const bool ok)
{
    const uint lanes = get_global_size(0);
    for (uint i = lane; ok && i < body_count; i += lanes) {
        if (bodies[i].inv_mass == 0.0f)
            continue;
        float3 v = bodies[i].linear_velocity.xyz * linear_damping_factor;
        float3 w = bodies[i].angular_velocity.xyz * angular_damping_factor;
        float4 position = bodies[i].position, orientation = bodies[i].orientation;
        position.xyz += v * h;
        orientation = rotate_by_angular_velocity(orientation, w, h, max_angular_step);
        float3 moved = v * h, turned = turn_of(w, h, max_angular_step);
        float3 push = split[i].linear.xyz, half_turn = 0.5f * h * split[i].angular.xyz;
        position.xyz += push * h;
        orientation = push_orientation(orientation, half_turn);
        moved += push * h, turned += 2.0f * half_turn;
        split[i].linear = (float4)(0.0f);
        split[i].angular = (float4)(0.0f);
        bodies[i].position = position;
        bodies[i].orientation = orientation;
        if (kick)
            v += kicks[2 * i].xyz, w += kicks[2 * i + 1].xyz;
        v += gravity_h;
% if summed:
        if (take)
            take_warm_sum(warm_sums + RB_WARM_SUM_WORDS * i, &v, &w);
% endif
        bodies[i].linear_velocity = (float4)(v, 0.0f);
        bodies[i].angular_velocity = (float4)(w, 0.0f);
        if (first) {
            deltas[i].linear = (float4)(moved, 0.0f);
            deltas[i].angular = (float4)(turned, 0.0f);
        } else {
            deltas[i].linear = (float4)(deltas[i].linear.xyz + moved, 0.0f);
            deltas[i].angular = (float4)(deltas[i].angular.xyz + turned, 0.0f);
        }
    }
}

% endif
% if not serial:

/* One sweep's rows of the constraint at `index`, solved on a private copy
 * (every load issued at once, none repeated); the impulses solved are
 * written back.
% if fused:
 * With what the substeps fold into their sweeps (Sweep): before the rows,
 * the copy's targets refreshed for the substep (the first sweep of every
 * substep but the first: refresh_batches' arithmetic, by the same lanes, on
 * the copy the rows read); after them, in the last velocity sweep of a
 * substep that another follows, its impulses carried (carry_impulses) and,
 * for a summed warm start, their velocity changes added to the bodies' sums,
 * which the bodies take when they move (move_bodies). The impulses are final
 * then, so neither needs a pass over the constraints, nor a barrier, of its
 * own.
% endif
 */
inline void solve_copy(__global ContactConstraint* constraints,${" __global const ContactGeometry* geometry," if geometry_cache else ""} uint index,
                       ${velocity_space} Body* bodies, __global const BodyInertia* inertia,
                       ${velocity_space} SplitVelocity* split, const float relaxation,
                       const Sweep s${joint_params}${fused_params})
{
% if joints:
    if (is_joint(index)) {  /* (a joint's item: solved in place) */
        solve_joint(joints, index & RB_EDGE_INDEX_MASK, bodies, inertia, split, inv_h,
                    joint_recovery, s);
        return;
    }
% endif
    ContactConstraint c = constraints[index];
% if fused:
    if (s.refresh_velocity || s.refresh_push) {
        uint a = c.body_a, b = c.body_b;
        refresh_targets_private(&c, deltas[b].linear.xyz - deltas[a].linear.xyz,
                                deltas[a].angular.xyz, deltas[b].angular.xyz, h,
                                penetration_slop, penetration_recovery, s.refresh_velocity,
                                s.refresh_push);
    }
% endif
    solve_rows(&c,${" &geometry[index]," if geometry_cache else ""} bodies, inertia, split, relaxation, s);
% if fused:
    if (s.carry)
        carry_impulses_private(&c);
% if summed:
    if (s.sum)
        sum_contact_warm_start(&c, bodies, inertia, warm_sums);
% endif
% endif
    if (s.velocity) {
        constraints[index].normal_impulse = c.normal_impulse;
        constraints[index].tangent1_impulse = c.tangent1_impulse;
        constraints[index].tangent2_impulse = c.tangent2_impulse;
    }
% if fused:
    if (s.refresh_velocity)
        constraints[index].velocity_target = c.velocity_target;
    if (s.refresh_push)
        constraints[index].position_target = c.position_target;
    if (s.push || s.refresh_push)
% else:
    if (s.push)
% endif
        constraints[index].push_impulse = c.push_impulse;
}
% endif
% if not serial and not persistent:

/* Lane `lane`'s share of one batch of a sweep (a work group's lanes). */
inline void solve_batch_lanes(__global ContactConstraint* constraints, __global const uint* order,
                              uint first, uint end, uint batch, uint lane,
                              __global Body* bodies, __global const BodyInertia* inertia,
                              __global SplitVelocity* split, const float relaxation,
                              const Sweep s${joint_params})
{
    const uint2 share = batch_share(first, end, batch, lane, ${work_group_size}u);
    for (uint i = share.x; i < end; i += share.y)
        solve_copy(constraints, order[i], bodies, inertia, split, relaxation, s${joint_args});
}
% endif
% if persistent:

/* Lane `lane`'s share of one batch of a sweep over the whole launch: the
 * velocity rows of its share, and the push rows of the share of lane
 * `push_lane` when the batch has at most push_offset constraints, else of
 * its own (see solve_groups). */
inline void solve_batch_persistent(__global ContactConstraint* constraints,${"\n                                   __global const ContactGeometry* geometry," if geometry_cache else ""}
                                   __global const uint* order, uint first, uint end, uint batch,
                                   uint lane, uint push_lane, uint push_offset,
                                   volatile __global Body* bodies,
                                   __global const BodyInertia* inertia,
                                   volatile __global SplitVelocity* split,
                                   const float relaxation, const Sweep s${joint_params}${fused_params})
{
    const uint lanes = get_global_size(0);
    const uint push_owner = push_owner_of(first, end, lane, push_lane, push_offset);
    /* the velocity rows of its share, then the push rows of push_owner's: one
     * loop over the two kinds, so that the launch carries one copy of a visit */
    #pragma unroll 1
    for (uint kind = 0; kind < 2; ++kind) {
        const bool push = kind == 1;
        if (push ? !s.push : !s.velocity)
            continue;
        Sweep rows = s;
        rows.velocity = !push;
        rows.push = push;
% if fused:
        if (push) {
            rows.refresh_velocity = rows.carry = rows.sum = false;
        } else {
            /* (a sweep without push rows refreshes their targets with the velocity rows') */
            rows.refresh_push = s.refresh_push && !s.push;
        }
% endif
        const uint2 share = batch_share(first, end, batch, push ? push_owner : lane, lanes);
        for (uint i = share.x; i < end; i += share.y)
            solve_copy(constraints,${" geometry," if geometry_cache else ""} order[i], bodies, inertia, split, relaxation, rows${joint_args}${fused_args});
    }
}
% endif

% if serial:
/* The warm start (passes & WARM_START_PASS) and `velocity_sweeps` velocity
 * sweeps (and `position_sweeps` push sweeps beside them) over the groups
 * group_offset .. group_end - 1. A work-item is responsible for one group:
 * its constraints one after another. */
% elif not persistent:
/* The warm start (passes & WARM_START_PASS) and `velocity_sweeps` velocity
 * sweeps (and `position_sweeps` push sweeps beside them) over the groups
 * group_offset + 0, 1, ... A work group is responsible for one group: its
 * batches one after another, a barrier after each. */
% else:
/* The warm start (passes & WARM_START_PASS) and `velocity_sweeps` velocity
 * sweeps (and `position_sweeps` push sweeps beside them) over the one group
 * group_offset of all constraints, by every work group of the launch: a
 * lane is responsible for the constraints of a batch at its index (`lane`,
 * below: the work groups' lanes interleaved) plus multiples of the launch's
 * size, and all wait for all after each batch (`sync`: the device-wide
 * barrier's words, shared with the global colouring launched before). */
% endif
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void solve_groups(${signature("solve_groups")})
{
% if serial:
    const uint group = group_offset + get_global_id(0);
    if (group >= group_end)
        return;
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint begin = offsets[0], end = offsets[group_batch_count[group]];
% if geometry_cache:
    if (passes & GEOMETRY_PASS)
        store_geometry_share(constraints, order, begin, end, 1u, bodies, inertia, geometry);
% endif
    if (passes & WARM_START_PASS)
        warm_start_group_serial(constraints, order, begin, end, bodies, inertia${joint_args});
    const uint sweeps = max(velocity_sweeps, position_sweeps);
    for (uint sweep = 0; sweep < sweeps; ++sweep) {
        const Sweep s = sweep_of(sweep, passes, velocity_sweeps, position_sweeps,
                                 velocity_release_from, position_release_from);
        solve_group_serial(constraints,${" geometry," if geometry_cache else ""} order, begin, end, bodies, inertia, split,
                           relaxation, s${joint_args});
    }
% elif not persistent:
    const uint lane = get_local_id(0), group = group_offset + get_group_id(0);
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint batch_count = group_batch_count[group];
    if (passes & WARM_START_PASS) {
        for (uint step = 0; step < batch_count; ++step) {
            const uint batch = batch_count - 1 - step;  /* the highest colour first */
            warm_start_batch(constraints, order, offsets[batch], offsets[batch + 1], batch, lane,
                             ${work_group_size}u, bodies, inertia${joint_args});
            barrier(CLK_GLOBAL_MEM_FENCE);
        }
    }
    const uint sweeps = max(velocity_sweeps, position_sweeps);
    for (uint sweep = 0; sweep < sweeps; ++sweep) {
        const Sweep s = sweep_of(sweep, passes, velocity_sweeps, position_sweeps,
                                 velocity_release_from, position_release_from);
        for (uint step = 0; step < batch_count; ++step) {
            const uint batch = batch_count - 1 - step;
            solve_batch_lanes(constraints, order, offsets[batch], offsets[batch + 1], batch, lane,
                              bodies, inertia, split, relaxation, s${joint_args});
            barrier(CLK_GLOBAL_MEM_FENCE);
        }
    }
% else:
    __local uint barrier_ok;
    /* (the colouring before, on the same `sync`, may have given up) */
    device_barrier_start(sync, &barrier_ok);
    /* A batch's constraints go round the work groups first (lane k: slot
     * k / groups of group k % groups), so that a batch smaller than the launch
     * is solved by a lane or a few on every compute unit rather than by full
     * warps of the first few: a lane's constraint is a long chain of
     * instructions, and a compute unit issues those of all its busy warps.
     * Within a work group the slots go round its warps (group_slot). */
    const uint lane = group_slot(get_local_id(0)) * get_num_groups(0) + get_group_id(0);
    /* In a batch of at most push_offset constraints (half a work group's slots
     * on every compute unit), a constraint's push rows are solved by the lane
     * half a work group further on the same compute unit, idle otherwise, so
     * that the sweeps that solve both run them side by side as other warps'
     * instruction streams; in a larger batch that lane has rows of its own. */
    const uint push_offset = ${work_group_size // 2}u * get_num_groups(0);
    const uint push_lane = (lane + push_offset) % get_global_size(0);
    __global const uint* offsets = group_batches + group_offset * (MAX_BATCHES + 1);
    const uint batch_count = group_batch_count[group_offset];
    const uint sweeps = max(velocity_sweeps, position_sweeps);
% if fused:
    /* The sweeps take over the substeps' passes over the constraints (Sweep,
     * solve_copy) where there is a velocity sweep to fold them into: each
     * substep's last velocity sweep carries its impulses and sums their warm
     * start, the bodies take the sums when they move, and the next substep's
     * first sweep refreshes the targets of what it solves. */
    const bool folded = velocity_sweeps > 0u;
% else:
    const bool folded = false;  /* (fold_substeps off: the passes of their own) */
% endif
% if geometry_cache:
    /* the step's ContactGeometry, read by the sweeps behind the warm start's
     * barriers, or behind one of its own */
    if ((passes & GEOMETRY_PASS) != 0u) {
        if (barrier_ok)
            store_geometry_share(constraints, order, offsets[0] + lane, offsets[batch_count],
                                 get_global_size(0), bodies, inertia, geometry);
        if ((passes & WARM_START_PASS) == 0u)
            device_barrier(sync, &barrier_ok);
    }
% endif
    /* (substeps 0: the warm start and sweeps alone, the bodies left where they are) */
    for (uint substep = 0; substep < max(substeps, 1u); ++substep) {
        /* the previous substep's last sweep carried (and summed) the impulses */
        const bool carried = folded && substep > 0;
        if (substep > 0) {
            /* the bodies move over the substep that ended and take this one's
             * gravity${" (and their warm start's sums, when carried)" if summed else ""}; then the constraints' targets follow them */
<%
    # the bodies take the sums as they move when the sweeps summed every warm start
    # (with joints, the joints' warm starts are summed after the move: take_warm_sums)
    take = "false" if joints else "carried && (passes & WARM_START_PASS) != 0"
%>\
            move_bodies(bodies, split, deltas, body_count, lane, h, linear_damping_factor,
                        angular_damping_factor, max_angular_step, substep == 1,
                        gravity.xyz * h, kicks, kicked != 0u,${" warm_sums, %s," % take if summed else ""}
                        barrier_ok);
            device_barrier(sync, &barrier_ok);
            if (!carried) {
                if (barrier_ok)
                    refresh_batches(constraints, order, offsets, batch_count, lane, push_lane,
                                    push_offset, deltas, h, penetration_slop,
                                    penetration_recovery);
% if not summed:
                device_barrier(sync, &barrier_ok);
% endif
            }
        }
% if summed:
<%
    # a joint's warm start is always a pass of its own (it measures the poses of the
    # substep it starts); the contacts' joins it unless the sweeps that carried them
    # summed them
    sum_pass = "" if joints else " && !carried"
%>\
        if ((passes & WARM_START_PASS) != 0u${sum_pass}) {
            /* the warm start's impulses summed per body (a contact's unless the sweep
             * that carried it summed it), then every body takes its sum */
            sum_warm_starts(constraints, order, offsets, batch_count, lane, bodies, inertia,
                            warm_sums,${" !carried," if joints else ""} barrier_ok${joint_args});
            device_barrier(sync, &barrier_ok);
            take_warm_sums(bodies, warm_sums, body_count, lane, barrier_ok);
            device_barrier(sync, &barrier_ok);
        } else if (substep > 0 && !carried) {
            device_barrier(sync, &barrier_ok);  /* (the refresh before the sweeps) */
        }
% else:
        if (passes & WARM_START_PASS) {
            for (uint step = 0; step < batch_count; ++step) {
                const uint batch = batch_count - 1 - step;  /* the highest colour first */
                const uint first = offsets[batch], end = offsets[batch + 1];
                /* an unused colour (inherited colours can leave gaps), or a launch that
                 * gave up its barrier (no more work) */
                if (first == end || !barrier_ok)
                    continue;
                warm_start_batch(constraints, order, first, end, batch, lane,
                                 get_global_size(0), bodies, inertia${joint_args});
                device_barrier(sync, &barrier_ok);
            }
        }
% endif
        /* (the restitution in the last substep only) */
        const bool last_substep = substep + 1u >= max(substeps, 1u);
        const uint substep_passes = last_substep ? passes : passes & ~RESTITUTION_PASS;
        for (uint sweep = 0; sweep < sweeps; ++sweep) {
            ${"Sweep" if fused else "const Sweep"} s = sweep_of(sweep, substep_passes, velocity_sweeps, position_sweeps,
                                     velocity_release_from, position_release_from);
% if fused:
            s.refresh_velocity = carried && sweep == 0 && s.velocity;
            s.refresh_push = carried && sweep == 0;
            s.carry = folded && !last_substep && sweep + 1 == velocity_sweeps;
            s.sum = ${"s.carry && (passes & WARM_START_PASS) != 0" if summed else "false"};
% endif
            for (uint step = 0; step < batch_count; ++step) {
                const uint batch = batch_count - 1 - step;
                const uint first = offsets[batch], end = offsets[batch + 1];
                if (first == end || !barrier_ok)  /* (as in the warm start) */
                    continue;
                solve_batch_persistent(constraints,${" geometry," if geometry_cache else ""} order, first, end, batch, lane, push_lane,
                                       push_offset, bodies, inertia, split, relaxation,
                                       s${joint_args}${fused_args});
                device_barrier(sync, &barrier_ok);
            }
        }
% if support_chains:
        /* (unconditional: a device-wide barrier under a branch costs PoCL a copy of what
         * follows it, so a solve without substeps, which moves nothing, runs no phase
         * through the loop's count; without gravity `up` is 0 and no body gains
         * anything) */
        const float g = length(gravity.xyz);
        propagate_supports(constraints, order, offsets[0], offsets[batch_count], bodies,
                           supports, links, body_count, lane, substeps > 0u, support_rounds,
                           (substep & 1u) != 0u ? RB_SUPPORT_INDEX : 0u,
                           g > 0.0f ? -gravity.xyz / g : (float3)(0.0f),
                           RB_SUPPORT_SLACK * g * h, sync, &barrier_ok);
% endif
    }
    /* the last substep's motion: no integrator launch follows */
    if (substeps > 0)
        move_bodies(bodies, split, deltas, body_count, lane, h, linear_damping_factor,
                    angular_damping_factor, max_angular_step, substeps == 1, (float3)(0.0f),
                    kicks, false,${" warm_sums, false," if summed else ""} barrier_ok);
    device_barrier_leave(sync);
% endif
}

/* One work-item per body: move it by its push velocity over dt, then clear
 * the push. A work group is responsible for consecutive bodies (as many as
 * the host's launch asks: the solver's work-group size does not fit here). */
__kernel void apply_split_velocities(${signature("apply_split_velocities")})
{
    uint i = get_global_id(0);
    if (i >= body_count || bodies[i].inv_mass == 0.0f)
        return;
    float3 v = split[i].linear.xyz, w = split[i].angular.xyz;
    bodies[i].position.xyz += v * dt;
    float4 q = bodies[i].orientation;
    float3 h = 0.5f * dt * w;  /* q += (h, 0) q: first order, renormalised */
    float4 dq = (float4)(q.w * h + cross3(h, q.xyz), -dot3(h, q.xyz));
    q += dq;
    bodies[i].orientation = q * (1.0f / sqrt1(dot3(q.xyz, q.xyz) + q.w * q.w));
    split[i].linear = (float4)(0.0f);
    split[i].angular = (float4)(0.0f);
}
