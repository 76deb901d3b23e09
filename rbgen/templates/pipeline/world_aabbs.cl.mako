/* World-space AABB of every body.
 *
 * One work-item per body; a work group is responsible for ${work_group_size}
 * consecutive bodies (see write_world_aabb), swept along its travel when it
 * is fast (sweep_world_aabb). A World computes its AABBs in
 * prepare_bodies instead (one launch less per step); this kernel serves
 * callers without that stage.
 */
${cl_constants()}

${cl_structs("Body", "Shape", "Aabb")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/world_aabb.cl.mako"/>

__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void compute_world_aabbs(__global const Body* bodies,
                         __global const Shape* shapes,
                         __global const float4* hull_vertices,
                         __global Aabb* aabbs,
                         const uint body_count,
                         const float margin)
{
    uint i = get_global_id(0);
    if (i >= body_count)
        return;
    Body body = bodies[i];
    float3 r0, r1, r2;
    quat_to_rows(body.orientation, &r0, &r1, &r2);
    write_world_aabb(body, shapes[body.shape], r0, r1, r2, hull_vertices, margin, &aabbs[i]);
    sweep_world_aabb(body, &aabbs[i]);
}
