/* Vector arithmetic spelled out, for hot per-item code.
 *
 * Why: PoCL as packaged for distributions (the CPU device here) builds its
 * builtin library for a generic x86-64 target and the kernel for the host
 * CPU, so LLVM will not inline the builtins: every dot, cross, fabs, fmax,
 * sqrt or normalize is an out-of-line call, several times dearer than the
 * spelled-out arithmetic, that also stops PoCL vectorising across
 * work-items. GPU compilers turn these helpers into the same
 * instructions as the builtins, with the same rounding (IEEE sqrt; dot as
 * multiply-adds).
 * common/quaternion.cl.mako includes this file: a template that includes
 * both must include only the quaternion helpers.
 */
inline float dot3(float3 a, float3 b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

inline float3 cross3(float3 a, float3 b)
{
    return (float3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

/* A 3x3 matrix given by its rows times v (world inverse inertias). */
inline float3 mul_rows(const float3 row[3], float3 v)
{
    return (float3)(dot3(row[0], v), dot3(row[1], v), dot3(row[2], v));
}

/* |x| by clearing the sign bit (what fabs compiles to). */
inline float abs1(float x)
{
    return as_float(as_uint(x) & 0x7FFFFFFFu);
}

inline float3 abs3(float3 v)
{
    return as_float3(as_uint3(v) & (uint3)(0x7FFFFFFFu));
}

inline float max1(float a, float b)
{
    return a > b ? a : b;
}

inline float min1(float a, float b)
{
    return a < b ? a : b;
}

/* Correctly rounded square root: the compiler's intrinsic where it has one
 * (clang: an instruction), else the builtin. */
inline float sqrt1(float x)
{
#if defined(__has_builtin)
#if __has_builtin(__builtin_sqrtf)
    return __builtin_sqrtf(x);
#else
    return sqrt(x);
#endif
#else
    return sqrt(x);
#endif
}

inline float length3(float3 v)
{
    return sqrt1(dot3(v, v));
}

/* v / |v| (v must not be zero). */
inline float3 normalize3(float3 v)
{
    return v * (1.0f / length3(v));
}

inline float clamp1(float x, float lo, float hi)
{
    return min1(max1(x, lo), hi);
}
