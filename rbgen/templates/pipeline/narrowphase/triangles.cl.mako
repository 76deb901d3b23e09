<% max_clip = max_face_vertices + 3 %>\
/* Narrowphase kernels for a body against one triangle of a static mesh: ${", ".join(kinds)}.
 *
 * One work-item per queued pair; a work group is responsible for ${work_group_size}
 * consecutive entries of the kind's queue. The midphase made the pairs (the body, the
 * mesh, sub-feature 1 + the triangle); everything is computed in the mesh's frame, where
 * the triangles are stored, and the manifold stored in the world. The triangle is
 * two-sided, and a contact whose nearest triangle feature is inactive takes the face
 * normal (triangle.cl.mako), so a shape crossing the seams of a flat surface does not bump.
 *
 * sphere_triangle: the triangle's closest point to the centre.
 * capsule_triangle: the closest points of the segment and the triangle; on the face
 * normal, the part of the segment over the triangle gives up to two points (a capsule
 * lying on it).
 * box_triangle and hull_triangle (kernel convex_triangle; each in a program of its own,
 * so that a work group holds one kind of shape): a separating-axis test with the
 * triangle as a two-sided polygon: its normal both ways, the shape's faces, and edge
 * pairs (a box: the triangle's edges against its three edge directions, measured on
 * both extents; a hull: only the pairs of a hull edge and a triangle edge that form a
 * face of the Minkowski difference, found on the Gauss map and measured between the
 * edges, which scales to large hulls). When the best axis's nearest triangle feature
 * is inactive, or when it penetrates and would push a shape whose centre lies over the
 * triangle through to the side its centre is not on, the triangle's normal (facing the
 * centre) is used instead (the part of the shape over the triangle; what lies beyond
 * that feature is its neighbour's). A face axis clips the other
 * side's polygon against the reference face's side planes (Sutherland-Hodgman; up to
 * ${max_clip} points: faces have at most ${max_face_vertices} vertices), an edge axis gives
 * the closest points of the two edges; at most four points are kept (the deepest, the
 * farthest from it, the extremes across).
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "HullFace", "HullEdge", "MeshTriangle", "ContactManifold")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>
<%include file="/pipeline/narrowphase/store_manifold.cl.mako"/>
<%include file="/pipeline/narrowphase/segments.cl.mako"/>
<%include file="/pipeline/narrowphase/triangle.cl.mako"/>
<%namespace name="polygons" file="/pipeline/narrowphase/polygons.cl.mako"/>

/* Below this distance a closest-point normal is noise: the face normal is used. */
#define TOUCHING 1e-6f

<%def name="queued_pair()">\
    uint slot = get_global_id(0);
    if (slot >= queue_counts[kind])
        return;
    QueuedPair q = decode_queue_entry(queues[kind * pair_capacity + slot], pairs);
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    Shape mesh = shapes[b.shape];
    Triangle tri = load_triangle(mesh, q.sub, mesh_triangles, mesh_vertices);
    Placement frame = placement_of(b);\
</%def>\
<%def name="queue_args(kernel)"><% pad = " " * len("void " + kernel + "(") %>\
__global const Pair* pairs,
${pad}__global const Body* bodies,
${pad}__global const Shape* shapes,
${pad}__global const uint* queues,
${pad}__global const uint* queue_counts,
${pad}const uint pair_capacity,
${pad}const uint kind,
${pad}__global ContactManifold* slots,
${pad}__global uint* contact_flags,
${pad}__global uint* tile_counts,
${pad}const float margin,
${pad}__global const MeshTriangle* mesh_triangles,
${pad}__global const float4* mesh_vertices\
</%def>
/* The face normal towards the side of the triangle `p` is on (+normal on the plane). */
inline float facing(const Triangle* t, float3 p)
{
    return dot3(t->normal, p - t->v[0]) >= 0.0f ? 1.0f : -1.0f;
}

