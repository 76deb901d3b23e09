/* Separating-axis test between two boxes, in closed form.
 *
 * One work-item per queued box-box pair; a work group is responsible for
 * ${work_group_size} consecutive entries of the kind's queue. The 15 axes of
 * two boxes (3 face normals of each, 9 cross products of their axes) are
 * measured from the boxes' axes and half extents alone: no vertex or face
 * array is read. Feature codes are those of the generic test on the boxes'
 * cooked hulls (faces +x, -x, +y, -y, +z, -z; edge directions x, y, z), so
 * the clipping stage is shared: face 2i + (negative side) of the first box,
 * 6 + the face of the second, then 12 + 3i + j for axis i of the first
 * crossed with axis j of the second. Like the generic test, it stops at the
 * first axis that separates by more than `margin`, tries last step's best
 * axis first (per-pair cache keyed by the bodies), and appends touching pairs
 * to the clipping queue with group-aggregated atomics.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "SatCacheEntry", "SatResult")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>

/* See the generic test: preferences between near-equal axes. */
#define FACE_TOLERANCE 1e-4f
#define EDGE_TOLERANCE 1e-4f
#define PARALLEL_SIN2 1e-8f
#define FIRST_EDGE_FEATURE 12u

/* Two boxes in the world: axes (columns of the rotations), half extents, and
 * the offset between their centres. */
typedef struct {
    float3 a[3], b[3];
    float3 extent_a, extent_b;
    float3 offset;  /* centre of b - centre of a */
} BoxPair;

inline void box_axes(float4 q, float3* axes)
{
    axes[0] = quat_rotate(q, (float3)(1.0f, 0.0f, 0.0f));
    axes[1] = quat_rotate(q, (float3)(0.0f, 1.0f, 0.0f));
    axes[2] = quat_rotate(q, (float3)(0.0f, 0.0f, 1.0f));
}

/* Half width of a box along a unit axis. */
inline float box_reach(const float3* axes, float3 extent, float3 axis)
{
    return extent.x * fabs(dot(axes[0], axis)) + extent.y * fabs(dot(axes[1], axis))
         + extent.z * fabs(dot(axes[2], axis));
}

inline float component(float3 v, uint i)
{
    return i == 0 ? v.x : (i == 1 ? v.y : v.z);
}

/* Axis i of the first box, turned towards the second: the face facing it. */
inline float4 first_face(const BoxPair* g, uint i, uint* feature)
{
    float t = dot(g->a[i], g->offset);
    float3 axis = t >= 0.0f ? g->a[i] : -g->a[i];
    *feature = 2u * i + (t >= 0.0f ? 0u : 1u);
    return (float4)(axis, fabs(t) - component(g->extent_a, i) - box_reach(g->b, g->extent_b, g->a[i]));
}

/* Axis j of the second box: its face that faces the first box. */
inline float4 second_face(const BoxPair* g, uint j, uint* feature)
{
    float u = dot(g->b[j], g->offset);
    float3 axis = u >= 0.0f ? g->b[j] : -g->b[j];
    /* the facing face of the second box has outward normal -axis */
    *feature = 6u + 2u * j + (u >= 0.0f ? 1u : 0u);
    return (float4)(axis, fabs(u) - component(g->extent_b, j) - box_reach(g->a, g->extent_a, g->b[j]));
}

/* Axis i of the first box crossed with axis j of the second (w = -INFINITY when parallel). */
inline float4 edge_axis(const BoxPair* g, uint i, uint j)
{
    float3 axis = cross(g->a[i], g->b[j]);
    float sin2 = dot(axis, axis);
    if (sin2 < PARALLEL_SIN2)
        return (float4)(axis, -INFINITY);
    axis *= rsqrt(sin2);
    float d = dot(axis, g->offset);
    float gap = fabs(d) - box_reach(g->a, g->extent_a, axis) - box_reach(g->b, g->extent_b, axis);
    return (float4)(d >= 0.0f ? axis : -axis, gap);
}

