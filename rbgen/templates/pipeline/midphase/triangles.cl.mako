/* Midphase, triangle meshes: the (body, triangle) pairs of every (mesh, body) pair.
 *
 * count_triangle_pairs and write_triangle_pairs walk the mesh's BVH (bvh.cl.mako) with
 * the other body's world AABB in the mesh's frame: the first counts the triangles whose
 * box overlaps it, a scan of the counts (rbgen.primitives.Scan) gives each input pair
 * its place in the output, and the second walks again and writes them there, in leaf
 * order (the triangles' order), so the output is deterministic. A pair without a mesh
 * is copied (a count of 1). An output pair keeps its input's bodies, with sub = 1 + the
 * triangle (from the mesh's first). write_triangle_pairs' first work-item writes the
 * status: the output size needed when it exceeds the capacity (nothing is written past
 * it; the step is redone with a larger buffer), else 0.
 *
% if traversal == "global":
 * Traversal "global" (Bullet3's): a work group is responsible for ${work_group_size}
 * consecutive input pairs, one work-item each, and each walks its whole tree in global
 * memory.
% else:
 * Traversal "local": a work group is responsible for ${work_group_size} consecutive input
 * pairs, one work-item each. A subtree is a node whose subtree has at most
 * ${subtree_nodes} nodes under one that has more. Each work-item walks the top of its
 * tree (above the subtrees) in global memory up to the next subtree its box overlaps and
 * waits there; the group stages the lowest subtree any of its work-items waits for in
 * local memory (${subtree_nodes} nodes, ${16 * subtree_nodes} bytes), each work-item
 * waiting for it walks it there, and the group goes on until no work-item waits. So a
 * subtree is read from global memory once per group however many of the group's pairs
 * reach it, and every work-item still meets its triangles in leaf order.
% endif
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "Aabb", "BvhNode", "MeshTriangle")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/midphase/bvh.cl.mako"/>

#define WORK_GROUP_SIZE ${work_group_size}u
% if traversal == "local":
#define SUBTREE_NODES ${subtree_nodes}u
% endif

/* The mesh side of a pair: its first node and triangle and the query box, or none. */
typedef struct {
    uint node, end;           /* nodes still to walk (node == end: none) */
    uint first_triangle;
    MeshQuery query;
} MeshWalk;

/* The walk of pair `pair` (node == end when neither body is a mesh). */
inline MeshWalk walk_of(Pair pair, __global const Body* bodies, __global const Shape* shapes,
                        __global const float4* hull_vertices, __global const Aabb* aabbs)
{
    MeshWalk w;
    w.node = w.end = w.first_triangle = 0u;
    Body a = bodies[pair.a], b = bodies[pair.b];
    Shape sa = shapes[a.shape], sb = shapes[b.shape];
    bool mesh_a = sa.type == RB_SHAPE_MESH;
    if (!mesh_a && sb.type != RB_SHAPE_MESH)
        return w;
    Shape mesh = mesh_a ? sa : sb;
    w.query = mesh_query(aabbs[mesh_a ? pair.b : pair.a], mesh_a ? a : b, mesh, hull_vertices);
    w.node = mesh.child_offset;
    w.end = mesh.child_offset + mesh.child_count;
    w.first_triangle = mesh.face_offset;
    return w;
}

<%def name="visit(nodes, at, emit)">\
{
            BvhNode n = ${nodes}[${at}];
            bool hit = node_overlaps(n, w.query.q_lower, w.query.q_upper);
            if (n.index >= 0) {
                uint t = (uint)n.index;
                if (hit && triangle_overlaps(mesh_triangles[w.first_triangle + t], mesh_vertices, &w.query)) {
                    ${emit}
                }
                ${at} += 1u;
            } else {
                ${at} += hit ? 1u : subtree_size(n);
            }
        }\
</%def>
<%def name="walk(emit)">\
% if traversal == "global":
    while (w.node < w.end)
        ${visit("bvh_nodes", "w.node", emit)}
% else:
    __local BvhNode staged[SUBTREE_NODES];
    __local uint chosen;
    uint waiting = RB_NO_SUBTREE;  /* the subtree root this work-item waits at */
    for (;;) {
        /* the walk above the subtrees, up to the next overlapping subtree */
        while (waiting == RB_NO_SUBTREE && w.node < w.end) {
            BvhNode n = bvh_nodes[w.node];
            uint size = subtree_size(n);
            bool hit = node_overlaps(n, w.query.q_lower, w.query.q_upper);
            if (size <= SUBTREE_NODES) {
                if (hit)
                    waiting = w.node;
                w.node += size;
            } else {
                w.node += hit ? 1u : size;
            }
        }
        if (get_local_id(0) == 0)
            chosen = RB_NO_SUBTREE;
        barrier(CLK_LOCAL_MEM_FENCE);
        if (waiting != RB_NO_SUBTREE)
            atomic_min(&chosen, waiting);
        barrier(CLK_LOCAL_MEM_FENCE);
        uint root = chosen;
        if (root == RB_NO_SUBTREE)
            break;  /* (the same in every work-item) */
        uint size = subtree_size(bvh_nodes[root]);
        for (uint k = get_local_id(0); k < size; k += WORK_GROUP_SIZE)
            staged[k] = bvh_nodes[root + k];
        barrier(CLK_LOCAL_MEM_FENCE);
        if (waiting == root) {
            for (uint at = 0; at < size; )
                ${visit("staged", "at", emit)}
            waiting = RB_NO_SUBTREE;
        }
        barrier(CLK_LOCAL_MEM_FENCE);  /* before the next subtree replaces this one */
    }
% endif
</%def>
<%def name="pair_prologue()">\
    uint i = get_global_id(0);
    uint n = min(pair_count[0], pair_capacity);
    Pair pair;
    MeshWalk w;
    w.node = w.end = 0u;
    if (i < n) {
        pair = pairs[i];
        w = walk_of(pair, bodies, shapes, hull_vertices, aabbs);
    }
    bool copied = i < n && w.node == w.end;  /* no mesh: the pair itself */
</%def>

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void count_triangle_pairs(${signature("count_triangle_pairs")})
{
${pair_prologue()}
    uint count = copied ? 1u : 0u;
${walk("++count;")}
    if (i < n)
        counts[i] = count;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void write_triangle_pairs(${signature("write_triangle_pairs")})
{
${pair_prologue()}
    if (i == 0) {  /* the capacity needed (0 when everything fits); then the count of the
                    * pairs stored, so that no later kernel reads or writes past the capacity
                    * (this kernel's other work-items do not read it) */
        uint found = out_count[0];
        status[status_word] = found > out_capacity ? found : 0u;
        if (found > out_capacity)
            out_count[0] = out_capacity;
    }
    uint place = i < n ? offsets[i] : 0u;
    if (copied && place < out_capacity)
        out_pairs[place] = pair;
${walk("if (place < out_capacity) { Pair p; p.a = pair.a; p.b = pair.b; p.sub = t + 1u; out_pairs[place] = p; } ++place;")}
}
