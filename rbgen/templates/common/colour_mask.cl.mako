/* A body's colour mask: bit k set when one of its constraints has colour k,
 * 64 colours in two 32-bit words (lo: colours 0-31, hi: 32-63). */

/* index of the lowest clear bit of the mask (lo, hi); 64 if none */
inline uint lowest_free(uint lo, uint hi)
{
    if (lo != 0xFFFFFFFFu)
        return ctz(~lo);
    if (hi != 0xFFFFFFFFu)
        return 32 + ctz(~hi);
    return 64;
}
