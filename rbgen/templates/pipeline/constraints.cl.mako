/* Contact manifolds -> contact constraints (one per manifold, up to four
 * points, each with a normal row and two friction rows), and the constraint
 * edge of each (layouts: ConstraintEdge), which batching colours.
 *
 * Friction: per manifold, one tangent pair at the centre of the points (slot
 * 0 of the tangent arrays) and a twist row about the normal (slot 1 of
 * tangent1).
 *
 * The body a shock sweep holds still (tangent1.w, RB_SHOCK_HOLDS_*): of two
 * dynamic bodies whose normal is within 45 degrees of the vertical that gravity
 * defines, the lower (none without gravity).
 *
 * For every point: lever arms, effective masses of its rows, the normal
 * velocity target (restitution above a threshold velocity, of the approach
 * before this step's gravity, speculative
 * approach for points still apart,
 * and a separate split-impulse target that pushes out of penetration
 * beyond the slop without adding momentum),
% if warm_start:
 * and the previous step's accumulated impulses (up to a cap that leaves out an
 * impact's: contact_targets.cl.mako's CARRY_GROWTH), found through a hash table
 * keyed by (body a, body b, sub-feature) and matched per point by feature id,
 * else by distance
 * (friction impulses are carried as a world vector and re-projected onto the
 * new tangents); the edge inherits the previous edge's colour.
% else:
 * with zero starting impulses.
% endif
% if filter_joints:
 * A manifold between two bodies joined by a joint gets no point (the joint
 * holds them; a contact there would push against it): `joint_pairs` lists
 * the joined pairs (lower body first), sorted.
% endif
 */
${cl_constants()}

${cl_structs("Body", "BodyInertia", "ContactManifold", "ContactConstraint", "ConstraintEdge")}

<%include file="/common/inline_math.cl.mako"/>
<%include file="/pipeline/solvers/contact_masses.cl.mako"/>

<%include file="/common/hash.cl.mako"/>

<%include file="/pipeline/solvers/contact_targets.cl.mako"/>

/* cos 45 degrees: a contact whose normal is nearer the vertical holds a load
 * against gravity (shock_holds) */
#define SHOCK_VERTICAL 0.70710678f

/* The body a shock sweep holds still of a contact with unit normal n (A to B)
 * between bodies of these inverse masses (layouts: RB_SHOCK_HOLDS_*). */
inline float shock_holds(const float3 n, const float4 gravity, const float inv_mass_a,
                         const float inv_mass_b)
{
    float g2 = dot3(gravity.xyz, gravity.xyz);
    if (!(g2 > 0.0f) || !(inv_mass_a > 0.0f) || !(inv_mass_b > 0.0f))
        return (float)RB_SHOCK_HOLDS_NONE;
    float up = -dot3(n, gravity.xyz) * rsqrt(g2);  /* > 0: B above A */
    if (up >= SHOCK_VERTICAL)
        return (float)RB_SHOCK_HOLDS_A;
    return up <= -SHOCK_VERTICAL ? (float)RB_SHOCK_HOLDS_B : (float)RB_SHOCK_HOLDS_NONE;
}

/* Slot of a manifold's key (body a, body b, sub-feature) in the warm-starting
 * table (linear probing from here). */
inline uint pair_slot(uint a, uint b, uint sub, uint mask)
{
    return hash_pair(a, b, sub) & mask;
}

/* An orthonormal pair of tangents to unit n, chosen from n alone so that a
 * persistent contact keeps the same friction frame from step to step. */
inline void tangent_basis(float3 n, float3* t1, float3* t2)
{
    if (abs1(n.x) > 0.57735f)
        *t1 = normalize3((float3)(n.y, -n.x, 0.0f));
    else
        *t1 = normalize3((float3)(0.0f, n.z, -n.y));
    *t2 = cross3(n, *t1);
}

% if warm_start:

/* Is the previous step's constraint c the one of key (a, b, sub)? */
inline bool has_key(__global const ContactConstraint* c, uint a, uint b, uint sub)
{
    return c->body_a == a && c->body_b == b && c->sub == sub;
}

