/* Midphase, compounds: each compound body's children become bodies of their own for the
 * step, and the pairs of compounds become pairs of children.
 *
 * place_children: a work group is responsible for ${work_group_size} consecutive slots of
 * the placed arrays, which hold the world's bodies and then one proxy body per child of
 * each compound body (ChildProxy: its compound and which child). A body is copied with its
 * world AABB; a proxy is the compound's body moved to where the child is (the
 * compound's pose times the child's), with the child's shape, and its world AABB (grown
 * by the margin as every body's). The narrowphase reads the placed bodies, so every pair
 * kernel of the children's types serves compounds.
 *
 * count_child_pairs and write_child_pairs: one work-item per input pair; a work group is
 * responsible for ${work_group_size} consecutive pairs. A pair without a compound is
 * copied; a compound against a body gives its children whose boxes overlap the body's,
 * two compounds every pair of overlapping children, as pairs of placed bodies in the
 * input's order (sub-feature 0: resolve_child_manifolds names the children). Counts,
 * a scan and the writes place them as the triangle pairs are placed (triangles.cl.mako);
 * write_child_pairs' first work-item writes the status word.
 *
 * resolve_child_manifolds: one work-item per manifold; a work group is responsible for
 * ${work_group_size} consecutive manifolds. A proxy becomes its compound again and the
 * manifold's sub-feature names the child: 1 + (child << RB_SUB_CHILD_SHIFT | other),
 * other being the pair's triangle (the sub-feature the triangle kernels wrote less 1) or
 * the second compound's child.
 * Child shape types: ${", ".join(shape_types)}.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "Aabb", "CompoundChild", "ChildProxy", "ContactManifold")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/world_aabb.cl.mako"/>

inline bool boxes_overlap(Aabb p, Aabb q)
{
    return p.lower.x <= q.upper.x && p.lower.y <= q.upper.y && p.lower.z <= q.upper.z
        && q.lower.x <= p.upper.x && q.lower.y <= p.upper.y && q.lower.z <= p.upper.z;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void place_children(${signature("place_children")})
{
    uint i = get_global_id(0);
    if (i < body_count) {
        placed_bodies[i] = bodies[i];
        placed_aabbs[i] = aabbs[i];
        return;
    }
    if (i >= body_count + proxy_count)
        return;
    ChildProxy proxy = proxies[i - body_count];
    Body body = bodies[proxy.body];
    CompoundChild child = compound_children[shapes[body.shape].child_offset + proxy.child];
    body.position.xyz += quat_rotate(body.orientation, child.position.xyz);
    body.orientation = quat_mul(body.orientation, child.orientation);
    body.shape = child.shape;
    placed_bodies[i] = body;
    float3 r0, r1, r2;
    quat_to_rows(body.orientation, &r0, &r1, &r2);
    write_world_aabb(body, shapes[body.shape], r0, r1, r2, hull_vertices, margin, &placed_aabbs[i]);
}

/* A body of a pair: its compound's children (first proxy, count) or itself (count 0). */
inline uint children_of(uint body, __global const Body* placed_bodies, __global const Shape* shapes,
                        __global const uint* first_proxy, uint* first)
{
    Shape s = shapes[placed_bodies[body].shape];
    if (s.type != RB_SHAPE_COMPOUND)
        return 0u;
    *first = first_proxy[body];
    return s.child_count;
}

<%def name="each_child_pair(emit)">\
    uint first_a = pair.a, first_b = pair.b;
    uint count_a = children_of(pair.a, placed_bodies, shapes, first_proxy, &first_a);
    uint count_b = children_of(pair.b, placed_bodies, shapes, first_proxy, &first_b);
    if (count_a == 0u && count_b == 0u) {
        uint first = pair.a, second = pair.b;
        ${emit}
    } else {
        /* a body without children stands for itself: one "child" */
        for (uint ka = 0; ka < max(count_a, 1u); ++ka) {
            uint first = first_a + ka;
            Aabb box_a = placed_aabbs[first];
            for (uint kb = 0; kb < max(count_b, 1u); ++kb) {
                uint second = first_b + kb;
                if (boxes_overlap(box_a, placed_aabbs[second])) {
                    ${emit}
                }
            }
        }
    }
</%def>

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void count_child_pairs(${signature("count_child_pairs")})
{
    uint i = get_global_id(0);
    if (i >= min(pair_count[0], pair_capacity))
        return;
    Pair pair = pairs[i];
    uint count = 0u;
${each_child_pair("++count;")}
    counts[i] = count;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void write_child_pairs(${signature("write_child_pairs")})
{
    uint i = get_global_id(0);
    if (i == 0) {  /* the capacity needed (0 when everything fits); then the count of the
                    * pairs stored, so that no later kernel reads or writes past the capacity
                    * (this kernel's other work-items do not read it) */
        uint found = out_count[0];
        status[status_word] = found > out_capacity ? found : 0u;
        if (found > out_capacity)
            out_count[0] = out_capacity;
    }
    if (i >= min(pair_count[0], pair_capacity))
        return;
    Pair pair = pairs[i];
    uint place = offsets[i];
${each_child_pair("if (place < out_capacity) { Pair p; p.a = first; p.b = second; p.sub = pair.sub; out_pairs[place] = p; } ++place;")}
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void resolve_child_manifolds(${signature("resolve_child_manifolds")})
{
    uint i = get_global_id(0);
    if (i >= min(manifold_count[0], manifold_capacity))
        return;
    ContactManifold m = manifolds[i];
    uint a = m.body_a, b = m.body_b;
    if (a < body_count && b < body_count)
        return;
    uint first = 0u, other = 0u;
    if (a >= body_count) {
        ChildProxy p = proxies[a - body_count];
        m.body_a = p.body;
        first = p.child;
    }
    if (b >= body_count) {
        ChildProxy p = proxies[b - body_count];
        m.body_b = p.body;
        if (a >= body_count)
            other = p.child;
        else
            first = p.child;
    }
    /* a triangle pair's sub-feature is 1 + the triangle already */
    m.sub = (m.sub != 0u ? m.sub : 1u) + (first << RB_SUB_CHILD_SHIFT) + other;
    manifolds[i].body_a = m.body_a;
    manifolds[i].body_b = m.body_b;
    manifolds[i].sub = m.sub;
}
