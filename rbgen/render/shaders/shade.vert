// Colour pass: one vertex of one instance, with its world position and normal for lighting.
uniform mat4 view_proj;

in vec3 in_vert;
in vec3 in_norm;
in vec3 in_pos;
in vec4 in_rot;
in vec4 in_color;   // rgb linear; a = 1 for dynamic bodies, 0 for static ones (checkered)

out vec3 v_world;
out vec3 v_normal;
out vec4 v_color;

void main()
{
    v_world = in_pos + quat_rotate(in_rot, in_vert);
    v_normal = quat_rotate(in_rot, in_norm);
    v_color = in_color;
    gl_Position = view_proj * vec4(v_world, 1.0);
}