/* Index of the previous step's constraint of key (a, b, sub), or
 * RB_SOLVER_NONE: first at this constraint's own index i (the narrowphase
 * lists its pairs in a stable order, so a scene at rest finds them there,
 * reading the previous constraints in order), else through the table. */
inline uint find_previous(__global const ContactConstraint* previous, const uint previous_count,
                          __global const uint* previous_table, const uint previous_mask,
                          uint i, uint a, uint b, uint sub)
{
    if (i < previous_count && has_key(&previous[i], a, b, sub))
        return i;
    uint slot = pair_slot(a, b, sub, previous_mask);
    for (uint probe = 0; probe <= previous_mask; ++probe, slot = (slot + 1) & previous_mask) {
        uint j = previous_table[slot];
        if (j == RB_SOLVER_NONE || has_key(&previous[j], a, b, sub))
            return j;
    }
    return RB_SOLVER_NONE;
}

/* Copy the impulses of the previous step's constraint j (same key): per
 * point, those of the old point with the same feature id, else of the
 * nearest old point (relative to B) within match_distance (feature ids change
 * when the narrowphase swaps its reference face on a flat contact), all scaled
 * by the share a warm start carries from the old step's last substep
 * (contact_targets.cl.mako: CARRY_GROWTH, not an impact's impulse). */
inline void warm_start_from(__global const ContactConstraint* old, const float match_distance,
                            ContactConstraint* c)
{
    uint4 old_features = old->features;
    for (uint k = 0; k < c->point_count; ++k) {
        uint feature = ((uint*)&c->features)[k];
        uint match = RB_SOLVER_NONE;
        float nearest = match_distance * match_distance;
        for (uint m = 0; m < old->point_count; ++m) {
            if (((uint*)&old_features)[m] == feature) {
                match = m;
                break;
            }
            float3 d = old->r_b[m].xyz - c->r_b[k].xyz;
            float distance_sq = dot3(d, d);
            if (distance_sq < nearest)
                nearest = distance_sq, match = m;
        }
        if (match == RB_SOLVER_NONE)
            continue;
        ((float*)&c->normal_impulse)[k] = ((__global const float*)&old->normal_impulse)[match];
    }
    /* the manifold's friction pair (slot 0) and twist (tangent1 slot 1) */
    float3 friction = old->tangent1.xyz * old->tangent1_impulse.x
                    + old->tangent2.xyz * old->tangent2_impulse.x;
    c->tangent1_impulse.x = dot3(friction, c->tangent1.xyz);
    c->tangent2_impulse.x = dot3(friction, c->tangent2.xyz);
    c->tangent1_impulse.y = old->tangent1_impulse.y;
    /* the share the old constraint's cap allows (CARRY_GROWTH), of its total over
     * the old points */
    float4 old_impulse = old->normal_impulse;
    float old_total = old_impulse.x + old_impulse.y + old_impulse.z + old_impulse.w;
    float share = carried_share(old_total, old->tangent2_impulse.z, old->tangent2_impulse.w);
    c->normal_impulse *= share;
    c->tangent1_impulse.x *= share;
    c->tangent1_impulse.y *= share;
    c->tangent2_impulse.x *= share;
}
% endif

% if filter_joints:
/* Are bodies a and b joined (a pair of the sorted list, lower body first)? */
inline bool joined(__global const uint2* pairs, uint count, uint a, uint b)
{
    uint lo = min(a, b), hi = max(a, b);
    uint first = 0, end = count;
    while (first < end) {  /* the first pair not below (lo, hi) */
        uint middle = (first + end) / 2;
        uint2 p = pairs[middle];
        if (p.x < lo || (p.x == lo && p.y < hi))
            first = middle + 1;
        else
            end = middle;
    }
    return first < count && pairs[first].x == lo && pairs[first].y == hi;
}

% endif
/* The edge batching colours for contact i (layouts: ConstraintEdge): its bodies,
 * its item (the contact kind is 0: the item is the index), the colour global
 * batching starts it from, and its first point (spatial batching's cell). */
inline ConstraintEdge contact_edge(uint a, uint b, uint i, uint colour, float3 point)
{
    ConstraintEdge edge;
    edge.body_a = a;
    edge.body_b = b;
    edge.item = RB_EDGE_CONTACT << RB_EDGE_KIND_SHIFT | i;
    edge.colour = colour;
    edge.point = (float4)(point, 0.0f);
    return edge;
}

