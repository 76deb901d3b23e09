/* Two-level constraint batching (after Harada's two-level solver).
 *
 * Level 1 splits space into cells of at least the largest dynamic body's
 * size; a constraint belongs to the cell of its first contact point. Cells
 * get one of 8 colours by the parity of their coordinates, and each colour's
 * cells are hashed into groups_per_colour groups: two cells of one colour are
 * a whole cell apart, so their constraints share no body. Each dynamic body
 * is claimed, per colour, by the first group that touches it; a constraint
 * that loses a claim (a body wider than a cell) goes to the leftover group,
 * solved alone after the 8 colours, so correctness never depends on sizes.
 * The solver launches once per colour and once for the leftovers.
% if mode == "slabs":
 *
 * Slabs: the cells are slabs across slab_axis (infinite along the other
 * two axes), coloured by the parity of their index (2 colours); consecutive
 * slabs of a colour go to groups far apart (spread_slot). A slab holds whole stacks,
 * whose constraints one work-item then solves in index order (for piles
 * built bottom-up, from the ground up), which cells split over colours.
% endif
 *
% if solve_form == "lanes":
 * Level 2 colours each group's constraints into batches inside one work group
 * (batch_groups): a batch is a maximal set of constraints that share no dynamic
 * body, grown by rounds of "local minimum priority wins" (Luby) with barriers
 * between the rounds. Batch ${max_batches - 1} (the last) takes whatever is
 * left and is flagged to be solved by a single lane, so nothing is ever
 * dropped. Bodies are marked in per-colour copies of the stamp arrays, since
 * one body may be in a group of every colour.
% else:
 * Serial solve form: no level 2. The solver solves a group's constraints one after
 * another in one work-item, so a group is one batch: list_groups (a single
 * work-item, a few passes over a compact array) writes each group's
 * constraints in index order, which keeps the solve deterministic.
% endif
 *
 * Counts stay on the device: kernels read the constraint count from
 * constraint_count[0] and exit past it.
 */
${cl_constants()}

${cl_structs("ContactConstraint", "Body")}

<%include file="/common/inline_math.cl.mako"/>

#define MAX_BATCHES ${max_batches}
% if mode == "cells":
/* cell colours (parity of the cell coordinates) */
#define CELL_COLOURS 8
% elif mode == "slabs":
/* Slab k's group among `groups`: the van der Corput sequence (k's bits
 * reversed, read as a fraction) scaled to the groups, so that consecutive
 * slabs land far apart (16 groups: 0, 8, 4, 12, 2, ...) and any contiguous
 * range of groups holds its share of them. PoCL's CPU device hands each
 * thread a contiguous range of a launch's work groups: with consecutive
 * slabs in consecutive groups, a pile's few slabs all fell to one thread
 * (BoxBox 8,000 on 2 cores: 29.8 ms of solve a step with 2 threads, 29.0
 * with 1; spread, 14.7). Two slabs of one colour sharing a group are solved
 * one after the other, which is as correct. */
inline uint spread_slot(uint k, uint groups)
{
    k = (k << 16) | (k >> 16);
    k = ((k & 0x00ff00ffu) << 8) | ((k >> 8) & 0x00ff00ffu);
    k = ((k & 0x0f0f0f0fu) << 4) | ((k >> 4) & 0x0f0f0f0fu);
    k = ((k & 0x33333333u) << 2) | ((k >> 2) & 0x33333333u);
    k = ((k & 0x55555555u) << 1) | ((k >> 1) & 0x55555555u);
    return (uint)(((ulong)k * groups) >> 32);
}

/* slab colours (parity of the slab index) */
#define CELL_COLOURS 2
% endif
% if solve_form == "lanes":
/* a set of level-2 batching marks per cell colour and one for the leftover group */
#define BATCH_COLOURS (CELL_COLOURS + 1)
% endif

<%include file="/common/hash.cl.mako"/>

inline bool is_dynamic(__global const Body* bodies, uint body)
{
    return bodies[body].inv_mass > 0.0f;
}

