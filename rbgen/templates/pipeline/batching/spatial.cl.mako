/* Two-level batching of the constraint edges (after Harada's two-level solver).
 *
 * The edges (layouts: ConstraintEdge) stand for the constraints of every kind:
 * a group or batch holds edges, and `order` lists their items.
 *
 * Level 1 splits space into cells of at least the largest dynamic body's
 * size; an edge belongs to the cell of its point (a contact's first point).
% if mode == "cells":
 * Cells get one of 8 colours by the parity of their coordinates, and each
 * colour's cells are hashed into groups_per_colour groups: two cells of one
 * colour are a whole cell apart, so their edges share no body.
% elif mode == "columns":
 * The cells are columns along gravity (square in the plane of slab_axis and
 * column_axis, infinite along the third axis), coloured by the parity of their
 * two coordinates (4 colours) and hashed into groups_per_colour groups. A
 * column holds whole stacks, as a slab does, and a scene as wide as a few
 * slabs has many columns: work for every core of a CPU.
% else:
 * The cells are slabs across slab_axis (infinite along the other two axes),
 * coloured by the parity of their index (2 colours); consecutive slabs of a
 * colour go to groups far apart (spread_slot). A slab holds whole stacks,
 * whose edges one work-item then solves in index order (for piles built
 * bottom-up, from the ground up).
% endif
 * Each dynamic body is claimed, per colour, by the first group that touches
 * it; an edge that loses a claim (a body wider than a cell) goes to the
 * leftover group, solved alone after the colours, so correctness never
 * depends on sizes. The solver launches once per colour and once for the
 * leftovers.
 *
% if solve_form == "lanes":
 * Level 2 colours each group's edges into batches inside one work group
 * (batch_groups): a batch is a maximal set of edges that share no dynamic
 * body, grown by rounds of "local minimum priority wins" (Luby) with barriers
 * between the rounds. Batch ${max_batches - 1} (the last) takes whatever is
 * left and is solved by a single lane, so nothing is ever dropped. Bodies are
 * marked in per-colour copies of the mark arrays, since one body may be in a
 * group of every colour.
% else:
 * Serial solve form: no level 2. The solver solves a group's edges one after
 * another in one work-item, so a group is one batch: list_groups (a single
 * work-item, a few passes over a compact array) lists each group's edges in
 * index order, which keeps the solve deterministic.
% endif
 *
 * Counts stay on the device: kernels read the edge count from edge_count[0]
 * and exit past it.
 */
${cl_constants()}

${cl_structs("ConstraintEdge", "Body")}

<%include file="/common/inline_math.cl.mako"/>
<%include file="/common/hash.cl.mako"/>
<%include file="/common/grid_cells.cl.mako"/>

#define MAX_BATCHES ${max_batches}
% if mode == "cells":
/* cell colours (parity of the cell coordinates) */
#define CELL_COLOURS 8

/* A cell's colour: the parity of its coordinates. */
inline uint cell_colour(int3 cell)
{
    return (uint)(cell.x & 1) | ((uint)(cell.y & 1) << 1) | ((uint)(cell.z & 1) << 2);
}
% elif mode == "columns":
/* column colours (parity of the two column coordinates) */
#define CELL_COLOURS 4
% else:
/* slab colours (parity of the slab index) */
#define CELL_COLOURS 2

/* Slab k's group among `groups`: the van der Corput sequence (k's bits
 * reversed, read as a fraction) scaled to the groups, so that consecutive
 * slabs land far apart (16 groups: 0, 8, 4, 12, 2, ...) and any contiguous
 * range of groups holds its share of them: PoCL's CPU device hands each
 * thread a contiguous range of a launch's work groups, and a pile's few
 * consecutive slabs would all fall to one thread. Two slabs of one colour
 * sharing a group are solved one after the other, which is as correct. */
inline uint spread_slot(uint k, uint groups)
{
    k = (k << 16) | (k >> 16);
    k = ((k & 0x00ff00ffu) << 8) | ((k >> 8) & 0x00ff00ffu);
    k = ((k & 0x0f0f0f0fu) << 4) | ((k >> 4) & 0x0f0f0f0fu);
    k = ((k & 0x33333333u) << 2) | ((k >> 2) & 0x33333333u);
    k = ((k & 0x55555555u) << 1) | ((k >> 1) & 0x55555555u);
    return (uint)(((ulong)k * groups) >> 32);
}
% endif
% if solve_form == "lanes":
/* a set of level-2 batching marks per cell colour and one for the leftover group */
#define BATCH_COLOURS (CELL_COLOURS + 1)
% endif

