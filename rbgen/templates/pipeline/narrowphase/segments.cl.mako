/* ---- Closest points of two segments (edge-edge contacts, capsules) ---------
 *
 * The points p0 + s (p1 - p0) and q0 + t (q1 - q0), s and t in [0, 1], that
 * are closest; a segment may be a single point (zero length). When the
 * segments are parallel, s = 0 and t follows. */
inline void closest_points_of_segments(float3 p0, float3 p1, float3 q0, float3 q1,
                                       float3* on_p, float3* on_q)
{
    float3 d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
    float a = dot3(d1, d1), e = dot3(d2, d2), f = dot3(d2, r);
    float s = 0.0f, t = 0.0f;
    if (a > 0.0f && e > 0.0f) {
        float b = dot3(d1, d2), c = dot3(d1, r);
        float denom = a * e - b * b;
        s = denom > 1e-12f * a * e ? clamp1((b * f - c * e) / denom, 0.0f, 1.0f) : 0.0f;
        t = (b * s + f) / e;
        if (t < 0.0f)
            t = 0.0f, s = clamp1(-c / a, 0.0f, 1.0f);
        else if (t > 1.0f)
            t = 1.0f, s = clamp1((b - c) / a, 0.0f, 1.0f);
    } else if (a > 0.0f) {
        s = clamp1(-dot3(d1, r) / a, 0.0f, 1.0f);
    } else if (e > 0.0f) {
        t = clamp1(f / e, 0.0f, 1.0f);
    }
    *on_p = p0 + d1 * s;
    *on_q = q0 + d2 * t;
}
