/* Separating-axis test between two boxes, in closed form.
 *
 * One work-item per queued box-box pair; a work group is responsible for
 * ${work_group_size} consecutive entries of the kind's queue${" (the pair list: the world's only kind)" if direct else ""}. The 15 axes of
 * two boxes (3 face normals of each, 9 cross products of their axes) are
 * measured from the boxes' axes and half extents alone: no vertex or face
 * array is read. Feature codes are those of the generic test on the boxes'
 * cooked hulls (faces +x, -x, +y, -y, +z, -z; edge directions x, y, z), so
 * the clipping stage is shared: face 2i + (negative side) of the first box,
 * 6 + the face of the second, then 12 + 3i + j for axis i of the first
 * crossed with axis j of the second. Like the generic test, it stops at the
 * first axis that separates by more than `margin`, tries last step's best
 * axis first (per-pair cache keyed by (a, b, sub)), and appends touching pairs
 * to the clipping queue with group-aggregated atomics.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "SatCacheEntry", "SatResult")}

<%namespace name="shared" file="/pipeline/narrowphase/find_separating_axis.cl.mako"/>
<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>

${shared.definitions()}
/* Feature code of the first edge-edge axis (after the 6 + 6 faces). */
#define FIRST_EDGE_FEATURE 12u
/* an edge pair's axis within 1 degree of a face normal of either box gives way to that
 * face's axis where the face is at most this much deeper (m; see edge_gap) */
#define FACE_ALIGNED_COS2 0.99969541f
#define FACE_ALIGNED_TOLERANCE 1e-3f

/* Two boxes seen from the first one. Every axis is measured from the nine
 * cosines r[i][j] = a_i . b_j (a_i, b_j: the boxes' unit axes in the world)
 * and the offset in the first box's frame, as in Gottschalk's OBB test: a face
 * axis costs three multiply-adds, an edge axis a_i x b_j a few more, and no
 * world-space vector is formed until the best axis is known. */
typedef struct {
    float3 a[3], b[3];  /* world axes (columns of the rotations) */
    float r[3][3];      /* a_i . b_j */
    float abs_r[3][3];  /* |a_i . b_j| */
    float t[3];         /* centre of b - centre of a, in a's frame */
    float extent_a[3], extent_b[3];
} BoxPair;

/* The axes of a box in the world: the columns of its rotation. */
inline void box_axes(float4 q, float3* axes)
{
    float3 r0, r1, r2;
    quat_to_rows(q, &r0, &r1, &r2);
    axes[0] = (float3)(r0.x, r1.x, r2.x);
    axes[1] = (float3)(r0.y, r1.y, r2.y);
    axes[2] = (float3)(r0.z, r1.z, r2.z);
}

inline BoxPair box_pair(Body a, float3 extent_a, Body b, float3 extent_b)
{
    BoxPair g;
    box_axes(a.orientation, g.a);
    box_axes(b.orientation, g.b);
    float3 offset = b.position.xyz - a.position.xyz;
    for (uint i = 0; i < 3; ++i) {
        g.t[i] = dot3(g.a[i], offset);
        for (uint j = 0; j < 3; ++j) {
            g.r[i][j] = dot3(g.a[i], g.b[j]);
            g.abs_r[i][j] = abs1(g.r[i][j]);
        }
    }
    g.extent_a[0] = extent_a.x, g.extent_a[1] = extent_a.y, g.extent_a[2] = extent_a.z;
    g.extent_b[0] = extent_b.x, g.extent_b[1] = extent_b.y, g.extent_b[2] = extent_b.z;
    return g;
}

/* Separation along axis i of the first box: |t_i| - its half extent - the
 * second box's half width along a_i. */
inline float first_face_gap(const BoxPair* g, uint i)
{
    float reach_b = g->extent_b[0] * g->abs_r[i][0] + g->extent_b[1] * g->abs_r[i][1]
                  + g->extent_b[2] * g->abs_r[i][2];
    return abs1(g->t[i]) - g->extent_a[i] - reach_b;
}

