/* Quaternion and rotation helpers. Quaternions are float4 (x, y, z, w) with
 * w the scalar part; rotations are body-to-world. */
<%include file="/common/inline_math.cl.mako"/>

inline float4 quat_mul(float4 a, float4 b)
{
    return (float4)(a.w * b.xyz + b.w * a.xyz + cross3(a.xyz, b.xyz),
                    a.w * b.w - dot3(a.xyz, b.xyz));
}

inline float4 quat_conjugate(float4 q)
{
    return (float4)(-q.xyz, q.w);
}

/* q v q*, expanded: v + 2w (u x v) + 2 u x (u x v) with u = q.xyz. */
inline float3 quat_rotate(float4 q, float3 v)
{
    float3 t = 2.0f * cross3(q.xyz, v);
    return v + q.w * t + cross3(q.xyz, t);
}

/* Rows of the rotation matrix of a unit quaternion. */
inline void quat_to_rows(float4 q, float3* r0, float3* r1, float3* r2)
{
    float xx = q.x * q.x, yy = q.y * q.y, zz = q.z * q.z;
    float xy = q.x * q.y, xz = q.x * q.z, yz = q.y * q.z;
    float wx = q.w * q.x, wy = q.w * q.y, wz = q.w * q.z;
    *r0 = (float3)(1.0f - 2.0f * (yy + zz), 2.0f * (xy - wz), 2.0f * (xz + wy));
    *r1 = (float3)(2.0f * (xy + wz), 1.0f - 2.0f * (xx + zz), 2.0f * (yz - wx));
    *r2 = (float3)(2.0f * (xz - wy), 2.0f * (yz + wx), 1.0f - 2.0f * (xx + yy));
}
