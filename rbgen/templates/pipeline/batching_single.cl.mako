<% colours = min(64, max_batches - 1) %>\
/* Batching of a small world in one work group ("single" mode).
 *
 * All constraints form one group, coloured by one work group of
 * ${work_group_size} lanes whose local memory holds a mark and a colour mask
 * per body (body indices below ${max_bodies}): the colouring touches global
 * memory only to read the constraints' bodies and to keep each constraint's
 * colour. It is the level-2 colouring of the other modes without level 1,
 * for worlds whose bodies also fit a resident solve (rbgen.pipeline.solver),
 * so that batching and solving are one launch each.
 *
 * Colouring (Jones-Plassmann): in each round every uncoloured constraint
 * bids its priority (a bijective hash of its index, so no two are equal) on
 * its dynamic bodies with a local atomic_min; a constraint that holds the
 * lowest bid on each of its bodies takes the lowest colour free on both (a
 * bit per colour and body). Winners of one round share no body, so their
 * choices cannot clash; the lowest bid of the round always wins, so every
 * round colours at least one constraint. Static bodies are ignored: they
 * never move, so constraints on one static body may share a batch. A
 * constraint finding all ${colours} colours taken on its bodies goes to the
 * last batch slot (${max_batches - 1}), solved by a single lane in order, so
 * nothing is dropped whatever the contact graph.
 *
 * Output: `order` (constraint indices by colour), the batch offsets of group
 * 0 in `group_batches` and its batch count; every count stays on the device.
 */
${cl_constants()}

${cl_structs("ContactConstraint", "Body")}

#define MAX_BATCHES ${max_batches}
#define SERIAL_BATCH (MAX_BATCHES - 1)
/* colours tracked in a body's mask (two 32-bit words) */
#define COLOURS ${colours}
#define MAX_BODIES ${max_bodies}

<%include file="/common/hash.cl.mako"/>
<%include file="/common/colour_mask.cl.mako"/>

/* One work group colours the first constraint_count[0] constraints (see the
 * file comment). The lanes exchange data through local memory, with a barrier
 * between the phases of a round. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void colour_single(__global const ContactConstraint* constraints,
                   __global const uint* constraint_count,
                   __global const Body* bodies,
                   __global uint* constraint_colour,
                   __global uint* order,
                   __global uint* group_batches,
                   __global uint* group_batch_count,
                   const uint body_count)
{
    __local uint bid[MAX_BODIES], used_low[MAX_BODIES], used_high[MAX_BODIES];
    __local uint batch_size[MAX_BATCHES + 1];
    __local uint uncoloured, highest;  /* a flag, and the highest colour taken */
    const uint lane = get_local_id(0), n = constraint_count[0];

    for (uint body = lane; body < body_count; body += ${work_group_size})
        bid[body] = RB_SOLVER_NONE, used_low[body] = used_high[body] = 0;
    for (uint k = lane; k <= MAX_BATCHES; k += ${work_group_size})
        batch_size[k] = 0;
    for (uint c = lane; c < n; c += ${work_group_size})
        constraint_colour[c] = RB_SOLVER_NONE;
    if (lane == 0)
        highest = 0;
    barrier(CLK_LOCAL_MEM_FENCE | CLK_GLOBAL_MEM_FENCE);

    /* a lane only ever reads the colours of the constraints it writes them for */
    bool more = n > 0;
    while (more) {
        /* 1: every uncoloured constraint bids on its dynamic bodies (the flag is
         * cleared here: every lane read it before the last barrier) */
        if (lane == 0)
            uncoloured = 0;
        for (uint c = lane; c < n; c += ${work_group_size}) {
            if (constraint_colour[c] != RB_SOLVER_NONE)
                continue;
            uint a = constraints[c].body_a, b = constraints[c].body_b, priority = mix32(c);
            if (bodies[a].inv_mass > 0.0f)
                atomic_min(&bid[a], priority);
            if (bodies[b].inv_mass > 0.0f)
                atomic_min(&bid[b], priority);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        /* 2: a constraint holding the lowest bid on all its dynamic bodies takes
         * the lowest colour free on them (no other winner touches them) */
        for (uint c = lane; c < n; c += ${work_group_size}) {
            if (constraint_colour[c] != RB_SOLVER_NONE)
                continue;
            uint a = constraints[c].body_a, b = constraints[c].body_b, priority = mix32(c);
            bool dynamic_a = bodies[a].inv_mass > 0.0f, dynamic_b = bodies[b].inv_mass > 0.0f;
            if ((dynamic_a && bid[a] != priority) || (dynamic_b && bid[b] != priority)) {
                uncoloured = 1;  /* any lane's store of the same value will do */
                continue;
            }
            uint low = (dynamic_a ? used_low[a] : 0u) | (dynamic_b ? used_low[b] : 0u);
            uint high = (dynamic_a ? used_high[a] : 0u) | (dynamic_b ? used_high[b] : 0u);
            uint colour = lowest_free(low, high);
            if (colour < COLOURS) {
                uint low_bit = colour < 32 ? 1u << colour : 0u;
                uint high_bit = colour >= 32 ? 1u << (colour - 32) : 0u;
                if (dynamic_a)
                    used_low[a] |= low_bit, used_high[a] |= high_bit;
                if (dynamic_b)
                    used_low[b] |= low_bit, used_high[b] |= high_bit;
                atomic_max(&highest, colour);
            } else {
                colour = SERIAL_BATCH;
                atomic_max(&highest, (uint)SERIAL_BATCH);
            }
            constraint_colour[c] = colour;
            atomic_inc(&batch_size[colour]);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        /* 3: withdraw the bids */
        for (uint body = lane; body < body_count; body += ${work_group_size})
            bid[body] = RB_SOLVER_NONE;
        more = uncoloured != 0;
        barrier(CLK_LOCAL_MEM_FENCE);
    }

    /* batch offsets (one lane: at most MAX_BATCHES entries), then the list */
    const uint batch_count = n == 0 ? 0 : highest + 1;
    if (lane == 0) {
        uint total = 0;
        for (uint k = 0; k <= batch_count; ++k) {
            uint size = batch_size[k];
            batch_size[k] = total;
            group_batches[k] = total;
            total += size;
        }
        group_batch_count[0] = batch_count;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint c = lane; c < n; c += ${work_group_size})
        order[atomic_inc(&batch_size[constraint_colour[c]])] = c;
}
