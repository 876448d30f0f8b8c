//! The row kernel of the rectification (module doc of [`super`], "Per pixel"): the raw
//! position of each rectified pixel interpolated from its cell's lattice nodes in integers,
//! and the bilinear interpolation of the raw image with 8-bit weights; planned cells on one
//! window of the raw image, the others on the checked per-pixel path.

#[cfg(doc)]
use super::LATTICE_NODES;
use super::{MapNode, H, LATTICE_COLS, LATTICE_STEP_PX, Q_FRAC_BITS, W};
use rover_hal::IMAGE_PIXELS;
#[cfg(doc)]
use rover_hal::IMAGE_WIDTH_PX;

/// Fractional bits of a column-interpolated node (1/256 px x 8 = 1/2048 px).
const NODE_BITS: u32 = Q_FRAC_BITS - 3;
/// Bytes of a fast cell's window of the raw image: from one byte before the cell's first raw
/// pixel (so that every load of [`packed_cell`] has a nonzero offset from one address, one
/// instruction less per pixel on the rover CPU), the 2 x 2 neighbourhoods at `x_rel <= 7`,
/// `y_rel <= 1` from that pixel.
const WINDOW_LEN: usize = 1 + 7 + W + W + 2;

/// Rectifies row `row` of one image: `nodes` is that camera's lattice ([`LATTICE_NODES`]),
/// `raw` the raw image ([`IMAGE_PIXELS`] bytes), `out` the rectified row ([`IMAGE_WIDTH_PX`]
/// bytes). Pixels whose raw neighbourhood is outside `raw` (or whose nodes are missing) get 0.
///
/// The same bytes as the per-pixel formula of the module doc for every input (RECT-7),
/// computed cell by cell. Along a cell the raw position is affine, between the
/// cell's two column-interpolated nodes. A cell whose pixels all have their 2 x 2
/// neighbourhood inside the raw image and stay within 8 raw columns and 2 raw rows of its first
/// pixel is planned ([`plan_cell`]) and then run on one window of the raw image with a single
/// packed position register ([`packed_cell`]); any other cell takes the checked per-pixel
/// path.
pub fn rectify_row(nodes: &[MapNode], row: usize, raw: &[u8], out: &mut [u8]) {
    let j = row / LATTICE_STEP_PX;
    let b = (row % LATTICE_STEP_PX) as i32;
    let lattice_row = |jj: usize| nodes.get(jj * LATTICE_COLS..(jj + 1) * LATTICE_COLS);
    let (Some(upper), Some(lower)) = (lattice_row(j), lattice_row(j + 1)) else {
        out.fill(0);
        return;
    };
    // The two lattice rows as one array (upper row, then lower row), the raw image and the
    // output row as arrays.
    let pair: Option<&[MapNode; 2 * LATTICE_COLS]> = nodes
        .get(j * LATTICE_COLS..(j + 2) * LATTICE_COLS)
        .and_then(|s| s.try_into().ok());
    let image: Option<&[u8; IMAGE_PIXELS]> =
        raw.get(..IMAGE_PIXELS).and_then(|s| s.try_into().ok());
    let (Some(image), Some(pair), true) = (image, pair, out.len() == W) else {
        // An output row other than W pixels, or a raw image too short: every cell on the
        // checked path.
        checked_cells(upper, lower, b, raw, out);
        return;
    };
    let Ok(row_out) = <&mut [u8; W]>::try_from(out) else {
        return;
    };
    let nodes: [(i32, i32); LATTICE_COLS] =
        core::array::from_fn(|i| match (pair.get(i), pair.get(LATTICE_COLS + i)) {
            (Some(p0), Some(p1)) => column(p0, p1, b),
            _ => (-1, -1),
        });
    run_row(image, &nodes, row_out);
}

