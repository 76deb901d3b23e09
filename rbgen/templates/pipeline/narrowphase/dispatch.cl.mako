<%
    # shape-type test per name in a kind ("convex" covers boxes and hulls)
    type_tests = {
        "sphere": "{v} == RB_SHAPE_SPHERE",
        "plane": "{v} == RB_SHAPE_PLANE",
        "box": "{v} == RB_SHAPE_BOX",
        "hull": "{v} == RB_SHAPE_HULL",
        "capsule": "{v} == RB_SHAPE_CAPSULE",
        "convex": "({v} == RB_SHAPE_BOX || {v} == RB_SHAPE_HULL)",
    }
    def test(type_name, var):
        return type_tests[type_name].format(v=var)
%>/* Narrowphase dispatch and output.
 *
 * classify_pairs: one work-item per broadphase pair; a work group is
 * responsible for ${work_group_size} consecutive pairs. It clears the pair's
 * contact flag (work-item 0: the clipping queue's count too) and appends the
 * pair to the queue of its shape-type pair, so
 * that each pair kernel runs over a homogeneous queue. Appends are aggregated
 * per work group (one global atomic per kind and group).
 * Kinds: ${", ".join(kinds)}.
 *
 * scatter_manifolds: one work-item per pair; a work group is responsible for
 * ${work_group_size} consecutive pairs. Copies each flagged per-pair slot to
 * its place in the output (the exclusive prefix sum of the flags, so the
 * output is in pair order), adds the combined material coefficients
 * (friction sqrt(fa fb), restitution max(ra, rb)), sets the overflow word
 * (the count needed, or 0: the caller need not clear it) and clears the queue
 * counters for the next call.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "ContactManifold")}

<%include file="/common/inline_math.cl.mako"/>

#define KIND_COUNT ${len(kinds)}
#define NO_KIND KIND_COUNT

/* Queue of a pair whose shapes have types (ta, tb); *swapped when b comes first. */
inline uint kind_of(uint ta, uint tb, bool* swapped)
{
% for k, name in enumerate(kinds):
<% first, second = name.split("_") %>\
    if (${test(first, "ta")} && ${test(second, "tb")}) {
        *swapped = false;
        return ${k};  /* ${name} */
    }
% if first != second:
    if (${test(first, "tb")} && ${test(second, "ta")}) {
        *swapped = true;
        return ${k};  /* ${name}, bodies swapped */
    }
% endif
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
                    __global uint* sat_count)
{
    __local uint group_counts[KIND_COUNT];
    __local uint group_bases[KIND_COUNT];
    uint i = get_global_id(0);
    if (i == 0)  /* the clipping queue is filled by later kernels (no fill command) */
        sat_count[0] = 0u;
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
                       __global const uint* slot_offsets,
                       __global const uint* pair_count,
                       __global const uint* manifold_count,
                       __global const Body* bodies,
                       __global ContactManifold* manifolds,
                       const uint manifold_capacity,
                       __global uint* overflow,
                       __global uint* queue_counts)
{
    uint i = get_global_id(0);
    if (i == 0) {
        /* the capacity the host must grow to, 0 when everything fits */
        overflow[0] = manifold_count[0] > manifold_capacity ? manifold_count[0] : 0u;
        /* every reader of the queue counters ran before this kernel: clear them for
         * the next call's classify_pairs (instead of a fill command before it) */
        for (uint k = 0; k < KIND_COUNT; ++k)
            queue_counts[k] = 0u;
    }
    if (i >= pair_count[0] || contact_flags[i] == 0u || slot_offsets[i] >= manifold_capacity)
        return;
    ContactManifold m = slots[i];
    Body a = bodies[m.body_a], b = bodies[m.body_b];
    m.friction = sqrt1(a.friction * b.friction);
    m.restitution = max1(a.restitution, b.restitution);
    manifolds[slot_offsets[i]] = m;
}
