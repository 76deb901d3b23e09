/* ---- Quantized BVH walks (rbgen.bvh) -----------------------------------------
 *
 * Nodes are in depth-first order; an inner node stores minus the nodes of its
 * subtree, so a walk goes to node + 1 when a node's box overlaps the query and
 * past its subtree when it does not: no stack, and the leaves come out in order.
 * Boxes are compared quantized (16 bits an axis inside the mesh's quantization
 * box, both sides rounded outwards by a quantum, so nothing that overlaps is
 * missed); a leaf's triangle is then checked against its exact box.
 */

/* The nodes a walk skips at `node` when its box misses: 1 for a leaf, else its subtree. */
inline uint subtree_size(BvhNode node)
{
    return node.index >= 0 ? 1u : (uint)(-node.index);
}

inline bool node_overlaps(BvhNode node, uint3 lower, uint3 upper)
{
    return (node.bounds[0] & 0xFFFFu) <= upper.x && (node.bounds[0] >> 16) <= upper.y
        && (node.bounds[1] & 0xFFFFu) <= upper.z && lower.x <= (node.bounds[1] >> 16)
        && lower.y <= (node.bounds[2] & 0xFFFFu) && lower.z <= (node.bounds[2] >> 16);
}

/* A world box in a mesh's frame, exact and quantized. */
typedef struct {
    float3 lower, upper;      /* mesh frame */
    uint3 q_lower, q_upper;   /* quantized, rounded outwards by a quantum, clamped */
} MeshQuery;

/* `box` (world) in the frame of the mesh body `mesh_body`: exact when the body is not
 * rotated, else the box around the rotated box. */
inline MeshQuery mesh_query(Aabb box, Body mesh_body, Shape mesh, __global const float4* hull_vertices)
{
    MeshQuery m;
    float4 q = mesh_body.orientation;
    float3 p = mesh_body.position.xyz;
    if (q.x == 0.0f && q.y == 0.0f && q.z == 0.0f) {
        m.lower = box.lower.xyz - p;
        m.upper = box.upper.xyz - p;
    } else {
        float3 r0, r1, r2;
        quat_to_rows(q, &r0, &r1, &r2);
        /* the columns of R are the rows of R^T (world to mesh) */
        float3 c0 = (float3)(r0.x, r1.x, r2.x), c1 = (float3)(r0.y, r1.y, r2.y), c2 = (float3)(r0.z, r1.z, r2.z);
        float3 centre = 0.5f * (box.lower.xyz + box.upper.xyz) - p, half_size = 0.5f * (box.upper.xyz - box.lower.xyz);
        float3 in_mesh = (float3)(dot3(c0, centre), dot3(c1, centre), dot3(c2, centre));
        float3 reach = (float3)(dot3(abs3(c0), half_size), dot3(abs3(c1), half_size), dot3(abs3(c2), half_size));
        m.lower = in_mesh - reach;
        m.upper = in_mesh + reach;
    }
    float3 q_lo = hull_vertices[mesh.vertex_offset].xyz, q_hi = hull_vertices[mesh.vertex_offset + 1].xyz;
    float3 scale = (float)RB_BVH_QUANTA / (q_hi - q_lo);
    float3 lo = clamp(floor((m.lower - q_lo) * scale) - 1.0f, 0.0f, (float)RB_BVH_QUANTA);
    float3 hi = clamp(ceil((m.upper - q_lo) * scale) + 1.0f, 0.0f, (float)RB_BVH_QUANTA);
    m.q_lower = convert_uint3(lo);
    m.q_upper = convert_uint3(hi);
    return m;
}

/* Does triangle t's exact box overlap the query (closed boxes, as the broadphase's)? */
inline bool triangle_overlaps(MeshTriangle t, __global const float4* mesh_vertices, const MeshQuery* m)
{
    float3 a = mesh_vertices[t.vertices[0]].xyz, b = mesh_vertices[t.vertices[1]].xyz;
    float3 c = mesh_vertices[t.vertices[2]].xyz;
    float3 lo = fmin(fmin(a, b), c), hi = fmax(fmax(a, b), c);
    return lo.x <= m->upper.x && lo.y <= m->upper.y && lo.z <= m->upper.z
        && m->lower.x <= hi.x && m->lower.y <= hi.y && m->lower.z <= hi.z;
}
