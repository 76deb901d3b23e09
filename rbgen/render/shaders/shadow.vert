// Shadow pass: one vertex of one instance, into the light's orthographic clip space.
uniform mat4 light_view_proj;

in vec3 in_vert;
in vec3 in_pos;
in vec4 in_rot;

void main()
{
    gl_Position = light_view_proj * vec4(in_pos + quat_rotate(in_rot, in_vert), 1.0);
}
