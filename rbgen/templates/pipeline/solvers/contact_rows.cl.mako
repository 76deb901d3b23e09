<%doc>
  The rows of a contact constraint and how one constraint is solved, shared by
  the Gauss-Seidel solver (pgs.cl.mako) and the Jacobi solver with mass
  splitting (jacobi.cl.mako). The including template supplies the parameter
  normal_solve, the structs Body, BodyInertia, ContactConstraint,
  common/inline_math.cl.mako and contact_masses.cl.mako (row_mass: a shock
  sweep's normal rows); it may pass constraint_space, the address space
  of the constraint the solve functions read and update (default __private: a
  copy the caller loaded; __global: the constraint in place, for the serial
  form, see pgs.cl.mako); and geometry_cache (block normal solve only), with
  which the solve functions read each constraint's FaceBlock and FrictionRows
  from its ContactGeometry record (the struct supplied too) instead of deriving
  them, and store_geometry writes that record; and cpu_hints (the serial form:
  CPU devices), with which the solve functions are inlined into their callers and
  their loops over a manifold's points unrolled (PoCL keeps them as calls over
  stack arrays otherwise); other devices' source is unchanged by it.
</%doc>
<%page args="constraint_space='__private', geometry_cache=False, cpu_hints=False"/>
<%
    # the solve functions' extra parameter with a ContactGeometry cache
    geometry_param = ", __global const ContactGeometry* g" if geometry_cache else ""
    # solve_face_block's K rows (release case 2b) from the cache
    k_param = ", __global const float4* k_rows" if geometry_cache else ""
    # cpu_hints: a solve function inlined into its caller, a loop over points unrolled
    inlined = "__attribute__((always_inline)) inline " if cpu_hints else ""
    unroll = '_Pragma("unroll") ' if cpu_hints else ""
%>\
/* Contact rows: per point a normal row (impulse >= 0, drives the normal
 * velocity to its target), per manifold a friction pair at the centre of the
 * points, clamped to the disc |f| <= mu * the total normal impulse, and a
 * twist row about the normal; the impulses are accumulated. A row's Jacobian
 * terms (lever arm x direction, and the angular velocity change per unit
 * impulse) do not depend on the velocities, so they are computed before the
 * row reads any velocity: Gauss-Seidel is a chain of dependent row updates,
 * and only the dot products and the update itself stay on it. Loops over a
 * manifold's points run to the constant RB_MAX_MANIFOLD_POINTS and test the
 * count inside, so that compilers unroll them and keep the per-point arrays
 * in registers. */
inline float positive_part(float x)
{
    return x > 0.0f ? x : 0.0f;
}

inline void load_inertia(__global const BodyInertia* inertia, uint body, float3 rows[3])
{
    for (int r = 0; r < 3; ++r)
        rows[r] = inertia[body].inv_inertia_world[r].xyz;
}

% if normal_solve == "block":
/* a released point counts as approaching beyond its target, and a pushing
 * point's target as missed, above this fraction of the largest right-hand side
 * (float32 round-off of an exact solve stays far below) */
#define OVERSHOOT_TOLERANCE 1e-4f
/* below these ratios (det / product of the diagonal) the closed forms leave a
 * manifold to the rows: its points nearly on one line (or two coinciding), or
 * bodies (almost) without rotational freedom, where K has fewer independent
 * motions than the closed forms assume */
#define FLAT_SPREAD_RATIO 1e-3f
#define FLAT_MOBILITY_RATIO 1e-4f

/* What solve_face_points needs of its points' geometry (face_block): it
 * depends only on the lever arms, the normal, the tangents and the bodies'
 * masses and world inverse inertias, which hold for a whole step, so a solver
 * may derive it once a step and keep it (ContactGeometry). */
typedef struct {
    float u[4], v[4];          /* the points about their centre along t1, t2 (0 past count) */
    float suu, suv, svv;       /* M = G^T G = diag(count, spread): the spread's entries */
    float inv_spread;          /* 1 / the spread's determinant */
    float3 arm_a[3], arm_b0;   /* lever arm x n of force, moment along u, along v (B: the
                                  moments' arms are A's) */
    float3 turn_a[3], turn_b[3];  /* angular velocity change per unit of each */
    float3 q_row[3], inv_q[3];    /* the mobility Q and its inverse, by rows */
} FaceBlock;

/* The FaceBlock of `count` (3 or 4) points. Returns false when the points lie
 * nearly on one line or Q is nearly singular (see solve_face_points). */
${inlined}bool face_block(const uint count, const float3 n, const float3 t1, const float3 t2,
                ${constraint_space} const float4* r_a, ${constraint_space} const float4* r_b,
                float inv_mass_a, const float3 inv_inertia_a[3],
                float inv_mass_b, const float3 inv_inertia_b[3], __private FaceBlock* f)
{
    const float share = 1.0f / (float)count;
    float3 centre_a = (float3)(0.0f), centre_b = (float3)(0.0f);
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        centre_a += r_a[k].xyz, centre_b += r_b[k].xyz;
    centre_a *= share;
    centre_b *= share;
    /* M = G^T G = diag(count, spread): the points' second moments in the plane */
    float u[4] = {0.0f, 0.0f, 0.0f, 0.0f}, v[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    float suu = 0.0f, suv = 0.0f, svv = 0.0f;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        float3 d = r_a[k].xyz - centre_a;
        u[k] = dot3(d, t1);
        v[k] = dot3(d, t2);
        suu += u[k] * u[k], suv += u[k] * v[k], svv += v[k] * v[k];
    }
    float spread_det = suu * svv - suv * suv;
    if (!(spread_det > FLAT_SPREAD_RATIO * suu * svv))
        return false;
    f->suu = suu, f->suv = suv, f->svv = svv;
    f->inv_spread = 1.0f / spread_det;

    /* Q[i][j]: normal velocity change of motion i per unit of wrench j (rows
     * of G: force, moment along u, moment along v) */
    float3 arm_a[3] = {cross3(centre_a, n), cross3(t1, n), cross3(t2, n)};
    float3 arm_b[3] = {cross3(centre_b, n), arm_a[1], arm_a[2]};
    float3 turn_a[3], turn_b[3];
    ${unroll}for (uint i = 0; i < 3; ++i) {
        turn_a[i] = mul_rows(inv_inertia_a, arm_a[i]);
        turn_b[i] = mul_rows(inv_inertia_b, arm_b[i]);
    }
    float q[3][3];
    ${unroll}for (uint i = 0; i < 3; ++i)
        ${unroll}for (uint j = i; j < 3; ++j)
            q[i][j] = q[j][i] = dot3(arm_a[i], turn_a[j]) + dot3(arm_b[i], turn_b[j]);
    q[0][0] += inv_mass_a + inv_mass_b;
    /* Q^-1 by cofactors */
    float3 q_row0 = (float3)(q[0][0], q[0][1], q[0][2]);
    float3 q_row1 = (float3)(q[1][0], q[1][1], q[1][2]);
    float3 q_row2 = (float3)(q[2][0], q[2][1], q[2][2]);
    float3 inv_q0 = cross3(q_row1, q_row2), inv_q1 = cross3(q_row2, q_row0);
    float3 inv_q2 = cross3(q_row0, q_row1);
    float q_det = dot3(q_row0, inv_q0);
    if (!(q_det > FLAT_MOBILITY_RATIO * q[0][0] * q[1][1] * q[2][2]))
        return false;
    float inv_q_det = 1.0f / q_det;
    f->inv_q[0] = inv_q0 * inv_q_det, f->inv_q[1] = inv_q1 * inv_q_det;
    f->inv_q[2] = inv_q2 * inv_q_det;
    f->q_row[0] = q_row0, f->q_row[1] = q_row1, f->q_row[2] = q_row2;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k)
        f->u[k] = u[k], f->v[k] = v[k];
    ${unroll}for (uint i = 0; i < 3; ++i) {
        f->arm_a[i] = arm_a[i];
        f->turn_a[i] = turn_a[i];
        f->turn_b[i] = turn_b[i];
    }
    f->arm_b0 = arm_b[0];
    return true;
}

