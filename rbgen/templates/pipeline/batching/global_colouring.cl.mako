<% colours = min(64, max_batches - 1) %>\
/* Batching of a large world over the whole device ("global" mode).
 *
 * All constraint edges (layouts: ConstraintEdge; contacts and any other
 * kind) form one group whose batches (colours) are solved one after another
 * by every work group of the device (the PGS solver's persistent launch). One
 * launch of as many work groups as the device runs at once colours them, the
 * work groups stepping through the phases together with a device-wide
 * barrier (common/device_barrier.cl.mako).
 *
 * 1. Inherited colours. An edge whose constraint had an edge in the previous
 *    step starts from that edge's colour (ConstraintEdge.colour, copied by
 *    the constraint setup; RB_SOLVER_NONE for a new constraint). Each such
 *    edge sets its colour's bit on its dynamic bodies; a bit that was set
 *    already marks the colour as repeated on that body, and every edge whose
 *    colour is repeated on one of its bodies drops it. The others keep
 *    theirs: no two of them share a colour on a body, whatever the hints
 *    were. A scene at rest keeps its colouring, so the rounds below have only
 *    new edges to colour.
 * 2. Jones-Plassmann rounds over the rest: in each round every uncoloured
 *    edge bids its priority on its dynamic bodies with atomic_min; an edge
 *    that holds the lowest bid on each of its bodies takes the lowest colour
 *    free on both. Winners of one round share no body, so their choices
 *    cannot clash and need no atomics; the lowest bid of the round always
 *    wins, so every round colours at least one. Two bid arrays and two "some
 *    edge lost" flags alternate between rounds (a round clears the next
 *    round's): two device-wide barriers a round.
 *    The priority is the edge's index for the first `ordered_rounds` rounds:
 *    the rounds then give exactly the sequential first-fit colouring in index
 *    order (an edge is coloured after all its lower-indexed neighbours), and
 *    the narrowphase lists contacts in spatial order, which first-fit colours
 *    with fewer colours than a hashed priority.
 *    But a chain of ever higher indices is coloured one link a round, so
 *    after `ordered_rounds` rounds the rest bid a bijective hash of their
 *    index (few rounds) and their colours are provisional: not handed to the
 *    next step, whose ordered rounds go on from there. A static contact graph
 *    reaches the index-order colouring in a few steps and keeps it.
 * The colours depend on the edges and the previous step's colours alone,
 * not on timing. Static bodies are ignored. An edge finding all ${colours}
 * colours taken on its bodies goes to the last batch slot
 * (${max_batches - 1}), solved by a single lane in order, so nothing is
 * dropped whatever the constraint graph.
 *
 * The arrays that lanes of other work groups write during the launch (bids,
 * colour masks, the state words, the list) are read through volatile
 * pointers (see common/device_barrier.cl.mako); `pairs` and `edge_colour`
 * are read only by the lane that wrote them.
 *
 * Output: `order` (the edges' items by colour; inside a colour in any order,
 * which does not change a solve whose constraints share no body; the serial
 * slot sorted), the batch offsets of group 0 in `group_batches`, its batch
 * count, and every edge's colour in its `colour` field (the next step's
 * inherited colour; RB_SOLVER_NONE for a provisional colour). Every count
 * stays on the device.
 */
${cl_constants()}

${cl_structs("ConstraintEdge", "Body")}

#define MAX_BATCHES ${max_batches}
#define SERIAL_BATCH (MAX_BATCHES - 1)
/* colours tracked in a body's mask (two 32-bit words) */
#define COLOURS ${colours}
/* the layout of `state` (see colour_global) */
#define STATE_SYNC 0
#define STATE_LOST RB_BARRIER_WORDS
#define STATE_HIGHEST (STATE_LOST + 2)
#define STATE_BATCH_SIZE (STATE_HIGHEST + 1)

<%include file="/common/hash.cl.mako"/>
<%include file="/common/colour_mask.cl.mako"/>
<%include file="/common/device_barrier.cl.mako"/>

/* the mask words (lo, hi) and bit of colour k */
inline uint mask_word(uint k)
{
    return k < 32 ? 0u : 1u;
}

inline uint mask_bit(uint k)
{
    return 1u << (k & 31u);
}

/* Edge c takes colour k (its bodies' masks already hold k); the next step
 * inherits it unless it is provisional. */
inline void take_colour(__global ConstraintEdge* edges, __global uint* edge_colour,
                        volatile __global uint* highest, volatile __global uint* batch_size,
                        uint c, uint k, bool provisional)
{
    atomic_max(highest, k);
    edge_colour[c] = k;
    edges[c].colour = provisional ? RB_SOLVER_NONE : k;
    atomic_inc(&batch_size[k]);
}

