/* Sleeping islands (rbgen.pipeline.sleep): bodies at rest stop costing work.
 *
 * A body's rest timer grows while its fastest surface point, |v| + |w| extent,
 * moves slower than the threshold, and restarts otherwise. Islands are the
 * connected components of the awake dynamic bodies over the step's constraint
 * edges (contacts and joints; static bodies join nothing), found by a lock-free
 * union-find: a root only ever hooks under a lower root, so every island's root,
 * its label, is its lowest body index whatever order the atomics ran in. An
 * island whose every body has rested `time_to_sleep` falls asleep: its bodies'
 * velocities are zeroed, their inverse mass is set to 0 and their collision words
 * get RB_GROUP_STATIC, so that the other stages treat them as static (no pair
 * between two of them, no gravity, no integration, no colour conflict). An awake
 * body touching a sleeping one wakes that body's whole island (its label is kept
 * while it sleeps), as do forces applied to one of its bodies.
 *
 * End of a step, in order:
 *   sleep_begin    one work-item per body: its record backed up (for a redo), its
 *                  union-find node and marks cleared, its rest timer updated;
 *   sleep_link     one work-item per constraint edge: two awake dynamic bodies
 *                  united; an awake dynamic body touching a sleeping one marks the
 *                  sleeping island RB_SLEEP_WAKE;
 *   sleep_islands  one work-item per awake dynamic body: its island's root is its
 *                  label; a body that has not rested long enough marks the island
 *                  RB_SLEEP_RESTLESS;
 *   sleep_apply    one work-item per body: an island unmarked falls asleep, one
 *                  marked RB_SLEEP_WAKE wakes; each body's record, inverse mass and
 *                  collision word then agree.
 * Between steps, a WorldBatch reset: sleep_wake_environments (one work-item per
 * body: the bodies of the reset environments are awake and have not rested).
 * Start of a step that has forces, or after the host changed bodies or sleep
 * records: sleep_wake_forced (one work-item per body: a sleeping body with a force
 * or torque marks its island RB_SLEEP_WAKE), then sleep_apply without deciding.
 *
 * A work group is responsible for ${work_group_size} consecutive bodies or edges;
 * counts read from the device exit past them, so the host launches over capacity.
 */
${cl_constants()}

${cl_structs("Body", "BodySleep", "ConstraintEdge")}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sleep_begin(__global const Body* bodies,
                 __global BodySleep* records,
                 __global BodySleep* backup,
                 __global uint* parent,
                 __global uint* marks,
                 const uint body_count,
                 const float dt,
                 const float threshold)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    BodySleep record = records[i];
    backup[i] = record;
    parent[i] = i;
    marks[i] = 0;
    if (record.inv_mass == 0.0f || record.asleep != RB_SLEEP_AWAKE)
        return;
    float3 v = bodies[i].linear_velocity.xyz, w = bodies[i].angular_velocity.xyz;
    float speed = length(v) + length(w) * record.extent;
    record.timer = speed > threshold ? 0.0f : record.timer + dt;
    record.island = i;
    records[i] = record;
}

/* The root of x's tree, halving the path on the way (each write names an ancestor,
 * so a stale one is still true: trees only ever merge). */
inline uint find_root(volatile __global uint* parent, uint x)
{
    for (;;) {
        uint p = parent[x];
        if (p == x)
            return x;
        uint g = parent[p];
        if (g == p)
            return p;
        parent[x] = g;
        x = g;
    }
}

/* Joins the trees of a and b: the higher root hooks under the lower one, by a
 * compare-and-swap that fails (and retries) when that root was hooked meanwhile. */
