// Colour pass: one fragment. A sun (directional light) with a percentage-closer filtered
// shadow map, a sky/ground hemisphere ambient that shadowed places receive less of (a
// cheap stand-in for ambient occlusion that makes the inside of a pile read as inside),
// a little specular, and a gamma of 2.2 on output.
uniform vec3 light_dir;         // towards the light, unit
uniform vec3 up;                // the scene's up, unit (hemisphere ambient, checker)
uniform vec3 eye;
uniform mat4 light_view_proj;
uniform float shadow_texel;     // world size of one shadow-map texel
uniform int shadows;
uniform sampler2DShadow shadow_map;

in vec3 v_world;
in vec3 v_normal;
in vec4 v_color;

out vec4 f_color;

float sunlight(vec3 n)
{
    if (shadows == 0)
        return 1.0;
    // normal offset: look up the shadow map from a point pushed off the surface, so that a
    // face does not shadow itself
    vec4 p = light_view_proj * vec4(v_world + n * 1.5 * shadow_texel, 1.0);
    vec3 uvz = p.xyz / p.w * 0.5 + 0.5;
    if (any(lessThan(uvz, vec3(0.0))) || any(greaterThan(uvz, vec3(1.0))))
        return 1.0;   // outside the light's box: nothing there casts a shadow
    // four bilinear compares half a texel apart: a 3 x 3 texel footprint, smooth edges
    vec2 texel = 0.5 / vec2(textureSize(shadow_map, 0));
    float z = uvz.z - 0.0005;
    return 0.25 * (texture(shadow_map, vec3(uvz.xy + vec2(-texel.x, -texel.y), z))
                   + texture(shadow_map, vec3(uvz.xy + vec2(texel.x, -texel.y), z))
                   + texture(shadow_map, vec3(uvz.xy + vec2(-texel.x, texel.y), z))
                   + texture(shadow_map, vec3(uvz.xy + vec2(texel.x, texel.y), z)));
}

void main()
{
    vec3 n = normalize(v_normal);
    if (!gl_FrontFacing)
        n = -n;
    vec3 base = v_color.rgb;
    if (v_color.a < 0.5) {
        // static bodies: 1 m checker in world space, sampled just inside the surface
        // (faded out where a square shrinks towards a pixel, which would alias)
        vec3 c = floor(v_world - n * 0.01);
        float fade = clamp(2.0 - 4.0 * length(fwidth(v_world)), 0.0, 1.0);
        base *= 1.0 - 0.12 * fade * mod(c.x + c.y + c.z, 2.0);
    }
    float sun = sunlight(n);
    float diffuse = max(dot(n, light_dir), 0.0) * sun;
    float hemi = 0.5 + 0.5 * dot(n, up);
    vec3 ambient = mix(vec3(0.30, 0.28, 0.26), vec3(0.62, 0.68, 0.78), hemi)
                   * (0.55 + 0.45 * sun);
    vec3 view = normalize(eye - v_world);
    float spec = pow(max(dot(n, normalize(view + light_dir)), 0.0), 40.0) * sun;
    vec3 colour = base * (ambient + vec3(1.0, 0.96, 0.88) * 0.95 * diffuse) + 0.12 * spec;
    f_color = vec4(pow(clamp(colour, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);
}
