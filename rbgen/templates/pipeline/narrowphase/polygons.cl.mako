<%doc>
Polygon helpers of the kernels that clip polygons (clip.cl.mako, triangles.cl.mako), as
defs a template places where it wants them (`<%namespace name="polygons" .../>`, then
`${polygons.clip_polygon()}` and `${polygons.choose_contacts()}`): clipping a polygon by a
half-space (Sutherland-Hodgman) and the reduction of a manifold's points to four. The
including template defines MAX_CLIP_POINTS, the size of its polygon buffers.
</%doc>
<%def name="clip_polygon()">\
/* Clip a polygon (points + ids, n > 0) by the half-space dot(side, x) <= side_d
 * into (out_points, out_ids); returns the new size. New points get clip_id
 * (leaving the half-space) or clip_id + 1 (entering it). */
inline uint clip_polygon(const float3* points, const uint* ids, uint n, float3 side, float side_d,
                         uint clip_id, float3* out_points, uint* out_ids)
{
    uint m = 0;
    float3 prev = points[n - 1];
    float prev_d = dot3(side, prev) - side_d;
    for (uint k = 0; k < n; ++k) {
        float3 cur = points[k];
        float cur_d = dot3(side, cur) - side_d;
        if ((prev_d <= 0.0f) != (cur_d <= 0.0f) && m < MAX_CLIP_POINTS) {
            out_points[m] = prev + (cur - prev) * (prev_d / (prev_d - cur_d));
            out_ids[m++] = clip_id + (cur_d <= 0.0f ? 1u : 0u);
        }
        if (cur_d <= 0.0f && m < MAX_CLIP_POINTS) {
            out_points[m] = cur;
            out_ids[m++] = ids[k];
        }
        prev = cur, prev_d = cur_d;
    }
    return m;
}
</%def>
<%def name="choose_contacts()">\
/* Keep at most four of the n candidate points of a manifold with this
 * normal (see the header); returns how many, their indices in chosen. */
inline uint choose_contacts(const float4* candidates, uint n, float3 normal, uint* chosen)
{
    if (n <= 4) {
        for (uint k = 0; k < n; ++k)
            chosen[k] = k;
        return n;
    }
    /* the deepest point */
    chosen[0] = 0;
    for (uint k = 1; k < n; ++k)
        if (candidates[k].w < candidates[chosen[0]].w)
            chosen[0] = k;
    float3 p0 = candidates[chosen[0]].xyz;
    /* the farthest from it in the contact plane */
    float far2 = 0.0f;
    chosen[1] = chosen[0];
    for (uint k = 0; k < n; ++k) {
        float3 d = candidates[k].xyz - p0;
        d -= normal * dot3(normal, d);
        if (dot3(d, d) > far2)
            far2 = dot3(d, d), chosen[1] = k;
    }
    uint count = far2 > 0.0f ? 2 : 1;
    /* the extremes on both sides of the line through those two */
    float3 across = cross3(normal, candidates[chosen[1]].xyz - p0);
    float high = 0.0f, low = 0.0f;
    uint high_k = 0, low_k = 0;
    for (uint k = 0; k < n; ++k) {
        float side = dot3(across, candidates[k].xyz - p0);
        if (side > high)
            high = side, high_k = k;
        if (side < low)
            low = side, low_k = k;
    }
    float tolerance = 1e-6f * dot3(across, across);
    if (count == 2 && high > tolerance)
        chosen[count++] = high_k;
    if (count >= 2 && low < -tolerance)
        chosen[count++] = low_k;
    return count;
}
</%def>