/* One work-item per body mark (and per group counter): ${"batching marks of every colour cleared, " if solve_form == "lanes" else ""}cell claims released. A work group is
 * responsible for ${work_group_size} consecutive marks. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void reset_batching(
% if solve_form == "lanes":
                    __global uint* body_stamp,
                    __global uint* body_taken,
% endif
                    __global uint* body_owner,
                    __global uint* group_counts,
                    const uint body_count,
                    const uint group_count)
{
    uint i = get_global_id(0);
    if (i < group_count)
        group_counts[i] = 0;
% if solve_form == "lanes":
    if (i < BATCH_COLOURS * body_count) {
        body_stamp[i] = RB_SOLVER_NONE;
        body_taken[i] = RB_SOLVER_NONE;
    }
% endif
    if (i < CELL_COLOURS * body_count)
        body_owner[i] = RB_SOLVER_NONE;
}

<%def name="group_outputs(indent)">\
% if solve_form == "lanes":
${indent}volatile __global uint* group_counts,
${indent}__global uint* constraint_slot,
% else:
${indent}__global uint* constraint_group,
% endif
</%def>
<%def name="note_group()">\
    constraints[i].group = group;
% if solve_form == "lanes":
    constraint_slot[i] = atomic_inc(&group_counts[group]);
% else:
    constraint_group[i] = group;
% endif
</%def>
/* floor(x) as an int (|x| < 2^31), without PoCL's out-of-line floor call:
 * truncate, then step down where truncation went up (negative x). */
inline int floor_to_int(float x)
{
    int t = (int)x;
    return (float)t > x ? t - 1 : t;
}
% if mode == "cells":

/* Cell of a point, and its colour (parity of the coordinates). */
inline int4 cell_of(float3 p, float inv_cell_size)
{
    float3 c = p * inv_cell_size;
    return (int4)(floor_to_int(c.x), floor_to_int(c.y), floor_to_int(c.z), 0);
}

inline uint cell_colour(int4 cell)
{
    return (uint)(cell.x & 1) | ((uint)(cell.y & 1) << 1) | ((uint)(cell.z & 1) << 2);
}
% endif

/* Claim a dynamic body for a group within one colour; false when another
 * group of that colour holds it. */
inline bool claim_body(volatile __global uint* body_owner, uint colour, uint body_count,
                       uint body, uint group)
{
    uint held = atomic_cmpxchg(&body_owner[colour * body_count + body], RB_SOLVER_NONE, group);
    return held == RB_SOLVER_NONE || held == group;
}

/* One work-item per constraint: its ${"cell" if mode == "cells" else "slab"} (from its first contact point)
 * gives a colour and a group; if another group of that colour already holds
 * one of its dynamic bodies it goes to the leftover group. A work group is
 * responsible for ${work_group_size} consecutive constraints. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void assign_cells(__global ContactConstraint* constraints,
                  __global const uint* constraint_count,
                  __global const Body* bodies,
                  volatile __global uint* body_owner,
${group_outputs(" " * 18)}
                  const uint body_count,
                  const uint groups_per_colour,
% if mode == "slabs":
                  const float4 slab_axis,
% endif
                  const float inv_cell_size)
{
    uint i = get_global_id(0);
    if (i >= constraint_count[0])
        return;
    uint a = constraints[i].body_a, b = constraints[i].body_b;
    float3 point = bodies[b].position.xyz + constraints[i].r_b[0].xyz;
% if mode == "cells":
    int4 cell = cell_of(point, inv_cell_size);
    uint colour = cell_colour(cell);
    uint hash = mix32((uint)cell.x * 73856093u ^ (uint)cell.y * 19349663u ^ (uint)cell.z * 83492791u);
    uint group = colour * groups_per_colour + hash % groups_per_colour;
% else:
    int slab = floor_to_int(dot3(point, slab_axis.xyz) * inv_cell_size);
    uint colour = (uint)slab & 1u;
    uint group = colour * groups_per_colour + spread_slot((uint)(slab >> 1), groups_per_colour);
% endif
    bool owned = true;
    if (is_dynamic(bodies, a))
        owned = claim_body(body_owner, colour, body_count, a, group);
    if (is_dynamic(bodies, b))
        owned = claim_body(body_owner, colour, body_count, b, group) && owned;
    if (!owned)
        group = CELL_COLOURS * groups_per_colour;  /* the leftover group */
${note_group()}
}

