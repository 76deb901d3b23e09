/* Resetting environments of a WorldBatch between steps, on the device.
 *
 *   reset_bodies     one work-item per body reset: its new record from `states`
 *                    (environment envs[i / bodies_per_env], body i % bodies_per_env);
 *   forget_contacts  one work-item per constraint of the last step: a constraint
 *                    touching a body of a reset environment loses its key (both
 *                    bodies RB_SOLVER_NONE), so the next step warm-starts nothing of
 *                    it, as after `World.set_state` (rbgen.history).
 *
 * A work group is responsible for ${work_group_size} consecutive items; counts read
 * from the device exit past them, so the host launches over the capacity.
 */
${cl_constants()}

${cl_structs("Body", "ContactConstraint")}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void reset_bodies(__global Body* bodies,
                  __global const Body* states,
                  __global const uint* envs,
                  const uint count,
                  const uint bodies_per_env,
                  const uint first_env_body)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    uint env = envs[i / bodies_per_env];
    bodies[first_env_body + env * bodies_per_env + i % bodies_per_env] = states[i];
}

/* Whether a body's environment (its collision word, env << 1 | static) is reset;
 * shared static geometry belongs to none. */
inline bool in_reset(__global const uint* words, __global const uint* reset_flags, uint body)
{
    uint word = words[body];
    return word != RB_SHARED_STATIC && reset_flags[word >> 1] != 0;
}

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void forget_contacts(__global ContactConstraint* constraints,
                     __global const uint* constraint_count,
                     __global const uint* words,
                     __global const uint* reset_flags)
{
    uint i = get_global_id(0);
    if (i >= constraint_count[0])
        return;
    uint a = constraints[i].body_a, b = constraints[i].body_b;
    if (a == RB_SOLVER_NONE)
        return;  /* forgotten already */
    if (in_reset(words, reset_flags, a) || in_reset(words, reset_flags, b)) {
        constraints[i].body_a = RB_SOLVER_NONE;
        constraints[i].body_b = RB_SOLVER_NONE;
    }
}