/* Store points and normal computed in the mesh frame (normal from first to second). */
inline void store_in_world(__global ContactManifold* slots, __global uint* contact_flags,
                           __global uint* tile_counts, QueuedPair q, const Placement* frame,
                           float3 normal, float4* points, const uint* features, uint count)
{
    for (uint k = 0; k < count; ++k)
        points[k].xyz = point_to_world(frame, points[k].xyz);
    store_manifold(slots, contact_flags, tile_counts, q, rotate_to_world(frame, normal), points,
                   features, count);
}
% if "sphere_triangle" in kinds:

/* Sphere (first) against a triangle (second): one point, the triangle's closest point to
 * the centre; on an inactive feature, the centre's projection on the triangle's plane
 * with the face normal. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sphere_triangle(${queue_args("sphere_triangle")})
{
${queued_pair()}
    float radius = shapes[a.shape].extents.x;
    float3 c = point_to_local(&frame, a.position.xyz);
    uint feature;
    float3 p = closest_on_triangle(&tri, c, &feature);
    float3 d = p - c;
    float distance = length3(d);
    if (distance - radius > pair_reach)
        return;
    float3 normal;
    float4 point;
    if (feature_active(tri.edges, feature) && feature != TRIANGLE_FACE && distance > TOUCHING) {
        normal = d / distance;
        point = (float4)(p, distance - radius);
    } else {
        float height = dot3(tri.normal, c - tri.v[0]);
        normal = -facing(&tri, c) * tri.normal;
        point = (float4)(c - tri.normal * height, fabs(height) - radius);
        if (point.w > pair_reach)
            return;
    }
    store_in_world(slots, contact_flags, tile_counts, q, &frame, normal, &point, &feature, 1u);
}
% endif
% if "capsule_triangle" in kinds:

/* The closest points of a segment and a triangle; returns the squared distance. */
inline float closest_segment_triangle(const Triangle* t, float3 s0, float3 s1, float3* on_segment,
                                      float3* on_triangle, uint* feature)
{
    /* crossing the triangle: distance 0 where the segment meets its plane */
    float h0 = dot3(t->normal, s0 - t->v[0]), h1 = dot3(t->normal, s1 - t->v[0]);
    if ((h0 <= 0.0f) != (h1 <= 0.0f)) {
        float3 hit = s0 + (s1 - s0) * (h0 / (h0 - h1));
        uint f;
        float3 p = closest_on_triangle(t, hit, &f);
        if (f == TRIANGLE_FACE) {
            *on_segment = *on_triangle = p;
            *feature = TRIANGLE_FACE;
            return 0.0f;
        }
    }
    float best = INFINITY;
    float3 ends[2] = {s0, s1};
    for (uint k = 0; k < 2u; ++k) {
        uint f;
        float3 p = closest_on_triangle(t, ends[k], &f);
        float d2 = dot3(p - ends[k], p - ends[k]);
        if (d2 < best)
            best = d2, *on_segment = ends[k], *on_triangle = p, *feature = f;
    }
    for (uint k = 0; k < 3u; ++k) {
        float3 p, e;
        closest_points_of_segments(s0, s1, t->v[k], t->v[(k + 1u) % 3u], &p, &e);
        float d2 = dot3(p - e, p - e);
        if (d2 < best)
            best = d2, *on_segment = p, *on_triangle = e, *feature = TRIANGLE_EDGE + k;
    }
    return best;
}