inline void unite(volatile __global uint* parent, uint a, uint b)
{
    for (;;) {
        a = find_root(parent, a);
        b = find_root(parent, b);
        if (a == b)
            return;
        uint high = max(a, b), low = min(a, b);
        if (atomic_cmpxchg(&parent[high], high, low) == high)
            return;
    }
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sleep_link(__global const ConstraintEdge* edges,
                __global const uint* edge_count,
                __global const BodySleep* records,
                volatile __global uint* parent,
                volatile __global uint* marks)
{
    uint e = get_global_id(0);
    if (e >= edge_count[0])
        return;
    uint a = edges[e].body_a, b = edges[e].body_b;
    if (a == b)
        return;  /* a joint to the world */
    BodySleep ra = records[a], rb = records[b];
    if (ra.inv_mass == 0.0f || rb.inv_mass == 0.0f)
        return;  /* static bodies join no island */
    if (ra.asleep == RB_SLEEP_AWAKE && rb.asleep == RB_SLEEP_AWAKE)
        unite(parent, a, b);
    else if (ra.asleep != rb.asleep)
        atomic_or(&marks[ra.asleep != RB_SLEEP_AWAKE ? ra.island : rb.island], RB_SLEEP_WAKE);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sleep_islands(__global BodySleep* records,
                   volatile __global uint* parent,
                   volatile __global uint* marks,
                   const uint body_count,
                   const float time_to_sleep)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    BodySleep record = records[i];
    if (record.inv_mass == 0.0f || record.asleep != RB_SLEEP_AWAKE)
        return;
    uint root = find_root(parent, i);
    records[i].island = root;
    if (record.timer < time_to_sleep)
        atomic_or(&marks[root], RB_SLEEP_RESTLESS);
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sleep_wake_forced(__global const BodySleep* records,
                       volatile __global uint* marks,
                       const uint body_count,
                       __global const float4* forces,
                       __global const float4* lever_forces,
                       __global const float4* moments,
                       const uint force_terms)
{
    uint i = get_global_id(0);
    if (i >= body_count || records[i].asleep == RB_SLEEP_AWAKE)
        return;
    bool pushed = ((force_terms & RB_FORCE_FORCE) && any(forces[i].xyz != 0.0f))
               || ((force_terms & RB_FORCE_LEVER) && any(lever_forces[i].xyz != 0.0f))
               || ((force_terms & RB_FORCE_MOMENT) && any(moments[i].xyz != 0.0f));
    if (pushed)
        atomic_or(&marks[records[i].island], RB_SLEEP_WAKE);
}

/* `decide`: 1 at the end of a step (islands fall asleep or wake), 0 at the start
 * of one (sleeping islands marked RB_SLEEP_WAKE wake; the bodies and collision
 * words, which the host may have rewritten, are made to agree with the records). */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sleep_apply(__global Body* bodies,
                 __global BodySleep* records,
                 __global uint* words,
                 __global const uint* marks,
                 const uint body_count,
                 const uint decide)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    BodySleep record = records[i];
    if (record.inv_mass == 0.0f)
        return;
    uint mark = marks[record.island];
    if (record.asleep == RB_SLEEP_AWAKE) {
        if (decide && !(mark & RB_SLEEP_RESTLESS)) {
            record.asleep = RB_SLEEP_ASLEEP;
            records[i].asleep = RB_SLEEP_ASLEEP;
        }
    } else if (mark & RB_SLEEP_WAKE) {
        record.asleep = RB_SLEEP_AWAKE;
        record.timer = 0.0f;
        records[i] = record;
    }
    if (record.asleep == RB_SLEEP_AWAKE) {
        bodies[i].inv_mass = record.inv_mass;
        words[i] &= ~(uint)RB_GROUP_STATIC;
    } else {
        bodies[i].inv_mass = 0.0f;
        bodies[i].linear_velocity = (float4)(0.0f);
        bodies[i].angular_velocity = (float4)(0.0f);
        words[i] |= RB_GROUP_STATIC;
    }
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void sleep_wake_environments(__global BodySleep* records,
                             __global const uint* words,
                             __global const uint* reset_flags,
                             const uint body_count)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    uint word = words[i];
    if (word == RB_SHARED_STATIC || reset_flags[word >> 1] == 0)
        return;
    records[i].asleep = RB_SLEEP_AWAKE;
    records[i].timer = 0.0f;
    records[i].island = i;
}
