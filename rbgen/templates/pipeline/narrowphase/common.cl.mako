/* ---- Narrowphase helpers shared by every pair kernel ------------------------
 *
 * Queues: the dispatch kernel appends each pair to the queue of its shape-type
 * pair ("kind"). An entry is the pair index, with RB_PAIR_SWAPPED set when the
 * pair's body b has the kind's first shape type. Kind k's queue is
 * queue[k * pair_capacity ...] and its length queue_counts[k] (on the device).
 *
 * Every kernel computes with the kind's shape order (first, second) and stores
 * its manifold in the pair's order through store_manifold: one slot per pair
 * index, so the result is deterministic whatever order the queues have.
 */

/* A body's placement: rows of its rotation (body to world) and its position.
 * Device-private; it never crosses the host boundary. */
typedef struct {
    float3 r0, r1, r2;
    float3 position;
} Placement;

inline Placement placement_of(Body body)
{
    Placement p;
    quat_to_rows(body.orientation, &p.r0, &p.r1, &p.r2);
    p.position = body.position.xyz;
    return p;
}

inline float3 rotate_to_world(const Placement* p, float3 v)
{
    return (float3)(dot3(p->r0, v), dot3(p->r1, v), dot3(p->r2, v));
}

inline float3 rotate_to_local(const Placement* p, float3 v)
{
    return p->r0 * v.x + p->r1 * v.y + p->r2 * v.z;
}

inline float3 point_to_world(const Placement* p, float3 v)
{
    return rotate_to_world(p, v) + p->position;
}

inline float3 point_to_local(const Placement* p, float3 v)
{
    return rotate_to_local(p, v - p->position);
}

/* World plane (outward normal, offset) of a plane given in the body frame. */
inline float4 plane_to_world(const Placement* p, float4 local_plane)
{
    float3 n = rotate_to_world(p, local_plane.xyz);
    return (float4)(n, local_plane.w + dot3(n, p->position));
}

/* The largest separation at which a pair's points are kept: the contact margin
 * plus both bodies' speculative distances (Body.linear_velocity.w, written by
 * prepare_bodies: a fast body's travel this step, else 0). */
inline float pair_margin(float margin, Body a, Body b)
{
    return margin + a.linear_velocity.w + b.linear_velocity.w;
}

/* The pair a queue entry refers to, with its bodies in the kernel's shape order. */
typedef struct {
    uint index;     /* into the pair list and the per-pair manifold slots */
    uint first;     /* body with the kind's first shape type */
    uint second;    /* body with the kind's second shape type */
    uint sub;       /* the pair's sub-feature (Pair.sub), copied into its manifold */
    bool swapped;   /* first is the pair's body b */
} QueuedPair;

inline QueuedPair decode_queue_entry(uint entry, __global const Pair* pairs)
{
    QueuedPair q;
    q.index = entry & ~(uint)RB_PAIR_SWAPPED;
    q.swapped = (entry & (uint)RB_PAIR_SWAPPED) != 0u;
    Pair pair = pairs[q.index];
    q.first = q.swapped ? pair.b : pair.a;
    q.second = q.swapped ? pair.a : pair.b;
    q.sub = pair.sub;
    return q;
}
