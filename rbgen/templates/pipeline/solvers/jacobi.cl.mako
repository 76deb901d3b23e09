<%namespace name="group" file="/primitives/common.cl.mako"/>\
/* Jacobi over contact constraints with mass splitting (Tonge et al. 2012).
 *
 * Every constraint of a sweep is solved at once, against the velocities the
 * sweep started from: no colouring, no batches, one phase a sweep over all
 * constraints and one over all bodies. A body with k contacts is split into
 * k copies, one per contact, each with 1/k of its mass and inertia: a
 * constraint solves its rows (the same rows, block solve and friction as the
 * Gauss-Seidel solver, pipeline/solvers/contact_rows.cl.mako) on its copies, and the
 * body phase sets each body's velocity to the mean of its copies'. That mean
 * is the velocity plus the sum of the contacts' impulses through the whole
 * body's mass, so every contact pushes as much as it asked for, while a body
 * pressed from k sides never overshoots as plain Jacobi (each contact
 * against the whole body) does.
 *
 * Per step, before the sweeps (phases separated by a barrier):
 * 1. clear: every body's contact count k = 0;
 * 2. count: each constraint takes a slot on each of its dynamic bodies
 *    (atomic_inc; static bodies are not split and hold no list);
 * 3. chunk sums, 4. scan: the lists' offsets, an exclusive scan of k over
 *    the bodies in one chunk per work group;
 * 5. link: each constraint enters its two sides in its bodies' lists, and
 *    recomputes its row masses for the split bodies (set_row_masses);
 * 6. order: each body sorts its list (by side index), so that the sums of the
 *    body phase do not depend on the order the slots were taken in: results
 *    are the same from run to run.
 * Then the warm start and each sweep: a constraint phase (each constraint
 * writes the velocity change of its two copies to `changes`) and a body
 * phase (each dynamic body adds the mean of its list's changes).
 *
% if persistent:
 * Persistent variant: ONE launch runs all phases, its work groups (one per
 * compute unit) passing a barrier across the device between phases
 * (common/device_barrier.cl.mako); the arrays that lanes of other work groups
 * write during the launch are read through volatile pointers. A constraint
 * and a body are each handled by the lane at its index modulo the launch's
 * size in every phase, so what only that lane writes and reads back
 * (side_slots, the constraint's impulses and masses, a body's sorted list)
 * needs no barrier.
% else:
 * Phase variant: one launch per phase (the launch boundary is the barrier);
 * every launch has the same size, so a chunk of bodies belongs to the same
 * work group in phases 3 and 4.
% endif
 * Odd sweeps visit each manifold's points backwards, as in Gauss-Seidel.
 */
${cl_constants()}

${cl_structs("Body", "BodyInertia", "ContactConstraint", "SplitVelocity")}

/* `passes` of the persistent kernel: whether it runs the warm start */
#define WARM_START_PASS 1u
/* and whether its last velocity sweep applies the restitution
 * (contact_rows.cl.mako: apply_restitution) */
#define RESTITUTION_PASS 4u
/* a sweep's `reverse` bits: the points backwards, then the restitution */
#define SWEEP_REVERSED 1u
#define SWEEP_RESTITUTION 2u

<%include file="/common/inline_math.cl.mako"/>
% if persistent:
<%include file="/common/device_barrier.cl.mako"/>
% endif
<%include file="/pipeline/solvers/contact_masses.cl.mako"/>
<%include file="/pipeline/solvers/contact_rows.cl.mako"/>
${group.work_group_exclusive_scan("uint", work_group_size, min(32, work_group_size))}
${group.work_group_reduce("uint", "sum", "{a} + {b}", work_group_size)}
<%
    # written by lanes of other work groups during a persistent launch: volatile
    shared = "volatile __global" if persistent else "__global"
    segments = work_group_size // min(32, work_group_size)
%>\

/* A contact's share of body `body`: its inverse mass and world inverse
 * inertia times its number of contacts k (a static body: zero, unsplit). */