/* Record constraint i under its key (a, b, sub) for the next step's warm start. */
inline void insert_pair(__global uint* table, const uint mask, uint a, uint b, uint sub, uint i)
{
    uint slot = pair_slot(a, b, sub, mask);
    while (atomic_cmpxchg(&table[slot], RB_SOLVER_NONE, i) != RB_SOLVER_NONE)
        slot = (slot + 1) & mask;
}

/* One work-item per manifold: build its constraint and its edge (edges
 * first_contact_edge + i; the edges before them are the joints'); work-item 0
 * also writes the constraint and edge counts, and every work-item empties its
 * share of the next call's table (next_table_size slots; 0: none). A work group
 * is responsible for ${work_group_size} consecutive manifolds. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void setup_contact_constraints(__global const ContactManifold* manifolds,
                               __global const uint* manifold_count,
                               __global const Body* bodies,
                               __global const BodyInertia* inertia,
                               const uint capacity,
                               __global ContactConstraint* constraints,
                               __global uint* constraint_count,
                               __global ConstraintEdge* edges,
                               __global uint* edge_count,
                               const uint first_contact_edge,
                               __global uint* table,
                               const uint table_mask,
                               __global uint* next_table,
                               const uint next_table_size,
% if warm_start:
                               __global uint* kept_count,
                               __global const ContactConstraint* previous,
                               __global const ConstraintEdge* previous_edges,
                               const uint previous_first_contact_edge,
                               __global const uint* previous_count,
                               __global const uint* previous_table,
                               const uint previous_mask,
                               const float warm_start_factor,
                               const float match_distance,
% endif
% if filter_joints:
                               __global const uint2* joint_pairs,
                               const uint joint_pair_count,
% endif
                               const float dt,
                               const float4 gravity,
                               const float restitution_threshold,
                               const float penetration_slop,
                               const float penetration_recovery)
{
    /* the narrowphase reports its true count, which may exceed our capacity
     * (the World then grows the buffers and redoes the step) */
    uint i = get_global_id(0), count = manifold_count[0];
    count = count < capacity ? count : capacity;
    /* the next call's table, emptied here rather than by a launch of its own */
    for (uint slot = i; slot < next_table_size; slot += get_global_size(0))
        next_table[slot] = RB_SOLVER_NONE;
    if (i == 0)
        constraint_count[0] = count, edge_count[0] = first_contact_edge + count;
% if warm_start:
    if (i == 0)
        kept_count[0] = count;  /* for the next step's warm start */
% endif
    if (i >= count)
        return;
    __global const ContactManifold* m = &manifolds[i];
    uint a = m->body_a, b = m->body_b, sub = m->sub;
    float inv_mass_a = bodies[a].inv_mass, inv_mass_b = bodies[b].inv_mass;
    float3 xa = bodies[a].position.xyz, xb = bodies[b].position.xyz;
    float3 va = bodies[a].linear_velocity.xyz, vb = bodies[b].linear_velocity.xyz;
    float3 wa = bodies[a].angular_velocity.xyz, wb = bodies[b].angular_velocity.xyz;
    /* the velocity this step's gravity gave each body */
    float3 fall_a = inv_mass_a > 0.0f ? gravity.xyz * dt : (float3)(0.0f);
    float3 fall_b = inv_mass_b > 0.0f ? gravity.xyz * dt : (float3)(0.0f);
    float3 inv_inertia_a[3], inv_inertia_b[3];
    for (int r = 0; r < 3; ++r) {
        inv_inertia_a[r] = inertia[a].inv_inertia_world[r].xyz;
        inv_inertia_b[r] = inertia[b].inv_inertia_world[r].xyz;
    }

    ContactConstraint c;
    float3 n = m->normal.xyz, t1, t2;
    tangent_basis(n, &t1, &t2);
    c.normal = (float4)(n, m->friction);
    c.tangent1 = (float4)(t1, shock_holds(n, gravity, inv_mass_a, inv_mass_b));
    c.tangent2 = (float4)(t2, m->restitution);
    c.body_a = a;
    c.body_b = b;
    c.sub = sub;
    uint point_count = m->point_count;
    c.point_count = point_count < RB_MAX_MANIFOLD_POINTS ? point_count : RB_MAX_MANIFOLD_POINTS;