/* K's entries g_j . Q g_k (Q by rows; g_k = (1, u_k, v_k), (1, 0, 0) past the
 * points). */
inline void face_k_matrix(const float3 q_row0, const float3 q_row1, const float3 q_row2,
                          const float3 g[4], float k_matrix[4][4])
{
    float3 h[4];
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k)
        h[k] = (float3)(dot3(q_row0, g[k]), dot3(q_row1, g[k]), dot3(q_row2, g[k]));
    ${unroll}for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j)
        ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k)
            k_matrix[j][k] = dot3(g[j], h[k]);
}

/* Three or four points of one face: the contact problem K total = rhs on the
 * pushing points, total >= 0, and every released point reaching at least its
 * target, solved exactly.
 *
 * A normal row's Jacobian is affine in its point's coordinates (u, v) in the
 * contact plane about the points' centre (the lever arm's part along n drops
 * out of r x n): arm_a[k] = A0 + u_k A1 + v_k A2, likewise for B, so
 * K = G Q G^T with the rows g_k = (1, u_k, v_k) of G and the 3x3 mobility Q
 * of the face (normal velocity and two tilt rates per unit of force and of
 * the two moments). An impulse set acts through its wrench G^T total only,
 * and the normal velocity it adds at point k is g_k . Q wrench. K is PSD, so
 * every solution of the contact problem leaves the same velocities; they
 * differ only in how the impulse is shared, which is what the order below
 * decides.
 *
 * 1. All points pushing: the smallest totals with K total = rhs, total =
 *    G M^-1 Q^-1 M^-1 G^T rhs with M = G^T G (for three points, the one
 *    solution G^-T Q^-1 G^-1 rhs): evenly spread, no drift of the share
 *    between the points from step to step. Valid when the targets fit one
 *    rigid motion (the affine least-squares fit of rhs misses no point) and
 *    no total is negative: a face resting on a face, nearly always.
 * 2. Else (a corner still apart beside touching ones, a corner that would
 *    pull, the kink of the split-impulse slop) the active sets in turn, the
 *    larger first: three of four points (the plane p through their rhs, the
 *    wrench Q^-1 p, and the totals its barycentric split: cofactors c_i =
 *    g_j x g_l, D = g_i . c_i); then two, one and none (K's entries
 *    g_j . Q g_k). Among three-point sets that hold, the one releasing the
 *    point whose all-pushing total is lowest: for targets that fit one rigid
 *    motion the solutions lie on a line through the all-pushing totals, and
 *    that is the one nearest them (the point that would pull the most).
 * A least-squares compromise instead (what conjugate gradients without
 * releases give) tilts the box towards the gap on every sweep and kept stacks
 * of a dropped pile rocking for ever.
 * Straight-line code, no iteration: on a GPU a warp pays for the rare case
 * whenever one of its 32 manifolds takes it, so the rare case must be cheap.
 * Returns false, changing nothing, when the points lie nearly on one line, Q
 * is nearly singular, or round-off leaves no active set valid: the caller then
 * solves the rows one after another. Without `releases` only case 1 is tried
 * (false when it does not hold): a cheaper sweep, exact and order-free for
 * faces resting on faces, that leaves the other faces to the rows. */
<%def name="face_block_solver(name, cached_k)">\
${inlined}bool ${name}(const uint count, const __private FaceBlock* f, const float3 n,
                      const float relaxation, float inv_mass_a, float3* va, float3* wa,
                      float inv_mass_b, float3* vb, float3* wb, const float target[4],
                      float lambda[4], const bool releases${k_param if cached_k else ""})
{
    const bool four = count == 4;
    const float share = 1.0f / (float)count;
    const __private float* u = f->u;
    const __private float* v = f->v;
    const float suu = f->suu, suv = f->suv, svv = f->svv, inv_spread = f->inv_spread;
    const __private float3* arm_a = f->arm_a;
    const __private float3* turn_a = f->turn_a;
    const __private float3* turn_b = f->turn_b;
    const float3 arm_b0 = f->arm_b0;
    const float3 q_row0 = f->q_row[0], q_row1 = f->q_row[1], q_row2 = f->q_row[2];
    const float3 inv_q0 = f->inv_q[0], inv_q1 = f->inv_q[1], inv_q2 = f->inv_q[2];

    /* the normal velocity now (affine in u, v), and the wrench of the current
     * impulses; rhs_k = target_k - velocity_k + (K lambda)_k, what K total must reach */
    float3 dw = *wb - *wa;
    float3 speed = (float3)(dot3(n, *vb - *va) + dot3(*wb, arm_b0) - dot3(*wa, arm_a[0]),
                            dot3(dw, arm_a[1]), dot3(dw, arm_a[2]));
    float3 wrench = (float3)(0.0f);
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        wrench += (float3)(1.0f, u[k], v[k]) * lambda[k];
    float3 reached = (float3)(dot3(q_row0, wrench), dot3(q_row1, wrench), dot3(q_row2, wrench))
                   - speed;
    float3 g[4];
    float rhs[4], tolerance = 0.0f;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) {
        g[k] = (float3)(1.0f, u[k], v[k]);
        rhs[k] = k < count ? target[k] + dot3(g[k], reached) : 0.0f;
        tolerance = max1(tolerance, OVERSHOOT_TOLERANCE * abs1(rhs[k]));
    }

    /* 1. all pushing: the affine fit p of rhs, wrench z = Q^-1 p, totals G M^-1 z */
    float3 fit = (float3)(0.0f);
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        fit += g[k] * rhs[k];
    fit = (float3)(share * fit.x, (svv * fit.y - suv * fit.z) * inv_spread,
                   (suu * fit.z - suv * fit.y) * inv_spread);
    float3 z = (float3)(dot3(inv_q0, fit), dot3(inv_q1, fit), dot3(inv_q2, fit));
    float3 x = (float3)(share * z.x, (svv * z.y - suv * z.z) * inv_spread,
                        (suu * z.z - suv * z.y) * inv_spread);
    float total[4], even[4];
    bool valid = true;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        total[k] = even[k] = dot3(g[k], x);
        valid = valid && total[k] >= 0.0f && abs1(rhs[k] - dot3(g[k], fit)) <= tolerance;
    }

    if (!valid && !releases)
        return false;
    if (!valid) {
        /* 2a. three of four pushing, point m released */
        float lowest = FLT_MAX;  /* (not INFINITY: the solver may be built finite-math-only) */
        ${unroll}for (uint m = 0; m < 4; ++m) if (four) {
            /* (indices picked by compare, not array subscripts: registers on GPUs) */
            uint i = m == 0 ? 1 : 0, j = m <= 1 ? 2 : 1, l = m <= 2 ? 3 : 2;
            float3 c_i = cross3(g[j], g[l]), c_j = cross3(g[l], g[i]), c_l = cross3(g[i], g[j]);
            float det = dot3(g[i], c_i);
            /* (no branch out: the four sets are independent work, overlapped) */
            bool solvable = abs1(det) > FLAT_SPREAD_RATIO * (suu + svv);
            float inv_det = 1.0f / (solvable ? det : 1.0f);
            float3 plane = (c_i * rhs[i] + c_j * rhs[j] + c_l * rhs[l]) * inv_det;
            float3 w3 = (float3)(dot3(inv_q0, plane), dot3(inv_q1, plane), dot3(inv_q2, plane));
            float x_i = dot3(c_i, w3) * inv_det, x_j = dot3(c_j, w3) * inv_det;
            float x_l = dot3(c_l, w3) * inv_det;
            if (solvable && x_i >= 0.0f && x_j >= 0.0f && x_l >= 0.0f
                && dot3(g[m], plane) >= rhs[m] - tolerance && even[m] < lowest) {
                lowest = even[m], valid = true;
                total[m] = 0.0f, total[i] = x_i, total[j] = x_j, total[l] = x_l;
            }
        }
    }
    if (!valid) {
        /* 2b. two, one or none pushing: K's entries g_j . Q g_k */
        float k_matrix[4][4];
% if cached_k:
        ${unroll}for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j) {
            float4 row = k_rows[j];
            k_matrix[j][0] = row.x, k_matrix[j][1] = row.y, k_matrix[j][2] = row.z;
            k_matrix[j][3] = row.w;
        }
        /* the first candidate that holds is taken (a core runs one manifold:
         * the others are skipped) */
