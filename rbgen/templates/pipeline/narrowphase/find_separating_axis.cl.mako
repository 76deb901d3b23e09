<%doc>
What the separating-axis templates (sat.cl.mako, sat_box_box.cl.mako) share:
`definitions()`, the tolerances and the per-pair axis cache, and
`find_separating_axis(shape_arrays)`, the kernel. A template calls the kernel
def with the declarations of the shape arrays its test reads (placed after
`shapes`) and, as the call's body, the test of one pair: the body sees
`q` (QueuedPair), `a` and `b` (the bodies in the kind's order), `cache`,
`pairs` and `pair_reach` (the pair's margin, `pair_margin`), and sets
`touching`, `axis` and `feature`.
</%doc>
<%def name="definitions()">\
/* A face of the second shape wins over one of the first, and an edge pair over
 * the faces, only when better by these distances: a stable choice between
 * near-equal axes keeps the reference face (and the points) from flickering. */
#define FACE_TOLERANCE 1e-4f
#define EDGE_TOLERANCE 1e-4f
/* Edges closer to parallel than this (sine of the angle, squared) give no axis. */
#define PARALLEL_SIN2 1e-8f

/* Does a cache entry hold last step's axis of this pair (same bodies, same sub-feature)? */
inline bool cached_axis_of(SatCacheEntry cached, Pair pair)
{
    return cached.a == pair.a && cached.b == pair.b && cached.sub == pair.sub
        && cached.feature != (uint)RB_NO_FEATURE;
}

/* Keep the axis that decided this pair for the next step's first try. */
inline void remember_axis(__global SatCacheEntry* entry, Pair pair, uint feature)
{
    entry->a = pair.a;
    entry->b = pair.b;
    entry->sub = pair.sub;
    entry->feature = feature;
}
</%def>
<%def name="find_separating_axis(shape_arrays)">\
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void find_separating_axis(__global const Pair* pairs,
                          __global const Body* bodies,
                          __global const Shape* shapes,
% for declaration in shape_arrays:
                          ${declaration},
% endfor
% if direct:
                          __global const uint* pair_count,
                          __global uint* contact_flags,
                          __global uint* tile_counts,
                          const uint tile_count,
% else:
                          __global const uint* queues,
                          __global const uint* queue_counts,
                          const uint pair_capacity,
                          const uint kind,
% endif
                          __global SatCacheEntry* cache,
                          __global SatResult* results,
                          __global uint* result_count,
                          const float margin)
{
    __local uint group_count, group_base;
    uint slot = get_global_id(0);
% if direct:
    /* the world's only kind: its queue is the pair list itself, and this kernel,
     * the stage's first, clears the pairs' contact flags and the placement counts */
    uint queued = pair_count[0];
    if (slot < queued)
        contact_flags[slot] = 0u;
    if (slot < tile_count)
        tile_counts[slot] = 0u;
% else:
    uint queued = queue_counts[kind];
% endif
    if (get_local_id(0) == 0)
        group_count = 0;
    barrier(CLK_LOCAL_MEM_FENCE);

    bool touching = false;
    float4 axis = (float4)(0.0f);
    uint feature = 0, entry = 0;
    if (slot < queued) {
        entry = ${"slot" if direct else "queues[kind * pair_capacity + slot]"};
        QueuedPair q = decode_queue_entry(entry, pairs);
        Body a = bodies[q.first], b = bodies[q.second];
        const float pair_reach = pair_margin(margin, a, b);
${caller.body()}\
    }
    uint ticket = touching ? atomic_inc(&group_count) : 0u;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0 && group_count > 0)
        group_base = atomic_add(result_count, group_count);
    barrier(CLK_LOCAL_MEM_FENCE);
    if (touching) {
        SatResult r;
        r.axis = axis;
        r.pair = entry;
        r.feature = feature;
        results[group_base + ticket] = r;
    }
}
</%def>