/* Separation along a feature code (last step's best axis). */
inline float4 feature_separation(const BoxPair* g, uint feature)
{
    uint unused;
    if (feature < 6u)
        return first_face(g, feature / 2u, &unused);
    if (feature < FIRST_EDGE_FEATURE)
        return second_face(g, (feature - 6u) / 2u, &unused);
    uint e = feature - FIRST_EDGE_FEATURE;
    return edge_axis(g, e / 3u, e % 3u);
}

inline void remember_axis(__global SatCacheEntry* entry, Pair pair, uint feature)
{
    entry->a = pair.a;
    entry->b = pair.b;
    entry->feature = feature;
}

/* True when the boxes are within `margin`: then *best is the axis of least
 * penetration (w: separation) and *best_feature its code. */
inline bool box_box_test(const BoxPair* g, Pair pair, __global SatCacheEntry* entry, float margin,
                         float4* best, uint* best_feature)
{
    SatCacheEntry cached = *entry;
    if (cached.a == pair.a && cached.b == pair.b && cached.feature != (uint)RB_NO_FEATURE
            && feature_separation(g, cached.feature).w > margin)
        return false;  /* last step's axis still separates: the entry stays */

    float4 face_a = (float4)(0.0f, 0.0f, 0.0f, -INFINITY), face_b = face_a, edge = face_a;
    uint face_a_feature = 0, face_b_feature = 6u, edge_feature = FIRST_EDGE_FEATURE;
    for (uint i = 0; i < 3; ++i) {
        uint feature;
        float4 s = first_face(g, i, &feature);
        if (s.w > margin) {
            remember_axis(entry, pair, feature);
            return false;
        }
        if (s.w > face_a.w)
            face_a = s, face_a_feature = feature;
    }
    for (uint j = 0; j < 3; ++j) {
        uint feature;
        float4 s = second_face(g, j, &feature);
        if (s.w > margin) {
            remember_axis(entry, pair, feature);
            return false;
        }
        if (s.w > face_b.w)
            face_b = s, face_b_feature = feature;
    }
    for (uint i = 0; i < 3; ++i) {
        for (uint j = 0; j < 3; ++j) {
            float4 s = edge_axis(g, i, j);
            uint feature = FIRST_EDGE_FEATURE + 3u * i + j;
            if (s.w > margin) {
                remember_axis(entry, pair, feature);
                return false;
            }
            if (s.w > edge.w)
                edge = s, edge_feature = feature;
        }
    }

    *best = face_a, *best_feature = face_a_feature;
    if (face_b.w > face_a.w + FACE_TOLERANCE)
        *best = face_b, *best_feature = face_b_feature;
    if (edge.w > fmax(face_a.w, face_b.w) + EDGE_TOLERANCE)
        *best = edge, *best_feature = edge_feature;
    remember_axis(entry, pair, *best_feature);
    return true;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void find_separating_axis(__global const Pair* pairs,
                          __global const Body* bodies,
                          __global const Shape* shapes,
                          __global const uint* queues,
                          __global const uint* queue_counts,
                          const uint pair_capacity,
                          const uint kind,
                          __global SatCacheEntry* cache,
                          __global SatResult* results,
                          __global uint* result_count,
                          const float margin)
{
    __local uint group_count, group_base;
    uint slot = get_global_id(0);
    if (get_local_id(0) == 0)
        group_count = 0;
    barrier(CLK_LOCAL_MEM_FENCE);

    bool touching = false;
    float4 axis = (float4)(0.0f);
    uint feature = 0, entry = 0;
    if (slot < queue_counts[kind]) {
        entry = queues[kind * pair_capacity + slot];
        QueuedPair q = decode_queue_entry(entry, pairs);
        Body a = bodies[q.first], b = bodies[q.second];
        BoxPair g;
        box_axes(a.orientation, g.a);
        box_axes(b.orientation, g.b);
        g.extent_a = shapes[a.shape].extents.xyz;
        g.extent_b = shapes[b.shape].extents.xyz;
        g.offset = b.position.xyz - a.position.xyz;
        touching = box_box_test(&g, pairs[q.index], &cache[q.index], margin, &axis, &feature);
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