% else:
        face_k_matrix(q_row0, q_row1, q_row2, g, k_matrix);
        /* every candidate is evaluated (independent work, overlapped; no
         * branch out of the loops), the first that holds is taken */
% endif
        ${unroll}for (uint i = 0; i < RB_MAX_MANIFOLD_POINTS; ++i)
            ${unroll}for (uint j = i + 1; j < RB_MAX_MANIFOLD_POINTS; ++j) {
% if cached_k:
                if (valid)
                    continue;  /* (not break: a loop without one unrolls) */
% endif
                float kii = k_matrix[i][i], kij = k_matrix[i][j], kjj = k_matrix[j][j];
                float det = kii * kjj - kij * kij;
                bool holds = j < count && det > FLAT_SPREAD_RATIO * kii * kjj;
                det = holds ? det : 1.0f;
                float x_i = (kjj * rhs[i] - kij * rhs[j]) / det;
                float x_j = (kii * rhs[j] - kij * rhs[i]) / det;
                holds = holds && x_i >= 0.0f && x_j >= 0.0f;
                ${unroll}for (uint m = 0; m < RB_MAX_MANIFOLD_POINTS; ++m) if (m < count && m != i && m != j)
                    holds = holds && k_matrix[m][i] * x_i + k_matrix[m][j] * x_j >= rhs[m] - tolerance;
                if (holds && !valid) {
                    valid = true;
                    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k)
                        total[k] = k == i ? x_i : k == j ? x_j : 0.0f;
                }
            }
        ${unroll}for (uint i = 0; i < RB_MAX_MANIFOLD_POINTS; ++i) {
% if cached_k:
            if (valid)
                continue;
% endif
            float x_i = positive_part(rhs[i]) / (i < count ? k_matrix[i][i] : 1.0f);
            bool holds = i < count;
            ${unroll}for (uint m = 0; m < RB_MAX_MANIFOLD_POINTS; ++m) if (m < count && m != i)
                holds = holds && k_matrix[m][i] * x_i >= rhs[m] - tolerance;
            if (holds && !valid) {
                valid = true;
                ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k)
                    total[k] = k == i ? x_i : 0.0f;
            }
        }
        if (!valid)
            return false;
    }

    float change[4];
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        change[k] = positive_part(lambda[k] + relaxation * (total[k] - lambda[k])) - lambda[k];
    /* apply: the summed impulse and its moments */
    float3 applied = (float3)(0.0f);
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        lambda[k] += change[k];
        applied += g[k] * change[k];
    }
    *va -= n * (applied.x * inv_mass_a);
    *vb += n * (applied.x * inv_mass_b);
    *wa -= turn_a[0] * applied.x + turn_a[1] * applied.y + turn_a[2] * applied.z;
    *wb += turn_b[0] * applied.x + turn_b[1] * applied.y + turn_b[2] * applied.z;
    return true;
}
</%def>\
${face_block_solver("solve_face_block", geometry_cache)}\
% if geometry_cache:

/* solve_face_block with K derived from the FaceBlock: a shock sweep's, of the held
 * bodies (solve_contact), whose K the record does not keep. */
${face_block_solver("solve_held_face_block", False)}\
% endif

## (a build with a ContactGeometry cache reads each FaceBlock from the cache,
## solve_normal_cached: it has no use for the two functions that derive one)
% if not geometry_cache:
/* solve_face_block on the points' FaceBlock. */
bool solve_face_points(const uint count, const float3 n, const float3 t1, const float3 t2,
                       ${constraint_space} const float4* r_a, ${constraint_space} const float4* r_b,
                       const float relaxation,
                       float inv_mass_a, const float3 inv_inertia_a[3], float3* va, float3* wa,
                       float inv_mass_b, const float3 inv_inertia_b[3], float3* vb, float3* wb,
                       const float target[4], float lambda[4], const bool releases)
{
    FaceBlock f;
    return face_block(count, n, t1, t2, r_a, r_b, inv_mass_a, inv_inertia_a, inv_mass_b,
                      inv_inertia_b, &f)
           && solve_face_block(count, &f, n, relaxation, inv_mass_a, va, wa, inv_mass_b, vb,
                               wb, target, lambda, releases);
}
% endif

/* solve_normal_block for one or two points (an edge on a face, a corner): the contact problem K total = rhs, total >= 0, with the
 * velocity reached at a released point no slower than its target, solved
 * exactly by trying the active sets in turn (both pushing, either alone,
 * none), which for a regular 2x2 K finds its unique solution. Returns false,
 * changing nothing, when the two points (nearly) coincide in K (det below
 * FLAT_SPREAD_RATIO of the diagonal's product): the rows decide. */
