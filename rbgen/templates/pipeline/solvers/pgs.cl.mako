/* Projected Gauss-Seidel over batched contact constraints.
 *
% if solve_form == "lanes":
 * Lanes solve form: a work group is responsible for one level-1 group (no dynamic
 * body is shared with a group of the same launch) and walks its level-2
 * batches from the last to the first, with a barrier between batches (the
 * first-fit colourings give the lowest colours to the contacts of the
 * lowest-indexed bodies: a ground added first has all its contacts in batch
 * 0, which then comes after the weight above has been passed down. Solved
 * first, BoxBox 27,000 sank 3 cm into the ground, last 0.1 cm; alternating
 * the direction between sweeps held the ground too, but kept boxes of a
 * dropped 4 x 4 x 4 grid rocking at 0.3 m/s); the lanes of a batch
 * solve constraints that share no dynamic body, so they may write body
 * velocities without atomics. The last batch slot (${max_batches - 1}) holds any
 * remainder and is solved by lane 0 alone.
% else:
 * Serial solve form: a work-item is responsible for one level-1 group (no dynamic
 * body is shared with a group of the same launch) and solves its
 * constraints one after another (plain Gauss-Seidel: no batches, no
 * barriers, every row sees every earlier row's result).
% endif
 * One launch runs the warm start and any number of sweeps over the groups
 * it is given: all sweeps of a step when the groups are whole contact-graph
 * components, one sweep per cell colour otherwise.
% if persistent:
 * Persistent variant: the one group of all constraints (single or global batching)
 * is solved by every work group of the launch (as many as the device runs at
 * once), a batch's constraints spread over all their lanes, with a barrier
 * across the work groups after each batch (common/device_barrier.cl.mako):
 * the whole solve is one launch, and every compute unit takes part.
% endif
 *
 * Rows: per contact point a normal row (impulse >= 0, drives the normal
 * velocity to its target),
% if normal_solve == "block":
 * all points' normal rows of a manifold solved together as one block
 * (solve_normal_block: the exact contact solution, so that the result does
 * not depend on the order of the points: solving them one after another
 * leaves a residual torque that tips a symmetric column from its first step
 * and makes it lean or walk; rows one after another, forwards and backwards
 * on alternate sweeps, only for the degenerate manifolds it declines); the
 * sweeps before `velocity_release_from` of the launch (`position_release_from`
 * for the push rows) take only its all-pushing solution, which holds for a
 * face resting on a face, and leave the other manifolds to the rows: cheaper
 * sweeps, their residual removed by the complete block of the last ones, then
% else:
 * all points' normal rows first, one after another, forwards and backwards
 * on alternate sweeps (always solving point 0 first biases a heavy stack's
 * base and makes the whole column wobble), then
% endif
 * one friction pair at the centre of the points, clamped to the disc
 * |f| <= mu * the total normal impulse, and a twist row about the normal.
 * Impulses are accumulated, so warm starting applies last step's
 * totals once, for every constraint, before the first sweep.
% if warm_start_mode == "summed":
 * The warm start is summed rather than batched: every lane turns its
 * constraints' old impulses into velocity changes at once, adds them to
 * per-body sums of 64-bit fixed-point integers with atomics (integer sums do
 * not depend on the order of the additions: the same bits at every run),
 * and after one device-wide barrier every body takes its sum: two phases instead of
 * one batch step per colour.
% endif
 * The split-impulse position sweeps solve the same normal rows on separate
 * push velocities, which apply_split_velocities turns into a displacement
 * after integration and then forgets.
 *
 * A row's Jacobian terms (lever arm x direction, and the angular velocity
 * change per unit impulse) do not depend on the velocities, so they are
 * computed before the row reads any velocity: Gauss-Seidel is a chain of
 * dependent row updates, and only the dot products and the update itself
 * stay on it. Loops over a manifold's points run to the constant
 * RB_MAX_MANIFOLD_POINTS and test the count inside, so that compilers unroll
 * them and keep the per-point arrays in registers.
% if fast_math:
 * Built with -cl-fast-relaxed-math (the manifest's build_options): the
 * chain is shorter with approximate reciprocals and square roots and freely
 * fused and reordered arithmetic. Nothing here relies on an infinity or a NaN.
% endif
 */
${cl_constants()}

${cl_structs("Body", "BodyInertia", "ContactConstraint", "SplitVelocity")}

#define MAX_BATCHES ${max_batches}
% if solve_form == "lanes":
#define SERIAL_BATCH (MAX_BATCHES - 1)
% endif
/* what one solve_groups launch does before its sweeps (bit flags of `passes`) */
#define WARM_START_PASS 1u
#define FIRST_REVERSED 2u
% if warm_start_mode == "summed":
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
/* the summed warm start's fixed point: units of 2^-32 m/s (rad/s) */
#define WARM_SUM_ONE 4294967296.0f
% endif