inline void load_split_body(${shared} const Body* bodies, __global const BodyInertia* inertia,
                            volatile __global const uint* body_contacts, uint body,
                            float* inv_mass, float3 inv_inertia[3])
{
    float k = (float)max(body_contacts[body], 1u);
    *inv_mass = bodies[body].inv_mass * k;
    for (int r = 0; r < 3; ++r)
        inv_inertia[r] = inertia[body].inv_inertia_world[r].xyz * k;
}

/* The velocity change of a constraint's two copies: changes[4 i .. 4 i + 3]
 * = (linear, angular) of A, then of B; side s of constraint i is at 4 i + 2 s. */
inline void store_changes(${shared} float4* changes, uint i, const __private ContactBodies* p,
                          float3 va, float3 wa, float3 vb, float3 wb)
{
    if (p->inv_mass_a > 0.0f) {
        changes[4 * i] = (float4)(p->va - va, 0.0f);
        changes[4 * i + 1] = (float4)(p->wa - wa, 0.0f);
    }
    if (p->inv_mass_b > 0.0f) {
        changes[4 * i + 2] = (float4)(p->vb - vb, 0.0f);
        changes[4 * i + 3] = (float4)(p->wb - wb, 0.0f);
    }
}

<%def name="indices(chunks, constraints=True)">\
    const uint lane = get_global_id(0), lanes = get_global_size(0);
% if constraints:
    const uint count = min(constraint_count[0], capacity);
% endif
% if chunks:
    const uint local_lane = get_local_id(0), group = get_group_id(0), groups = get_num_groups(0);
    /* the bodies of this work group's chunk (phases 3 and 4), a run of them per lane */
    const uint chunk = (body_count + groups - 1) / groups;
    const uint chunk_begin = min(group * chunk, body_count);
    const uint chunk_end = min(chunk_begin + chunk, body_count);
    const uint run = (chunk + ${work_group_size - 1}u) / ${work_group_size}u;
    const uint run_begin = min(chunk_begin + local_lane * run, chunk_end);
    const uint run_end = min(run_begin + run, chunk_end);
    __local uint scratch[${2 * work_group_size}], segment_sums[${segments + 1}];
% endif
</%def>
<%def name="clear_phase()">\
        for (uint body = lane; body < body_count; body += lanes)
            body_contacts[body] = 0u;
</%def>
<%def name="count_phase()">\
        for (uint i = lane; i < count; i += lanes) {
            uint a = constraints[i].body_a, b = constraints[i].body_b;
            side_slots[2 * i] = bodies[a].inv_mass > 0.0f ? atomic_inc(&body_contacts[a])
                                                          : RB_SOLVER_NONE;
            side_slots[2 * i + 1] = bodies[b].inv_mass > 0.0f ? atomic_inc(&body_contacts[b])
                                                              : RB_SOLVER_NONE;
        }
</%def>
<%def name="chunk_sum_phase()">\
        uint sum = 0u;
        for (uint body = run_begin; body < run_end; ++body)
            sum += body_contacts[body];
        sum = work_group_sum_uint(sum, scratch);
        if (local_lane == 0u)
            chunk_sums[group] = sum;
</%def>
<%def name="scan_phase()">\
        /* the lists before this chunk: the earlier chunks' sums */
        uint before = 0u;
        for (uint g = local_lane; g < group; g += ${work_group_size}u)
            before += chunk_sums[g];
        before = work_group_sum_uint(before, scratch);
        uint run_sum = 0u, chunk_total;
        for (uint body = run_begin; body < run_end; ++body)
            run_sum += body_contacts[body];
        uint first = before + work_group_exclusive_scan_uint(run_sum, scratch, segment_sums,
                                                             &chunk_total);
        for (uint body = run_begin; body < run_end; ++body) {
            body_first[body] = first;
            first += body_contacts[body];
        }
