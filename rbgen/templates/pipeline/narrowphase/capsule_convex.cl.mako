/* Capsule (first) against a box or hull (second).
 *
 * One work-item per queued pair; a work group is responsible for
 * ${work_group_size} consecutive entries of the capsule_convex queue. A
 * capsule is its core segment swept by its radius, so everything is measured
 * on the segment and the radius subtracted. Work happens in the convex
 * shape's frame, where its cooked arrays are stored:
 *
 * 1. a separating-axis test between the segment and the shape (the shape's
 *    face normals; the segment crossed with the shape's edge directions)
 *    gives a lower bound of their distance (early-out beyond radius + margin)
 *    and, when the segment enters the shape, the axis of least penetration;
 * 2. segment outside: the closest points between the segment and the faces
 *    that face it (exact distance); when that is a face's interior, the part
 *    of the segment above the face gives up to two points (a capsule lying on
 *    a face), else one point;
 * 3. segment inside: a face axis keeps the part of the segment above the face
 *    (up to two points), an edge axis gives the closest points of the segment
 *    and the shape's supporting edge.
 * Points lie on the convex shape; the normal points from the capsule to it.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "HullFace", "ContactManifold")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>
<%include file="/pipeline/narrowphase/store_manifold.cl.mako"/>
<%include file="/pipeline/narrowphase/segments.cl.mako"/>

/* As in the convex-convex test: faces win near-ties against edges. */
#define EDGE_TOLERANCE 1e-4f
#define PARALLEL_SIN2 1e-8f
/* A closest-point normal this close to a face normal (squared length of their
 * difference, ~ angle^2) comes from the face's interior: the projection of a
 * segment end, exact up to rounding. Closest points on an edge stay single. */
#define FACE_NORMAL_TOLERANCE2 1e-8f
#define EDGE_FEATURE (1u << 31)

/* Clip the segment [*p0, *p1] to the prism above a polygon (inside every side
 * plane); false when nothing is left. */
inline bool clip_segment_to_face(float3* p0, float3* p1, HullFace face,
                                 __global const float4* vertices, __global const uint* face_indices)
{
    float3 n = face.plane.xyz;
    float t0 = 0.0f, t1 = 1.0f;
    float3 d = *p1 - *p0;
    float3 prev = vertices[face_indices[face.index_offset + face.index_count - 1]].xyz;
    for (uint k = 0; k < face.index_count; ++k) {
        float3 cur = vertices[face_indices[face.index_offset + k]].xyz;
        float3 side = cross3(cur - prev, n);  /* outward side normal */
        float at0 = dot3(side, *p0 - prev), rate = dot3(side, d);
        if (rate == 0.0f) {
            if (at0 > 0.0f)
                return false;
        } else {
            float t = -at0 / rate;
            if (rate > 0.0f)
                t1 = min1(t1, t);
            else
                t0 = max1(t0, t);
        }
        prev = cur;
    }
    if (t0 > t1)
        return false;
    float3 start = *p0;
    *p0 = start + d * t0;
    *p1 = start + d * t1;
    return true;
}

/* Closest points of a segment and a convex polygon the segment does not cross
 * (both in the shape frame); returns the squared distance. */
inline float closest_to_face(float3 s0, float3 s1, HullFace face, __global const float4* vertices,
                             __global const uint* face_indices, float3* on_segment, float3* on_face)
{
    float best = INFINITY;
    float3 ends[2] = {s0, s1};
    for (uint k = 0; k < 2; ++k) {
        /* an end above the polygon's interior (on its outer side): its projection */
        float3 top = ends[k], bottom = ends[k];
        float h = dot3(face.plane.xyz, ends[k]) - face.plane.w;
        if (h >= 0.0f && clip_segment_to_face(&top, &bottom, face, vertices, face_indices)) {
            if (h * h < best)
                best = h * h, *on_segment = ends[k], *on_face = ends[k] - face.plane.xyz * h;
        }
    }
    float3 prev = vertices[face_indices[face.index_offset + face.index_count - 1]].xyz;
    for (uint k = 0; k < face.index_count; ++k) {
        float3 cur = vertices[face_indices[face.index_offset + k]].xyz;
        float3 p, q;
        closest_points_of_segments(s0, s1, prev, cur, &p, &q);
        float d2 = dot3(p - q, p - q);
        if (d2 < best)
            best = d2, *on_segment = p, *on_face = q;
        prev = cur;
    }
    return best;
}