/* Offset of the centres along axis j of the second box. */
inline float second_offset(const BoxPair* g, uint j)
{
    return g->t[0] * g->r[0][j] + g->t[1] * g->r[1][j] + g->t[2] * g->r[2][j];
}

inline float second_face_gap(const BoxPair* g, uint j)
{
    float reach_a = g->extent_a[0] * g->abs_r[0][j] + g->extent_a[1] * g->abs_r[1][j]
                  + g->extent_a[2] * g->abs_r[2][j];
    return abs1(second_offset(g, j)) - g->extent_b[j] - reach_a;
}

/* Separation along a_i x b_j (-INFINITY when the axes are parallel). In a's
 * frame the axis is e_i x r_j, of length sqrt(1 - r_ij^2); its products with
 * the boxes' axes and the offset are 2x2 minors of r and t. The gap is the
 * unnormalised one over that length (<= 1), so a negative unnormalised gap at
 * most `at_most` bounds the gap by it: then -INFINITY is returned without the
 * square root and division (the axis cannot win).
 *
 * An axis within 1 degree (FACE_ALIGNED_COS2) of a face normal of either box
 * is also -INFINITY when that face axis (the shallower where both boxes have
 * one) is no deeper than it, within
 * FACE_ALIGNED_TOLERANCE: the face measures the same direction, and its
 * clipped manifold supports a resting box at four corners, where an edge pair
 * chosen by a few mrad of tilt gives one point and flickers with it. A
 * separating edge axis is never dropped for a face that does not separate. */
inline float edge_gap(const BoxPair* g, uint i, uint j, float at_most, float* offset_along)
{
    uint i1 = (i + 1u) % 3u, i2 = (i + 2u) % 3u, j1 = (j + 1u) % 3u, j2 = (j + 2u) % 3u;
    float sin2 = g->r[i1][j] * g->r[i1][j] + g->r[i2][j] * g->r[i2][j];
    if (sin2 < PARALLEL_SIN2)
        return -INFINITY;
    float d = g->t[i2] * g->r[i1][j] - g->t[i1] * g->r[i2][j];
    float reach = g->extent_a[i1] * g->abs_r[i2][j] + g->extent_a[i2] * g->abs_r[i1][j]
                + g->extent_b[j1] * g->abs_r[i][j2] + g->extent_b[j2] * g->abs_r[i][j1];
    *offset_along = d;
    float unnormalised = abs1(d) - reach;
    if (unnormalised <= 0.0f && unnormalised <= at_most)
        return -INFINITY;
    float gap = unnormalised / sqrt1(sin2);
    /* The axis's squared components along a_i2, a_i1 (r_i1j^2, r_i2j^2) and along
     * b_j2, b_j1 (r_ij1^2, r_ij2^2), over |axis|^2 = sin2 (the same in both frames). */
    float a_i2 = g->r[i1][j] * g->r[i1][j], a_i1 = g->r[i2][j] * g->r[i2][j];
    float b_j2 = g->r[i][j1] * g->r[i][j1], b_j1 = g->r[i][j2] * g->r[i][j2];
    float along_a = max1(a_i1, a_i2), along_b = max1(b_j1, b_j2);
    /* the shallower of the aligned faces: a box tilted by a few mrad on another has a
     * face of each within the angle, and either one measures the direction */
    float face = -INFINITY;
    if (along_a > FACE_ALIGNED_COS2 * sin2)
        face = first_face_gap(g, a_i1 >= a_i2 ? i1 : i2);
    if (along_b > FACE_ALIGNED_COS2 * sin2)
        face = max1(face, second_face_gap(g, b_j1 >= b_j2 ? j1 : j2));
    if (face >= gap - FACE_ALIGNED_TOLERANCE && (gap <= 0.0f || face > 0.0f))
        return -INFINITY;
    return gap;
}

