<%
    # the edge array each variant reads: unique directions, or edges with their faces
    edges_arg = "hull_edges" if edge_axes == "directions" else "hull_adjacency"
    edges_decl = ("__global const float4* hull_edges" if edge_axes == "directions"
                  else "__global const HullEdge* hull_adjacency")
%>/* Separating-axis test between convex shapes: ${first} (first) against ${second} (second).
 *
 * One work-item per queued pair; a work group is responsible for
 * ${work_group_size} consecutive entries of the kind's queue${" (the pair list: the world's only kind)" if direct else ""}. Candidate axes
 * are the first shape's outward face normals, the second's (negated), and
% if edge_axes == "directions":
 * the cross products of their unique edge directions (oriented whichever way
 * separates more).
% else:
 * the cross products of the edge pairs whose Gauss-map arcs intersect (the
 * pairs that form a face of the Minkowski difference A - B; any other pair
 * costs four dot products), oriented away from the first centre.
% endif
 * The axis of greatest separation is the contact normal
 * (least penetration). The test stops at the first axis that separates the
 * shapes by more than `margin`, and starts with the axis that was best for
 * this pair last step (the per-pair cache, keyed by the pair (a, b, sub)), which
 * is usually still separating. Pairs within the margin are appended, with
 * their axis and feature, to the clipping queue (group-aggregated atomics).
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "HullFace", "HullEdge", "SatCacheEntry", "SatResult")}

<%namespace name="shared" file="/pipeline/narrowphase/find_separating_axis.cl.mako"/>
<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>

${shared.definitions()}

/* The two shapes of a pair, placed in the world. */
typedef struct {
    Placement a, b;
    Shape shape_a, shape_b;
} ConvexPair;

% if "box" in (first, second):
/* Extent of a box along a world axis: centre +- |axis in box frame| . half extents. */
inline float2 box_interval(const Placement* p, Shape s, float3 axis)
{
    float reach = dot3(abs3(rotate_to_local(p, axis)), s.extents.xyz);
    float centre = dot3(axis, p->position);
    return (float2)(centre - reach, centre + reach);
}

% endif
% if "hull" in (first, second):
/* Extent of a hull's vertices along a world axis. */
inline float2 hull_interval(const Placement* p, Shape s, __global const float4* hull_vertices, float3 axis)
{
    float3 local_axis = rotate_to_local(p, axis);
    float lo = INFINITY, hi = -INFINITY;
    for (uint v = 0; v < s.vertex_count; ++v) {
        float d = dot3(local_axis, hull_vertices[s.vertex_offset + v].xyz);
        lo = min1(lo, d);
        hi = max1(hi, d);
    }
    float centre = dot3(axis, p->position);
    return (float2)(lo + centre, hi + centre);
}

% endif
<%def name="interval_call(kind, placement, shape)">\
% if kind == "box":
box_interval(${placement}, ${shape}, axis)\
% else:
hull_interval(${placement}, ${shape}, hull_vertices, axis)\
% endif
</%def>\
inline float2 interval_first(const ConvexPair* g, __global const float4* hull_vertices, float3 axis)
{
    return ${interval_call(first, "&g->a", "g->shape_a")};
}

inline float2 interval_second(const ConvexPair* g, __global const float4* hull_vertices, float3 axis)
{
    return ${interval_call(second, "&g->b", "g->shape_b")};
}

/* Along an unnormalised axis, oriented whichever way separates more:
 * min(second) - max(first) or min(first) - max(second). w = -INFINITY for a
 * degenerate axis (parallel edges). */
inline float4 interval_separation(const ConvexPair* g, __global const float4* hull_vertices, float3 axis)
{
    float sin2 = dot3(axis, axis);
    if (sin2 < PARALLEL_SIN2)
        return (float4)(axis, -INFINITY);
    axis *= 1.0f / sqrt1(sin2);
    float2 ia = interval_first(g, hull_vertices, axis);
    float2 ib = interval_second(g, hull_vertices, axis);
    float forward = ib.x - ia.y, backward = ia.x - ib.y;
    return forward >= backward ? (float4)(axis, forward) : (float4)(-axis, backward);
}

/* Along face f of the first shape: xyz the axis (first to second), w the separation. */
inline float4 first_face_separation(const ConvexPair* g, uint f, __global const HullFace* hull_faces,
                                    __global const float4* hull_vertices)
{
    float4 plane = plane_to_world(&g->a, hull_faces[g->shape_a.face_offset + f].plane);
    return (float4)(plane.xyz, interval_second(g, hull_vertices, plane.xyz).x - plane.w);
}

/* Along face f of the second shape (the axis is minus its outward normal). */
inline float4 second_face_separation(const ConvexPair* g, uint f, __global const HullFace* hull_faces,
                                     __global const float4* hull_vertices)
{
    float4 plane = plane_to_world(&g->b, hull_faces[g->shape_b.face_offset + f].plane);
    return (float4)(-plane.xyz, interval_first(g, hull_vertices, plane.xyz).x - plane.w);
}

% if edge_axes == "directions":
/* Along edge direction i of the first shape crossed with j of the second;
 * w = -INFINITY for parallel edges (no axis). */