/// The cells of a row between the column-interpolated `nodes`: planned ([`plan_cell`]) and run
/// on their window ([`packed_cell`]), or on the checked path.
#[inline(never)]
fn run_row(image: &[u8; IMAGE_PIXELS], nodes: &[(i32, i32); LATTICE_COLS], out: &mut [u8; W]) {
    // The rounding term 2^15 of the formula, opaque to the optimiser so that it stays in a
    // register and folds into the last multiply-accumulate (one instruction less per pixel).
    let rounding = core::hint::black_box(1 << 15);
    for (cell, out_cell) in out.chunks_exact_mut(LATTICE_STEP_PX).enumerate() {
        let (Some(&left), Some(&right)) = (nodes.get(cell), nodes.get(cell + 1)) else {
            continue;
        };
        let fast = plan_cell(left, right).and_then(|plan| Some((plan, plan.window(image)?)));
        match (fast, <&mut [u8; LATTICE_STEP_PX]>::try_from(&mut *out_cell)) {
            (Some((plan, (window, false))), Ok(cell_out)) => {
                packed_cell::<false>(window, cell_out, plan.a, plan.d, rounding)
            }
            (Some((plan, (window, true))), Ok(cell_out)) => {
                packed_cell::<true>(window, cell_out, plan.a, plan.d, rounding)
            }
            // The raw image's first IMAGE_PIXELS bytes are all the checked path can read.
            _ => checked_cell(image, out_cell, left, right),
        }
    }
}

/// Column interpolation of the nodes `p0` (upper) and `p1` (lower) at row fraction `b`
/// (1/2048 px; wrapping like the i32 arithmetic of the module doc's formula in the flight
/// build).
#[inline(always)]
fn column(p0: &MapNode, p1: &MapNode, b: i32) -> (i32, i32) {
    let c0 = LATTICE_STEP_PX as i32 - b;
    (
        p0.u.wrapping_mul(c0).wrapping_add(p1.u.wrapping_mul(b)),
        p0.v.wrapping_mul(c0).wrapping_add(p1.v.wrapping_mul(b)),
    )
}

/// A planned fast cell of [`rectify_row`]: `a`, `d` of [`packed_cell`] and the offset of its
/// first raw pixel in the raw image (bit 31: the cell touches two raw rows).
#[derive(Clone, Copy)]
struct CellPlan {
    a: u32,
    d: u32,
    offset: u32,
}

impl CellPlan {
    /// Bit of `offset` marking a cell on two raw rows.
    const TWO_ROWS: u32 = 1 << 31;

    /// The cell's window of `image` ([`WINDOW_LEN`]) and whether it touches two rows; `None`
    /// for a window that would start before the image (a cell at the first pixel) or reach
    /// past its end (next to the last rows): such cells are left to the checked path.
    #[inline(always)]
    fn window(self, image: &[u8; IMAGE_PIXELS]) -> Option<(&[u8; WINDOW_LEN], bool)> {
        let offset = ((self.offset & !Self::TWO_ROWS) as usize).checked_sub(1)?;
        let window = image.get(offset..offset + WINDOW_LEN)?.try_into().ok()?;
        Some((window, self.offset & Self::TWO_ROWS != 0))
    }
}