% if filter_joints:
    if (joined(joint_pairs, joint_pair_count, a, b))
        c.point_count = 0;  /* (an inactive constraint: the joint holds the pair) */
% endif
    c.features = (uint4)(m->features[0], m->features[1], m->features[2], m->features[3]);
    c.normal_impulse = c.tangent1_impulse = c.tangent2_impulse = c.push_impulse = (float4)(0.0f);
    float velocity_target[4] = {0}, position_target[4] = {0};
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) {
        c.r_a[k] = c.r_b[k] = (float4)(0.0f);
        if (k >= c.point_count)
            continue;
        float3 p = m->points[k].xyz;
        float separation = m->points[k].w;
        float3 ra = p - xa, rb = p - xb;

        /* normal velocity of B relative to A (> 0: separating) */
        float approach = dot3(vb + cross3(wb, rb) - va - cross3(wa, ra), n);
        /* and before this (sub)step's gravity (prepare_bodies added g dt to the dynamic
         * bodies): a bounce returns the speed the bodies came in with, not what
         * gravity adds in the step of the impact (Box2D v3 takes its relative
         * velocity before gravity too) */
        float incoming = approach - dot3(fall_b - fall_a, n);
        float bounce = incoming < -restitution_threshold ? -m->restitution * incoming : 0.0f;
        /* (the separation and the bounce kept for later substeps' targets) */
        c.r_a[k] = (float4)(ra, separation);
        c.r_b[k] = (float4)(rb, bounce);
        /* still apart: close the gap this (sub)step, no further; touching: stop the
         * approach (the bounce comes after the rows, in the step's last velocity
         * sweep: contact_rows.cl.mako's apply_restitution, for points that push) */
        float target = separation > 0.0f ? -separation / dt : 0.0f;
        float push = penetration_recovery / dt * max1(-separation - penetration_slop, 0.0f);
        velocity_target[k] = target;
        /* a point still apart may close (part of) its gap while the others
         * push out: a target of 0 there would make an exactly solved push
         * lift a tilted box whole instead of levelling it, and towers sway */
        position_target[k] = separation > 0.0f ? -penetration_recovery / dt * separation : push;
    }
    set_row_masses(&c, inv_mass_a, inv_inertia_a, inv_mass_b, inv_inertia_b);
    uint colour = RB_SOLVER_NONE;  /* inherited from the previous step's edge, if any */
    c.velocity_target = (float4)(velocity_target[0], velocity_target[1], velocity_target[2], velocity_target[3]);
    c.position_target = (float4)(position_target[0], position_target[1], position_target[2], position_target[3]);
% if warm_start:
    uint old = find_previous(previous, previous_count[0], previous_table, previous_mask, i, a, b,
                             sub);
    if (old != RB_SOLVER_NONE) {
        warm_start_from(&previous[old], match_distance, &c);
        /* global batching starts from the old colour */
        colour = previous_edges[previous_first_contact_edge + old].colour;
    }
    c.normal_impulse *= warm_start_factor;
    c.tangent1_impulse *= warm_start_factor;
    c.tangent2_impulse *= warm_start_factor;
% endif
    /* the cap on the next carry (contact_targets.cl.mako: CARRY_GROWTH): what this
     * one carried, and one substep of gravity (at least CARRY_ACCELERATION) on the
     * reduced mass at the face (the sum of the normal rows' masses) */
    float4 impulse = c.normal_impulse, normal_mass = c.normal_mass;
    c.tangent2_impulse.z = impulse.x + impulse.y + impulse.z + impulse.w;
    c.tangent2_impulse.w = max1(sqrt(dot3(gravity.xyz, gravity.xyz)), CARRY_ACCELERATION) * dt
                           * (normal_mass.x + normal_mass.y + normal_mass.z + normal_mass.w);
    constraints[i] = c;
    edges[first_contact_edge + i] = contact_edge(a, b, i, colour, xb + c.r_b[0].xyz);
    insert_pair(table, table_mask, a, b, sub, i);
}