inline float4 edge_separation(const ConvexPair* g, uint i, uint j, __global const float4* hull_edges,
                              __global const float4* hull_vertices)
{
    float3 ea = rotate_to_world(&g->a, hull_edges[g->shape_a.edge_offset + i].xyz);
    float3 eb = rotate_to_world(&g->b, hull_edges[g->shape_b.edge_offset + j].xyz);
    return interval_separation(g, hull_vertices, cross3(ea, eb));
}

% else:
/* Do the Gauss-map arcs (a, b) and (c, d) intersect? (a, b: the face normals
 * of an edge of A; c, d: the negated face normals of an edge of B.) Then the
 * edge pair forms a face of the Minkowski difference and is a candidate axis.
 * c and d must lie on both sides of the plane of arc ab, a and b on both
 * sides of the plane of arc cd, and the arcs on the same hemisphere. */
inline bool arcs_intersect(float3 a, float3 b, float3 c, float3 d)
{
    float3 b_x_a = cross3(b, a), d_x_c = cross3(d, c);
    float cba = dot3(c, b_x_a), dba = dot3(d, b_x_a);
    float adc = dot3(a, d_x_c), bdc = dot3(b, d_x_c);
    return cba * dba < 0.0f && adc * bdc < 0.0f && cba * bdc > 0.0f;
}

/* An edge of a hull in the world: its start, its direction and its two face normals. */
inline void world_edge(const Placement* p, Shape s, HullEdge e, __global const float4* hull_vertices,
                       __global const HullFace* hull_faces, float3* start, float3* direction,
                       float3* normal0, float3* normal1)
{
    *start = point_to_world(p, hull_vertices[s.vertex_offset + e.v0].xyz);
    *direction = point_to_world(p, hull_vertices[s.vertex_offset + e.v1].xyz) - *start;
    *normal0 = rotate_to_world(p, hull_faces[s.face_offset + e.f0].plane.xyz);
    *normal1 = rotate_to_world(p, hull_faces[s.face_offset + e.f1].plane.xyz);
}

/* Along the cross product of an edge pair that forms a Minkowski face, oriented
 * away from the first centre: the separation is the distance between the edge
 * lines (w = -INFINITY for parallel edges). */
inline float4 edge_pair_separation(float3 a0, float3 ea, float3 b0, float3 eb, float3 centre_a)
{
    float3 axis = cross3(ea, eb);
    float sin2 = dot3(axis, axis);
    if (sin2 < PARALLEL_SIN2 * dot3(ea, ea) * dot3(eb, eb))
        return (float4)(axis, -INFINITY);
    axis *= 1.0f / sqrt1(sin2);
    if (dot3(axis, a0 - centre_a) < 0.0f)
        axis = -axis;
    return (float4)(axis, dot3(axis, b0 - a0));
}

/* Along the cross product of edge i of the first shape and edge j of the second,
 * measured on the shapes' extents (valid for any edge pair: used for last
 * step's axis, which may no longer be a Minkowski face). */
inline float4 edge_pair_interval_separation(const ConvexPair* g, uint i, uint j,
                                            __global const HullEdge* hull_adjacency,
                                            __global const HullFace* hull_faces,
                                            __global const float4* hull_vertices)
{
    float3 a0, ea, b0, eb, n0, n1;
    world_edge(&g->a, g->shape_a, hull_adjacency[g->shape_a.adjacency_offset + i], hull_vertices,
               hull_faces, &a0, &ea, &n0, &n1);
    world_edge(&g->b, g->shape_b, hull_adjacency[g->shape_b.adjacency_offset + j], hull_vertices,
               hull_faces, &b0, &eb, &n0, &n1);
    return interval_separation(g, hull_vertices, cross3(normalize3(ea), normalize3(eb)));
}

% endif
/* Separation along a feature code: face of the first shape, face of the second, or edge pair. */
inline float4 feature_separation(const ConvexPair* g, uint feature, __global const HullFace* hull_faces,
                                 ${edges_decl}, __global const float4* hull_vertices)
{
    uint fa = g->shape_a.face_count, fb = g->shape_b.face_count;
% if edge_axes == "directions":
    if (feature < fa)
        return first_face_separation(g, feature, hull_faces, hull_vertices);
    if (feature < fa + fb)
        return second_face_separation(g, feature - fa, hull_faces, hull_vertices);
    uint e = feature - fa - fb;
    return edge_separation(g, e / g->shape_b.edge_count, e % g->shape_b.edge_count, hull_edges, hull_vertices);
% else:
    if (feature & (uint)RB_SAT_EDGE_PAIR) {
        uint e = feature & ~(uint)RB_SAT_EDGE_PAIR;
        uint eb = g->shape_b.adjacency_count;
        return edge_pair_interval_separation(g, e / eb, e % eb, hull_adjacency, hull_faces, hull_vertices);
    }
    if (feature < fa)
        return first_face_separation(g, feature, hull_faces, hull_vertices);
    return second_face_separation(g, feature - fa, hull_faces, hull_vertices);
% endif
}