/* Capsule (first) against a triangle (second): the closest points; on the face normal,
 * the ends of the part of the segment over the triangle. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void capsule_triangle(${queue_args("capsule_triangle")})
{
${queued_pair()}
    float4 capsule = shapes[a.shape].extents;  /* radius, half height */
    float radius = capsule.x;
    float3 half_axis = rotate_to_local(&frame, quat_rotate(a.orientation, (float3)(0.0f, capsule.y, 0.0f)));
    float3 centre = point_to_local(&frame, a.position.xyz);
    float3 s0 = centre - half_axis, s1 = centre + half_axis;
    float3 on_segment, on_triangle;
    uint feature;
    float distance = sqrt1(closest_segment_triangle(&tri, s0, s1, &on_segment, &on_triangle, &feature));
    if (distance - radius > pair_reach)
        return;
    float4 points[2];
    uint features[2];
    uint count = 0;
    float3 normal;
    if (feature_active(tri.edges, feature) && feature != TRIANGLE_FACE && distance > TOUCHING) {
        normal = (on_triangle - on_segment) / distance;
        points[0] = (float4)(on_triangle, distance - radius);
        features[0] = feature;
        count = 1;
    } else {
        float side = facing(&tri, centre);
        normal = -side * tri.normal;
        float3 c0 = s0, c1 = s1;
        if (clip_segment_to_triangle(&tri, &c0, &c1)) {
            float3 ends[2] = {c0, c1};
            for (uint k = 0; k < (dot3(c1 - c0, c1 - c0) > 1e-12f ? 2u : 1u); ++k) {
                float height = dot3(tri.normal, ends[k] - tri.v[0]);
                if (side * height - radius > pair_reach)
                    continue;
                points[count] = (float4)(ends[k] - tri.normal * height, side * height - radius);
                features[count++] = 8u + k;
            }
        }
        if (count == 0) {
            /* beside the triangle (over an inactive edge): the closest point on the face normal */
            float height = side * dot3(tri.normal, on_segment - on_triangle);
            if (height - radius > pair_reach)
                return;
            points[0] = (float4)(on_triangle, height - radius);
            features[0] = feature;
            count = 1;
        }
    }
    store_in_world(slots, contact_flags, tile_counts, q, &frame, normal, points, features, count);
}
% endif
% if convex != "none":

#define MAX_CLIP_POINTS ${max_clip}
/* The shape's face axis wins over the triangle's normal, and an edge axis over both,
 * only when better by these distances (stable choices, as in the convex-convex test). */
#define FACE_TOLERANCE 1e-4f
#define EDGE_TOLERANCE 1e-4f
#define PARALLEL_SIN2 1e-8f
#define REFERENCE_ON_SHAPE (1u << 30)
#define EDGE_CONTACT (1u << 31)
#define CLIPPED_BY_EDGE 32u

${polygons.clip_polygon()}

${polygons.choose_contacts()}

/* Extent of the ${convex} (placed by `shape_in_mesh`) along a mesh-frame axis. */
inline float2 convex_interval(const Placement* shape_in_mesh, Shape s, __global const float4* hull_vertices,
                              float3 axis)
{
    float3 local_axis = rotate_to_local(shape_in_mesh, axis);
    float centre = dot3(axis, shape_in_mesh->position);
% if convex == "box":
    float reach = dot3(abs3(local_axis), s.extents.xyz);
    return (float2)(centre - reach, centre + reach);
% else:
    float lo = INFINITY, hi = -INFINITY;
    for (uint v = 0; v < s.vertex_count; ++v) {
        float d = dot3(local_axis, hull_vertices[s.vertex_offset + v].xyz);
        lo = min1(lo, d);
        hi = max1(hi, d);
    }
    return (float2)(lo + centre, hi + centre);
% endif
}

/* Vertex k of a face of the shape, in the mesh frame. */
inline float3 face_vertex(const Placement* shape_in_mesh, Shape s, HullFace face, uint k,
                          __global const float4* hull_vertices, __global const uint* face_indices)
{
    return point_to_world(shape_in_mesh, hull_vertices[s.vertex_offset + face_indices[face.index_offset + k]].xyz);
}

% if convex == "box":
/* The shape's edge parallel to `direction` (shape frame) that reaches farthest along
 * `towards` (mesh frame); its end points in the mesh frame. */