% if solve_form == "lanes":
/* A single work-item turns the group counts into offsets (exclusive scan);
 * group_count is a few hundred at most. */
__kernel void scan_groups(__global const uint* group_counts,
                          __global uint* group_offsets,
                          const uint group_count)
{
    uint total = 0;
    for (uint g = 0; g < group_count; ++g) {
        group_offsets[g] = total;
        total += group_counts[g];
    }
    group_offsets[group_count] = total;
}

/* One work-item per constraint: write its index into its group's list and
 * clear its level-2 state. A work group is responsible for
 * ${work_group_size} consecutive constraints. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void scatter_groups(__global const ContactConstraint* constraints,
                    __global const uint* constraint_count,
                    __global const uint* constraint_slot,
                    __global const uint* group_offsets,
                    __global uint* group_list,
                    __global uint* constraint_batch,
                    __global uint* constraint_blocked)
{
    uint i = get_global_id(0);
    if (i >= constraint_count[0])
        return;
    group_list[group_offsets[constraints[i].group] + constraint_slot[i]] = i;
    constraint_batch[i] = RB_SOLVER_NONE;
    constraint_blocked[i] = RB_SOLVER_NONE;
}

/* Dynamic bodies of a constraint; a static one is reported as RB_SOLVER_NONE. */
inline uint2 dynamic_bodies(__global const ContactConstraint* constraints,
                            __global const Body* bodies, uint c)
{
    uint a = constraints[c].body_a, b = constraints[c].body_b;
    return (uint2)(is_dynamic(bodies, a) ? a : RB_SOLVER_NONE,
                   is_dynamic(bodies, b) ? b : RB_SOLVER_NONE);
}