/// The plan of the cell between the column-interpolated nodes `(lu, lv)` and `(ru, rv)`
/// (1/2048 px) for [`packed_cell`]; `None` when a pixel of the cell has no room for its
/// 2 x 2 neighbourhood in the image, or the cell's pixels leave 8 raw columns or 2 raw rows
/// from its first one. Each condition is "a value below 2^k"; they are tested together on the
/// OR of the values shifted right by their k.
#[inline(always)]
fn plan_cell((lu, lv): (i32, i32), (ru, rv): (i32, i32)) -> Option<CellPlan> {
    let (lu, lv, ru, rv) = (lu as u32, lv as u32, ru as u32, rv as u32);
    // Both columns and rows in 0..1024 px: the steps below cannot overflow.
    let nodes_out = (lu | ru | lv | rv) >> (NODE_BITS + 10);
    let (du, dv) = (ru.wrapping_sub(lu), rv.wrapping_sub(lv));
    // First pixel's column x0 and its fraction (1/16384 px); the last pixel's column
    // relative to x0 must stay below 8 (its field in the packed position).
    let x0 = lu >> NODE_BITS;
    let qu_frac = (lu & ((1 << NODE_BITS) - 1)) << 3;
    let last = qu_frac.wrapping_add(du.wrapping_mul(LATTICE_STEP_PX as u32 - 1));
    // The rightmost pixel column (x0, or x0 + last / 2^14 when the row runs right) must have
    // its right neighbour in the image: x <= W - 2, i.e. x + (1024 - (W - 1)) < 1024.
    let x_max = x0 + (last >> Q_FRAC_BITS) + (1024 - (W as u32 - 1));
    // The upper of the cell's (at most two) raw rows, from the rows of both nodes; the rows of
    // both nodes relative to it (so of every pixel between them) must lie in 0..2 px, and the
    // lower row must have its lower neighbour in the image: y_base + 1 <= H - 2.
    let (y0, y8) = (lv >> NODE_BITS, rv >> NODE_BITS);
    let dy = y8.wrapping_sub(y0) as i32;
    let y_base = y0.wrapping_add((dy >> 1) as u32);
    let v0 = (lv << 3).wrapping_sub(y_base << Q_FRAC_BITS);
    let v8 = (rv << 3).wrapping_sub(y_base << Q_FRAC_BITS);
    let y_max = y_base + 1 + (1024 - (H as u32 - 1));
    let out = nodes_out
        | (last >> (Q_FRAC_BITS + 3))
        | ((x_max | y_max) >> 10)
        | ((v0 | v8) >> (Q_FRAC_BITS + 1));
    if out != 0 {
        return None;
    }
    let offset = y_base * W as u32 + x0;
    Some(CellPlan {
        a: (qu_frac << 15) | v0,
        d: (du << 15).wrapping_add(dv),
        // dy is -1, 0 or 1 here: bit 31 set exactly when the cell touches two rows.
        offset: offset | (dy as u32) << 31,
    })
}

/// One fast cell ([`rectify_row`]): `a` packs the first pixel's raw position relative to the
/// window's first pixel `(x0, y_base)`: bits 15..31 the column `qu - x0 2^14` (1/16384 px,
/// below 8 px), bits 0..14 the row `qv - y_base 2^14` (below 2 px); `d` packs the per-pixel
/// step the same way. Every position of the cell stays inside both fields (checked by the
/// caller), so `a + k d` is exactly the packed position of pixel `k`. `TWO_ROWS`: the cell
/// touches two raw rows (else the row bit is always 0).
#[inline(always)]
fn packed_cell<const TWO_ROWS: bool>(
    window: &[u8; WINDOW_LEN],
    out: &mut [u8],
    mut a: u32,
    d: u32,
    rounding: i32,
) {
    for px in out.iter_mut() {
        let x = 1 + (a >> 29) as usize;
        let o = if TWO_ROWS {
            x + ((a >> Q_FRAC_BITS) & 1) as usize * W
        } else {
            x
        };
        let wx = ((a >> 21) & 0xff) as i32;
        let wy = ((a >> (Q_FRAC_BITS - 8)) & 0xff) as i32;
        if let Some(&[i00, i10, .., i01, i11]) = window.get(o..o + W + 2) {
            *px = bilinear_rounded([i00, i10, i01, i11], wx, wy, rounding);
        }
        // Keeps the next pixel's loads after this store: eight interleaved pixels run out
        // of registers on the rover CPU (a compiler-only barrier, no instruction is emitted).
        core::sync::atomic::compiler_fence(core::sync::atomic::Ordering::SeqCst);
        a = a.wrapping_add(d);
    }
}