inline void shape_supporting_edge(const Placement* shape_in_mesh, Shape s, float3 direction, float3 towards,
                                  __global const float4* hull_vertices, __global const HullFace* hull_faces,
                                  __global const uint* face_indices, float3* e0, float3* e1)
{
    float3 local_towards = rotate_to_local(shape_in_mesh, towards);
    float best = -INFINITY;
    float3 best0 = (float3)(0.0f), best1 = (float3)(0.0f);
    for (uint f = 0; f < s.face_count; ++f) {
        HullFace face = hull_faces[s.face_offset + f];
        float3 prev = hull_vertices[s.vertex_offset + face_indices[face.index_offset + face.index_count - 1]].xyz;
        for (uint k = 0; k < face.index_count; ++k) {
            float3 cur = hull_vertices[s.vertex_offset + face_indices[face.index_offset + k]].xyz;
            float3 edge = cur - prev;
            float reach = dot3(local_towards, cur + prev);
            if (abs1(dot3(edge, direction)) > 0.9999f * length3(edge) * length3(direction) && reach > best)
                best = reach, best0 = prev, best1 = cur;
            prev = cur;
        }
    }
    *e0 = point_to_world(shape_in_mesh, best0);
    *e1 = point_to_world(shape_in_mesh, best1);
}
% endif

/* ${"Box" if convex == "box" else "Hull"} (first) against a triangle (second); see the header. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void convex_triangle(${queue_args("convex_triangle")},
                     __global const float4* hull_vertices,
                     __global const HullFace* hull_faces,
                     __global const uint* face_indices,
% if convex == "box":
                     __global const float4* hull_edges)
% else:
                     __global const HullEdge* hull_adjacency)
% endif
{
${queued_pair()}
    Shape s = shapes[a.shape];
    /* the shape placed in the mesh frame */
    Placement shape_in_mesh;
    quat_to_rows(quat_mul(quat_conjugate(b.orientation), a.orientation),
                 &shape_in_mesh.r0, &shape_in_mesh.r1, &shape_in_mesh.r2);
    shape_in_mesh.position = point_to_local(&frame, a.position.xyz);

    /* 1. the triangle's normal, oriented whichever way separates more */
    float plane = dot3(tri.normal, tri.v[0]);
    float2 along_normal = convex_interval(&shape_in_mesh, s, hull_vertices, tri.normal);
    float forward = plane - along_normal.y, backward = along_normal.x - plane;
    float4 best = forward >= backward ? (float4)(tri.normal, forward) : (float4)(-tri.normal, backward);
    if (best.w > pair_reach)
        return;
    /* 2. the shape's faces: the triangle's least projection less the face's offset */
    float4 face = (float4)(0.0f, 0.0f, 0.0f, -INFINITY);
    uint face_index = 0;
    bool face_active = true;
    for (uint f = 0; f < s.face_count; ++f) {
        float4 local_plane = hull_faces[s.face_offset + f].plane;
        float3 m = rotate_to_world(&shape_in_mesh, local_plane.xyz);
        float offset = local_plane.w + dot3(m, shape_in_mesh.position);
        float separation = min1(min1(dot3(m, tri.v[0]), dot3(m, tri.v[1])), dot3(m, tri.v[2])) - offset;
        if (separation > pair_reach)
            return;
        if (separation > face.w)
            face = (float4)(m, separation), face_index = f,
            face_active = feature_active(tri.edges, supporting_feature(&tri, m));
    }
    float4 edge = (float4)(0.0f, 0.0f, 0.0f, -INFINITY);
    uint edge_k = 0, edge_j = 0;
    bool edge_active = true;