inline bool is_dynamic(__global const Body* bodies, uint body)
{
    return bodies[body].inv_mass > 0.0f;
}

% if solve_form == "lanes":
/* One work-item per body mark (and per group counter): the batching marks of
 * every colour cleared, the cell claims released. A work group is responsible
 * for ${work_group_size} consecutive marks. */
% else:
/* One work-item per body mark (and per group counter): the cell claims
 * released. A work group is responsible for ${work_group_size} consecutive marks. */
% endif
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

/* Claim a dynamic body for a group within one colour; false when another
 * group of that colour holds it. */
inline bool claim_body(volatile __global uint* body_owner, uint colour, uint body_count,
                       uint body, uint group)
{
    uint held = atomic_cmpxchg(&body_owner[colour * body_count + body], RB_SOLVER_NONE, group);
    return held == RB_SOLVER_NONE || held == group;
}

/* One work-item per edge: the ${{"cells": "cell", "columns": "column"}.get(mode, "slab")} of its point gives a colour and a group;
 * if another group of that colour already holds one of its dynamic bodies it
 * goes to the leftover group. ${"Its slot in its group's list is counted too. " if solve_form == "lanes" else ""}A work group is responsible for
 * ${work_group_size} consecutive edges. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void assign_cells(__global const ConstraintEdge* edges,
                  __global const uint* edge_count,
                  __global const Body* bodies,
                  volatile __global uint* body_owner,
% if solve_form == "lanes":
                  volatile __global uint* group_counts,
                  __global uint* edge_slot,
% endif
                  __global uint* edge_group,
                  const uint body_count,
                  const uint groups_per_colour,
% if mode in ("slabs", "columns"):
                  const float4 slab_axis,
% endif
% if mode == "columns":
                  const float4 column_axis,
% endif
                  const float inv_cell_size)
{
    uint i = get_global_id(0);
    if (i >= edge_count[0])
        return;
    uint a = edges[i].body_a, b = edges[i].body_b;
    float3 point = edges[i].point.xyz;
% if mode == "cells":
    int3 cell = cell_of_scaled(point * inv_cell_size);
    uint colour = cell_colour(cell);
    uint hash = mix32((uint)cell.x * 73856093u ^ (uint)cell.y * 19349663u ^ (uint)cell.z * 83492791u);
    uint group = colour * groups_per_colour + hash % groups_per_colour;
% elif mode == "columns":
    int u = cell_index(dot3(point, slab_axis.xyz) * inv_cell_size);
    int v = cell_index(dot3(point, column_axis.xyz) * inv_cell_size);
    uint colour = (uint)(u & 1) | ((uint)(v & 1) << 1);
    uint hash = mix32((uint)(u >> 1) * 73856093u ^ (uint)(v >> 1) * 83492791u);
    uint group = colour * groups_per_colour + hash % groups_per_colour;
% else:
    int slab = cell_index(dot3(point, slab_axis.xyz) * inv_cell_size);
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
    edge_group[i] = group;
% if solve_form == "lanes":
    edge_slot[i] = atomic_inc(&group_counts[group]);
% endif
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

/* One work-item per edge: write its index into its group's list and clear
 * its level-2 state. A work group is responsible for ${work_group_size}
 * consecutive edges. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void scatter_groups(__global const uint* edge_count,
                    __global const uint* edge_group,
                    __global const uint* edge_slot,
                    __global const uint* group_offsets,
                    __global uint* group_list,
                    __global uint* edge_batch,
                    __global uint* edge_blocked)
{
    uint i = get_global_id(0);
    if (i >= edge_count[0])
        return;
    group_list[group_offsets[edge_group[i]] + edge_slot[i]] = i;
    edge_batch[i] = RB_SOLVER_NONE;
    edge_blocked[i] = RB_SOLVER_NONE;
}

/* Dynamic bodies of an edge; a static one is reported as RB_SOLVER_NONE. */
inline uint2 dynamic_bodies(__global const ConstraintEdge* edges, __global const Body* bodies,
                            uint e)
{
    uint a = edges[e].body_a, b = edges[e].body_b;
    return (uint2)(is_dynamic(bodies, a) ? a : RB_SOLVER_NONE,
                   is_dynamic(bodies, b) ? b : RB_SOLVER_NONE);
}

