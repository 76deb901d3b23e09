/* Narrowphase kernels for pairs with a sphere, a capsule or a plane: ${", ".join(kinds)}.
 *
 * One work-item per queued pair; a work group is responsible for
 * ${work_group_size} consecutive entries of the kind's queue. Each kernel
 * writes the pair's manifold slot when the separation is at most `margin`
 * (contacts within the margin persist, so resting contacts survive a step).
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "HullFace", "ContactManifold")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>
<%include file="/pipeline/narrowphase/store_manifold.cl.mako"/>
% if any("capsule" in k for k in kinds):
<%include file="/pipeline/narrowphase/segments.cl.mako"/>
% endif

/* Any unit vector: the normal used when two centres coincide. */
#define FALLBACK_NORMAL ((float3)(0.0f, 1.0f, 0.0f))

<%def name="queued_pair()">\
    uint slot = get_global_id(0);
    if (slot >= queue_counts[kind])
        return;
    QueuedPair q = decode_queue_entry(queues[kind * pair_capacity + slot], pairs);\
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
${pad}const float margin\
</%def>
% if "sphere_sphere" in kinds:

/* Sphere (first) against sphere (second): one point, normal along the centres. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sphere_sphere(${queue_args("sphere_sphere")})
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float ra = shapes[a.shape].extents.x, rb = shapes[b.shape].extents.x;
    float3 d = b.position.xyz - a.position.xyz;
    float distance = length3(d);
    float separation = distance - ra - rb;
    if (separation > pair_reach)
        return;
    float3 normal = distance > 1e-6f * (ra + rb) ? d / distance : FALLBACK_NORMAL;
    float4 point = (float4)(b.position.xyz - normal * rb, separation);
    uint feature = 0u;
    store_manifold(slots, contact_flags, tile_counts, q, normal, &point, &feature, 1u);
}
% endif
% if "sphere_plane" in kinds:

/* Sphere (first) against plane (second): one point on the plane below the centre. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sphere_plane(${queue_args("sphere_plane")})
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float radius = shapes[a.shape].extents.x;
    Placement plane_body = placement_of(b);
    float4 plane = plane_to_world(&plane_body, shapes[b.shape].extents);
    float height = dot3(plane.xyz, a.position.xyz) - plane.w;
    float separation = height - radius;
    if (separation > pair_reach)
        return;
    float4 point = (float4)(a.position.xyz - plane.xyz * height, separation);
    uint feature = 0u;
    store_manifold(slots, contact_flags, tile_counts, q, -plane.xyz, &point, &feature, 1u);
}
% endif
% if "sphere_convex" in kinds:

/* Closest point to c on the convex polygon `face` (local frame), c above its plane. */
inline float3 closest_point_on_face(float3 c, HullFace face, __global const float4* vertices,
                                    __global const uint* face_indices)
{
    float3 n = face.plane.xyz;
    float3 projected = c - n * (dot3(n, c) - face.plane.w);
    float3 best = projected;
    float best_distance2 = INFINITY;
    bool inside = true;
    float3 prev = vertices[face_indices[face.index_offset + face.index_count - 1]].xyz;
    for (uint k = 0; k < face.index_count; ++k) {
        float3 cur = vertices[face_indices[face.index_offset + k]].xyz;
        float3 edge = cur - prev;
        if (dot3(cross3(edge, n), projected - prev) > 0.0f) {
            /* outside this edge: the closest point may lie on it */
            inside = false;
            float t = clamp1(dot3(c - prev, edge) / dot3(edge, edge), 0.0f, 1.0f);
            float3 on_edge = prev + edge * t;
            float d2 = dot3(c - on_edge, c - on_edge);
            if (d2 < best_distance2)
                best_distance2 = d2, best = on_edge;
        }
        prev = cur;
    }
    return inside ? projected : best;
}

/* Sphere (first) against a box or hull (second): the closest feature.
 * Centre outside: the closest point over the faces that face the centre.
 * Centre inside: the face of least penetration. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sphere_convex(${queue_args("sphere_convex")},
                   __global const float4* hull_vertices,
                   __global const HullFace* hull_faces,
                   __global const uint* face_indices)
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float radius = shapes[a.shape].extents.x;
    Shape hull = shapes[b.shape];
    Placement hull_body = placement_of(b);
    __global const float4* vertices = hull_vertices + hull.vertex_offset;
    __global const HullFace* faces = hull_faces + hull.face_offset;
    float3 c = point_to_local(&hull_body, a.position.xyz);

    uint deepest_face = 0;
    float deepest = -INFINITY;
    for (uint f = 0; f < hull.face_count; ++f) {
        float s = dot3(faces[f].plane.xyz, c) - faces[f].plane.w;
        if (s > deepest)
            deepest = s, deepest_face = f;
    }
    float3 surface = c, normal;
    float separation;
    uint feature = deepest_face;
    if (deepest <= 0.0f) {
        /* centre inside: push out through the nearest face */
        normal = -faces[deepest_face].plane.xyz;
        surface = c + normal * deepest;
        separation = deepest - radius;
    } else {
        if (deepest - radius > pair_reach)
            return;  /* a face plane already separates by more than the margin */
        float best_distance2 = INFINITY;
        for (uint f = 0; f < hull.face_count; ++f) {
            if (dot3(faces[f].plane.xyz, c) - faces[f].plane.w <= 0.0f)
                continue;
            float3 p = closest_point_on_face(c, faces[f], vertices, face_indices);
            float d2 = dot3(p - c, p - c);
            if (d2 < best_distance2)
                best_distance2 = d2, surface = p, feature = f;
        }
        float distance = sqrt1(best_distance2);
        normal = (surface - c) / distance;
        separation = distance - radius;
    }
    if (separation > pair_reach)
        return;
    float4 point = (float4)(point_to_world(&hull_body, surface), separation);
    store_manifold(slots, contact_flags, tile_counts, q, rotate_to_world(&hull_body, normal), &point, &feature, 1u);
}
% endif
% if any("capsule" in k for k in kinds):