/* True when the shapes are within `margin`: then *best is the axis of least
 * penetration (w: separation) and *best_feature its code. */
inline bool separating_axis_test(const ConvexPair* g, Pair pair, __global SatCacheEntry* entry,
                                 __global const HullFace* hull_faces,
                                 ${edges_decl},
                                 __global const float4* hull_vertices, float margin,
                                 float4* best, uint* best_feature)
{
    SatCacheEntry cached = *entry;
    if (cached_axis_of(cached, pair)) {
        float4 s = feature_separation(g, cached.feature, hull_faces, ${edges_arg}, hull_vertices);
        if (s.w > margin)
            return false;  /* last step's axis still separates: the entry stays */
    }
    uint fa = g->shape_a.face_count, fb = g->shape_b.face_count;

    float4 face_a = (float4)(0.0f, 0.0f, 0.0f, -INFINITY);
    uint face_a_feature = 0;
    for (uint f = 0; f < fa; ++f) {
        float4 s = first_face_separation(g, f, hull_faces, hull_vertices);
        if (s.w > margin) {
            remember_axis(entry, pair, f);
            return false;
        }
        if (s.w > face_a.w)
            face_a = s, face_a_feature = f;
    }
    float4 face_b = (float4)(0.0f, 0.0f, 0.0f, -INFINITY);
    uint face_b_feature = fa;
    for (uint f = 0; f < fb; ++f) {
        float4 s = second_face_separation(g, f, hull_faces, hull_vertices);
        if (s.w > margin) {
            remember_axis(entry, pair, fa + f);
            return false;
        }
        if (s.w > face_b.w)
            face_b = s, face_b_feature = fa + f;
    }
    float4 edge = (float4)(0.0f, 0.0f, 0.0f, -INFINITY);
% if edge_axes == "directions":
    uint ea = g->shape_a.edge_count, eb = g->shape_b.edge_count;
    uint edge_feature = fa + fb;
    for (uint i = 0; i < ea; ++i) {
        for (uint j = 0; j < eb; ++j) {
            float4 s = edge_separation(g, i, j, hull_edges, hull_vertices);
            if (s.w > margin) {
                remember_axis(entry, pair, fa + fb + i * eb + j);
                return false;
            }
            if (s.w > edge.w)
                edge = s, edge_feature = fa + fb + i * eb + j;
        }
    }
% else:
    uint ea = g->shape_a.adjacency_count, eb = g->shape_b.adjacency_count;
    uint edge_feature = RB_SAT_EDGE_PAIR;
    /* in the second shape's frame, its edges are read as stored: no transform in the inner loop */
    __global const float4* vertices_b = hull_vertices + g->shape_b.vertex_offset;
    __global const HullFace* faces_b = hull_faces + g->shape_b.face_offset;
    __global const HullEdge* edges_b = hull_adjacency + g->shape_b.adjacency_offset;
    float3 centre_a = point_to_local(&g->b, g->a.position);
    for (uint i = 0; i < ea; ++i) {
        float3 a0, dir_a, na0, na1;
        world_edge(&g->a, g->shape_a, hull_adjacency[g->shape_a.adjacency_offset + i], hull_vertices,
                   hull_faces, &a0, &dir_a, &na0, &na1);
        a0 = point_to_local(&g->b, a0);
        dir_a = rotate_to_local(&g->b, dir_a);
        na0 = rotate_to_local(&g->b, na0);
        na1 = rotate_to_local(&g->b, na1);
        for (uint j = 0; j < eb; ++j) {
            HullEdge e = edges_b[j];
            if (!arcs_intersect(na0, na1, -faces_b[e.f0].plane.xyz, -faces_b[e.f1].plane.xyz))
                continue;
            float3 b0 = vertices_b[e.v0].xyz;
            float4 s = edge_pair_separation(a0, dir_a, b0, vertices_b[e.v1].xyz - b0, centre_a);
            uint code = (uint)RB_SAT_EDGE_PAIR | (i * eb + j);
            if (s.w > margin) {
                remember_axis(entry, pair, code);
                return false;
            }
            if (s.w > edge.w)
                edge = s, edge_feature = code;
        }
    }
    edge.xyz = rotate_to_world(&g->b, edge.xyz);
% endif
    *best = face_a, *best_feature = face_a_feature;
    if (face_b.w > face_a.w + FACE_TOLERANCE)
        *best = face_b, *best_feature = face_b_feature;
    if (edge.w > max1(face_a.w, face_b.w) + EDGE_TOLERANCE)
        *best = edge, *best_feature = edge_feature;
    remember_axis(entry, pair, *best_feature);
    return true;
}

<%call expr="shared.find_separating_axis(shape_arrays=(
        '__global const float4* hull_vertices', '__global const HullFace* hull_faces', edges_decl))">\
        ConvexPair g;
        g.a = placement_of(a);
        g.b = placement_of(b);
        g.shape_a = shapes[a.shape];
        g.shape_b = shapes[b.shape];
        touching = separating_axis_test(&g, pairs[q.index], &cache[q.index], hull_faces, ${edges_arg},
                                        hull_vertices, pair_reach, &axis, &feature);
</%call>
