/* Cells of a uniform grid, shared by the broadphase's grid and spatial batching
 * (included once per program). Cell k of an axis spans [k s, (k + 1) s) for a
 * cell side s; the conversions saturate, so that far-away points share the
 * border cells (which keeps neighbours neighbours) instead of wrapping. */

/* The cell index of a coordinate already measured in cells (over the side). */
inline int cell_index(float scaled)
{
    return convert_int_sat_rtn(floor(scaled));
}

/* The cell of a point already measured in cells (its coordinates over the side). */
inline int3 cell_of_scaled(float3 scaled)
{
    return convert_int3_sat_rtn(floor(scaled));
}

/* The cell of a point in a grid of cells of side cell_size. */
inline int3 cell_of(float3 point, float cell_size)
{
    return cell_of_scaled(point / cell_size);
}