/* Separation along a feature code (last step's best axis). */
inline float feature_gap(const BoxPair* g, uint feature)
{
    if (feature < 6u)
        return first_face_gap(g, feature / 2u);
    if (feature < FIRST_EDGE_FEATURE)
        return second_face_gap(g, (feature - 6u) / 2u);
    uint e = feature - FIRST_EDGE_FEATURE;
    float unused;
    return edge_gap(g, e / 3u, e % 3u, -INFINITY, &unused);
}

/* The world axis of a feature code, turned from the first box towards the second. */
inline float3 feature_axis(const BoxPair* g, uint feature)
{
    if (feature < 6u)
        return (feature & 1u) ? -g->a[feature / 2u] : g->a[feature / 2u];
    if (feature < FIRST_EDGE_FEATURE) {
        float3 axis = g->b[(feature - 6u) / 2u];
        /* the second box's facing face has outward normal -axis */
        return (feature & 1u) ? axis : -axis;
    }
    uint e = feature - FIRST_EDGE_FEATURE;
    float d;
    edge_gap(g, e / 3u, e % 3u, -INFINITY, &d);
    float3 axis = normalize3(cross3(g->a[e / 3u], g->b[e % 3u]));
    return d >= 0.0f ? axis : -axis;
}

/* True when the boxes are within `margin`: then *best is the axis of least
 * penetration (w: separation) and *best_feature its code. */
inline bool box_box_test(const BoxPair* g, Pair pair, __global SatCacheEntry* entry, float margin,
                         float4* best, uint* best_feature)
{
    SatCacheEntry cached = *entry;
    if (cached_axis_of(cached, pair) && feature_gap(g, cached.feature) > margin)
        return false;  /* last step's axis still separates: the entry stays */

    float face_a = -INFINITY, face_b = -INFINITY, edge = -INFINITY;
    uint face_a_feature = 0, face_b_feature = 6u, edge_feature = FIRST_EDGE_FEATURE;
    for (uint i = 0; i < 3; ++i) {
        float gap = first_face_gap(g, i);
        uint feature = 2u * i + (g->t[i] >= 0.0f ? 0u : 1u);
        if (gap > margin) {
            remember_axis(entry, pair, feature);
            return false;
        }
        if (gap > face_a)
            face_a = gap, face_a_feature = feature;
    }
    for (uint j = 0; j < 3; ++j) {
        float gap = second_face_gap(g, j);
        uint feature = 6u + 2u * j + (second_offset(g, j) >= 0.0f ? 1u : 0u);
        if (gap > margin) {
            remember_axis(entry, pair, feature);
            return false;
        }
        if (gap > face_b)
            face_b = gap, face_b_feature = feature;
    }
    /* an edge axis must beat both faces by EDGE_TOLERANCE to be chosen */
    float edge_floor = max1(face_a, face_b) + EDGE_TOLERANCE;
    for (uint i = 0; i < 3; ++i) {
        for (uint j = 0; j < 3; ++j) {
            float unused;
            float gap = edge_gap(g, i, j, edge_floor, &unused);
            uint feature = FIRST_EDGE_FEATURE + 3u * i + j;
            if (gap > margin) {
                remember_axis(entry, pair, feature);
                return false;
            }
            if (gap > edge)
                edge = gap, edge_feature = feature;
        }
    }

    float gap = face_a;
    *best_feature = face_a_feature;
    if (face_b > face_a + FACE_TOLERANCE)
        gap = face_b, *best_feature = face_b_feature;
    if (edge > edge_floor)
        gap = edge, *best_feature = edge_feature;
    *best = (float4)(feature_axis(g, *best_feature), gap);
    remember_axis(entry, pair, *best_feature);
    return true;
}

<%call expr="shared.find_separating_axis(shape_arrays=())">\
        BoxPair g = box_pair(a, shapes[a.shape].extents.xyz, b, shapes[b.shape].extents.xyz);
        touching = box_box_test(&g, pairs[q.index], &cache[q.index], pair_reach, &axis,
                                &feature);
</%call>
