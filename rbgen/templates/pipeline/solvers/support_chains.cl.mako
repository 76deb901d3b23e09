<%doc>
  Support chains: the functions of the pass that follows a substep's velocity sweeps and
  stops a stack from sinking into itself along whole chains of supports. Included by
  solvers/pgs.cl.mako (a persistent launch runs the pass between its sweeps and the
  bodies' move) and by solvers/support.cl.mako (its kernels, one launch a phase, for
  every other solve). The including template supplies the structs ContactConstraint and
  Body and common/inline_math.cl.mako. `velocity_space`: where the bodies live
  (a persistent launch reads them through volatile pointers).
</%doc>
<%page args="velocity_space='__global'"/>\
/* Support chains. A few sweeps carry a stack's weight down only a few layers a sweep,
 * and a stack whose contacts are new (or whose load changed) sinks while its weight
 * finds its way to the ground: about g (T h)^2 / 2 for T substeps of h, where T grows
 * with the stack's height. The shock sweep holds each lower body still, but in colour
 * order, not from the ground up. This pass does in a few phases what a sweep from the
 * ground up would do for the motion along the normals: after the sweeps of each
 * substep, every dynamic body that a contact holds up against gravity (tangent1.w,
 * shock_holds) takes one such contact as its support (offer_support: a touching one
 * first, then the lowest index), and a body approaching its support along that contact's
 * normal faster than the contact's gap allows (its nearest point's, over the substep)
 * gains the velocity against gravity (along `up`) that stops it, its support's gain
 * included:
 *   gain_k = max(0, e_k + c_k gain_(support's lower body)),
 *   e_k = ((v_lower - v_k) . n_k - gap_k / h) / (up . n_k),   c_k = 1
 * (c_k 0 where the lower body has no support: its gain is 0). Linear velocities: turning
 * is the sweeps' business (support_link: a body that tips over an edge is not sinking).
 * Along `up`, not n: a contact's normal tilts as its boxes rock, and gains along it
 * walked a pyramid's top sideways a centimetre in 10 s. Such maps compose, max(a, e + c x)
 * after max(a', e' + c' x) is max(max(a, e + c a'), (e + c e') + (c c') x) for c >= 0,
 * so `rounds` rounds of pointer jumping (each link composed with its ancestor's, and the
 * ancestor replaced by the ancestor's) solve every chain of up to 2^rounds bodies, and
 * deeper ones from their lowest 2^rounds links up. It is a velocity projection, as the
 * shock sweep is: it adds the momentum that the ground would have given a rigid stack,
 * and no contact impulse, so the warm start still learns the loads from the sweeps. */

/* a chain that ends (a link's ancestor); as a key, no support */
#define RB_NO_SUPPORT 0xffffffffu
/* a support's key: set when every point of its contact is apart (below it the index,
 * 30 bits, or its complement: offer_support) */
#define RB_SUPPORT_APART 0x80000000u
#define RB_SUPPORT_INDEX 0x3fffffffu
/* support_link's slack, in what gravity adds to a velocity over a substep: how much
 * slower than its centre a body's fastest point may approach its support and the body
 * still count as sinking (a lattice's boxes rock by less; a box tipping over an edge
 * turns by more) */
#define RB_SUPPORT_SLACK 0.5f

/* The body that contact c holds up against gravity, else RB_NO_SUPPORT. */
inline uint held_up(__global const ContactConstraint* c)
{
    const float holds = c->tangent1.w;
    if (holds == (float)RB_SHOCK_HOLDS_A)
        return c->body_b;
    return holds == (float)RB_SHOCK_HOLDS_B ? c->body_a : RB_NO_SUPPORT;
}

/* The body that holds the other up (a contact that holds one up). */
inline uint holding_up(__global const ContactConstraint* c)
{
    return c->tangent1.w == (float)RB_SHOCK_HOLDS_A ? c->body_a : c->body_b;
}

/* The contact's unit normal pointing into the body it holds up. */
inline float3 up_normal(__global const ContactConstraint* c)
{
    const float3 n = c->normal.xyz;
    return c->tangent1.w == (float)RB_SHOCK_HOLDS_A ? n : -n;
}

/* The speed (>= 0) at which the contact's bodies may approach over the substep: its
 * nearest point's gap over h (the velocity targets, contact_targets.cl.mako: -gap / h
 * while apart, 0 once touching). */
inline float allowed_approach(__global const ContactConstraint* c)
{
    const float4 t = c->velocity_target;
    const uint count = c->point_count;
    float nearest = t.x;
    if (count > 1)
        nearest = max1(nearest, t.y);
    if (count > 2)
        nearest = max1(nearest, t.z);
    if (count > 3)
        nearest = max1(nearest, t.w);
    return count > 0 ? max1(-nearest, 0.0f) : 0.0f;
}