bool solve_two_points(const uint count, const float3 n,
                      ${constraint_space} const float4* r_a, ${constraint_space} const float4* r_b,
                      const float relaxation,
                      float inv_mass_a, const float3 inv_inertia_a[3], float3* va, float3* wa,
                      float inv_mass_b, const float3 inv_inertia_b[3], float3* vb, float3* wb,
                      const float target[4], float lambda[4])
{
    if (count == 0)
        return true;
    const bool two = count == 2;
    float3 arm_a0 = cross3(r_a[0].xyz, n), arm_b0 = cross3(r_b[0].xyz, n);
    float3 arm_a1 = cross3(r_a[1].xyz, n), arm_b1 = cross3(r_b[1].xyz, n);
    float3 turn_a0 = mul_rows(inv_inertia_a, arm_a0), turn_b0 = mul_rows(inv_inertia_b, arm_b0);
    float3 turn_a1 = mul_rows(inv_inertia_a, arm_a1), turn_b1 = mul_rows(inv_inertia_b, arm_b1);
    float inv_mass = inv_mass_a + inv_mass_b;
    float k00 = inv_mass + dot3(arm_a0, turn_a0) + dot3(arm_b0, turn_b0);
    float k01 = inv_mass + dot3(arm_a0, turn_a1) + dot3(arm_b0, turn_b1);
    float k11 = inv_mass + dot3(arm_a1, turn_a1) + dot3(arm_b1, turn_b1);
    float det = k00 * k11 - k01 * k01;
    if (two && !(det > FLAT_SPREAD_RATIO * k00 * k11))
        return false;
    if (!(k00 > 0.0f))
        return false;
    /* rhs_j = target_j - normal velocity_j + (K lambda)_j: what K total must reach */
    float3 dv = *vb - *va;
    float speed0 = dot3(n, dv) + dot3(*wb, arm_b0) - dot3(*wa, arm_a0);
    float speed1 = dot3(n, dv) + dot3(*wb, arm_b1) - dot3(*wa, arm_a1);
    float lambda1 = two ? lambda[1] : 0.0f;
    float rhs0 = target[0] - speed0 + k00 * lambda[0] + k01 * lambda1;
    float rhs1 = target[1] - speed1 + k01 * lambda[0] + k11 * lambda1;
    float tolerance = OVERSHOOT_TOLERANCE * max1(abs1(rhs0), two ? abs1(rhs1) : 0.0f);
    float total0 = 0.0f, total1 = 0.0f;
    float both0 = (k11 * rhs0 - k01 * rhs1) / det, both1 = (k00 * rhs1 - k01 * rhs0) / det;
    float alone0 = positive_part(rhs0 / k00), alone1 = two ? positive_part(rhs1 / k11) : 0.0f;
    if (!two) {
        total0 = alone0;
    } else if (both0 >= 0.0f && both1 >= 0.0f) {
        total0 = both0, total1 = both1;
    } else if (k01 * alone0 >= rhs1 - tolerance) {  /* point 1 released, still fast enough */
        total0 = alone0;
    } else if (k01 * alone1 >= rhs0 - tolerance) {
        total1 = alone1;
    }
    float change0 = positive_part(lambda[0] + relaxation * (total0 - lambda[0])) - lambda[0];
    float change1 = two ? positive_part(lambda1 + relaxation * (total1 - lambda1)) - lambda1 : 0.0f;
    lambda[0] += change0;
    if (two)
        lambda[1] += change1;
    float applied = change0 + change1;
    *va -= n * (applied * inv_mass_a);
    *vb += n * (applied * inv_mass_b);
    *wa -= turn_a0 * change0 + turn_a1 * change1;
    *wb += turn_b0 * change0 + turn_b1 * change1;
    return true;
}

% if not geometry_cache:
/* The normal rows of one manifold as a block: the accumulated impulses
 * lambda[k] (>= 0) of its `count` points are replaced by the exact solution of
 * the contact problem: every point that keeps a positive impulse reaches its
 * normal velocity target, K (total - lambda) = target - vn with K[j][k] = the
 * normal velocity change at point j per unit impulse at point k, and every
 * released point (impulse 0) reaches at least its target. Solving the rows
 * one after another instead leaves a residual torque after each sweep, which
 * tips a symmetric column from its first step and makes it lean or walk.
 * Three or four points: solve_face_points; one or two: solve_two_points.
 * Returns false, changing nothing, for the degenerate geometry those decline
 * (points nearly on one line or coinciding, bodies without rotational
 * freedom), and without `releases` for three or four points whose solution
 * would release one (see solve_face_points): the caller then solves the rows
 * one after another. Updates the velocities in place. */
bool solve_normal_block(const uint count, const float3 n, const float3 t1, const float3 t2,
                        ${constraint_space} const float4* r_a, ${constraint_space} const float4* r_b,
                        const float relaxation,
                        float inv_mass_a, const float3 inv_inertia_a[3], float3* va, float3* wa,
                        float inv_mass_b, const float3 inv_inertia_b[3], float3* vb, float3* wb,
                        const float target[4], float lambda[4], const bool releases)
{
    if (count >= 3)
        return solve_face_points(count, n, t1, t2, r_a, r_b, relaxation, inv_mass_a,
                                 inv_inertia_a, va, wa, inv_mass_b, inv_inertia_b, vb, wb,
                                 target, lambda, releases);
    return solve_two_points(count, n, r_a, r_b, relaxation, inv_mass_a, inv_inertia_a, va, wa,
                            inv_mass_b, inv_inertia_b, vb, wb, target, lambda);
}
% endif

% endif
/* The two bodies of one constraint as the solver sees them: inverse masses
 * and world inverse inertias, and the (push) velocities being solved for.
 * Functions take it as `__private ContactBodies*`: NVIDIA's compiler treats an
 * unqualified pointer as generic and refuses to pass its inertia arrays on to
 * array parameters (private). */
typedef struct {
    float inv_mass_a, inv_mass_b;
    float3 inv_inertia_a[3], inv_inertia_b[3];
    float3 va, wa, vb, wb;
} ContactBodies;

/* One row: impulse along `direction` at lever arms ra, rb (or a pure torque
 * about `direction` when `linear` is 0). arm_*: lever arm x direction;
 * turn_*: angular velocity change per unit impulse. */
typedef struct {
    float3 linear, arm_a, arm_b, turn_a, turn_b;
} Row;

inline Row point_row(float3 direction, float3 ra, float3 rb, const __private ContactBodies* p)
{
    Row row;
    row.linear = direction;
    row.arm_a = cross3(ra, direction);
    row.arm_b = cross3(rb, direction);
    row.turn_a = mul_rows(p->inv_inertia_a, row.arm_a);
    row.turn_b = mul_rows(p->inv_inertia_b, row.arm_b);
    return row;
}

inline Row twist_row(float3 axis, const __private ContactBodies* p)
{
    Row row;
    row.linear = (float3)(0.0f);
    row.arm_a = row.arm_b = axis;
    row.turn_a = mul_rows(p->inv_inertia_a, axis);
    row.turn_b = mul_rows(p->inv_inertia_b, axis);
    return row;
}

/* velocity of B relative to A along the row */
inline float row_speed(const Row* row, const __private ContactBodies* p)
{
    float3 s = row->linear * (p->vb - p->va) + row->arm_b * p->wb - row->arm_a * p->wa;
    return s.x + s.y + s.z;
}

inline void apply_row(const Row* row, float impulse, __private ContactBodies* p)
{
    p->va -= row->linear * (impulse * p->inv_mass_a);
    p->wa -= row->turn_a * impulse;
    p->vb += row->linear * (impulse * p->inv_mass_b);
    p->wb += row->turn_b * impulse;
}

/* The normal rows of one manifold one after another (Gauss-Seidel), slot s
 * being point reverse ? 3 - s : s, with mass[s], target[s] and impulse[s]
 * (accumulated, kept >= 0) given in slot order. Each row's speed is its
 * speed before the manifold plus what the rows solved before it added
 * (K[t][s] times their changes: K[t][s] = J_t M^-1 J_s^T does not depend on
 * the velocities), and the velocities change once, at the end: the same
 * updates as applying each row to the velocities in turn, but the dependent
 * chain from row to row is a few scalar operations instead of a dot product
 * over both bodies' velocities and a store of them. Always inlined and
 * unrolled, so that the rows and speeds stay in registers. */
