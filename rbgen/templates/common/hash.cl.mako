/* Integer hashes shared by the templates (included once per program). */

/* A bijective mix of 32-bit integers (lowbias32): distinct inputs get
 * distinct, well spread outputs (batching priorities and group hashes). */
inline uint mix32(uint x)
{
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

/* A hash of an ordered pair of 32-bit integers (the warm-start table's key,
 * a body pair): both words multiplied by odd constants, then mixed. */
inline uint hash_pair(uint a, uint b)
{
    uint h = a * 0x9e3779b1u ^ (b + 0x7f4a7c15u) * 0x85ebca77u;
    h ^= h >> 15;
    h *= 0x2c1b3c6du;
    h ^= h >> 13;
    return h;
}