/* The segment of a capsule (along its local y axis) in the world. */
inline void capsule_segment(Body body, float half_height, float3* p0, float3* p1)
{
    float3 half_axis = quat_rotate(body.orientation, (float3)(0.0f, half_height, 0.0f));
    *p0 = body.position.xyz - half_axis;
    *p1 = body.position.xyz + half_axis;
}

/* A unit vector perpendicular to v, or FALLBACK_NORMAL when v is zero. */
inline float3 any_perpendicular(float3 v)
{
    if (dot3(v, v) == 0.0f)
        return FALLBACK_NORMAL;
    float3 other = abs1(v.x) < 0.9f * length3(v) ? (float3)(1.0f, 0.0f, 0.0f) : (float3)(0.0f, 1.0f, 0.0f);
    return normalize3(cross3(v, other));
}
% endif
% if "sphere_capsule" in kinds:

/* Sphere (first) against capsule (second): the sphere against the closest point
 * of the capsule's segment. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sphere_capsule(${queue_args("sphere_capsule")})
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float ra = shapes[a.shape].extents.x;
    float4 capsule = shapes[b.shape].extents;  /* radius, half height */
    float3 p0, p1, centre = a.position.xyz, on_centre, on_segment;
    capsule_segment(b, capsule.y, &p0, &p1);
    closest_points_of_segments(centre, centre, p0, p1, &on_centre, &on_segment);
    float3 d = on_segment - centre;
    float distance = length3(d);
    float separation = distance - ra - capsule.x;
    if (separation > pair_reach)
        return;
    float3 normal = distance > 1e-6f * (ra + capsule.x) ? d / distance : any_perpendicular(p1 - p0);
    float4 point = (float4)(on_segment - normal * capsule.x, separation);
    uint feature = 0u;
    store_manifold(slots, contact_flags, tile_counts, q, normal, &point, &feature, 1u);
}
% endif
% if "capsule_capsule" in kinds:

/* Capsule (first) against capsule (second): the closest points of the segments;
 * parallel segments that overlap along their axis touch at the two ends of the
 * overlap. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void capsule_capsule(${queue_args("capsule_capsule")})
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float4 ca = shapes[a.shape].extents, cb = shapes[b.shape].extents;
    float3 a0, a1, b0, b1, on_a, on_b;
    capsule_segment(a, ca.y, &a0, &a1);
    capsule_segment(b, cb.y, &b0, &b1);
    closest_points_of_segments(a0, a1, b0, b1, &on_a, &on_b);
    float3 d = on_b - on_a;
    float distance = length3(d);
    float separation = distance - ca.x - cb.x;
    if (separation > pair_reach)
        return;
    float3 da = a1 - a0, db = b1 - b0;
    float3 normal = distance > 1e-6f * (ca.x + cb.x) ? d / distance : any_perpendicular(da);

    float4 points[2];
    uint features[2] = {0u, 1u};
    uint count = 1;
    points[0] = (float4)(on_b - normal * cb.x, separation);
    float la2 = dot3(da, da), lb2 = dot3(db, db);
    float3 twist = cross3(da, db);
    if (la2 > 0.0f && lb2 > 0.0f && dot3(twist, twist) < 1e-6f * la2 * lb2) {
        /* parallel: the overlap of b's segment on a's axis, as fractions of a */
        float u0 = dot3(b0 - a0, da) / la2, u1 = dot3(b1 - a0, da) / la2;
        float lo = max1(0.0f, min1(u0, u1)), hi = min1(1.0f, max1(u0, u1));
        if ((hi - lo) * sqrt1(la2) > 1e-4f * (ca.x + cb.x)) {
            float3 ends[2] = {a0 + da * lo, a0 + da * hi};
            for (uint k = 0; k < 2; ++k) {
                float3 across, on_second;
                closest_points_of_segments(ends[k], ends[k], b0, b1, &across, &on_second);
                points[k] = (float4)(on_second - normal * cb.x,
                                     dot3(normal, on_second - ends[k]) - ca.x - cb.x);
            }
            count = 2;
        }
    }
    store_manifold(slots, contact_flags, tile_counts, q, normal, points, features, count);
}
% endif
% if "capsule_plane" in kinds:

/* Capsule (first) against plane (second): each end of the segment within the
 * margin (plus the radius) of the plane gives a point. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void capsule_plane(${queue_args("capsule_plane")})
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    float4 capsule = shapes[a.shape].extents;
    Placement plane_body = placement_of(b);
    float4 plane = plane_to_world(&plane_body, shapes[b.shape].extents);
    float3 ends[2];
    capsule_segment(a, capsule.y, &ends[0], &ends[1]);
    float4 points[2];
    uint features[2];
    uint count = 0;
    for (uint k = 0; k < (capsule.y > 0.0f ? 2u : 1u); ++k) {
        float height = dot3(plane.xyz, ends[k]) - plane.w;
        if (height - capsule.x > pair_reach)
            continue;
        points[count] = (float4)(ends[k] - plane.xyz * height, height - capsule.x);
        features[count++] = k;
    }
    if (count > 0)
        store_manifold(slots, contact_flags, tile_counts, q, -plane.xyz, points, features, count);
}
% endif
% if "convex_plane" in kinds:

/* Box or hull (first) against plane (second): the deepest vertex, and the
 * vertices of the incident face (the face whose normal is most opposed to the
 * plane's: the hull's support along -n, as Jolt's GetSupportingFace) within
 * the pair's margin of the plane, reduced to at most four (the deepest, the
 * farthest from it, then the extremes on both sides of the line through those
 * two). Only the face: a hull smaller than the margin has every vertex within
 * it, and points on its far side would let it rest on its top corners and
 * sink. The vertices are streamed, not stored, so any hull size works. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void convex_plane(${queue_args("convex_plane")},
                  __global const float4* hull_vertices,
                  __global const HullFace* hull_faces,
                  __global const uint* face_indices)
{
${queued_pair()}
    Body a = bodies[q.first], b = bodies[q.second];
    const float pair_reach = pair_margin(margin, a, b);
    Shape hull = shapes[a.shape];
    Placement hull_body = placement_of(a), plane_body = placement_of(b);
    float4 plane = plane_to_world(&plane_body, shapes[b.shape].extents);
    __global const float4* vertices = hull_vertices + hull.vertex_offset;
    __global const HullFace* faces = hull_faces + hull.face_offset;

    /* the deepest vertex */
    uint chosen[4];
    float best = INFINITY;
    for (uint v = 0; v < hull.vertex_count; ++v) {
        float s = dot3(plane.xyz, point_to_world(&hull_body, vertices[v].xyz)) - plane.w;
        if (s < best)
            best = s, chosen[0] = v;
    }
    if (best > pair_reach)
        return;
    uint count = 1;
    float3 p0 = point_to_world(&hull_body, vertices[chosen[0]].xyz);

    /* the incident face: its normal (local frame) most opposed to the plane's */
    float3 down = rotate_to_local(&hull_body, plane.xyz);
    HullFace face = faces[0];
    float most_opposed = INFINITY;
    for (uint f = 0; f < hull.face_count; ++f) {
        float c = dot3(faces[f].plane.xyz, down);
        if (c < most_opposed)
            most_opposed = c, face = faces[f];
    }
    __global const uint* corners = face_indices + face.index_offset;

    /* the face's touching vertex farthest from the deepest, in the contact plane */
    float far2 = 0.0f;
    for (uint k = 0; k < face.index_count; ++k) {
        float3 p = point_to_world(&hull_body, vertices[corners[k]].xyz);
        float3 d = p - p0;
        d -= plane.xyz * dot3(plane.xyz, d);
        if (dot3(plane.xyz, p) - plane.w <= pair_reach && dot3(d, d) > far2)
            far2 = dot3(d, d), chosen[1] = corners[k];
    }
    if (far2 > 0.0f) {
        count = 2;
        /* the face's extremes on both sides of the line p0 p1 */
        float3 p1 = point_to_world(&hull_body, vertices[chosen[1]].xyz);
        float3 across = cross3(plane.xyz, p1 - p0);
        float high = 0.0f, low = 0.0f;
        uint high_vertex = 0, low_vertex = 0;
        for (uint k = 0; k < face.index_count; ++k) {
            float3 p = point_to_world(&hull_body, vertices[corners[k]].xyz);
            if (dot3(plane.xyz, p) - plane.w > pair_reach)
                continue;
            float side = dot3(across, p - p0);
            if (side > high)
                high = side, high_vertex = corners[k];
            if (side < low)
                low = side, low_vertex = corners[k];
        }
        float tolerance = 1e-6f * dot3(across, across);
        if (high > tolerance)
            chosen[count++] = high_vertex;
        if (low < -tolerance)
            chosen[count++] = low_vertex;
    }

    float4 points[4];
    for (uint k = 0; k < count; ++k) {
        float3 p = point_to_world(&hull_body, vertices[chosen[k]].xyz);
        float s = dot3(plane.xyz, p) - plane.w;
        points[k] = (float4)(p - plane.xyz * s, s);
    }
    store_manifold(slots, contact_flags, tile_counts, q, -plane.xyz, points, chosen, count);
}
% endif