/* Contact i (i < 2^30) offers itself as the support of the body it holds up: the
 * lowest key of a body's offers wins, a contact with a point touching before one all
 * apart, then the lowest index, or with `flip` (RB_SUPPORT_INDEX) the highest: substeps
 * alternate, as a body's supports are solved in turn, so that none leans on one side of
 * a brick wall (the lowest always: a pyramid's top walked 2 cm sideways in 10 s).
 * supports[k] keeps the complement of body k's lowest key, so that zero, its value
 * between passes (support_apply clears it again), is no support. */
inline void offer_support(__global const ContactConstraint* constraints, const uint i,
                          const uint flip, volatile __global uint* supports)
{
    __global const ContactConstraint* c = &constraints[i];
    const uint upper = held_up(c);
    if (upper == RB_NO_SUPPORT)
        return;
    const uint key = (allowed_approach(c) > 0.0f ? RB_SUPPORT_APART : 0u) | (i ^ flip);
    atomic_max(&supports[upper], ~key);
}

/* Body k's support key (RB_NO_SUPPORT: none). */
inline uint support_key(volatile __global const uint* supports, const uint k)
{
    return ~supports[k];
}

/* The contact of support key `key` (offered with `flip`). */
inline __global const ContactConstraint* support_contact(
        __global const ContactConstraint* constraints, const uint key, const uint flip)
{
    return &constraints[(key & RB_SUPPORT_INDEX) ^ flip];
}

/* Body k's link (a, e, c, as_float(ancestor)): gain_k = max(a, e + c gain_ancestor),
 * no ancestor (RB_NO_SUPPORT) counting as a gain of 0 (see above); `up`: against
 * gravity, a unit vector; `slack`: RB_SUPPORT_SLACK |g| h. */
inline float4 support_link(__global const ContactConstraint* constraints,
                           ${velocity_space} const Body* bodies,
                           volatile __global const uint* supports, const uint flip,
                           const float3 up, const float slack, const uint k)
{
    const uint key = support_key(supports, k);
    if (key == RB_NO_SUPPORT)
        return (float4)(0.0f, 0.0f, 0.0f, as_float(RB_NO_SUPPORT));
    __global const ContactConstraint* c = support_contact(constraints, key, flip);
    const uint lower = holding_up(c);
    const float3 n = up_normal(c);
    const bool a_low = c->tangent1.w == (float)RB_SHOCK_HOLDS_A;
    const float3 vl = bodies[lower].linear_velocity.xyz, wl = bodies[lower].angular_velocity.xyz;
    const float3 vu = bodies[k].linear_velocity.xyz, wu = bodies[k].angular_velocity.xyz;
    const float4 t4 = c->velocity_target;
    const float targets[4] = {t4.x, t4.y, t4.z, t4.w};
    const uint count = c->point_count;
    /* the centre's approach (what a sinking stack's bodies share), unless its fastest
     * point approaches slower by more than `slack`: a body that turns about a point that
     * holds still (it tips over an edge) is not sinking, and lifting its centre lifted
     * the point and threw it (a dropped pile's boxes flew at 3 m/s); then that point's */
    float fastest = -FLT_MAX;
    for (uint p = 0; p < RB_MAX_MANIFOLD_POINTS; ++p) if (p < count) {
        const float3 r_low = a_low ? c->r_a[p].xyz : c->r_b[p].xyz;
        const float3 r_up = a_low ? c->r_b[p].xyz : c->r_a[p].xyz;
        fastest = max1(fastest, dot3(vl + cross3(wl, r_low) - vu - cross3(wu, r_up), n)
                                    - max1(-targets[p], 0.0f));
    }
    const float centre = dot3(vl - vu, n) - allowed_approach(c);
    /* (a gain along `up` closes the approach along n by gain (up . n), up . n >= cos 45) */
    const float e = (fastest >= centre - slack ? centre : fastest) / max1(dot3(up, n), 0.5f);
    const uint below = support_key(supports, lower);
    return (float4)(0.0f, e, below == RB_NO_SUPPORT ? 0.0f : 1.0f,
                    as_float(below == RB_NO_SUPPORT ? RB_NO_SUPPORT : lower));
}

/* One round of pointer jumping: body k's link composed with its ancestor's (`links`:
 * the previous round's). */
inline float4 support_jump(volatile __global const float4* links, const uint k)
{
    const float4 r = links[k];
    const uint ancestor = as_uint(r.w);
    if (ancestor == RB_NO_SUPPORT)
        return r;
    const float4 p = links[ancestor];
    return (float4)(max1(r.x, r.y + r.z * p.x), r.y + r.z * p.y, r.z * p.z, p.w);
}

/* Body k takes its gain along `up` (its link after the last round; an ancestor left
 * means a chain deeper than the rounds reach: its gain is taken as 0), and is left
 * without a support for the next substep's offers. */
inline void support_apply(${velocity_space} Body* bodies, volatile __global uint* supports,
                          const float3 up, const float4 link, const uint k)
{
    if (support_key(supports, k) == RB_NO_SUPPORT)
        return;
    supports[k] = 0u;
    const float gain = max1(link.x, link.y);
    if (gain > 0.0f)
        bodies[k].linear_velocity = (float4)(bodies[k].linear_velocity.xyz + gain * up, 0.0f);
}
