/* A barrier across every work group of one launch, for kernels that loop
 * over dependent phases (colour after colour) without a launch per phase.
 * It needs every work group of the launch running at once: the host launches
 * no more groups than the device runs together (one per compute unit, see
 * rbgen.pipeline.device_barrier), so that a group spinning here never waits for one
 * that has not started. OpenCL 1.2 promises no such forward progress; the
 * launch size is what makes it hold.
 *
 * sync[RB_BARRIER_ARRIVALS] counts the arrivals since the launch began: every
 * group passes the same sequence of barriers, so a group whose arrival is
 * number a (from 0) is at barrier a / groups, which opens once
 * (a / groups + 1) * groups arrivals are in. One atomic to arrive and polls
 * to leave: no reset between barriers, which would cost a round trip to the
 * shared cache each, and no count of barriers kept by the lanes (a private
 * counter live across barriers hung PoCL's colouring with 4 or more lanes a
 * group). sync[RB_BARRIER_DEPARTURES]
 * counts the groups that have left (device_barrier_leave): the last of them zeroes both
 * counters, so they are zero between launches and the buffer serves every
 * launch that uses it, one launch at a time.
 *
 * Giving up instead of hanging: should the groups not all run at once after
 * all (a GPU shared with other processes through MPS, a driver that holds
 * groups back), the groups that do run would wait for ever. A waiting group
 * therefore gives up after sync[RB_BARRIER_SPIN_LIMIT] polls (set by the host:
 * seconds on the device, far beyond any phase; 0: never), sets
 * sync[RB_BARRIER_ABANDONED], and every group then skips the rest of its work,
 * passing its remaining barriers without waiting (a kernel started after the
 * flag was set does nothing): the launch ends with its work undone and the
 * flag set, which the host reads without blocking, redoing
 * the step in a mode without device-wide barriers. Kernels that run one after
 * another on one step's data share the buffer, so a later one does nothing
 * after an earlier one gave up. The flag stays set until the host clears it.
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
 * arrivals that open this barrier; returns false if the barrier was abandoned
 * (by this group after its polls ran out, or by another). Not inlined: kept
 * out of the work group's barrier regions, so that PoCL, which turns the code
 * between barriers into loops over the lanes, sees one call there instead of
 * a spinning loop: inlined, the loop broke the colouring of batching_global
 * with more than one lane a group (stores of one phase lost: bids of earlier
 * rounds survived their clearing), the cause inside PoCL not pinned down */
__attribute__((noinline))
bool barrier_arrive_and_wait(volatile __global uint* sync)
{
    const uint groups = get_num_groups(0);
    const uint open_at = (atomic_inc(&sync[RB_BARRIER_ARRIVALS]) / groups + 1) * groups;
    const uint limit = sync[RB_BARRIER_SPIN_LIMIT];
    for (uint polls = 1; sync[RB_BARRIER_ARRIVALS] < open_at; ++polls) {
        /* (the flag every 256 polls: a poll is a round trip to the shared cache) */
        if ((polls & 255u) == 0u && sync[RB_BARRIER_ABANDONED] != 0u)
            return false;
        if (polls == limit) {
            atomic_xchg(&sync[RB_BARRIER_ABANDONED], 1u);
            return false;
        }
    }
    return true;
}

/* A barrier across the launch's work groups. `ok`: a __local word of the
 * kernel's (device_barrier_start sets it), 1 while every barrier has passed; a group
 * whose wait was abandoned (by itself or another) gets 0 here, every lane
 * alike, and from then on passes its barriers without waiting, doing none of
 * its work (callers test `ok` around every phase). The local barriers stay
 * unconditional: PoCL miscompiled kernels that left their barrier loops
 * early (a return there ran lane 0's code on every lane, and crashed). */
inline void device_barrier(volatile __global uint* sync, __local uint* ok)
{
    write_mem_fence(CLK_GLOBAL_MEM_FENCE);
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0 && *ok)
        *ok = barrier_arrive_and_wait(sync);
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
}

/* At a kernel's start: `ok` = 1, or 0 when an earlier persistent launch on this
 * buffer gave up (the kernel then does none of its work). */
inline void device_barrier_start(volatile __global uint* sync, __local uint* ok)
{
    if (get_local_id(0) == 0)
        *ok = sync[RB_BARRIER_ABANDONED] == 0u;
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* After a kernel's last device-wide barrier, by every work group once: the last
 * group to leave zeroes the counters for the next launch (every other group
 * has stopped polling them by then). */
inline void device_barrier_leave(volatile __global uint* sync)
{
    if (get_local_id(0) == 0 && atomic_inc(&sync[RB_BARRIER_DEPARTURES]) == get_num_groups(0) - 1) {
        atomic_xchg(&sync[RB_BARRIER_ARRIVALS], 0u);
        atomic_xchg(&sync[RB_BARRIER_DEPARTURES], 0u);
    }
}