__attribute__((always_inline))
inline void solve_normal_rows(const uint count, const float3 n, ${constraint_space} const float4* r_a,
                              ${constraint_space} const float4* r_b, const float mass[4],
                              const float target[4], const float relaxation, const bool reverse,
                              float impulse[4], __private ContactBodies* p)
{
    Row rows[4];
    float speed[4], change[4];
#pragma unroll
    for (uint slot = 0; slot < RB_MAX_MANIFOLD_POINTS; ++slot) {
        uint k = reverse ? RB_MAX_MANIFOLD_POINTS - 1 - slot : slot;
        bool active = k < count;
        rows[slot] = point_row(n, active ? r_a[k].xyz : (float3)(0.0f),
                               active ? r_b[k].xyz : (float3)(0.0f), p);
        speed[slot] = row_speed(&rows[slot], p);
        change[slot] = 0.0f;
    }
    const float inv_mass = p->inv_mass_a + p->inv_mass_b;
#pragma unroll
    for (uint slot = 0; slot < RB_MAX_MANIFOLD_POINTS; ++slot) {
        uint k = reverse ? RB_MAX_MANIFOLD_POINTS - 1 - slot : slot;
        if (k < count) {
            float total = positive_part(impulse[slot]
                                        + relaxation * mass[slot] * (target[slot] - speed[slot]));
            change[slot] = total - impulse[slot];
            impulse[slot] = total;
        }
#pragma unroll
        for (uint later = slot + 1; later < RB_MAX_MANIFOLD_POINTS; ++later)
            speed[later] += (inv_mass + dot3(rows[later].arm_a, rows[slot].turn_a)
                             + dot3(rows[later].arm_b, rows[slot].turn_b)) * change[slot];
    }
    float applied = 0.0f;
    float3 turn_a = (float3)(0.0f), turn_b = (float3)(0.0f);
#pragma unroll
    for (uint slot = 0; slot < RB_MAX_MANIFOLD_POINTS; ++slot) {
        applied += change[slot];
        turn_a += rows[slot].turn_a * change[slot];
        turn_b += rows[slot].turn_b * change[slot];
    }
    p->va -= n * (applied * p->inv_mass_a);
    p->wa -= turn_a;
    p->vb += n * (applied * p->inv_mass_b);
    p->wb += turn_b;
}

/* A manifold's friction rows: the pair along tangent1 and tangent2 at the
 * centre of its points, the twist row about the normal, and the points'
 * summed distance from B's centre point (the twist's lever times the count).
 * Like a FaceBlock they hold for a step. */
typedef struct {
    Row tangent1, tangent2, twist;
    float radius;
} FrictionRows;

inline void friction_rows(${constraint_space} const ContactConstraint* c,
                          const __private ContactBodies* p, __private FrictionRows* rows)
{
    uint count = c->point_count;
    float3 ra = (float3)(0.0f), rb = (float3)(0.0f);
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        ra += c->r_a[k].xyz, rb += c->r_b[k].xyz;
    float share = count > 0 ? 1.0f / (float)count : 0.0f;
    ra *= share;
    rb *= share;
    rows->tangent1 = point_row(c->tangent1.xyz, ra, rb, p);
    rows->tangent2 = point_row(c->tangent2.xyz, ra, rb, p);
    float radius = 0.0f;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        radius += length3(c->r_b[k].xyz - rb);
    rows->radius = radius;
    rows->twist = twist_row(c->normal.xyz, p);
}

/* A friction pair (rows row1, row2): the accumulated (f1, f2) is clamped to
 * the disc |f| <= limit. Always inlined: as a call (PoCL declines to inline
 * it) the bodies' state would go through memory. */
__attribute__((always_inline))
inline void solve_friction_pair(const Row* row1, const Row* row2, float mass1, float mass2,
                                float limit, float relaxation, float* impulse1,
                                float* impulse2, __private ContactBodies* p)
{
    float f1 = *impulse1 - relaxation * mass1 * row_speed(row1, p);
    float f2 = *impulse2 - relaxation * mass2 * row_speed(row2, p);
    float length_sq = f1 * f1 + f2 * f2;
    if (length_sq > limit * limit) {
        /* (length_sq at least the smallest normal float: a fast-math build takes the
         * reciprocal square root, infinite for a denormal flushed to zero, and the
         * limit of a point that does not push is 0, so 0 * infinity would be NaN) */
        float scale = limit / sqrt1(max1(length_sq, FLT_MIN));
        f1 *= scale;
        f2 *= scale;
    }
    apply_row(row1, f1 - *impulse1, p);
    apply_row(row2, f2 - *impulse2, p);
    *impulse1 = f1;
    *impulse2 = f2;
}

inline void unpack4(float4 v, float out[4])
{
    out[0] = v.x, out[1] = v.y, out[2] = v.z, out[3] = v.w;
}

inline float4 pack4(const float in[4])
{
    return (float4)(in[0], in[1], in[2], in[3]);
}

inline void reverse4(float a[4])
{
    float t = a[0];
    a[0] = a[3], a[3] = t;
    t = a[1];
    a[1] = a[2], a[2] = t;
}

% if geometry_cache:

/* A constraint's ContactGeometry record (layouts): its FaceBlock (three or
 * four points, when the block solve takes them: face_arm[0].w 1, else 0) and
 * its FrictionRows, derived from the bodies in *p. A solver writes it once a
 * step (its lever arms, normal and the bodies' inertias hold for the step)
 * and every sweep reads it instead of deriving it again: the same values, so
 * the same results. */