<%include file="/common/inline_math.cl.mako"/>
% if persistent:
<%include file="/common/device_barrier.cl.mako"/>
% endif
<%
    # the velocities' address space: in the persistent variant other work groups of
    # the same launch write them between batches, so they are read through
    # volatile pointers (see common/device_barrier.cl.mako)
    shared = "volatile __global" if persistent else "__global"
%>\

<%
    # The serial form solves each constraint in place: a private copy (the GPU
    # lanes form's way to issue every load at once) is a 352-byte memcpy a visit on
    # PoCL, whose fields are then read back through failed store forwarding
    # (PoCL BoxBox 8,000: the copy and those reads were ~10% of the solve).
    constraint_space = "__global" if solve_form == "serial" else "__private"
%>\
<%include file="/pipeline/solvers/contact_rows.cl.mako" args="constraint_space=constraint_space"/>

inline void load_bodies(__private ContactBodies* p, ${shared} const Body* bodies,
                        __global const BodyInertia* inertia, uint a, uint b)
{
    p->inv_mass_a = bodies[a].inv_mass;
    p->inv_mass_b = bodies[b].inv_mass;
    load_inertia(inertia, a, p->inv_inertia_a);
    load_inertia(inertia, b, p->inv_inertia_b);
}

/* Where a sweep reads and writes the velocities it solves for: the bodies'
 * velocities (or push velocities) in global memory, or the copies a resident
 * solve keeps in local memory. Only dynamic bodies are written back. */
inline void load_velocities(__private ContactBodies* p, ${shared} const Body* bodies, uint a, uint b)
{
    p->va = bodies[a].linear_velocity.xyz, p->wa = bodies[a].angular_velocity.xyz;
    p->vb = bodies[b].linear_velocity.xyz, p->wb = bodies[b].angular_velocity.xyz;
}

/* (whole float4s, w = 0 as unused: a store of .xyz alone through a volatile
 * pointer is a read-modify-write, a round trip more per batch step) */
inline void store_velocities(const __private ContactBodies* p, ${shared} Body* bodies, uint a, uint b)
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

inline void load_push(__private ContactBodies* p, ${shared} const SplitVelocity* split, uint a, uint b)
{
    p->va = split[a].linear.xyz, p->wa = split[a].angular.xyz;
    p->vb = split[b].linear.xyz, p->wb = split[b].angular.xyz;
}

inline void store_push(const __private ContactBodies* p, ${shared} SplitVelocity* split, uint a, uint b)
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
% if warm_start_mode == "summed":

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
% endif

<%
    # where each kind of sweep finds its velocities (see load_velocities)
    memory = {"velocities": "bodies", "push": "split"}
    fence = "CLK_GLOBAL_MEM_FENCE"
    batch_barrier = "device_barrier(sync, &barrier_ok);" if persistent else f"barrier({fence});"
    lanes = "get_global_size(0)" if persistent else work_group_size
%>\
<%def name="visit(solves)">\
{
% if solve_form == "serial":
                /* in place (see constraint_space) */
                __global ContactConstraint* c = &constraints[order[i]];
% else:
                /* a private copy: every load is issued at once, none is repeated */
                const uint index = order[i];
                ContactConstraint constraint = constraints[index];
                __private ContactConstraint* c = &constraint;
% endif
                uint a = c->body_a, b = c->body_b;
% for k, (name, when, action, source, results) in enumerate(solves):
% if k == 0:
                ContactBodies ${name};
                load_bodies(&${name}, bodies, inertia, a, b);
% else:
                ContactBodies ${name} = ${solves[0][0]};
% endif
% endfor
<%
    # the solves read first, then compute, then write: they touch disjoint
    # velocities, so their chains overlap instead of queueing behind each
    # other's (volatile) stores
    guarded = [(f"if ({when}) " if when else "", name, action, source, results)
               for name, when, action, source, results in solves]
%>\
% for guard, name, action, source, results in guarded:
                ${guard}load_${source}(&${name}, ${memory[source]}, a, b);
% endfor
% for guard, name, action, source, results in guarded:
                ${guard}${action.format(state="&" + name)};
% endfor
% for guard, name, action, source, results in guarded:
                ${guard}{
                    store_${source}(&${name}, ${memory[source]}, a, b);
% for field in (results if solve_form == "lanes" else ()):
                    constraints[index].${field} = c->${field};
% endfor
                }
% endfor
            }\
