<% max_clip = 2 * max_face_vertices %>\
/* Contact points of convex pairs that passed the separating-axis test.
 *
 * clip_incident_face: one work-item per separating-axis result; a work group
 * is responsible for ${work_group_size} consecutive results. For a face axis
 * the face is the reference face, the incident face is the other shape's face
 * most antiparallel to it; the incident polygon is clipped against the
 * reference face's side planes (Sutherland-Hodgman) and the points at most
 * `margin` above the reference plane are kept (up to ${max_clip} per pair:
 * faces have at most ${max_face_vertices} vertices). For an edge-edge axis,
 * the closest points of the two supporting edges give one point.
 *
 * Reduction: at most four of the clipped points are kept (the deepest; the
 * farthest from it in the contact plane; the extremes on both sides of the
 * line through those two) and the manifold is stored in the pair's slot.
 * The reduction works on the clipped points in private memory, so the points
 * never make a round trip through global memory.
 *
 * Feature ids: face contacts are reference face | incident face << 11 |
 * point << 22 | (reference on the second shape) << 29, where point is the
 * incident vertex (< 32) or 32 + 2 * the reference edge that clipped it
 * (+ 1 where the incident boundary enters that edge's side plane), or 127
 * for the fallback when nothing survives the clipping (the incident shape's
 * deepest vertex: deep, off-centre overlaps); edge
 * contacts are 1 << 31 | first edge << 15 | second edge.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "HullFace", "HullEdge", "SatResult", "ContactManifold")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>
<%include file="/pipeline/narrowphase/store_manifold.cl.mako"/>
<%include file="/pipeline/narrowphase/segments.cl.mako"/>
<%namespace name="polygons" file="/pipeline/narrowphase/polygons.cl.mako"/>

#define MAX_CLIP_POINTS ${max_clip}
#define CLIPPED_BY_EDGE 32u
#define SUPPORT_VERTEX 127u
#define REFERENCE_ON_SECOND (1u << 29)
#define EDGE_CONTACT (1u << 31)
/* Polygon edges this close to a direction (cosine) count as parallel to it. */
#define PARALLEL_COS 0.9999f

/* World position of vertex k of a polygon. */
inline float3 polygon_vertex(const Placement* p, Shape s, HullFace face, uint k,
                             __global const float4* hull_vertices, __global const uint* face_indices)
{
    return point_to_world(p, hull_vertices[s.vertex_offset + face_indices[face.index_offset + k]].xyz);
}

${polygons.clip_polygon()}

/* Face contact: clip the incident face of `incident` against reference face f of
 * `reference`; write points on the second shape with their separation. */
