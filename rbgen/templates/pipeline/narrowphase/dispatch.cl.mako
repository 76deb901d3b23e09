<%!
    from rbgen.pipeline.narrowphase.kinds import pair_kernel
    from rbgen.shapes import shape_type
%>/* Narrowphase dispatch and output.
 *
 * classify_pairs: one work-item per broadphase pair; a work group is
 * responsible for ${work_group_size} consecutive pairs. It clears the pair's
 * contact flag (the first work-items: the placement tiles' manifold counts
 * too) and appends the pair to
 * the queue of its shape-type pair, so that each pair kernel runs over a
 * homogeneous queue. Appends are aggregated per work group (one global atomic
 * per kind and group).
 * Kinds: ${", ".join(kinds)}.
 *
 * scatter_manifolds: a work group is responsible for one placement tile of
 * ${placement_tile} consecutive pairs, each of its ${work_group_size} work-items for
 * ${placement_tile // work_group_size} consecutive pairs. The pair kernels counted the
 * manifolds of every tile (tile_counts), so a group finds where its tile
 * starts by summing the counts of the tiles before it, and places its
 * flagged slots in pair order (deterministic) with a work-group scan: no
 * separate prefix-sum launches. It copies each flagged per-pair slot there,
 * adds the combined material coefficients (friction sqrt(fa fb), restitution
 * max(ra, rb)); the last group writes the manifold count and the overflow
 * word (the count needed, or 0: the caller need not clear it); work-item 0
 * clears the queue counters and the clipping queue's count for the next call
 * (keeping that count in sat_count[1] for inspection).
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "ContactManifold")}

<%include file="/common/inline_math.cl.mako"/>

#define KIND_COUNT ${len(kinds)}
#define NO_KIND KIND_COUNT
#define PLACEMENT_TILE ${placement_tile}u
#define WORK_GROUP_SIZE ${work_group_size}u
/* consecutive pairs per work-item in scatter_manifolds */
#define PAIRS_PER_ITEM ${placement_tile // work_group_size}u

/* Queue of a pair whose shapes have types (ta, tb); *swapped when b comes first. */
inline uint kind_of(uint ta, uint tb, bool* swapped)
{
% for k, name in enumerate(kinds):
% for first, second in pair_kernel(name).pairs:
<% f, s = shape_type(first).type_constant, shape_type(second).type_constant %>\
    if (ta == ${f} && tb == ${s}) {
        *swapped = false;
        return ${k};  /* ${name} */
    }
% if first != second:
    if (ta == ${s} && tb == ${f}) {
        *swapped = true;
        return ${k};  /* ${name}, bodies swapped */
    }
% endif
% endfor
% endfor
    *swapped = false;
    return NO_KIND;  /* not a supported pair: Narrowphase construction rejects such worlds */
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void classify_pairs(__global const Pair* pairs,
                    __global const uint* pair_count,
                    __global const Body* bodies,
                    __global const Shape* shapes,
                    __global uint* contact_flags,
                    __global uint* queues,
                    __global uint* queue_counts,
                    const uint pair_capacity,
                    __global uint* tile_counts,
                    const uint tile_count)
{
    __local uint group_counts[KIND_COUNT];
    __local uint group_bases[KIND_COUNT];
    uint i = get_global_id(0);
    if (i < tile_count)  /* counted by the pair kernels that store manifolds */
        tile_counts[i] = 0u;
    if (get_local_id(0) == 0)
        for (uint k = 0; k < KIND_COUNT; ++k)
            group_counts[k] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);

    uint kind = NO_KIND, ticket = 0;
    bool swapped = false;
    if (i < pair_count[0]) {
        contact_flags[i] = 0u;
        Pair pair = pairs[i];
        uint ta = shapes[bodies[pair.a].shape].type;
        uint tb = shapes[bodies[pair.b].shape].type;
        kind = kind_of(ta, tb, &swapped);
        if (kind != NO_KIND)
            ticket = atomic_inc(&group_counts[kind]);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0)
        for (uint k = 0; k < KIND_COUNT; ++k)
            group_bases[k] = group_counts[k] ? atomic_add(&queue_counts[k], group_counts[k]) : 0u;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (kind != NO_KIND)
        queues[kind * pair_capacity + group_bases[kind] + ticket] = i | (swapped ? (uint)RB_PAIR_SWAPPED : 0u);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void scatter_manifolds(__global const ContactManifold* slots,
                       __global const uint* contact_flags,
                       __global const uint* tile_counts,
                       __global const uint* pair_count,
                       const uint pair_list_size,
                       __global const Body* bodies,
                       __global ContactManifold* manifolds,
                       const uint manifold_capacity,
                       __global uint* manifold_count,
                       __global uint* overflow,
                       __global uint* queue_counts,
                       __global uint* sat_count)
{
    __local uint earlier[WORK_GROUP_SIZE];  /* manifolds of earlier tiles, partial sums */
    __local uint running[WORK_GROUP_SIZE];  /* manifolds of this tile, per work-item */
    uint l = get_local_id(0), tile = get_group_id(0);
    uint n = min(pair_count[0], pair_list_size);  /* no count reaches past the list */
    uint first = tile * PLACEMENT_TILE + l * PAIRS_PER_ITEM;
    if (get_global_id(0) == 0) {
        /* every reader of these counters ran before this kernel: clear them for the
         * next call (instead of fill commands before it) */
        for (uint k = 0; k < KIND_COUNT; ++k)
            queue_counts[k] = 0u;
        sat_count[1] = sat_count[0];
        sat_count[0] = 0u;
    }

    uint before = 0, mine = 0;
    for (uint t = l; t < tile; t += WORK_GROUP_SIZE)
        before += tile_counts[t];
    for (uint k = 0; k < PAIRS_PER_ITEM; ++k)
        if (first + k < n)
            mine += contact_flags[first + k];
    earlier[l] = before;
    running[l] = mine;
    barrier(CLK_LOCAL_MEM_FENCE);
    /* inclusive scans of both (Hillis-Steele): earlier[last] is the tile's start */
    for (uint d = 1; d < WORK_GROUP_SIZE; d <<= 1) {
        uint e = l >= d ? earlier[l - d] : 0u, r = l >= d ? running[l - d] : 0u;
        barrier(CLK_LOCAL_MEM_FENCE);
        earlier[l] += e;
        running[l] += r;
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    uint tile_start = earlier[WORK_GROUP_SIZE - 1];
    if (tile == get_num_groups(0) - 1 && l == WORK_GROUP_SIZE - 1) {
        uint total = tile_start + running[l];  /* the last tile: every manifold is counted */
        manifold_count[0] = total;
        /* the capacity the host must grow to, 0 when everything fits */
        overflow[0] = total > manifold_capacity ? total : 0u;
    }

    uint place = tile_start + running[l] - mine;
    for (uint k = 0; k < PAIRS_PER_ITEM && place < manifold_capacity; ++k) {
        uint i = first + k;
        if (i >= n || contact_flags[i] == 0u)
            continue;
        ContactManifold m = slots[i];
        Body a = bodies[m.body_a], b = bodies[m.body_b];
        m.friction = sqrt1(a.friction * b.friction);
        m.restitution = max1(a.restitution, b.restitution);
        manifolds[place++] = m;
    }
}
