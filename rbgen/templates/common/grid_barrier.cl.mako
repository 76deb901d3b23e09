/* A barrier across every work group of one launch, for kernels that loop
 * over dependent phases (colour after colour) without a launch per phase.
 * It needs every work group of the launch running at once: the host launches
 * no more groups than the device runs together (one per compute unit, see
 * rbgen.pipeline.grid), so that a group spinning here never waits for one
 * that has not started. OpenCL 1.2 promises no such forward progress; the
 * launch size is what makes it hold.
 *
 * sync[0] counts the arrivals since the launch began: every group passes the
 * same sequence of barriers, so a group whose arrival is number a (from 0) is
 * at barrier a / groups, which opens once (a / groups + 1) * groups arrivals
 * are in. One atomic to arrive and polls to leave: no reset between barriers,
 * which would cost a round trip to the shared cache each, and no count of
 * barriers kept by the lanes (a private counter live across barriers hung
 * PoCL's colouring with 4 or more lanes a group). sync[1] counts the groups
 * that have left their last barrier (grid_leave): the last of them zeroes
 * both words, so the buffer is zero between launches and serves every launch
 * that uses it, one launch at a time.
 *
 * Visibility: every lane fences its global writes before arriving, so that
 * they reach the device's shared cache before any group leaves (a write
 * fence: NVIDIA's compiler makes write_mem_fence(CLK_GLOBAL_MEM_FENCE) a
 * device-wide membar.gl, but mem_fence(CLK_GLOBAL_MEM_FENCE) only a
 * membar.cta, and barrier(CLK_GLOBAL_MEM_FENCE) no fence at all). That alone
 * does not make them seen: an NVIDIA compute unit serves plain global loads
 * from its own L1 cache, which other compute units' stores do not update, so
 * a line it read before the barrier can be stale after it. Data that another
 * work group writes during the launch must therefore be read through a
 * volatile pointer (a load from the shared cache) or an atomic; data that
 * only the lane that wrote it reads back needs neither. */

/* one work group's turn at the barrier (one lane): arrive, and wait for the
 * arrivals that open this barrier. Not inlined: kept out of the work group's
 * barrier regions, so that PoCL, which turns the code between barriers into
 * loops over the lanes, sees one call there instead of a spinning loop:
 * inlined, the loop broke the colouring of batching_global with more than one
 * lane a group (stores of one phase lost: bids of earlier rounds survived
 * their clearing), the cause inside PoCL not pinned down */
__attribute__((noinline))
void grid_arrive_and_wait(volatile __global uint* sync)
{
    const uint groups = get_num_groups(0);
    const uint open_at = (atomic_inc(&sync[0]) / groups + 1) * groups;
    while (sync[0] < open_at)
        ;
}

inline void grid_barrier(volatile __global uint* sync)
{
    write_mem_fence(CLK_GLOBAL_MEM_FENCE);
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0)
        grid_arrive_and_wait(sync);
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
}

/* After a kernel's last grid barrier, by every work group: the last group to
 * leave zeroes the barrier's words for the next launch (every other group
 * has stopped polling them by then). */
inline void grid_leave(volatile __global uint* sync)
{
    if (get_local_id(0) == 0 && atomic_inc(&sync[1]) == get_num_groups(0) - 1) {
        atomic_xchg(&sync[0], 0u);
        atomic_xchg(&sync[1], 0u);
    }
}