inline uint clip_faces(const Placement* reference, Shape ref_shape, uint f,
                       const Placement* incident, Shape inc_shape, bool reference_is_second,
                       __global const float4* hull_vertices, __global const HullFace* hull_faces,
                       __global const uint* face_indices, float margin,
                       float4* out_points, uint* out_features)
{
    HullFace ref_face = hull_faces[ref_shape.face_offset + f];
    float4 ref_plane = plane_to_world(reference, ref_face.plane);

    /* the incident face: most antiparallel to the reference normal */
    float3 ref_normal_in_incident = rotate_to_local(incident, ref_plane.xyz);
    uint inc = 0;
    float lowest = INFINITY;
    for (uint g = 0; g < inc_shape.face_count; ++g) {
        float d = dot3(hull_faces[inc_shape.face_offset + g].plane.xyz, ref_normal_in_incident);
        if (d < lowest)
            lowest = d, inc = g;
    }
    HullFace inc_face = hull_faces[inc_shape.face_offset + inc];

    /* the polygon being clipped alternates between two buffers */
    float3 polygon[MAX_CLIP_POINTS], clipped[MAX_CLIP_POINTS];
    uint ids[MAX_CLIP_POINTS], clipped_ids[MAX_CLIP_POINTS];
    uint n = inc_face.index_count;
    if (n > ${max_face_vertices}u)
        n = ${max_face_vertices}u;  /* the host sizes the buffers for the largest face */
    for (uint k = 0; k < n; ++k) {
        polygon[k] = polygon_vertex(incident, inc_shape, inc_face, k, hull_vertices, face_indices);
        ids[k] = k;
    }

    /* side planes of the reference polygon: cross(edge, normal) points outwards */
    float3 prev = polygon_vertex(reference, ref_shape, ref_face, ref_face.index_count - 1,
                                 hull_vertices, face_indices);
    bool in_clipped = false;  /* where the last clipping left the polygon */
    for (uint j = 0; j < ref_face.index_count && n > 0; ++j) {
        float3 cur = polygon_vertex(reference, ref_shape, ref_face, j, hull_vertices, face_indices);
        float3 side = cross3(cur - prev, ref_plane.xyz);
        if (in_clipped)
            n = clip_polygon(clipped, clipped_ids, n, side, dot3(side, prev),
                             CLIPPED_BY_EDGE + 2u * j, polygon, ids);
        else
            n = clip_polygon(polygon, ids, n, side, dot3(side, prev), CLIPPED_BY_EDGE + 2u * j,
                             clipped, clipped_ids);
        in_clipped = !in_clipped;
        prev = cur;
    }
    if (in_clipped)
        for (uint k = 0; k < n; ++k)
            polygon[k] = clipped[k], ids[k] = clipped_ids[k];

    /* keep what lies at most `margin` above the reference face */
    uint face_code = (f & 0x7FFu) | ((inc & 0x7FFu) << 11) | (reference_is_second ? REFERENCE_ON_SECOND : 0u);
    uint count = 0;
    for (uint k = 0; k < n; ++k) {
        float s = dot3(ref_plane.xyz, polygon[k]) - ref_plane.w;
        if (s > margin)
            continue;
        /* an incident point on the first shape moves onto the second's reference plane */
        float3 on_second = reference_is_second ? polygon[k] - ref_plane.xyz * s : polygon[k];
        out_points[count] = (float4)(on_second, s);
        out_features[count++] = face_code | (ids[k] << 22);
    }
    if (count == 0) {
        /* the incident face lies beside the reference face (deep, off-centre overlap):
         * fall back to the incident shape's deepest vertex */
        float3 deepest = (float3)(0.0f);
        float lowest_s = INFINITY;
        for (uint v = 0; v < inc_shape.vertex_count; ++v) {
            float3 p = point_to_world(incident, hull_vertices[inc_shape.vertex_offset + v].xyz);
            float s = dot3(ref_plane.xyz, p) - ref_plane.w;
            if (s < lowest_s)
                lowest_s = s, deepest = p;
        }
        if (lowest_s <= margin) {
            float3 on_second = reference_is_second ? deepest - ref_plane.xyz * lowest_s : deepest;
            out_points[0] = (float4)(on_second, lowest_s);
            out_features[0] = face_code | (SUPPORT_VERTEX << 22);
            count = 1;
        }
    }
    return count;
}

/* The polygon edge of a shape parallel to `direction` (local) that reaches
 * farthest along `towards` (world); its end points in the world. */
inline void supporting_edge(const Placement* p, Shape s, float3 direction, float3 towards,
                            __global const float4* hull_vertices, __global const HullFace* hull_faces,
                            __global const uint* face_indices, float3* e0, float3* e1)
{
    float3 local_towards = rotate_to_local(p, towards);
    float best = -INFINITY;
    float3 best0 = (float3)(0.0f), best1 = (float3)(0.0f);
    for (uint f = 0; f < s.face_count; ++f) {
        HullFace face = hull_faces[s.face_offset + f];
        float3 prev = hull_vertices[s.vertex_offset + face_indices[face.index_offset + face.index_count - 1]].xyz;
        for (uint k = 0; k < face.index_count; ++k) {
            float3 cur = hull_vertices[s.vertex_offset + face_indices[face.index_offset + k]].xyz;
            float3 edge = cur - prev;
            float reach = dot3(local_towards, cur + prev);
            if (abs1(dot3(edge, direction)) > PARALLEL_COS * length3(edge) && reach > best)
                best = reach, best0 = prev, best1 = cur;
            prev = cur;
        }
    }
    *e0 = point_to_world(p, best0);
    *e1 = point_to_world(p, best1);
}

${polygons.choose_contacts()}