% if convex == "box":
    /* 3. triangle edge k x the box's edge direction j, measured on both extents */
    for (uint k = 0; k < 3u; ++k) {
        float3 e = tri.v[(k + 1u) % 3u] - tri.v[k];
        for (uint j = 0; j < s.edge_count; ++j) {
            float3 u = rotate_to_world(&shape_in_mesh, hull_edges[s.edge_offset + j].xyz);
            float3 axis = cross3(e, u);
            float sin2 = dot3(axis, axis);
            if (sin2 < PARALLEL_SIN2 * dot3(e, e) * dot3(u, u))
                continue;
            axis *= 1.0f / sqrt1(sin2);
            float2 shape_range = convex_interval(&shape_in_mesh, s, hull_vertices, axis);
            float p0 = dot3(axis, tri.v[0]), p1 = dot3(axis, tri.v[1]), p2 = dot3(axis, tri.v[2]);
            float lo = min1(min1(p0, p1), p2), hi = max1(max1(p0, p1), p2);
            float ahead = lo - shape_range.y, behind = shape_range.x - hi;
            float separation = max1(ahead, behind);
            if (separation > pair_reach)
                return;
            if (ahead < behind)
                axis = -axis;
            if (separation > edge.w)
                edge = (float4)(axis, separation), edge_k = k, edge_j = j,
                edge_active = feature_active(tri.edges, supporting_feature(&tri, axis));
        }
    }
% else:
    /* 3. hull edge j and triangle edge k, only where they form a face of the Minkowski
     * difference: where the Gauss-map arc of edge j (between its faces' normals) crosses
     * that of minus edge k, the half circle from -n through -side_k to n (a flat
     * triangle's edge joins its two faces n and -n through its outward side). In the
     * hull's frame, where its arrays are stored; the separation is the distance between
     * the edge lines along their cross product, turned away from the hull's centre. */
    float3 corner[3], normal_local = rotate_to_local(&shape_in_mesh, tri.normal);
    for (uint k = 0; k < 3u; ++k)
        corner[k] = point_to_local(&shape_in_mesh, tri.v[k]);
    __global const float4* vertices = hull_vertices + s.vertex_offset;
    __global const HullFace* faces = hull_faces + s.face_offset;
    for (uint j = 0; j < s.adjacency_count; ++j) {
        HullEdge he = hull_adjacency[s.adjacency_offset + j];
        float3 na = faces[he.f0].plane.xyz, nb = faces[he.f1].plane.xyz;
        float3 a0 = vertices[he.v0].xyz, a1 = vertices[he.v1].xyz;
        for (uint k = 0; k < 3u; ++k) {
            float3 e = corner[(k + 1u) % 3u] - corner[k];
            float da = dot3(na, e), db = dot3(nb, e);
            if (da * db >= 0.0f)
                continue;  /* the arc does not cross the great circle of -edge k */
            float3 crossing = na + (nb - na) * (da / (da - db));
            if (dot3(crossing, cross3(e, normal_local)) >= 0.0f)
                continue;  /* it crosses on the half circle through +side_k */
            float3 axis = cross3(a1 - a0, e);
            float sin2 = dot3(axis, axis);
            if (sin2 < PARALLEL_SIN2 * dot3(a1 - a0, a1 - a0) * dot3(e, e))
                continue;
            axis *= 1.0f / sqrt1(sin2);
            if (dot3(axis, a0) < 0.0f)
                axis = -axis;
            float separation = dot3(axis, corner[k] - a0);
            if (separation > pair_reach)
                return;
            if (separation > edge.w)
                edge = (float4)(rotate_to_world(&shape_in_mesh, axis), separation), edge_k = k,
                edge_j = j, edge_active = feature_active(tri.edges, TRIANGLE_EDGE + k);
        }
    }
