// Shared by every pass: an instance's transform. Each vertex of a shape's mesh is
// rotated by its body's unit quaternion (x, y, z, w) and moved to the body's position.
vec3 quat_rotate(vec4 q, vec3 v)
{
    vec3 t = 2.0 * cross(q.xyz, v);
    return v + q.w * t + cross(q.xyz, t);
}