/* Reduce a pair's candidates to at most four points and store its manifold. */
inline void reduce_and_store(SatResult r, const float4* candidates, const uint* candidate_features,
                             uint n, __global const Pair* pairs, __global ContactManifold* slots,
                             __global uint* contact_flags, __global uint* tile_counts)
{
    if (n == 0)
        return;
    uint chosen[4];
    uint count = choose_contacts(candidates, n, r.axis.xyz, chosen);
    float4 points[4];
    uint features[4];
    for (uint k = 0; k < count; ++k) {
        points[k] = candidates[chosen[k]];
        features[k] = candidate_features[chosen[k]];
    }
    store_manifold(slots, contact_flags, tile_counts, decode_queue_entry(r.pair, pairs),
                   r.axis.xyz, points, features, count);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void clip_incident_face(__global const Pair* pairs,
                        __global const Body* bodies,
                        __global const Shape* shapes,
                        __global const float4* hull_vertices,
                        __global const HullFace* hull_faces,
                        __global const uint* face_indices,
                        __global const float4* hull_edges,
                        __global const HullEdge* hull_adjacency,
                        __global const SatResult* results,
                        __global const uint* result_count,
                        __global ContactManifold* slots,
                        __global uint* contact_flags,
                        __global uint* tile_counts,
                        const float margin)
{
    uint slot = get_global_id(0);
    if (slot >= result_count[0])
        return;
    SatResult r = results[slot];
    QueuedPair q = decode_queue_entry(r.pair, pairs);
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    Shape sa = shapes[a.shape], sb = shapes[b.shape];
    Placement pa = placement_of(a), pb = placement_of(b);
    float4 out_points[MAX_CLIP_POINTS];
    uint out_features[MAX_CLIP_POINTS];

    uint count;
    if (r.feature < sa.face_count) {
        count = clip_faces(&pa, sa, r.feature, &pb, sb, false, hull_vertices, hull_faces,
                           face_indices, pair_reach, out_points, out_features);
    } else if (r.feature < sa.face_count + sb.face_count) {
        count = clip_faces(&pb, sb, r.feature - sa.face_count, &pa, sa, true, hull_vertices,
                           hull_faces, face_indices, pair_reach, out_points, out_features);
    } else if (r.feature & (uint)RB_SAT_EDGE_PAIR) {
        /* an edge pair of the Gauss-map test: the edges themselves are known */
        uint e = r.feature & ~(uint)RB_SAT_EDGE_PAIR;
        uint i = e / sb.adjacency_count, j = e % sb.adjacency_count;
        HullEdge edge_a = hull_adjacency[sa.adjacency_offset + i];
        HullEdge edge_b = hull_adjacency[sb.adjacency_offset + j];
        float3 a0 = point_to_world(&pa, hull_vertices[sa.vertex_offset + edge_a.v0].xyz);
        float3 a1 = point_to_world(&pa, hull_vertices[sa.vertex_offset + edge_a.v1].xyz);
        float3 b0 = point_to_world(&pb, hull_vertices[sb.vertex_offset + edge_b.v0].xyz);
        float3 b1 = point_to_world(&pb, hull_vertices[sb.vertex_offset + edge_b.v1].xyz);
        float3 on_a, on_b;
        closest_points_of_segments(a0, a1, b0, b1, &on_a, &on_b);
        out_points[0] = (float4)(on_b, r.axis.w);
        out_features[0] = EDGE_CONTACT | ((i & 0x7FFFu) << 15) | (j & 0x7FFFu);
        count = 1;
    } else {
        /* an edge-direction pair: find the supporting edges along the axis */
        uint e = r.feature - sa.face_count - sb.face_count;
        uint i = e / sb.edge_count, j = e % sb.edge_count;
        float3 a0, a1, b0, b1;
        supporting_edge(&pa, sa, hull_edges[sa.edge_offset + i].xyz, r.axis.xyz, hull_vertices,
                        hull_faces, face_indices, &a0, &a1);
        supporting_edge(&pb, sb, hull_edges[sb.edge_offset + j].xyz, -r.axis.xyz, hull_vertices,
                        hull_faces, face_indices, &b0, &b1);
        float3 on_a, on_b;
        closest_points_of_segments(a0, a1, b0, b1, &on_a, &on_b);
        out_points[0] = (float4)(on_b, r.axis.w);
        out_features[0] = EDGE_CONTACT | ((i & 0x7FFFu) << 15) | (j & 0x7FFFu);
        count = 1;
    }
    reduce_and_store(r, out_points, out_features, count, pairs, slots, contact_flags, tile_counts);
}
