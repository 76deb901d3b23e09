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