${inlined}void store_geometry(${constraint_space} const ContactConstraint* c, const __private ContactBodies* p,
                    __global ContactGeometry* g)
{
    uint count = c->point_count;
    FaceBlock f;
    bool block = count >= 3
                 && face_block(count, c->normal.xyz, c->tangent1.xyz, c->tangent2.xyz, c->r_a,
                               c->r_b, p->inv_mass_a, p->inv_inertia_a, p->inv_mass_b,
                               p->inv_inertia_b, &f);
    if (block) {
        g->face_u = pack4(f.u);
        g->face_v = pack4(f.v);
        g->face_spread = (float4)(f.suu, f.suv, f.svv, f.inv_spread);
        ${unroll}for (uint i = 0; i < 3; ++i) {
            g->face_arm[i] = (float4)(f.arm_a[i], 0.0f);
            g->face_turn_a[i] = (float4)(f.turn_a[i], 0.0f);
            g->face_turn_b[i] = (float4)(f.turn_b[i], 0.0f);
            g->face_q[i] = (float4)(f.q_row[i], 0.0f);
            g->face_inv_q[i] = (float4)(f.inv_q[i], 0.0f);
        }
        g->face_arm[3] = (float4)(f.arm_b0, 0.0f);
        float3 points[4];
        float k_matrix[4][4];
        ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k)
            points[k] = (float3)(1.0f, f.u[k], f.v[k]);
        face_k_matrix(f.q_row[0], f.q_row[1], f.q_row[2], points, k_matrix);
        ${unroll}for (uint j = 0; j < RB_MAX_MANIFOLD_POINTS; ++j)
            g->face_k[j] = pack4(k_matrix[j]);
    }
    g->face_arm[0].w = block ? 1.0f : 0.0f;
    /* a shock sweep's face block (solve_contact: `held`), with the held body's
     * mass and inertia zero as hold_still leaves them */
    const float holds = c->tangent1.w;
    bool held_block = false;
    if (count >= 3 && holds != (float)RB_SHOCK_HOLDS_NONE) {
        const bool a = holds == (float)RB_SHOCK_HOLDS_A;
        const float3 none[3] = {(float3)(0.0f), (float3)(0.0f), (float3)(0.0f)};
        FaceBlock h;
        held_block = face_block(count, c->normal.xyz, c->tangent1.xyz, c->tangent2.xyz, c->r_a,
                                c->r_b, a ? 0.0f : p->inv_mass_a, a ? none : p->inv_inertia_a,
                                a ? p->inv_mass_b : 0.0f, a ? p->inv_inertia_b : none, &h);
        if (held_block) {
            ${unroll}for (uint i = 0; i < 3; ++i) {
                g->held_q[i] = (float4)(h.q_row[i], 0.0f);
                g->held_inv_q[i] = (float4)(h.inv_q[i], 0.0f);
            }
        }
    }
    g->held_q[0].w = held_block ? 1.0f : 0.0f;
    FrictionRows rows;
    friction_rows(c, p, &rows);
    g->friction_arm_a[0] = (float4)(rows.tangent1.arm_a, 0.0f);
    g->friction_arm_b[0] = (float4)(rows.tangent1.arm_b, 0.0f);
    g->friction_turn_a[0] = (float4)(rows.tangent1.turn_a, 0.0f);
    g->friction_turn_b[0] = (float4)(rows.tangent1.turn_b, 0.0f);
    g->friction_arm_a[1] = (float4)(rows.tangent2.arm_a, 0.0f);
    g->friction_arm_b[1] = (float4)(rows.tangent2.arm_b, 0.0f);
    g->friction_turn_a[1] = (float4)(rows.tangent2.turn_a, 0.0f);
    g->friction_turn_b[1] = (float4)(rows.tangent2.turn_b, 0.0f);
    g->twist_turn[0] = (float4)(rows.twist.turn_a, rows.radius);
    g->twist_turn[1] = (float4)(rows.twist.turn_b, 0.0f);
}

/* The FrictionRows stored in g (directions n, t1, t2: the constraint's). */
inline void load_friction_rows(__global const ContactGeometry* g, const float3 n,
                               const float3 t1, const float3 t2, __private FrictionRows* rows)
{
    rows->tangent1.linear = t1;
    rows->tangent1.arm_a = g->friction_arm_a[0].xyz;
    rows->tangent1.arm_b = g->friction_arm_b[0].xyz;
    rows->tangent1.turn_a = g->friction_turn_a[0].xyz;
    rows->tangent1.turn_b = g->friction_turn_b[0].xyz;
    rows->tangent2.linear = t2;
    rows->tangent2.arm_a = g->friction_arm_a[1].xyz;
    rows->tangent2.arm_b = g->friction_arm_b[1].xyz;
    rows->tangent2.turn_a = g->friction_turn_a[1].xyz;
    rows->tangent2.turn_b = g->friction_turn_b[1].xyz;
    rows->twist.linear = (float3)(0.0f);
    rows->twist.arm_a = rows->twist.arm_b = n;
    rows->twist.turn_a = g->twist_turn[0].xyz;
    rows->twist.turn_b = g->twist_turn[1].xyz;
    rows->radius = g->twist_turn[0].w;
}

/* The FaceBlock of three or four points read from g: both bodies' (`holds`
 * RB_SHOCK_HOLDS_NONE), or a shock sweep's with the body `holds` names held
 * still (its turns zero, Q from held_q). False when the block solve does not
 * take the points so (the rows do). */
inline bool load_face_block(__global const ContactGeometry* g, const float holds,
                            __private FaceBlock* f)
{
    const bool held = holds != (float)RB_SHOCK_HOLDS_NONE;
    if ((held ? g->held_q[0].w : g->face_arm[0].w) == 0.0f)
        return false;
    unpack4(g->face_u, f->u);
    unpack4(g->face_v, f->v);
    float4 spread = g->face_spread;
    f->suu = spread.x, f->suv = spread.y, f->svv = spread.z, f->inv_spread = spread.w;
    const bool still_a = holds == (float)RB_SHOCK_HOLDS_A;
    const bool still_b = holds == (float)RB_SHOCK_HOLDS_B;
    ${unroll}for (uint i = 0; i < 3; ++i) {
        f->arm_a[i] = g->face_arm[i].xyz;
        f->turn_a[i] = still_a ? (float3)(0.0f) : g->face_turn_a[i].xyz;
        f->turn_b[i] = still_b ? (float3)(0.0f) : g->face_turn_b[i].xyz;
        f->q_row[i] = held ? g->held_q[i].xyz : g->face_q[i].xyz;
        f->inv_q[i] = held ? g->held_inv_q[i].xyz : g->face_inv_q[i].xyz;
    }
    f->arm_b0 = g->face_arm[3].xyz;
    return true;
}

/* solve_normal_block with three or four points' FaceBlock read from g. */
${inlined}bool solve_normal_cached(const uint count, const float3 n,
                         ${constraint_space} const float4* r_a, ${constraint_space} const float4* r_b,
                         const float relaxation, __private ContactBodies* p,
                         __global const ContactGeometry* g, const float target[4],
                         float lambda[4], const bool releases)
{
    if (count < 3)
        return solve_two_points(count, n, r_a, r_b, relaxation, p->inv_mass_a, p->inv_inertia_a,
                                &p->va, &p->wa, p->inv_mass_b, p->inv_inertia_b, &p->vb,
                                &p->wb, target, lambda);
    FaceBlock f;
    if (!load_face_block(g, (float)RB_SHOCK_HOLDS_NONE, &f))
        return false;
    return solve_face_block(count, &f, n, relaxation, p->inv_mass_a, &p->va, &p->wa,
                            p->inv_mass_b, &p->vb, &p->wb, target, lambda, releases, g->face_k);
}
% endif

/* Apply last step's accumulated impulses of one constraint (warm start) to
 * its bodies' velocities in *p: their sum and its moment about each body's
 * centre first, then one velocity change a body (one inverse-inertia product
 * a body instead of one a point and row). */