/// The checked per-pixel path of [`rectify_row`] for all cells of `out`, lattice rows `upper`,
/// `lower` at row fraction `b`.
fn checked_cells(upper: &[MapNode], lower: &[MapNode], b: i32, raw: &[u8], out: &mut [u8]) {
    let step = LATTICE_STEP_PX as i32;
    for (cell, out_cell) in out.chunks_mut(LATTICE_STEP_PX).enumerate() {
        let corners = (upper.get(cell..cell + 2), lower.get(cell..cell + 2));
        let (Some(&[p00, p10]), Some(&[p01, p11])) = corners else {
            out_cell.fill(0);
            continue;
        };
        let column = |p0: MapNode, p1: MapNode| {
            (
                p0.u.wrapping_mul(step - b)
                    .wrapping_add(p1.u.wrapping_mul(b)),
                p0.v.wrapping_mul(step - b)
                    .wrapping_add(p1.v.wrapping_mul(b)),
            )
        };
        checked_cell(raw, out_cell, column(p00, p01), column(p10, p11));
    }
}

/// One cell on the checked path: left and right column-interpolated nodes `(lu, lv)`,
/// `(ru, rv)` (1/2048 px); the raw position `q` in 1/16384 px is stepped by `R - L` per
/// pixel (wrapping, like the flight build's i32 arithmetic).
#[inline(never)]
fn checked_cell(raw: &[u8], out: &mut [u8], (lu, lv): (i32, i32), (ru, rv): (i32, i32)) {
    let step = LATTICE_STEP_PX as i32;
    let (mut qu, mut qv) = (lu.wrapping_mul(step), lv.wrapping_mul(step));
    let (du, dv) = (ru.wrapping_sub(lu), rv.wrapping_sub(lv));
    for px in out.iter_mut() {
        *px = sample(raw, qu, qv);
        qu = qu.wrapping_add(du);
        qv = qv.wrapping_add(dv);
    }
}

/// Bilinear sample of `raw` at `(qu, qv)` (1/16384 px), 8-bit weights, rounded half up; 0
/// outside.
#[inline(always)]
fn sample(raw: &[u8], qu: i32, qv: i32) -> u8 {
    if qu < 0 || qv < 0 {
        return 0;
    }
    let (x, y) = ((qu >> Q_FRAC_BITS) as usize, (qv >> Q_FRAC_BITS) as usize);
    if x + 1 >= W || y + 1 >= H {
        return 0;
    }
    let wx = (qu >> (Q_FRAC_BITS - 8)) & 0xff;
    let wy = (qv >> (Q_FRAC_BITS - 8)) & 0xff;
    let top = y * W + x;
    // The 2 x 2 neighbourhood: one window of W + 2 bytes, indexed at fixed offsets inside it.
    let Some(window) = raw.get(top..top + W + 2) else {
        return 0;
    };
    let (Some(&i00), Some(&i10), Some(&i01), Some(&i11)) = (
        window.first(),
        window.get(1),
        window.get(W),
        window.get(W + 1),
    ) else {
        return 0;
    };
    bilinear([i00, i10, i01, i11], wx, wy)
}

/// The module doc's bilinear formula for the neighbourhood `[I00, I10, I01, I11]` and the
/// weights `wx`, `wy` (0..=255): `I00 (256 - wx) + I10 wx = 256 I00 + (I10 - I00) wx`,
/// exactly (and the same along y), so three multiplications; every term fits an i32.
#[inline(always)]
fn bilinear(i: [u8; 4], wx: i32, wy: i32) -> u8 {
    bilinear_rounded(i, wx, wy, 1 << 15)
}

/// [`bilinear`] with its rounding term `rounding` (always `2^15`) passed in.
#[inline(always)]
fn bilinear_rounded([i00, i10, i01, i11]: [u8; 4], wx: i32, wy: i32, rounding: i32) -> u8 {
    let (i00, i10, i01, i11) = (
        i32::from(i00),
        i32::from(i10),
        i32::from(i01),
        i32::from(i11),
    );
    let upper = (i00 << 8) + (i10 - i00) * wx;
    let lower = (i01 << 8) + (i11 - i01) * wx;
    (((upper << 8) + rounding + (lower - upper) * wy) >> 16) as u8
}