/* One work group per level-1 group: colour the group's edges into batches of
 * edges with no dynamic body in common, then write their items sorted by
 * batch to `order` and the batch offsets to `group_batches`. Lanes exchange
 * data only through memory, separated by barriers. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void batch_groups(__global const ConstraintEdge* edges,
                  __global const Body* bodies,
                  __global const uint* group_offsets,
                  __global const uint* group_list,
                  volatile __global uint* all_body_stamps,
                  __global uint* all_body_taken,
                  __global uint* edge_batch,
                  __global uint* edge_blocked,
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
                uint e = group_list[i];
                if (edge_batch[e] == RB_SOLVER_NONE)
                    edge_batch[e] = batch;
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
                uint e = group_list[i];
                if (edge_batch[e] != RB_SOLVER_NONE || edge_blocked[e] == batch)
                    continue;
                uint2 body = dynamic_bodies(edges, bodies, e);
                uint priority = mix32(e);
                if (body.x != RB_SOLVER_NONE)
                    atomic_min(&body_stamp[body.x], priority);
                if (body.y != RB_SOLVER_NONE)
                    atomic_min(&body_stamp[body.y], priority);
            }
            barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
            /* 2: a candidate that won all its bodies joins the batch */
            for (uint i = begin + lane; i < end; i += ${work_group_size}) {
                uint e = group_list[i];
                if (edge_batch[e] != RB_SOLVER_NONE || edge_blocked[e] == batch)
                    continue;
                uint2 body = dynamic_bodies(edges, bodies, e);
                uint priority = mix32(e);
                bool won = (body.x == RB_SOLVER_NONE || body_stamp[body.x] == priority)
                        && (body.y == RB_SOLVER_NONE || body_stamp[body.y] == priority);
                if (won) {
                    edge_batch[e] = batch;
                    if (body.x != RB_SOLVER_NONE)
                        body_taken[body.x] = batch;
                    if (body.y != RB_SOLVER_NONE)
                        body_taken[body.y] = batch;
                }
            }
            barrier(CLK_GLOBAL_MEM_FENCE);
            /* 3: clear the bids; a loser next to a taken body waits for the next batch */
            for (uint i = begin + lane; i < end; i += ${work_group_size}) {
                uint e = group_list[i];
                uint assigned = edge_batch[e];
                if (assigned != RB_SOLVER_NONE && assigned != batch)
                    continue;
                uint2 body = dynamic_bodies(edges, bodies, e);
                if (body.x != RB_SOLVER_NONE)
                    body_stamp[body.x] = RB_SOLVER_NONE;
                if (body.y != RB_SOLVER_NONE)
                    body_stamp[body.y] = RB_SOLVER_NONE;
                if (assigned == batch)
                    continue;
                atomic_inc(&unassigned_left);
                if (edge_blocked[e] == batch)
                    continue;
                if ((body.x != RB_SOLVER_NONE && body_taken[body.x] == batch)
                    || (body.y != RB_SOLVER_NONE && body_taken[body.y] == batch))
                    edge_blocked[e] = batch;
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
        atomic_inc(&batch_offsets[edge_batch[group_list[i]]]);
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
        uint e = group_list[i];
        order[begin + atomic_inc(&batch_offsets[edge_batch[e]])] = edges[e].item;
    }
}
% else:

/* A single work-item lists every group's edges in index order (count,
 * exclusive scan, scatter: three passes over the compact group array, cheap
 * on a CPU) and describes each group as one batch of the solver. */
__kernel void list_groups(__global const ConstraintEdge* edges,
                          __global const uint* edge_count,
                          __global const uint* edge_group,
                          __global uint* group_counts,
                          __global uint* group_offsets,
                          __global uint* order,
                          __global uint* group_batches,
                          __global uint* group_batch_count,
                          const uint edge_capacity,
                          const uint group_count)
{
    const uint n = edge_count[0] < edge_capacity ? edge_count[0] : edge_capacity;
    for (uint i = 0; i < n; ++i)
        group_counts[edge_group[i]] += 1;
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
        order[group_counts[edge_group[i]]++] = edges[i].item;
}
% endif