${inlined}void warm_start_contact(const ${constraint_space} ContactConstraint* c, __private ContactBodies* p)
{
    uint count = c->point_count;
    float3 n = c->normal.xyz, t1 = c->tangent1.xyz, t2 = c->tangent2.xyz;
    float normal_impulse[4], tangent1_impulse[4], tangent2_impulse[4];
    unpack4(c->normal_impulse, normal_impulse);
    unpack4(c->tangent1_impulse, tangent1_impulse);
    unpack4(c->tangent2_impulse, tangent2_impulse);
    float3 impulse = (float3)(0.0f), moment_a = (float3)(0.0f), moment_b = (float3)(0.0f);
    /* the normal impulses at their points, the friction pair at their centre
     * and the twist about n (tangent1 slot 1) */
    float3 ra = (float3)(0.0f), rb = (float3)(0.0f);
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        float3 point_impulse = n * normal_impulse[k];
        impulse += point_impulse;
        moment_a += cross3(c->r_a[k].xyz, point_impulse);
        moment_b += cross3(c->r_b[k].xyz, point_impulse);
        ra += c->r_a[k].xyz, rb += c->r_b[k].xyz;
    }
    float share = count > 0 ? 1.0f / (float)count : 0.0f;
    float3 friction = t1 * tangent1_impulse[0] + t2 * tangent2_impulse[0];
    float3 twist = n * tangent1_impulse[1];
    impulse += friction;
    moment_a += cross3(ra * share, friction) + twist;
    moment_b += cross3(rb * share, friction) + twist;
    p->va -= impulse * p->inv_mass_a;
    p->wa -= mul_rows(p->inv_inertia_a, moment_a);
    p->vb += impulse * p->inv_mass_b;
    p->wb += mul_rows(p->inv_inertia_b, moment_b);
}

/* Restitution, Box2D v3's b2ApplyRestitution: after the rows, every point that
 * pushed in any of the step's velocity sweeps (bit k of `pushed` for point k;
 * a point that stopped its approach in an early substep and has lifted off
 * since still bounces, as with Box2D v3's maxNormalImpulse > 0) and came in faster
 * than the threshold (its bounce, r_b[k].w, > 0: the restitution times the
 * approach before the step, set up with the constraint) has its normal row
 * driven to the bounce velocity, the accumulated impulse kept >= 0. Friction is not
 * solved again: the rows before settled the impact (compression), and this
 * adds restitution times the approach along the normal alone, so an
 * off-centre impact with sticking friction does not gain energy as a bounce
 * in the rows' own target would. The points bounce together: a face whose
 * points all bounce is solved exactly as a block (normal_solve block; with a
 * ContactGeometry cache, the step's FaceBlock from g), else
 * the rows of the bouncing points are swept RESTITUTION_ROUNDS times (one
 * sweep, as Box2D v3 has, leaves a landing face turning: the first point's
 * row lifts its corner alone). Known limit (Box2D v3's too): the bounce is
 * the approach before the step, so with substeps a corner that lands after
 * an impact elsewhere turned the body within the step is driven to more than
 * it came in with, and the body gains energy (tests/test_world_properties.py
 * keeps a strict xfail on it). */
#define RESTITUTION_ROUNDS 8
inline void apply_restitution(const uint count, const float3 n, const float3 t1, const float3 t2,
                              ${constraint_space} const float4* r_a,
                              ${constraint_space} const float4* r_b${geometry_param},
                              const float mass[4], const uint pushed, float impulse[4],
                              __private ContactBodies* p)
{
    float target[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    bool bounces[4] = {false, false, false, false}, every = true;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count) {
        target[k] = r_b[k].w;
        bounces[k] = target[k] > 0.0f && (pushed >> k & 1u) != 0u;
        every = every && bounces[k];
    }
    bool solved = false;
% if geometry_cache:
    if (every)
        solved = solve_normal_cached(count, n, r_a, r_b, 1.0f, p, g, target, impulse, true);
% elif normal_solve == "block":
    if (every)
        solved = solve_normal_block(count, n, t1, t2, r_a, r_b, 1.0f, p->inv_mass_a,
                                    p->inv_inertia_a, &p->va, &p->wa, p->inv_mass_b,
                                    p->inv_inertia_b, &p->vb, &p->wb, target, impulse, true);
% endif
    for (uint round = 0; !solved && round < RESTITUTION_ROUNDS; ++round)
        ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count && bounces[k]) {
            Row row = point_row(n, r_a[k].xyz, r_b[k].xyz, p);
            float total = positive_part(impulse[k] + mass[k] * (target[k] - row_speed(&row, p)));
            apply_row(&row, total - impulse[k], p);
            impulse[k] = total;
        }
}

/* Whether constraint c bounces this step (a point with a bounce velocity). */
inline bool bounces(${constraint_space} const ContactConstraint* c)
{
    bool any = false;
    for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < c->point_count)
        any = any || c->r_b[k].w > 0.0f;
    return any;
}

/* The body that `holds` names (layouts: RB_SHOCK_HOLDS_*) held still in *p: its
 * inverse mass and inertia zero, so no row moves it and its velocities are not
 * stored back, and its spin zero, so that the rows carry its translation to the
 * other body but not its turning: matched to a turning support's surface, a box
 * on it turns too, and in a sweep that walks a column in order each layer
 * passed a larger turn to the next (the CPU's serial form launched a 30-layer
 * lattice's top layer at 1,300 m/s within 5 steps). Returns the share of a
 * change of the normal impulse to keep (solve_contact): the other body's inverse mass over both bodies', so that a
 * correction the held rows found for that body alone is kept as the impulse
 * that stops the same approach between the bodies as they are (1 when nothing
 * is held). */
inline float hold_still(__private ContactBodies* p, const float holds)
{
    const float both = p->inv_mass_a + p->inv_mass_b;
    if (holds == (float)RB_SHOCK_HOLDS_A) {
        const float share = p->inv_mass_b / both;
        p->inv_mass_a = 0.0f;
        p->inv_inertia_a[0] = p->inv_inertia_a[1] = p->inv_inertia_a[2] = (float3)(0.0f);
        p->wa = (float3)(0.0f);
        return share;
    }
    if (holds == (float)RB_SHOCK_HOLDS_B) {
        const float share = p->inv_mass_a / both;
        p->inv_mass_b = 0.0f;
        p->inv_inertia_b[0] = p->inv_inertia_b[1] = p->inv_inertia_b[2] = (float3)(0.0f);
        p->wb = (float3)(0.0f);
        return share;
    }
    return 1.0f;
}

% if geometry_cache:
/* The held body's turns (hold_still: RB_SHOCK_HOLDS_*) of friction rows read
 * from a ContactGeometry record made zero, as friction_rows gives them for a
 * held body's zero inertia. */
inline void hold_rows_still(__private FrictionRows* rows, const float holds)
{
    if (holds == (float)RB_SHOCK_HOLDS_A)
        rows->tangent1.turn_a = rows->tangent2.turn_a = rows->twist.turn_a = (float3)(0.0f);
    if (holds == (float)RB_SHOCK_HOLDS_B)
        rows->tangent1.turn_b = rows->tangent2.turn_b = rows->twist.turn_b = (float3)(0.0f);
}

% endif
/* Solve one sweep's rows of one constraint, updating its impulses and its
 * bodies' velocities in *p: its velocity rows, or with `push` its split-impulse
 * push rows (its normal rows alone, on the push velocities in *p, to
 * position_target, into push_impulse; `reverse`, `restitution` and `shock` are
 * the velocity rows'). Both kinds reach the normal rows through one call of the
 * block solve, so that a caller that picks the kind at run time (a persistent
 * launch's visit, pgs.cl.mako) carries one copy of it: on NVIDIA GPUs each
 * inlined copy of the block solve added registers and spills to the whole
 * launch. `releases`: the block solve may release points (see
 * solve_normal_block; normal_solve block only); `restitution`: then apply
 * its restitution (apply_restitution: the step's last velocity sweep).
 * `shock`: a shock sweep (pgs.cl.mako: SHOCK_PASS) holds the lower body of a
 * contact that carries a load against gravity still (tangent1.w, hold_still),
 * so that a stack's velocities agree from the ground up within the sweep: its
 * normal rows with their masses of the held bodies (contact_masses.cl.mako's
 * row_mass; the block
 * solve derives its own), its friction rows with their masses of both
 * (under-relaxed for the held body: friction rows of the held masses, stiffer
 * in a one-sided sweep, walked a 55-layer lattice apart). What the normal rows
 * add is kept in the free body's share (hold_still): the impulse that stops the
 * same approach with both bodies free, so the warm start learns a stack's load
 * from the sweep that sees it whole, without the one-sided correction's
 * overshoot (kept whole, it pumped a 55-layer lattice apart at 1 + 1 sweeps).
 * A manifold that bounces this step is left to the rows and the restitution
 * before (no pull takes its bounce back). */
