/* Uniform-grid cells and buckets, shared by the grid's templates (included,
 * not compiled alone).
 *
 * Small bodies live in the cell of their lower corner. The cell side is at
 * least the size of every small body (SMALL_SLACK times the largest), so two
 * overlapping small bodies sit in the same or adjacent cells. Cells are
 * folded into a table of grid_dim^3 buckets (coordinates modulo
 * grid_dim >= 3), so the buckets around a cell are distinct; a body of a far
 * cell folded into a visited bucket cannot overlap (its true cell would be a
 * neighbour with the same bucket) and fails the box test.
 */

/* Neighbour m of the 27 cells around a cell, m = 9 (dz + 1) + 3 (dy + 1) + (dx + 1):
 * m = 13 is the cell itself, m > 13 the 13 cells after it in (z, y, x) order. */
inline int3 neighbour_offset(int m)
{
    return (int3)(m % 3 - 1, m / 3 % 3 - 1, m / 9 - 1);
}

/* Side of the grid cells: a little more than the largest small body. */
inline float grid_cell_size(float largest_small_size)
{
    return fmax(SMALL_SLACK * largest_small_size, FLT_MIN);
}

<%include file="/common/grid_cells.cl.mako"/>

/* A cell's coordinates modulo grid_dim, in [0, grid_dim). */
inline int3 folded_cell(int3 cell, int grid_dim)
{
    return (cell % grid_dim + grid_dim) % grid_dim;
}

/* Bucket of a cell from its folded coordinates: linearised. */
inline uint folded_bucket(int3 folded, int grid_dim)
{
    return ((uint)folded.z * (uint)grid_dim + (uint)folded.y) * (uint)grid_dim + (uint)folded.x;
}

/* Bucket of a cell: its coordinates modulo grid_dim, linearised. */
inline uint bucket_of(int3 cell, int grid_dim)
{
    return folded_bucket(folded_cell(cell, grid_dim), grid_dim);
}

/* Bucket of neighbour m (see neighbour_offset) of the cell with folded
 * coordinates `folded`: one step folds back by one add or subtract. */
inline uint neighbour_bucket(int3 folded, int m, int grid_dim)
{
    int3 cell = folded + neighbour_offset(m);
    cell = select(cell, cell + grid_dim, cell < 0);
    cell = select(cell, cell - grid_dim, cell >= grid_dim);
    return folded_bucket(cell, grid_dim);
}
