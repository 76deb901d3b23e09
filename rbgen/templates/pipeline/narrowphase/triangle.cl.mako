/* ---- A mesh triangle as the triangle pair kernels see it (mesh frame) ----------
 *
 * A pair of a body and a mesh comes from the midphase with sub-feature 1 + the
 * triangle (from the mesh's first, Shape.face_offset). A triangle is two-sided: its
 * normal is oriented towards the other shape where a contact uses it.
 *
 * Features: the face, edge k (vertex k to vertex k + 1) or vertex k. The face is always
 * active; an edge is active by its MeshTriangle.edges bit (open, sharp or non-manifold:
 * rbgen.mesh); a vertex when either of its two edges is. A contact on an inactive
 * feature takes the face normal (no bump on the seams of a tessellated surface).
 */
#define TRIANGLE_FACE 0u
#define TRIANGLE_EDGE 1u    /* + k: edge k */
#define TRIANGLE_VERTEX 4u  /* + k: vertex k */

typedef struct {
    float3 v[3];     /* vertices, counter-clockwise around normal */
    float3 normal;   /* unit */
    uint edges;      /* active-edge bits */
} Triangle;

inline Triangle load_triangle(Shape mesh, uint sub, __global const MeshTriangle* mesh_triangles,
                              __global const float4* mesh_vertices)
{
    MeshTriangle t = mesh_triangles[mesh.face_offset + sub - 1u];
    Triangle tri;
    tri.v[0] = mesh_vertices[t.vertices[0]].xyz;
    tri.v[1] = mesh_vertices[t.vertices[1]].xyz;
    tri.v[2] = mesh_vertices[t.vertices[2]].xyz;
    tri.normal = normalize3(cross3(tri.v[1] - tri.v[0], tri.v[2] - tri.v[0]));
    tri.edges = t.edges;
    return tri;
}

inline bool feature_active(uint edges, uint feature)
{
    if (feature == TRIANGLE_FACE)
        return true;
    if (feature < TRIANGLE_VERTEX)
        return ((edges >> (feature - TRIANGLE_EDGE)) & 1u) != 0u;
    uint k = feature - TRIANGLE_VERTEX;
    return (((edges >> k) | (edges >> ((k + 2u) % 3u))) & 1u) != 0u;
}

/* The triangle's feature nearest to the shape along `axis` (pointing from the shape to
 * the triangle): the vertices of least projection, within a tolerance. */
inline uint supporting_feature(const Triangle* t, float3 axis)
{
    float p0 = dot3(axis, t->v[0]), p1 = dot3(axis, t->v[1]), p2 = dot3(axis, t->v[2]);
    float lowest = min1(min1(p0, p1), p2);
    float tolerance = 1e-4f * (max1(max1(p0, p1), p2) - lowest) + 1e-6f;
    uint near = (p0 <= lowest + tolerance ? 1u : 0u) | (p1 <= lowest + tolerance ? 2u : 0u)
              | (p2 <= lowest + tolerance ? 4u : 0u);
    switch (near) {
    case 1u: return TRIANGLE_VERTEX + 0u;
    case 2u: return TRIANGLE_VERTEX + 1u;
    case 4u: return TRIANGLE_VERTEX + 2u;
    case 3u: return TRIANGLE_EDGE + 0u;
    case 6u: return TRIANGLE_EDGE + 1u;
    case 5u: return TRIANGLE_EDGE + 2u;
    default: return TRIANGLE_FACE;
    }
}

/* The triangle's point closest to p and its feature (Ericson, Real-Time Collision
 * Detection, 5.1.5: the Voronoi regions of the vertices, edges and face). */
inline float3 closest_on_triangle(const Triangle* t, float3 p, uint* feature)
{
    float3 a = t->v[0], b = t->v[1], c = t->v[2];
    float3 ab = b - a, ac = c - a, ap = p - a;
    float d1 = dot3(ab, ap), d2 = dot3(ac, ap);
    if (d1 <= 0.0f && d2 <= 0.0f) {
        *feature = TRIANGLE_VERTEX + 0u;
        return a;
    }
    float3 bp = p - b;
    float d3 = dot3(ab, bp), d4 = dot3(ac, bp);
    if (d3 >= 0.0f && d4 <= d3) {
        *feature = TRIANGLE_VERTEX + 1u;
        return b;
    }
    float vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) {
        *feature = TRIANGLE_EDGE + 0u;
        return a + ab * (d1 / (d1 - d3));
    }
    float3 cp = p - c;
    float d5 = dot3(ab, cp), d6 = dot3(ac, cp);
    if (d6 >= 0.0f && d5 <= d6) {
        *feature = TRIANGLE_VERTEX + 2u;
        return c;
    }
    float vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) {
        *feature = TRIANGLE_EDGE + 2u;
        return a + ac * (d2 / (d2 - d6));
    }
    float va = d3 * d6 - d5 * d4;
    if (va <= 0.0f && d4 - d3 >= 0.0f && d5 - d6 >= 0.0f) {
        *feature = TRIANGLE_EDGE + 1u;
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    float scale = 1.0f / (va + vb + vc);
    *feature = TRIANGLE_FACE;
    return a + ab * (vb * scale) + ac * (vc * scale);
}

/* The outward normal of the side plane through edge k (dot <= dot at v[k]: inside). */
inline float3 side_normal(const Triangle* t, uint k)
{
    return cross3(t->v[(k + 1u) % 3u] - t->v[k], t->normal);
}

/* Clip the segment [*p0, *p1] to the prism over the triangle (inside its three side
 * planes); false when nothing is left. */
inline bool clip_segment_to_triangle(const Triangle* t, float3* p0, float3* p1)
{
    float t0 = 0.0f, t1 = 1.0f;
    float3 d = *p1 - *p0;
    for (uint k = 0; k < 3u; ++k) {
        float3 side = side_normal(t, k);
        float at0 = dot3(side, *p0 - t->v[k]), rate = dot3(side, d);
        if (rate == 0.0f) {
            if (at0 > 0.0f)
                return false;
        } else if (rate > 0.0f) {
            t1 = min1(t1, -at0 / rate);
        } else {
            t0 = max1(t0, -at0 / rate);
        }
    }
    if (t0 > t1)
        return false;
    float3 start = *p0;
    *p0 = start + d * t0;
    *p1 = start + d * t1;
    return true;
}