% endif
    float4 normal_axis = best;
    uint reference = 0u;  /* 0: the triangle's face, 1: the shape's face, 2: an edge pair */
    if (face.w > best.w + FACE_TOLERANCE)
        best = face, reference = 1u;
    if (edge.w > max1(best.w, face.w) + EDGE_TOLERANCE)
        best = edge, reference = 2u;
    /* an axis whose nearest triangle feature is inactive (a seam of a flat or concave
     * surface) is no normal: the triangle's own is, and the neighbours beyond that
     * feature give the contacts beside this triangle */
    bool on_inactive = (reference == 1u && !face_active) || (reference == 2u && !edge_active);
    if (on_inactive)
        best = normal_axis, reference = 0u;
    /* nor is a penetrating axis that would push the shape through the triangle, away
     * from the side its centre is on, while the centre lies over the triangle (a thin
     * part driven past the plane by a fast impact, where the least penetration lies
     * beyond the surface and a neighbour pushes back: the sphere and capsule kernels
     * likewise take the centre's side): the normal facing the centre is, with the depth
     * along it. A separating axis stays (it is a true normal), and so does one of a
     * shape whose centre lies beside the triangle: beside a convex fold the shape lies
     * below the triangle's plane extended, and the depth along its normal would be
     * that of the plane, not of the triangle (a resting hull kicked up by decimetres) */
    float centre_side = facing(&tri, shape_in_mesh.position);
    uint centre_over;
    closest_on_triangle(&tri, shape_in_mesh.position, &centre_over);
    bool through = best.w < 0.0f && centre_over == TRIANGLE_FACE &&
                   centre_side * dot3(best.xyz, tri.normal) > 0.0f;
    if (through) {
        best = centre_side > 0.0f ? (float4)(-tri.normal, backward) : (float4)(tri.normal, forward);
        reference = 0u;
    }

    float3 polygon[MAX_CLIP_POINTS], clipped[MAX_CLIP_POINTS];
    uint ids[MAX_CLIP_POINTS], clipped_ids[MAX_CLIP_POINTS];
    float4 candidates[MAX_CLIP_POINTS];
    uint candidate_features[MAX_CLIP_POINTS];
    uint n = 0, count = 0;
    if (reference == 0u) {
        /* the shape's face most along the axis (towards the triangle), clipped to the triangle */
        float3 local_axis = rotate_to_local(&shape_in_mesh, best.xyz);
        uint incident = 0;
        float most = -INFINITY;
        for (uint f = 0; f < s.face_count; ++f) {
            float d = dot3(hull_faces[s.face_offset + f].plane.xyz, local_axis);
            if (d > most)
                most = d, incident = f;
        }
        HullFace inc = hull_faces[s.face_offset + incident];
        n = min(inc.index_count, (uint)${max_face_vertices});
        for (uint k = 0; k < n; ++k) {
            polygon[k] = face_vertex(&shape_in_mesh, s, inc, k, hull_vertices, face_indices);
            ids[k] = k;
        }
        bool in_clipped = false;
        for (uint k = 0; k < 3u && n > 0; ++k) {
            float3 side = side_normal(&tri, k);
            if (in_clipped)
                n = clip_polygon(clipped, clipped_ids, n, side, dot3(side, tri.v[k]), CLIPPED_BY_EDGE + 2u * k,
                                 polygon, ids);
            else
                n = clip_polygon(polygon, ids, n, side, dot3(side, tri.v[k]), CLIPPED_BY_EDGE + 2u * k,
                                 clipped, clipped_ids);
            in_clipped = !in_clipped;
        }
        float3 outward = -best.xyz;  /* the triangle's normal towards the shape */
        for (uint k = 0; k < n; ++k) {
            float3 p = in_clipped ? clipped[k] : polygon[k];
            float separation = dot3(outward, p - tri.v[0]);
            if (separation > pair_reach)
                continue;
            candidates[count] = (float4)(p - outward * separation, separation);
            candidate_features[count++] = (incident << 8) | (in_clipped ? clipped_ids[k] : ids[k]);
        }
        if (count == 0 && on_inactive)
            return;  /* the shape lies beyond the inactive feature, over a neighbour */
        if (count == 0) {
            /* the face lies beside the triangle: the shape's deepest vertex */
            float3 deepest = (float3)(0.0f);
            float lowest = INFINITY;
            for (uint v = 0; v < s.vertex_count; ++v) {
                float3 p = point_to_world(&shape_in_mesh, hull_vertices[s.vertex_offset + v].xyz);
                float separation = dot3(outward, p - tri.v[0]);
                if (separation < lowest)
                    lowest = separation, deepest = p;
            }
            if (lowest > pair_reach)
                return;
            candidates[0] = (float4)(deepest - outward * lowest, lowest);
            candidate_features[0] = (incident << 8) | 127u;
            count = 1;
        }
    } else if (reference == 1u) {
        /* the triangle clipped against the shape's face */
        HullFace ref = hull_faces[s.face_offset + face_index];
        float offset = hull_faces[s.face_offset + face_index].plane.w + dot3(best.xyz, shape_in_mesh.position);
        for (uint k = 0; k < 3u; ++k)
            polygon[k] = tri.v[k], ids[k] = k;
        n = 3;
        bool in_clipped = false;
        float3 prev = face_vertex(&shape_in_mesh, s, ref, ref.index_count - 1, hull_vertices, face_indices);
        for (uint j = 0; j < ref.index_count && n > 0; ++j) {
            float3 cur = face_vertex(&shape_in_mesh, s, ref, j, hull_vertices, face_indices);
            float3 side = cross3(cur - prev, best.xyz);
            if (in_clipped)
                n = clip_polygon(clipped, clipped_ids, n, side, dot3(side, prev), CLIPPED_BY_EDGE + 2u * j,
                                 polygon, ids);
            else
                n = clip_polygon(polygon, ids, n, side, dot3(side, prev), CLIPPED_BY_EDGE + 2u * j,
                                 clipped, clipped_ids);
            in_clipped = !in_clipped;
            prev = cur;
        }
        for (uint k = 0; k < n; ++k) {
            float3 p = in_clipped ? clipped[k] : polygon[k];
            float separation = dot3(best.xyz, p) - offset;
            if (separation > pair_reach)
                continue;
            candidates[count] = (float4)(p, separation);
            candidate_features[count++] = REFERENCE_ON_SHAPE | (face_index << 8)
                                          | (in_clipped ? clipped_ids[k] : ids[k]);
        }
        if (count == 0) {
            /* the triangle lies beside the face: its deepest vertex */
            uint k = 0;
            for (uint j = 1; j < 3u; ++j)
                if (dot3(best.xyz, tri.v[j]) < dot3(best.xyz, tri.v[k]))
                    k = j;
            float separation = dot3(best.xyz, tri.v[k]) - offset;
            if (separation > pair_reach)
                return;
            candidates[0] = (float4)(tri.v[k], separation);
            candidate_features[0] = REFERENCE_ON_SHAPE | (face_index << 8) | 127u;
            count = 1;
        }
    } else {
        float3 e0, e1, on_shape, on_triangle;
% if convex == "box":
        /* edge k of the triangle and the box's supporting edge parallel to direction j */
        shape_supporting_edge(&shape_in_mesh, s, hull_edges[s.edge_offset + edge_j].xyz, best.xyz,
                              hull_vertices, hull_faces, face_indices, &e0, &e1);
% else:
        /* edge k of the triangle and the hull's edge j */
        HullEdge he = hull_adjacency[s.adjacency_offset + edge_j];
        e0 = point_to_world(&shape_in_mesh, hull_vertices[s.vertex_offset + he.v0].xyz);
        e1 = point_to_world(&shape_in_mesh, hull_vertices[s.vertex_offset + he.v1].xyz);
% endif
        closest_points_of_segments(e0, e1, tri.v[edge_k], tri.v[(edge_k + 1u) % 3u], &on_shape, &on_triangle);
        candidates[0] = (float4)(on_triangle, best.w);
        candidate_features[0] = EDGE_CONTACT | (edge_k << 16) | edge_j;
        count = 1;
    }
    uint chosen[4];
    uint kept = choose_contacts(candidates, count, best.xyz, chosen);
    float4 points[4];
    uint features[4];
    for (uint k = 0; k < kept; ++k) {
        points[k] = candidates[chosen[k]];
        features[k] = candidate_features[chosen[k]];
    }
    store_in_world(slots, contact_flags, tile_counts, q, &frame, best.xyz, points, features, kept);
}
% endif