</%def>\
<%def name="each_constraint(*solves)">\
% if persistent:
        for (uint step = 0; step < batch_count; ++step) {
            const uint batch = batch_count - 1 - step;  /* the highest colour first */
            const uint first = offsets[batch], end = offsets[batch + 1];
            /* an unused colour (inherited colours can leave gaps), or a launch that
             * gave up its barrier (no more work; see grid_barrier) */
            if (first == end || !barrier_ok)
                continue;
% if any(solve[3] == "push" for solve in solves):
            /* (see push_lane: only while that lane has no velocity rows of this batch) */
            const uint push_owner = end - first <= push_offset ? push_lane : lane;
% endif
% for name, when, action, source, results in solves:
<%
    # each kind of solve by the lanes that own it (see push_lane), a loop each
    owner = "push_owner" if source == "push" else "lane"
%>\
            uint ${source}_begin = first + ${owner}, ${source}_stride = ${lanes};
            if (batch == SERIAL_BATCH)  /* the remainder: one lane alone, in order */
                ${source}_stride = ${owner} == 0 ? 1 : 0, ${source}_begin = ${owner} == 0 ? first : end;
            ${f"if ({when}) " if when else ""}for (uint i = ${source}_begin; i < end; i += ${source}_stride) ${visit([(name, None, action, source, results)])}
% endfor
            ${batch_barrier}
        }
% elif solve_form == "lanes":
        for (uint step = 0; step < batch_count; ++step) {
            const uint batch = batch_count - 1 - step;  /* the highest colour first */
            uint begin = offsets[batch];
            uint end = offsets[batch + 1];
            uint stride = ${lanes};
            if (batch == SERIAL_BATCH)  /* the remainder: lane 0 alone, in order */
                stride = lane == 0 ? 1 : 0, begin = lane == 0 ? begin : end;
            for (uint i = begin + lane; i < end; i += stride) ${visit(solves)}
            ${batch_barrier}
        }
% else:
        for (uint i = begin; i < end; ++i) ${visit(solves)}
% endif
</%def>\
<% velocities = "velocities" %>\

% if persistent:
/* The warm start, `velocity_sweeps` and then `position_sweeps` sweeps over
 * the one group of all constraints, by every work group of the launch: a
 * lane is responsible for the constraints of a batch at its index (`lane`,
 * below: the work groups' lanes interleaved) plus multiples of the launch's
 * size, and all wait for all after each
 * batch (`sync`: the device-wide barrier's words, shared with the global colouring
 * launched before). */
% elif solve_form == "lanes":
/* The warm start and `velocity_sweeps` (then `position_sweeps`) sweeps over
 * the groups group_offset + 0, 1, ... (one launch). A work group is
 * responsible for one level-1 group: its batches in order, a barrier after
 * each. */
% else:
/* The warm start and `velocity_sweeps` (then `position_sweeps`) sweeps over
 * the groups group_offset .. group_end - 1 (one launch). A work-item is
 * responsible for one level-1 group: its constraints one after another. */
