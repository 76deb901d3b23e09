/* How a body moves over a (sub)step: the rotation by its angular velocity and
 * the split-impulse push, written once for the integrator and for a solver
 * that integrates its substeps itself. The including template supplies
 * common/quaternion.cl.mako. */

/* Below this angular speed * dt, sin(a/2)/a and cos(a/2) are replaced by their
 * series (the next terms are below float precision). */
#define SMALL_ROTATION 0.001f

inline float4 quat_normalized(float4 q)
{
    return q * (1.0f / sqrt1(dot3(q.xyz, q.xyz) + q.w * q.w));
}

/* q turned by the angular velocity w over dt (axis-angle, sin(a/2)/a by its
 * series for small angles), at most max_angular_step radians; renormalised. */
inline float4 rotate_by_angular_velocity(float4 q, float3 w, float dt, float max_angular_step)
{
    float speed = length3(w);
    if (speed * dt > max_angular_step)
        w *= max_angular_step / (dt * speed), speed = max_angular_step / dt;
    float half_angle = 0.5f * speed * dt;
    float4 dq;
    if (speed * dt < SMALL_ROTATION) {
        /* sin(s dt / 2) / s = dt/2 - dt^3 s^2 / 48 + O(s^4); cos(a) = 1 - a^2/2 + O(a^4) */
        dq.xyz = w * (0.5f * dt - dt * dt * dt * (1.0f / 48.0f) * speed * speed);
        dq.w = 1.0f - 0.5f * half_angle * half_angle;
    } else {
        dq.xyz = w * (sin(half_angle) / speed);
        dq.w = cos(half_angle);
    }
    float4 turned = quat_mul(dq, q);
    return quat_normalized(turned);
}

/* The rotation vector w dt that rotate_by_angular_velocity applied (clamped). */
inline float3 turn_of(float3 w, float dt, float max_angular_step)
{
    float3 turned = w * dt;
    float speed = length3(w);
    if (speed * dt > max_angular_step)
        turned *= max_angular_step / (dt * speed);
    return turned;
}

/* q turned by a push's angular velocity over dt, to first order: q + (h, 0) q
 * with h = push dt / 2, renormalised (the push is small and is applied once). */
inline float4 push_orientation(float4 q, float3 h)
{
    float3 hq = h * q.xyz;
    float4 dq = (float4)(q.w * h + (h.yzx * q.zxy - h.zxy * q.yzx), -(hq.x + hq.y + hq.z));
    return normalize(q + dq);
}