/* An edge's bid in a Jones-Plassmann round: its index in the ordered rounds
 * (first-fit in index order), else a hash of it (few rounds). */
inline uint bid_priority(uint c, bool ordered)
{
    return ordered ? c : mix32(c);
}

/* Colours the first edge_count[0] edges (see the file comment). Scratch:
 * `pairs` (2 per edge: its dynamic bodies, RB_SOLVER_NONE for a static one),
 * `bids` (2 per body), `used` (4 per body: the colour mask, then the
 * repeated-colour mask of step 1) and `state`: the device-wide barrier's
 * RB_BARRIER_WORDS words (which the solver's launch after this one shares),
 * the 2 lost flags, the highest colour taken and MAX_BATCHES + 1 batch
 * counters. The first `ordered_rounds` rounds bid edge indices. A work
 * group is responsible for every edge and body at its lanes' indices plus
 * multiples of the launch's size, in every phase. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void colour_global(__global ConstraintEdge* edges,
                   __global const uint* edge_count,
                   __global const Body* bodies,
                   __global uint* edge_colour,
                   volatile __global uint* order,
                   __global uint* group_batches,
                   __global uint* group_batch_count,
                   __global uint* pairs,
                   volatile __global uint* bids,
                   volatile __global uint* used,
                   volatile __global uint* state,
                   const uint body_count,
                   const uint ordered_rounds)
{
    const uint id = get_global_id(0), lanes = get_global_size(0);
    volatile __global uint* sync = state + STATE_SYNC;
    volatile __global uint* lost = state + STATE_LOST;
    volatile __global uint* highest = state + STATE_HIGHEST;
    volatile __global uint* batch_size = state + STATE_BATCH_SIZE;
    volatile __global uint* repeated = used + 2 * body_count;
    /* 0 once a device-wide barrier was given up: every later phase is skipped */
    __local uint barrier_ok;
    device_barrier_start(sync, &barrier_ok);
    const uint n = barrier_ok ? edge_count[0] : 0u;

    for (uint body = id; body < body_count && barrier_ok; body += lanes) {
        bids[body] = bids[body_count + body] = RB_SOLVER_NONE;
        used[2 * body] = used[2 * body + 1] = 0;
        repeated[2 * body] = repeated[2 * body + 1] = 0;
    }
    for (uint k = id; k <= MAX_BATCHES && barrier_ok; k += lanes)
        batch_size[k] = 0;
    if (id == 0 && barrier_ok)
        lost[0] = lost[1] = *highest = 0;
    /* every edge's dynamic bodies, and its inherited colour, if any */
    for (uint c = id; c < n && barrier_ok; c += lanes) {
        uint a = edges[c].body_a, b = edges[c].body_b;
        uint hint = edges[c].colour;
        pairs[2 * c] = bodies[a].inv_mass > 0.0f ? a : RB_SOLVER_NONE;
        pairs[2 * c + 1] = bodies[b].inv_mass > 0.0f ? b : RB_SOLVER_NONE;
        edge_colour[c] = hint < COLOURS ? hint : RB_SOLVER_NONE;
    }
    device_barrier(sync, &barrier_ok);

    /* 1. inherited colours: mark them on the bodies, noting repeats */
    for (uint c = id; c < n && barrier_ok; c += lanes) {
        uint k = edge_colour[c];
        if (k == RB_SOLVER_NONE)
            continue;
        uint word = mask_word(k), bit = mask_bit(k);
        for (uint side = 0; side < 2; ++side) {
            uint body = pairs[2 * c + side];
            if (body != RB_SOLVER_NONE && (atomic_or(&used[2 * body + word], bit) & bit))
                atomic_or(&repeated[2 * body + word], bit);
        }
    }
    device_barrier(sync, &barrier_ok);
    /* keep the colours repeated on neither body; list the rest for the rounds */
    for (uint c = id; c < n && barrier_ok; c += lanes) {
        uint k = edge_colour[c];
        bool keep = k != RB_SOLVER_NONE;
        if (keep) {
            uint word = mask_word(k), bit = mask_bit(k);
            for (uint side = 0; side < 2; ++side) {
                uint body = pairs[2 * c + side];
                keep = keep && (body == RB_SOLVER_NONE || !(repeated[2 * body + word] & bit));
            }
        }
        if (keep)
            take_colour(edges, edge_colour, highest, batch_size, c, k, false);
        else
            edge_colour[c] = RB_SOLVER_NONE;
    }
    /* the masks keep only the colours kept (a repeated colour was dropped by all) */
    for (uint body = id; body < body_count && barrier_ok; body += lanes) {
        used[2 * body] &= ~repeated[2 * body];
        used[2 * body + 1] &= ~repeated[2 * body + 1];
    }
    device_barrier(sync, &barrier_ok);

    /* 2. Jones-Plassmann rounds over the uncoloured edges */
    bool more = n > 0;
    for (uint round = 0; more; ++round) {
        volatile __global uint* bid = bids + (round & 1) * body_count;
        volatile __global uint* next_bid = bids + ((round + 1) & 1) * body_count;
        const bool ordered = round < ordered_rounds;
        /* every uncoloured edge bids on its dynamic bodies; the next
         * round's bids are cleared (the last round read them before its barrier) */
        for (uint body = id; body < body_count && barrier_ok; body += lanes)
            next_bid[body] = RB_SOLVER_NONE;
        for (uint c = id; c < n && barrier_ok; c += lanes) {
            if (edge_colour[c] != RB_SOLVER_NONE)
                continue;
            uint a = pairs[2 * c], b = pairs[2 * c + 1], priority = bid_priority(c, ordered);
            if (a != RB_SOLVER_NONE)
                atomic_min(&bid[a], priority);
            if (b != RB_SOLVER_NONE)
                atomic_min(&bid[b], priority);
        }
        device_barrier(sync, &barrier_ok);
        /* an edge holding the lowest bid on all its dynamic bodies takes
         * the lowest colour free on them (no other winner touches them); the
         * next round's flag is cleared (nobody reads it now) */
        if (id == 0 && barrier_ok)
            lost[(round + 1) & 1] = 0;
        for (uint c = id; c < n && barrier_ok; c += lanes) {
            if (edge_colour[c] != RB_SOLVER_NONE)
                continue;
            uint a = pairs[2 * c], b = pairs[2 * c + 1], priority = bid_priority(c, ordered);
            bool dynamic_a = a != RB_SOLVER_NONE, dynamic_b = b != RB_SOLVER_NONE;
            if ((dynamic_a && bid[a] != priority) || (dynamic_b && bid[b] != priority)) {
                lost[round & 1] = 1;  /* any lane's store of the same value will do */
                continue;
            }
            uint low = (dynamic_a ? used[2 * a] : 0u) | (dynamic_b ? used[2 * b] : 0u);
            uint high = (dynamic_a ? used[2 * a + 1] : 0u) | (dynamic_b ? used[2 * b + 1] : 0u);
            uint k = lowest_free(low, high);
            if (k < COLOURS) {
                uint word = mask_word(k), bit = mask_bit(k);
                if (dynamic_a)
                    used[2 * a + word] |= bit;
                if (dynamic_b)
                    used[2 * b + word] |= bit;
            } else {
                k = SERIAL_BATCH;
            }
            take_colour(edges, edge_colour, highest, batch_size, c, k, !ordered);
        }
        device_barrier(sync, &barrier_ok);
        more = barrier_ok && lost[round & 1] != 0;
    }

    /* batch offsets (one lane: at most MAX_BATCHES entries), then the list */
    const uint batch_count = n == 0 || !barrier_ok ? 0 : *highest + 1;
    if (id == 0 && barrier_ok) {
        uint total = 0;
        for (uint k = 0; k <= batch_count; ++k) {
            uint size = batch_size[k];
            batch_size[k] = total;
            group_batches[k] = total;
            total += size;
        }
        group_batch_count[0] = batch_count;
    }
    device_barrier(sync, &barrier_ok);
    for (uint c = id; c < n && barrier_ok; c += lanes) {
        uint k = edge_colour[c];
        order[atomic_inc(&batch_size[k])] = edges[c].item;
    }
    /* the serial slot is solved in list order: make it item order (insertion
     * sort by one lane; the slot holds only what 64 colours could not take) */
    device_barrier(sync, &barrier_ok);
    if (id == 0 && barrier_ok && batch_count > SERIAL_BATCH) {
        const uint begin = group_batches[SERIAL_BATCH], end = group_batches[SERIAL_BATCH + 1];
        for (uint i = begin + 1; i < end; ++i) {
            uint value = order[i], j = i;
            for (; j > begin && order[j - 1] > value; --j)
                order[j] = order[j - 1];
            order[j] = value;
        }
    }
    device_barrier_leave(sync);
}