/* The shape's edge parallel to `direction` reaching farthest along `towards` (shape frame). */
inline void supporting_edge(Shape s, float3 direction, float3 towards, __global const float4* vertices,
                            __global const HullFace* faces, __global const uint* face_indices,
                            float3* e0, float3* e1)
{
    float best = -INFINITY;
    for (uint f = 0; f < s.face_count; ++f) {
        HullFace face = faces[f];
        float3 prev = vertices[face_indices[face.index_offset + face.index_count - 1]].xyz;
        for (uint k = 0; k < face.index_count; ++k) {
            float3 cur = vertices[face_indices[face.index_offset + k]].xyz;
            float3 edge = cur - prev;
            float reach = dot3(towards, cur + prev);
            if (abs1(dot3(edge, direction)) > 0.9999f * length3(edge) && reach > best)
                best = reach, *e0 = prev, *e1 = cur;
            prev = cur;
        }
    }
}

/* Up to two points where the part of [s0, s1] above `face` lies within the margin:
 * points on the face plane, separation less the radius. */
inline uint points_above_face(float3 s0, float3 s1, HullFace face, uint f, float radius, float margin,
                              __global const float4* vertices, __global const uint* face_indices,
                              float4* points, uint* features)
{
    if (!clip_segment_to_face(&s0, &s1, face, vertices, face_indices))
        return 0;
    float3 ends[2] = {s0, s1};
    uint count = 0;
    for (uint k = 0; k < (dot3(s1 - s0, s1 - s0) > 1e-12f ? 2u : 1u); ++k) {
        float h = dot3(face.plane.xyz, ends[k]) - face.plane.w;
        if (h - radius > margin)
            continue;
        points[count] = (float4)(ends[k] - face.plane.xyz * h, h - radius);
        features[count++] = (f << 1) | k;
    }
    return count;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void capsule_convex(__global const Pair* pairs,
                    __global const Body* bodies,
                    __global const Shape* shapes,
                    __global const uint* queues,
                    __global const uint* queue_counts,
                    const uint pair_capacity,
                    const uint kind,
                    __global ContactManifold* slots,
                    __global uint* contact_flags,
                    __global uint* tile_counts,
                    const float margin,
                    __global const float4* hull_vertices,
                    __global const HullFace* hull_faces,
                    __global const uint* face_indices,
                    __global const float4* hull_edges)
{
    uint slot = get_global_id(0);
    if (slot >= queue_counts[kind])
        return;
    QueuedPair q = decode_queue_entry(queues[kind * pair_capacity + slot], pairs);
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float4 capsule = shapes[a.shape].extents;  /* radius, half height */
    float radius = capsule.x;
    Shape hull = shapes[b.shape];
    __global const float4* vertices = hull_vertices + hull.vertex_offset;
    __global const HullFace* faces = hull_faces + hull.face_offset;
    Placement frame = placement_of(b);
    float3 half_axis = rotate_to_local(&frame, quat_rotate(a.orientation, (float3)(0.0f, capsule.y, 0.0f)));
    float3 centre = point_to_local(&frame, a.position.xyz);
    float3 s0 = centre - half_axis, s1 = centre + half_axis;

    /* 1. separating axes: faces (normal from the capsule to the shape is -n) */
    float best = -INFINITY;
    float3 normal = (float3)(0.0f, 1.0f, 0.0f);
    uint best_face = 0, best_edge = 0;
    bool edge_axis = false;
    for (uint f = 0; f < hull.face_count; ++f) {
        float s = min1(dot3(faces[f].plane.xyz, s0), dot3(faces[f].plane.xyz, s1)) - faces[f].plane.w;
        if (s > best)
            best = s, best_face = f, normal = -faces[f].plane.xyz;
    }
    float face_best = best;
    for (uint j = 0; j < hull.edge_count && capsule.y > 0.0f; ++j) {
        float3 axis = cross3(s1 - s0, hull_edges[hull.edge_offset + j].xyz);
        float sin2 = dot3(axis, axis) / dot3(s1 - s0, s1 - s0);
        if (sin2 < PARALLEL_SIN2)
            continue;
        axis = normalize3(axis);
        float lo = INFINITY, hi = -INFINITY;
        for (uint v = 0; v < hull.vertex_count; ++v) {
            float d = dot3(axis, vertices[v].xyz);
            lo = min1(lo, d);
            hi = max1(hi, d);
        }
        float seg_lo = min1(dot3(axis, s0), dot3(axis, s1)), seg_hi = max1(dot3(axis, s0), dot3(axis, s1));
        float forward = lo - seg_hi, backward = seg_lo - hi;
        float s = max1(forward, backward);
        if (s > best && s > face_best + EDGE_TOLERANCE)
            best = s, best_edge = j, edge_axis = true, normal = forward >= backward ? axis : -axis;
    }
    if (best - radius > pair_reach)
        return;

    float4 points[2];
    uint features[2];
    uint count = 0;
    if (best > 0.0f) {
        /* 2. the segment is outside: exact closest points over the faces facing it */
        float nearest = INFINITY;
        float3 on_segment = s0, on_hull = s0;
        uint nearest_face = 0;
        for (uint f = 0; f < hull.face_count; ++f) {
            HullFace face = faces[f];
            if (max1(dot3(face.plane.xyz, s0), dot3(face.plane.xyz, s1)) - face.plane.w <= 0.0f)
                continue;
            float3 p, h;
            float d2 = closest_to_face(s0, s1, face, vertices, face_indices, &p, &h);
            if (d2 < nearest)
                nearest = d2, on_segment = p, on_hull = h, nearest_face = f;
        }
        float distance = sqrt1(nearest);
        if (distance - radius > pair_reach)
            return;
        normal = (on_hull - on_segment) / distance;
        float3 off_face = normal + faces[nearest_face].plane.xyz;
        if (dot3(off_face, off_face) < FACE_NORMAL_TOLERANCE2) {
            normal = -faces[nearest_face].plane.xyz;
            count = points_above_face(s0, s1, faces[nearest_face], nearest_face, radius, pair_reach,
                                      vertices, face_indices, points, features);
        }
        if (count == 0) {
            points[0] = (float4)(on_hull, distance - radius);
            features[0] = nearest_face << 1;
            count = 1;
        }
    } else if (!edge_axis) {
        /* 3. the segment enters through a face: the part of it above that face */
        count = points_above_face(s0, s1, faces[best_face], best_face, radius, pair_reach, vertices,
                                  face_indices, points, features);
        if (count == 0) {
            /* the segment passes beside the face: its deepest end */
            float3 n = faces[best_face].plane.xyz;
            float3 deepest = dot3(n, s0) < dot3(n, s1) ? s0 : s1;
            float h = dot3(n, deepest) - faces[best_face].plane.w;
            points[0] = (float4)(deepest - n * h, h - radius);
            features[0] = best_face << 1;
            count = 1;
        }
    } else {
        /* 3. the segment crosses an edge: closest points with the supporting edge */
        float3 e0 = s0, e1 = s1, on_segment, on_edge;
        supporting_edge(hull, hull_edges[hull.edge_offset + best_edge].xyz, -normal, vertices, faces,
                        face_indices, &e0, &e1);
        closest_points_of_segments(s0, s1, e0, e1, &on_segment, &on_edge);
        points[0] = (float4)(on_edge, best - radius);
        features[0] = EDGE_FEATURE | best_edge;
        count = 1;
    }
    for (uint k = 0; k < count; ++k)
        points[k].xyz = point_to_world(&frame, points[k].xyz);
    store_manifold(slots, contact_flags, tile_counts, q, rotate_to_world(&frame, normal), points, features, count);
}