</%def>
<%def name="link_phase()">\
        for (uint i = lane; i < count; i += lanes) {
            ContactConstraint constraint = constraints[i];
            uint a = constraint.body_a, b = constraint.body_b;
            uint slot_a = side_slots[2 * i], slot_b = side_slots[2 * i + 1];
            if (slot_a != RB_SOLVER_NONE)
                lists[body_first[a] + slot_a] = 2 * i;
            if (slot_b != RB_SOLVER_NONE)
                lists[body_first[b] + slot_b] = 2 * i + 1;
            if (max(body_contacts[a], body_contacts[b]) > 1u) {
                /* the rows' masses between the contact's shares of its bodies */
                float inv_mass_a, inv_mass_b;
                float3 inv_inertia_a[3], inv_inertia_b[3];
                load_split_body(bodies, inertia, body_contacts, a, &inv_mass_a, inv_inertia_a);
                load_split_body(bodies, inertia, body_contacts, b, &inv_mass_b, inv_inertia_b);
                set_row_masses(&constraint, inv_mass_a, inv_inertia_a, inv_mass_b, inv_inertia_b);
                constraints[i].normal_mass = constraint.normal_mass;
                constraints[i].tangent1_mass = constraint.tangent1_mass;
                constraints[i].tangent2_mass = constraint.tangent2_mass;
            }
        }
</%def>
<%def name="order_phase()">\
        /* insertion sort of each list: a few entries (a box in a pile has ~8) */
        for (uint body = lane; body < body_count; body += lanes) {
            uint first = body_first[body], end = first + body_contacts[body];
            for (uint j = first + 1; j < end; ++j) {
                uint side = lists[j], at = j;
                for (; at > first && lists[at - 1] > side; --at)
                    lists[at] = lists[at - 1];
                lists[at] = side;
            }
        }
</%def>
<%def name="constraint_phase(action, memory, results=())">\
        for (uint i = lane; i < count; i += lanes) {
            /* a private copy: every load is issued at once, none is repeated */
            ContactConstraint constraint = constraints[i];
            __private ContactConstraint* c = &constraint;
            uint a = c->body_a, b = c->body_b;
            ContactBodies p;
            load_split_body(bodies, inertia, body_contacts, a, &p.inv_mass_a, p.inv_inertia_a);
            load_split_body(bodies, inertia, body_contacts, b, &p.inv_mass_b, p.inv_inertia_b);
% if memory == "bodies":
            p.va = bodies[a].linear_velocity.xyz, p.wa = bodies[a].angular_velocity.xyz;
            p.vb = bodies[b].linear_velocity.xyz, p.wb = bodies[b].angular_velocity.xyz;
% else:
            p.va = split[a].linear.xyz, p.wa = split[a].angular.xyz;
            p.vb = split[b].linear.xyz, p.wb = split[b].angular.xyz;
% endif
            float3 va = p.va, wa = p.wa, vb = p.vb, wb = p.wb;
            ${action};
            store_changes(changes, i, &p, va, wa, vb, wb);
% for field in results:
            constraints[i].${field} = c->${field};
% endfor
        }
</%def>
<%def name="body_phase(memory)">\
        for (uint body = lane; body < body_count; body += lanes) {
            uint k = body_contacts[body];
            if (k == 0u)
                continue;
            uint first = body_first[body];
            float3 linear = (float3)(0.0f), angular = (float3)(0.0f);
            for (uint j = first; j < first + k; ++j) {
                uint side = lists[j];
                linear += changes[2 * side].xyz;
                angular += changes[2 * side + 1].xyz;
            }
            float share = 1.0f / (float)k;
% if memory == "bodies":
            bodies[body].linear_velocity = (float4)(bodies[body].linear_velocity.xyz
                                                    + linear * share, 0.0f);
            bodies[body].angular_velocity = (float4)(bodies[body].angular_velocity.xyz
                                                     + angular * share, 0.0f);
% else:
            split[body].linear = (float4)(split[body].linear.xyz + linear * share, 0.0f);
            split[body].angular = (float4)(split[body].angular.xyz + angular * share, 0.0f);
% endif
        }
</%def>
<%
    velocity_results = ("normal_impulse", "tangent1_impulse", "tangent2_impulse")
    sweep = ("solve_contact(c, &p, relaxation, (reverse & SWEEP_REVERSED) != 0, true, "
             "(reverse & SWEEP_RESTITUTION) != 0, false, false)")
%>\
% if persistent:

/* The whole solve of one step: the lists, the warm start (passes &
 * WARM_START_PASS), `velocity_sweeps` sweeps on the velocities and
 * `position_sweeps` on the push velocities, by every work group of the
 * launch (`sync`: the device-wide barrier's words). */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void solve_jacobi(${signature("solve_jacobi")})
{
${indices(True)}\
    /* 0 once a device-wide barrier was given up: the phases that index through what
     * earlier phases wrote are skipped from then on (the scan's run on as they
     * are: they index nothing they did not bound themselves) */
    __local uint barrier_ok;
    device_barrier_start(sync, &barrier_ok);
    if (barrier_ok) {
${clear_phase()}\
    }
    device_barrier(sync, &barrier_ok);
    if (barrier_ok) {
${count_phase()}\
    }
    device_barrier(sync, &barrier_ok);
    {
${chunk_sum_phase()}\
    }
    device_barrier(sync, &barrier_ok);
    {
${scan_phase()}\
    }
    device_barrier(sync, &barrier_ok);
    if (barrier_ok) {
${link_phase()}\
    }
    device_barrier(sync, &barrier_ok);
    if (barrier_ok) {
${order_phase()}\
    }
    if (passes & WARM_START_PASS) {
        if (barrier_ok) {
${constraint_phase("warm_start_contact(c, &p)", "bodies")}\
        }
        device_barrier(sync, &barrier_ok);
        if (barrier_ok) {
${body_phase("bodies")}\
        }
        device_barrier(sync, &barrier_ok);
    }
    for (uint s = 0; s < velocity_sweeps; ++s) {
        const uint reverse = ((s & 1) != 0 ? SWEEP_REVERSED : 0u)
                           | ((passes & RESTITUTION_PASS) != 0 && s + 1 == velocity_sweeps
                              ? SWEEP_RESTITUTION : 0u);
        if (barrier_ok) {
${constraint_phase(sweep, "bodies", velocity_results)}\
        }
        device_barrier(sync, &barrier_ok);
        if (barrier_ok) {
${body_phase("bodies")}\
        }
        device_barrier(sync, &barrier_ok);
    }
    for (uint s = 0; s < position_sweeps; ++s) {
        if (barrier_ok) {
${constraint_phase("solve_push(c, &p, relaxation, true)", "split", ("push_impulse",))}\
        }
        device_barrier(sync, &barrier_ok);
        if (barrier_ok) {
${body_phase("split")}\
        }
        device_barrier(sync, &barrier_ok);
    }
    device_barrier_leave(sync);
}
% else:
<%
    phases = [
        ("clear", "phase 1: every body's contact count to zero", clear_phase),
        ("count", "phase 2: each constraint's slot on each of its dynamic bodies", count_phase),
        ("chunk_sums", "phase 3: each work group's chunk of bodies: its contacts", chunk_sum_phase),
        ("scan", "phase 4: each body's list offset", scan_phase),
        ("link", "phase 5: the lists, and the row masses between split bodies", link_phase),
        ("order", "phase 6: each body's list in side order", order_phase),
    ]
%>\
% for name, what, phase in phases:

/* ${what} */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jacobi_${name}(${signature("jacobi_" + name)})
{
${indices(name in ("chunk_sums", "scan"), name in ("count", "link"))}\
    {
${phase()}\
    }
}
% endfor

/* the warm start's constraint phase: every constraint's old impulses */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jacobi_warm_start(${signature("jacobi_warm_start")})
{
${indices(False)}\
    {
${constraint_phase("warm_start_contact(c, &p)", "bodies")}\
    }
}

/* a velocity sweep's constraint phase (`reverse`: points backwards) */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jacobi_sweep(${signature("jacobi_sweep")})
{
${indices(False)}\
    {
${constraint_phase(sweep, "bodies", velocity_results)}\
    }
}

/* a velocity sweep's body phase */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jacobi_average(${signature("jacobi_average")})
{
${indices(False, False)}\
    {
${body_phase("bodies")}\
    }
}

/* a position sweep's constraint phase (push velocities) */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jacobi_push(${signature("jacobi_push")})
{
${indices(False)}\
    {
${constraint_phase("solve_push(c, &p, relaxation, true)", "split", ("push_impulse",))}\
    }
}

/* a position sweep's body phase */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void jacobi_average_push(${signature("jacobi_average_push")})
{
${indices(False, False)}\
    {
${body_phase("split")}\
    }
}
% endif
