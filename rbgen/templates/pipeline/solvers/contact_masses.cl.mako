<%doc>
  The effective masses of a contact constraint's rows, shared by the constraint
  setup (constraints.cl.mako), the Jacobi solver (jacobi.cl.mako), which
  recomputes them for bodies split over their contacts, and the PGS solver
  (pgs.cl.mako), whose shock sweep recomputes the normal rows' with a body held. The including template
  supplies the parameter friction, the struct ContactConstraint and
  common/inline_math.cl.mako.
</%doc>
/* 1 / (J M^-1 J^T) for a row with direction d at lever arms ra, rb. */
inline float row_mass(float3 d, float3 ra, float3 rb, float inv_mass_a, float inv_mass_b,
                      const float3 inv_inertia_a[3], const float3 inv_inertia_b[3])
{
    float3 ca = cross3(ra, d), cb = cross3(rb, d);
    float k = inv_mass_a + inv_mass_b + dot3(ca, mul_rows(inv_inertia_a, ca))
            + dot3(cb, mul_rows(inv_inertia_b, cb));
    return k > 0.0f ? 1.0f / k : 0.0f;
}

/* The effective masses of every row of constraint c (its frame and lever
 * arms set) between bodies of these inverse masses and world inverse
 * inertias: per point the normal row,
 * the friction pair at the centre of the points (tangent slot 0) and the
 * twist row about the normal (tangent1 slot 1).
 */
void set_row_masses(__private ContactConstraint* c, float inv_mass_a,
                    const float3 inv_inertia_a[3], float inv_mass_b,
                    const float3 inv_inertia_b[3])
{
    float3 n = c->normal.xyz, t1 = c->tangent1.xyz, t2 = c->tangent2.xyz;
    float normal_mass[4] = {0}, tangent1_mass[4] = {0}, tangent2_mass[4] = {0};
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) {
        if (k >= c->point_count)
            continue;
        float3 ra = c->r_a[k].xyz, rb = c->r_b[k].xyz;
        normal_mass[k] = row_mass(n, ra, rb, inv_mass_a, inv_mass_b, inv_inertia_a, inv_inertia_b);
    }
    float3 centre_a = (float3)(0.0f), centre_b = (float3)(0.0f);
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < c->point_count)
        centre_a += c->r_a[k].xyz, centre_b += c->r_b[k].xyz;
    float share = c->point_count > 0 ? 1.0f / (float)c->point_count : 0.0f;
    centre_a *= share;
    centre_b *= share;
    tangent1_mass[0] = row_mass(t1, centre_a, centre_b, inv_mass_a, inv_mass_b, inv_inertia_a,
                                inv_inertia_b);
    tangent2_mass[0] = row_mass(t2, centre_a, centre_b, inv_mass_a, inv_mass_b, inv_inertia_a,
                                inv_inertia_b);
    float twist = dot3(n, mul_rows(inv_inertia_a, n)) + dot3(n, mul_rows(inv_inertia_b, n));
    tangent1_mass[1] = twist > 0.0f ? 1.0f / twist : 0.0f;
    c->normal_mass = (float4)(normal_mass[0], normal_mass[1], normal_mass[2], normal_mass[3]);
    c->tangent1_mass = (float4)(tangent1_mass[0], tangent1_mass[1], tangent1_mass[2],
                                tangent1_mass[3]);
    c->tangent2_mass = (float4)(tangent2_mass[0], tangent2_mass[1], tangent2_mass[2],
                                tangent2_mass[3]);
}