${inlined}void solve_contact(${constraint_space} ContactConstraint* c${geometry_param}, __private ContactBodies* p,
                   const float relaxation, const bool velocity_reverse, const bool releases,
                   const bool restitution, const bool velocity_shock, const bool push)
{
    const bool reverse = velocity_reverse && !push, shock = velocity_shock && !push;
    /* (a shock sweep holds a body of this contact still) */
    const bool held = shock && c->tangent1.w != (float)RB_SHOCK_HOLDS_NONE;
    float kept_share = 1.0f;  /* (of what the normal rows add: hold_still) */
    if (shock) {
        if (bounces(c))
            return;
        kept_share = hold_still(p, c->tangent1.w);
    }
    uint count = c->point_count;
    float3 n = c->normal.xyz, t1 = c->tangent1.xyz, t2 = c->tangent2.xyz;
    float friction = c->normal.w;
    float normal_impulse[4], tangent1_impulse[4], tangent2_impulse[4];
    float normal_mass[4], tangent1_mass[4], tangent2_mass[4], target[4];
    /* (a push sweep's normal rows: their impulses and targets in these; the
     * friction rows' fields are read below the push rows' return) */
    unpack4(push ? c->push_impulse : c->normal_impulse, normal_impulse);
    unpack4(c->normal_mass, normal_mass);
    unpack4(push ? c->position_target : c->velocity_target, target);

    bool solved = false;  /* by the block solve; else row after row */
% if geometry_cache:
    if (held && count >= 3) {
        /* the held sweep's face block (K derived: the record keeps both bodies') */
        FaceBlock f;
        solved = load_face_block(g, c->tangent1.w, &f)
                 && solve_held_face_block(count, &f, n, relaxation, p->inv_mass_a, &p->va,
                                          &p->wa, p->inv_mass_b, &p->vb, &p->wb, target,
                                          normal_impulse, releases);
    } else {
        solved = solve_normal_cached(count, n, c->r_a, c->r_b, relaxation, p, g, target,
                                     normal_impulse, releases);
    }
% elif normal_solve == "block":
    solved = solve_normal_block(count, n, t1, t2, c->r_a, c->r_b, relaxation,
                                p->inv_mass_a, p->inv_inertia_a, &p->va, &p->wa,
                                p->inv_mass_b, p->inv_inertia_b, &p->vb, &p->wb, target,
                                normal_impulse, releases);
% endif
    if (held && !solved) {
        /* the rows' masses with the held body's share gone (only the rows read them;
         * the block solve derives its own from *p) */
        for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
            normal_mass[k] = row_mass(n, c->r_a[k].xyz, c->r_b[k].xyz, p->inv_mass_a,
                                      p->inv_mass_b, p->inv_inertia_a, p->inv_inertia_b);
    }
    /* alternate the point order between sweeps, so that no point is always first:
     * slot s visits point k = reverse ? 3 - s : s, with the per-point arrays
     * reversed to match rather than indexed by k (subscripts that stay constants
     * keep the arrays in registers, on PoCL and on GPUs alike) */
    if (reverse) {
        reverse4(normal_impulse), reverse4(normal_mass), reverse4(target);
    }
    if (!solved)
        solve_normal_rows(count, n, c->r_a, c->r_b, normal_mass, target, relaxation, reverse,
                          normal_impulse, p);
    if (reverse)
        reverse4(normal_impulse);
    if (push) {
        c->push_impulse = pack4(normal_impulse);
        return;
    }
    unpack4(c->tangent1_impulse, tangent1_impulse);
    unpack4(c->tangent2_impulse, tangent2_impulse);
    unpack4(c->tangent1_mass, tangent1_mass);
    unpack4(c->tangent2_mass, tangent2_mass);
    /* one friction pair at the centre of the points: |(f1, f2)| <= mu * total normal
     * impulse, and a twist row about n: |f| <= mu * total * mean point distance */
    float total = 0.0f;
    ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
        total += normal_impulse[k];
    float share = count > 0 ? 1.0f / (float)count : 0.0f;
    FrictionRows rows;
% if geometry_cache:
    load_friction_rows(g, n, t1, t2, &rows);
    if (held)  /* (as friction_rows derives them from *p: the held body does not turn) */
        hold_rows_still(&rows, c->tangent1.w);
% else:
    friction_rows(c, p, &rows);
% endif
    float limit = friction * total;
    solve_friction_pair(&rows.tangent1, &rows.tangent2, tangent1_mass[0], tangent2_mass[0],
                        limit, relaxation, &tangent1_impulse[0], &tangent2_impulse[0], p);
    float twist_limit = limit * rows.radius * share;
    float twist_total = tangent1_impulse[1]
                        - relaxation * tangent1_mass[1] * row_speed(&rows.twist, p);
    twist_total = min1(max1(twist_total, -twist_limit), twist_limit);
    apply_row(&rows.twist, twist_total - tangent1_impulse[1], p);
    tangent1_impulse[1] = twist_total;
    if (c->tangent2.w > 0.0f) {
        /* a restitution: the points that pushed, kept in tangent2_impulse's slot 1
         * (layouts: ContactConstraint; zero at setup) */
        uint pushed = (uint)tangent2_impulse[1];
        ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count && normal_impulse[k] > 0.0f)
            pushed |= 1u << k;
        tangent2_impulse[1] = (float)pushed;
        if (restitution) {
            unpack4(c->normal_mass, normal_mass);  /* (in point order again) */
            apply_restitution(count, n, t1, t2, c->r_a, c->r_b${", g" if geometry_cache else ""},
                              normal_mass, pushed, normal_impulse, p);
        }
    }
    if (held) {
        float carried[4];  /* (the normal impulses before this sweep: not yet stored) */
        unpack4(c->normal_impulse, carried);
        ${unroll}for (uint k = 0; k < RB_MAX_MANIFOLD_POINTS; ++k) if (k < count)
            normal_impulse[k] = carried[k] + kept_share * (normal_impulse[k] - carried[k]);
    }
    c->normal_impulse = pack4(normal_impulse);
    c->tangent1_impulse = pack4(tangent1_impulse);
    c->tangent2_impulse = pack4(tangent2_impulse);
}

/* Normal rows of one constraint on its bodies' push velocities in *p (split
 * impulse); `releases` as in solve_contact. */
${inlined}void solve_push(${constraint_space} ContactConstraint* c${geometry_param}, __private ContactBodies* p, const float relaxation,
                const bool releases)
{
    solve_contact(c${", g" if geometry_cache else ""}, p, relaxation, false, releases, false, false, true);
}