/* One work group per level-1 group: colour the group's constraints into
 * batches of constraints with no dynamic body in common, then write the list
 * sorted by batch to `order` and the batch offsets to `group_batches`.
 * Lanes exchange data only through memory, separated by barriers. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void batch_groups(__global const ContactConstraint* constraints,
                  __global const Body* bodies,
                  __global const uint* group_offsets,
                  __global const uint* group_list,
                  volatile __global uint* all_body_stamps,
                  __global uint* all_body_taken,
                  __global uint* constraint_batch,
                  __global uint* constraint_blocked,
                  __global uint* order,
                  __global uint* group_batches,
                  __global uint* group_batch_count,
                  const uint body_count,
                  const uint groups_per_colour)
{
    __local uint candidates_left, unassigned_left;
    __local uint batch_offsets[MAX_BATCHES + 1];
    const uint lane = get_local_id(0), group = get_group_id(0);
    const uint begin = group_offsets[group], end = group_offsets[group + 1];
    /* this group's colour owns one copy of the body marks */
    const uint colour = group / groups_per_colour;
    volatile __global uint* body_stamp = all_body_stamps + colour * body_count;
    __global uint* body_taken = all_body_taken + colour * body_count;

    uint batch_count = 0;
    bool done = begin == end;
    while (!done) {
        uint batch = batch_count++;
        if (batch == MAX_BATCHES - 1) {
            /* Last batch: everything left, solved by one lane in order. */
            for (uint i = begin + lane; i < end; i += ${work_group_size}) {
                uint c = group_list[i];
                if (constraint_batch[c] == RB_SOLVER_NONE)
                    constraint_batch[c] = batch;
            }
            barrier(CLK_GLOBAL_MEM_FENCE);
            break;
        }
        uint candidates, unassigned;
        do {
            if (lane == 0)
                candidates_left = 0, unassigned_left = 0;
            /* 1: every candidate bids its priority on its dynamic bodies */
            for (uint i = begin + lane; i < end; i += ${work_group_size}) {
                uint c = group_list[i];
                if (constraint_batch[c] != RB_SOLVER_NONE || constraint_blocked[c] == batch)
                    continue;
                uint2 body = dynamic_bodies(constraints, bodies, c);
                uint priority = mix32(c);
                if (body.x != RB_SOLVER_NONE)
                    atomic_min(&body_stamp[body.x], priority);
                if (body.y != RB_SOLVER_NONE)
                    atomic_min(&body_stamp[body.y], priority);
            }
            barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
            /* 2: a candidate that won all its bodies joins the batch */
            for (uint i = begin + lane; i < end; i += ${work_group_size}) {
                uint c = group_list[i];
                if (constraint_batch[c] != RB_SOLVER_NONE || constraint_blocked[c] == batch)
                    continue;
                uint2 body = dynamic_bodies(constraints, bodies, c);
                uint priority = mix32(c);
                bool won = (body.x == RB_SOLVER_NONE || body_stamp[body.x] == priority)
                        && (body.y == RB_SOLVER_NONE || body_stamp[body.y] == priority);
                if (won) {
                    constraint_batch[c] = batch;
                    if (body.x != RB_SOLVER_NONE)
                        body_taken[body.x] = batch;
                    if (body.y != RB_SOLVER_NONE)
                        body_taken[body.y] = batch;
                }
            }
            barrier(CLK_GLOBAL_MEM_FENCE);
            /* 3: clear the bids; a loser next to a taken body waits for the next batch */
            for (uint i = begin + lane; i < end; i += ${work_group_size}) {
                uint c = group_list[i];
                uint assigned = constraint_batch[c];
                if (assigned != RB_SOLVER_NONE && assigned != batch)
                    continue;
                uint2 body = dynamic_bodies(constraints, bodies, c);
                if (body.x != RB_SOLVER_NONE)
                    body_stamp[body.x] = RB_SOLVER_NONE;
                if (body.y != RB_SOLVER_NONE)
                    body_stamp[body.y] = RB_SOLVER_NONE;
                if (assigned == batch)
                    continue;
                atomic_inc(&unassigned_left);
                if (constraint_blocked[c] == batch)
                    continue;
                if ((body.x != RB_SOLVER_NONE && body_taken[body.x] == batch)
                    || (body.y != RB_SOLVER_NONE && body_taken[body.y] == batch))
                    constraint_blocked[c] = batch;
                else
                    atomic_inc(&candidates_left);
            }
            barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
            candidates = candidates_left;
            unassigned = unassigned_left;
            barrier(CLK_LOCAL_MEM_FENCE);
        } while (candidates != 0);
        done = unassigned == 0;
    }

    /* Sort the group's list by batch: count, scan (one lane), scatter. */
    for (uint k = lane; k <= MAX_BATCHES; k += ${work_group_size})
        batch_offsets[k] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint i = begin + lane; i < end; i += ${work_group_size})
        atomic_inc(&batch_offsets[constraint_batch[group_list[i]]]);
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lane == 0) {
        __global uint* offsets = group_batches + group * (MAX_BATCHES + 1);
        uint total = 0;
        for (uint k = 0; k <= batch_count; ++k) {
            uint size = batch_offsets[k];
            batch_offsets[k] = total;
            offsets[k] = begin + total;
            total += size;
        }
        group_batch_count[group] = batch_count;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint i = begin + lane; i < end; i += ${work_group_size}) {
        uint c = group_list[i];
        order[begin + atomic_inc(&batch_offsets[constraint_batch[c]])] = c;
    }
}
% else:
/* A single work-item lists every group's constraints in index order (count,
 * exclusive scan, scatter: three passes over the compact group array, cheap
 * on a CPU) and describes each group as one batch of the solver. */
__kernel void list_groups(__global const uint* constraint_count,
                          __global const uint* constraint_group,
                          __global uint* group_counts,
                          __global uint* group_offsets,
                          __global uint* order,
                          __global uint* group_batches,
                          __global uint* group_batch_count,
                          const uint constraint_capacity,
                          const uint group_count)
{
    const uint n = constraint_count[0] < constraint_capacity ? constraint_count[0]
                                                             : constraint_capacity;
    for (uint i = 0; i < n; ++i)
        group_counts[constraint_group[i]] += 1;
    uint total = 0;
    for (uint g = 0; g < group_count; ++g) {
        uint size = group_counts[g];
        __global uint* offsets = group_batches + g * (MAX_BATCHES + 1);
        group_offsets[g] = offsets[0] = total;
        group_counts[g] = total;  /* now the group's write cursor */
        total += size;
        offsets[1] = total;
        group_batch_count[g] = size > 0 ? 1 : 0;
    }
    group_offsets[group_count] = total;
    for (uint i = 0; i < n; ++i)
        order[group_counts[constraint_group[i]]++] = i;
}
% endif