% endif
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void solve_groups(__global ContactConstraint* constraints,
                  __global const uint* order,
                  __global const uint* group_batches,
                  __global const uint* group_batch_count,
                  ${shared} Body* bodies,
                  __global const BodyInertia* inertia,
                  ${shared} SplitVelocity* split,
% if persistent:
                  volatile __global uint* sync,
% endif
% if warm_start_mode == "summed":
                  volatile __global long* warm_sums,
                  const uint body_count,
% endif
                  const float relaxation,
                  const uint group_offset,
% if solve_form == "serial":
                  const uint group_end,
% endif
                  const uint passes,
<%
    scalars = ["velocity_sweeps", "position_sweeps"]
    if normal_solve == "block":
        scalars += ["velocity_release_from", "position_release_from"]
%>\
                  ${",\n                  ".join("const uint " + name for name in scalars)})
{
% if persistent:
    __local uint barrier_ok;
    device_barrier_start(sync, &barrier_ok);  /* (the colouring before, on the same `sync`, may have given up) */
    /* a batch's constraints go round the work groups first (lane k: local lane
     * k / groups of group k % groups), so that a batch smaller than the launch
     * is solved by one lane or a few on every compute unit rather than by full
     * warps of the first few: a lane's constraint is a long chain of
     * instructions, and a compute unit issues those of all its busy warps
     * (H200 BoxBox 1,000 / 8,000 boxes: 1.01 / 1.19 -> 0.61 / 0.80 ms a step,
     * the same trajectories) */
    const uint lane = get_local_id(0) * get_num_groups(0) + get_group_id(0);
    /* In a batch of at most push_offset constraints (one warp's worth of lanes on
     * every compute unit), a constraint's push rows (split impulse) are solved by
     * another lane than its velocity rows: the lane a warp further on the same
     * compute unit (so that its plain loads of the constraint share that unit's
     * cache with the owner of the other fields), idle otherwise. The two solves
     * touch disjoint velocities and impulses, so in the sweeps that do both they
     * run side by side as two warps' instruction streams instead of one after
     * the other in one. Each lane solves the same constraints' rows of its kind
     * at every sweep. Measured on the H200 (BoxBox, 2026-12-03) with the split in
     * every batch: 1,000 / 8,000 boxes 0.61 / 0.81 -> 0.59 / 0.77 ms a step, the
     * same trajectories, but 27,000 / 111,375 1.21 / 3.63 -> 1.27 / 3.77 (there
     * the second lane has rows of its own, and the constraint and its bodies are
     * loaded twice): hence the size rule, which was not timed on the GPU. */
    const uint push_offset = min(32u, ${work_group_size}u / 2u) * get_num_groups(0);
    const uint push_lane = (lane + push_offset) % get_global_size(0);
    const uint group = group_offset;
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint batch_count = group_batch_count[group];
% elif solve_form == "lanes":
    const uint lane = get_local_id(0), group = group_offset + get_group_id(0);
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint batch_count = group_batch_count[group];
% else:
    const uint group = group_offset + get_global_id(0);
    if (group >= group_end)
        return;
    __global const uint* offsets = group_batches + group * (MAX_BATCHES + 1);
    const uint begin = offsets[0], end = offsets[group_batch_count[group]];
% endif
<%
    velocity_results = ("normal_impulse", "tangent1_impulse", "tangent2_impulse")
    # (the state's name, the flag that enables it, the call, the velocities, the results)
    warm_start = ("state", None, "warm_start_contact(c, {state})", velocities, ())
    # whether a sweep's block solve may release points (see the kernel's comment)
    velocity_releases = "sweep >= velocity_release_from" if normal_solve == "block" else "false"
    push_releases = "sweep >= position_release_from" if normal_solve == "block" else "false"
    velocity_sweep = ("state", "velocity",
                      f"solve_contact(c, {{state}}, relaxation, reverse, {velocity_releases})",
                      velocities, velocity_results)
    push_sweep = ("push_state", "push", f"solve_push(c, {{state}}, relaxation, {push_releases})",
                  "push", ("push_impulse",))
%>\
    if (passes & WARM_START_PASS) {
% if warm_start_mode == "summed":
        /* 1. every constraint's old impulses as velocity changes, summed per body */
        const uint all_begin = offsets[0], all_end = offsets[batch_count];
        for (uint i = all_begin + lane; barrier_ok && i < all_end; i += ${lanes}) {
            ContactConstraint constraint = constraints[order[i]];
            __private ContactConstraint* c = &constraint;
            uint a = c->body_a, b = c->body_b;
            ContactBodies state;
            load_bodies(&state, bodies, inertia, a, b);
            state.va = state.wa = state.vb = state.wb = (float3)(0.0f);
            warm_start_contact(c, &state);
            if (state.inv_mass_a > 0.0f)
                add_warm_sum(warm_sums + RB_WARM_SUM_WORDS * a, state.va, state.wa);
            if (state.inv_mass_b > 0.0f)
                add_warm_sum(warm_sums + RB_WARM_SUM_WORDS * b, state.vb, state.wb);
        }
        ${batch_barrier}
        /* 2. every body takes its sum, and clears it for the next step */
        for (uint body = lane; barrier_ok && body < body_count; body += ${lanes}) {
            volatile __global long* sums = warm_sums + RB_WARM_SUM_WORDS * body;
            if (bodies[body].inv_mass > 0.0f) {
                float3 linear = warm_sum_vector(sums), angular = warm_sum_vector(sums + 3);
                bodies[body].linear_velocity = (float4)(bodies[body].linear_velocity.xyz + linear, 0.0f);
                bodies[body].angular_velocity = (float4)(bodies[body].angular_velocity.xyz + angular, 0.0f);
                for (uint k = 0; k < RB_WARM_SUM_WORDS; ++k)
                    sums[k] = 0;
            }
        }
        ${batch_barrier}
% else:
${each_constraint(warm_start)}\
% endif
    }
    /* The velocity and the position sweeps at once: the push rows read only
     * push velocities and impulses, the velocity rows neither, so sweep s of
     * each sees what it would see alone, and one batch step (one barrier)
     * serves both. */
    const uint sweeps = max(velocity_sweeps, position_sweeps);
    for (uint sweep = 0; sweep < sweeps; ++sweep) {
        const bool reverse = ((passes & FIRST_REVERSED) != 0) != ((sweep & 1) != 0);
        const bool velocity = sweep < velocity_sweeps, push = sweep < position_sweeps;
${each_constraint(velocity_sweep, push_sweep)}\
    }
% if persistent:
    device_barrier_leave(sync);
% endif
}

/* One work-item per body: move it by its push velocity over dt, then clear
 * the push. A work group is responsible for consecutive bodies (as many as
 * the host's launch asks: the solver's work-group size does not fit here). */
__kernel void apply_split_velocities(__global Body* bodies, __global SplitVelocity* split,
                                     const uint body_count, const float dt)
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
