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

/* A hash of a body pair and a sub-feature (the warm-start table's key): each
 * word multiplied by an odd constant, then mixed; sub 0 (a whole-body pair)
 * hashes as the pair alone. */
inline uint hash_pair(uint a, uint b, uint sub)
{
    uint h = a * 0x9e3779b1u ^ (b + 0x7f4a7c15u) * 0x85ebca77u ^ sub * 0xc2b2ae35u;
    h ^= h >> 15;
    h *= 0x2c1b3c6du;
    h ^= h >> 13;
    return h;
}
