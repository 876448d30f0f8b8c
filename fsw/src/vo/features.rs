//! Feature selection (H04 sec. 2 "Feature Selection"; H05 sec. II.A): Forstner interest
//! operator on the left image, best pixel per grid cell, sort, top N with a minimum distance.
//!
//! The Forstner operator builds, at each pixel, the normal matrix of the gradients over a 5x5
//! window, `N = sum [gx^2 gx*gy; gx*gy gy^2]`, and scores the pixel by `w = det(N) / trace(N)`
//! (the inverse of the size of the error ellipse of a corner located at that pixel, so the
//! paper's "lower interest value is better" is "higher `w` is better" here) with the roundness
//! `q = 4 det(N) / trace(N)^2` to reject edges. The window sums are kept as running column sums,
//! one image row per work item, so the operator needs three rows of 640 sums instead of an
//! interest image.

#[cfg(any(target_arch = "arm", test))]
#[macro_use]
mod interleaved;
#[cfg(not(target_arch = "arm"))]
mod planar;
mod selection;

use super::image::Image;
use super::{VoConfig, TEMPLATE_HALF};
#[cfg(test)]
use interleaved::ColumnSums;
#[cfg(any(target_arch = "arm", test))]
use interleaved::{add_window, score_full, score_partial, slide_rows, Interleaved, SPAN};
#[cfg(not(target_arch = "arm"))]
use planar::Planar;
#[cfg(test)]
use planar::{det_trace, pretest};
use rover_hal::{IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX};
#[cfg(test)]
use selection::ranks_before;
pub use selection::{heap_sort_descending, select_more, select_with_min_distance};
use selection::{sift_down, sift_down_best};

/// Side of a grid cell, pixels (much smaller than the minimum feature distance).
pub const GRID_PX: usize = 10;
/// Grid columns.
pub const GRID_COLS: usize = IMAGE_WIDTH_PX / GRID_PX;
/// Grid rows.
pub const GRID_ROWS: usize = IMAGE_HEIGHT_PX / GRID_PX;
/// Grid cells.
pub const CELL_COUNT: usize = GRID_COLS * GRID_ROWS;
/// Half side of the Forstner window (5x5).
pub const WINDOW_HALF: usize = 2;
/// Features keep this distance from the image border, pixels (template plus refinement room).
pub const BORDER_PX: usize = TEMPLATE_HALF + 4;
/// First image row the operator scores.
pub const FIRST_ROW: usize = BORDER_PX;
/// One past the last image row the operator scores.
pub const END_ROW: usize = IMAGE_HEIGHT_PX - BORDER_PX;

/// The best pixel of a grid cell.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Candidate {
    /// Forstner interest `w` (0 for an empty cell).
    pub interest: f32,
    /// Column, pixels.
    pub x: u16,
    /// Row, pixels.
    pub y: u16,
}

/// The Forstner operator's running state: column sums of the gradient products over the
/// window rows, and the best candidate per grid cell.
#[derive(Debug, Clone)]
pub struct ForstnerDetector {
    columns: NativeSums,
    cells: [Candidate; CELL_COUNT],
    candidate_count: usize,
}

impl Default for ForstnerDetector {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// An empty grid cell (`Candidate::default()`, usable in a `const`).
const NO_CANDIDATE: Candidate = Candidate {
    interest: 0.0,
    x: 0,
    y: 0,
};

impl ForstnerDetector {
    /// A detector with zero sums and empty cells (as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        columns: NativeSums::ZERO,
        cells: [NO_CANDIDATE; CELL_COUNT],
        candidate_count: 0,
    };
}

/// One image row as an array.
type Row<'a> = &'a [u8; IMAGE_WIDTH_PX];

/// The rows a central-difference gradient row `y` needs: the row above, the row itself, the
/// row below. `None` at the first and last rows.
fn gradient_rows<'a>(image: &Image<'a>, y: usize) -> Option<[Row<'a>; 3]> {
    let up = image.row(y.checked_sub(1)?)?.try_into().ok()?;
    let mid = image.row(y)?.try_into().ok()?;
    let down = image.row(y + 1)?.try_into().ok()?;
    Some([up, mid, down])
}

/// First column a scored window reaches (the first centre [`BORDER_PX`] minus the half window).
const SUM_FIRST_COL: usize = BORDER_PX - WINDOW_HALF;
/// One past the last column a scored window reaches (the last centre is
/// `IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF - 1`).
const SUM_END_COL: usize = IMAGE_WIDTH_PX - BORDER_PX;

/// Central-difference gradients `(gx, gy)` at column `c` of the row whose neighbours are
/// `[up, mid, down]` (`gx = I(c + 1) - I(c - 1)`, `gy = I(y + 1) - I(y - 1)`), with the row's
/// pixels `m0 = I(c - 1)` and `m2 = I(c + 1)` given.
#[inline(always)]
fn gradient(up: u8, down: u8, m0: i32, m2: i32) -> (i32, i32) {
    (m2 - m0, i32::from(down) - i32::from(up))
}

/// The thresholds of one call: `min_interest` and `min_roundness` (f64 of the config's f32)
/// and their integer parts for [`Floors`].
#[derive(Clone, Copy)]
struct Thresholds {
    min_interest: f64,
    min_roundness: f64,
    /// `floor(4 min_interest) - 1` (saturating; `as` maps NaN to 0).
    #[cfg_attr(not(any(target_arch = "arm", test)), allow(dead_code))]
    trace_floor: i32,
    /// `floor(min_interest) - 1` (saturating).
    #[cfg_attr(not(any(target_arch = "arm", test)), allow(dead_code))]
    w_floor: i32,
}

impl Thresholds {
    fn new(config: &VoConfig) -> Self {
        let min_interest = f64::from(config.min_interest);
        Self {
            min_interest,
            min_roundness: f64::from(config.min_roundness),
            trace_floor: ((4.0 * min_interest) as i32).saturating_sub(1),
            w_floor: (min_interest as i32).saturating_sub(1),
        }
    }
}

/// The column sums of this build's target: [`Interleaved`] on the rover CPU (32-bit Arm).
#[cfg(target_arch = "arm")]
type NativeSums = Interleaved;
/// The column sums of this build's target: [`Planar`] on the host.
#[cfg(not(target_arch = "arm"))]
type NativeSums = Planar;

/// Bytes the host's column sums add to [`ForstnerDetector`] over the rover CPU's (0 there):
/// the rover-CPU size of a structure holding a detector is its host size minus this.
pub const HOST_LAYOUT_EXTRA_BYTES: usize =
    core::mem::size_of::<NativeSums>() - core::mem::size_of::<[[i32; 3]; IMAGE_WIDTH_PX]>();

impl ForstnerDetector {
    /// Clears the cells and the running sums (in place: the detector becomes
    /// [`Self::EMPTY`]); the next row to score is [`FIRST_ROW`].
    pub fn reset(&mut self) {
        self.columns.clear();
        self.cells.fill(NO_CANDIDATE);
        self.candidate_count = 0;
    }

    /// Scores image row `y` (rows must come in order from [`FIRST_ROW`] to `END_ROW - 1`, one
    /// call each) and keeps the best pixel of each grid cell whose interest and roundness pass
    /// the thresholds of `config`.
    pub fn process_row(&mut self, image: &Image, y: usize, config: &VoConfig) {
        self.process_row_masked(image, y, config, 0);
    }

    /// [`Self::process_row`] that skips the grid cells of this row's grid row whose bit is set
    /// in `skip_cells` (bit `c` for grid column `c`): they are not scored and stay as they are
    /// (empty: a grid row's cells are cleared at its first row of the pass, so until then they
    /// hold the previous pass's values; the candidates are read only after the whole pass).
    /// The running column sums are kept for every column a window reaches, so the other cells
    /// get exactly the scores of the unmasked operator.
    pub fn process_row_masked(
        &mut self,
        image: &Image,
        y: usize,
        config: &VoConfig,
        skip_cells: u64,
    ) {
        #[cfg(target_arch = "arm")]
        interleaved_row!(self, image, y, config, skip_cells);
        #[cfg(not(target_arch = "arm"))]
        {
            // The rover CPU's row code, with the host's layout (kept apart from
            // `interleaved_row!`: shared through a function, the grid-row preamble changed the
            // rover CPU build's code).
            let cell_row = y / GRID_PX;
            let cells = self
                .cells
                .get_mut(cell_row * GRID_COLS..(cell_row + 1) * GRID_COLS)
                .unwrap_or(&mut []);
            if y == FIRST_ROW || y % GRID_PX == 0 {
                cells.fill(NO_CANDIDATE);
            }
            if y == FIRST_ROW {
                self.columns.clear();
                self.candidate_count = 0;
                self.columns.add_window(image, FIRST_ROW);
            } else {
                self.columns
                    .slide_rows(image, y + WINDOW_HALF, y - WINDOW_HALF - 1);
            }
            self.columns
                .score_row(cells, y, skip_cells, &Thresholds::new(config));
        }
    }

    /// Compacts the non-empty cells and sorts them by descending interest (heap sort: bounded,
    /// no recursion; ties keep a deterministic order). Returns the number of candidates.
    pub fn sort_candidates(&mut self) -> usize {
        let count = self.compact_candidates();
        let list = self.cells.get_mut(..count).unwrap_or(&mut []);
        heap_sort_descending(list);
        count
    }

    /// First step of an incremental [`Self::sort_candidates`]: compacts the non-empty cells to
    /// the front and returns their number `n`. Then [`Self::heapify_step`] for `start` from
    /// `n / 2 - 1` down to 0, then [`Self::sort_step`] for `end` from `n - 1` down to 1 give the
    /// same order as [`Self::sort_candidates`].
    pub fn compact_candidates(&mut self) -> usize {
        let mut count = 0usize;
        for k in 0..CELL_COUNT {
            let Some(&c) = self.cells.get(k) else { break };
            if c.interest > 0.0 {
                if let Some(slot) = self.cells.get_mut(count) {
                    *slot = c;
                }
                count += 1;
            }
        }
        self.candidate_count = count;
        count
    }

    /// One heap-building step of the incremental sort (see [`Self::compact_candidates`]).
    pub fn heapify_step(&mut self, start: usize) {
        let n = self.candidate_count;
        if let Some(list) = self.cells.get_mut(..n) {
            sift_down(list, start, n);
        }
    }

    /// One sort-down step of the incremental sort (see [`Self::compact_candidates`]).
    pub fn sort_step(&mut self, end: usize) {
        let n = self.candidate_count;
        if let Some(list) = self.cells.get_mut(..n) {
            if end < n {
                list.swap(0, end);
                sift_down(list, 0, end);
            }
        }
    }

    /// One step of building the best-first heap of the compacted candidates (a max-heap on
    /// the rank: the root is the best), for `start` from `n / 2 - 1` down to 0 after
    /// [`Self::compact_candidates`]. Then [`Self::pop_best`] gives the candidates in the order
    /// of [`Self::sort_candidates`] (the rank is a strict total order: no two cells share a
    /// pixel), one at a time, so the selection stops as soon as it has its features instead of
    /// sorting every cell (the timing budget).
    pub fn best_heapify_step(&mut self, start: usize) {
        let n = self.candidate_count;
        if let Some(list) = self.cells.get_mut(..n) {
            sift_down_best(list, start, n);
        }
    }

    /// The best candidate of the best-first heap of the first `len` compacted candidates
    /// (see [`Self::best_heapify_step`]), moved to position `len - 1`; the heap is then the
    /// first `len - 1`. `None` when `len` is 0 or beyond the candidates.
    pub fn pop_best(&mut self, len: usize) -> Option<Candidate> {
        if len == 0 || len > self.candidate_count {
            return None;
        }
        let list = self.cells.get_mut(..len)?;
        if let [first, .., last] = list {
            core::mem::swap(first, last);
        }
        sift_down_best(list, 0, len - 1);
        list.last().copied()
    }

    /// The sorted candidates (after [`Self::sort_candidates`]).
    pub fn candidates(&self) -> &[Candidate] {
        self.cells.get(..self.candidate_count).unwrap_or(&[])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference operator, written plainly (running sums of every interior column, a
    /// trace bound and the f64 tests at every centre), with the state passed in: the
    /// reference of `vo_1_optimised_operator_equals_the_reference`.
    mod reference {
        use super::super::*;

        /// The rows a central-difference gradient row `y` needs, cut to the interior columns
        /// `1..width-1`: left and right neighbours in row `y`, the pixels above and below. `None` at the
        /// first and last rows.
        fn gradient_rows<'a>(image: &Image<'a>, y: usize) -> Option<[&'a [u8]; 4]> {
            let up = image.row(y.checked_sub(1)?)?;
            let mid = image.row(y)?;
            let down = image.row(y + 1)?;
            let n = IMAGE_WIDTH_PX - 2;
            Some([
                mid.get(..n)?,
                mid.get(2..n + 2)?,
                up.get(1..n + 1)?,
                down.get(1..n + 1)?,
            ])
        }

        /// Central-difference gradients `(gx, gy)` of the interior pixels of image row `y` (columns
        /// 1..width-1), `None` at the first and last rows.
        fn row_gradients<'a>(
            image: &Image<'a>,
            y: usize,
        ) -> Option<impl Iterator<Item = (i32, i32)> + 'a> {
            let [l, r, u, d] = gradient_rows(image, y)?;
            Some(
                l.iter()
                    .zip(r)
                    .zip(u.iter().zip(d))
                    .map(|((&l, &r), (&u, &d))| {
                        (i32::from(r) - i32::from(l), i32::from(d) - i32::from(u))
                    }),
            )
        }

        /// The column sums of the gradient products, `[xx, yy, xy]` per column.
        type ColumnSums = [[i32; 3]; IMAGE_WIDTH_PX];

        /// Adds the gradient products of image row `y` to the column sums.
        fn add_row(image: &Image, y: usize, sums: &mut ColumnSums) {
            let Some(g) = row_gradients(image, y) else {
                return;
            };
            for (s, (gx, gy)) in sums.iter_mut().skip(1).zip(g) {
                s[0] += gx * gx;
                s[1] += gy * gy;
                s[2] += gx * gy;
            }
        }

        /// Moves the window down one row: adds the products of row `add`, removes those of row
        /// `remove` (one pass over the sums).
        fn slide_rows(image: &Image, add: usize, remove: usize, sums: &mut ColumnSums) {
            let (Some([al, ar, au, ad]), Some([rl, rr, ru, rd])) =
                (gradient_rows(image, add), gradient_rows(image, remove))
            else {
                return;
            };
            let added = al.iter().zip(ar).zip(au.iter().zip(ad));
            let removed = rl.iter().zip(rr).zip(ru.iter().zip(rd));
            for (s, (((&al, &ar), (&au, &ad)), ((&rl, &rr), (&ru, &rd)))) in
                sums.iter_mut().skip(1).zip(added.zip(removed))
            {
                let (ax, ay) = (i32::from(ar) - i32::from(al), i32::from(ad) - i32::from(au));
                let (rx, ry) = (i32::from(rr) - i32::from(rl), i32::from(rd) - i32::from(ru));
                s[0] += ax * ax - rx * rx;
                s[1] += ay * ay - ry * ry;
                s[2] += ax * ay - rx * ry;
            }
        }

        /// Scores the window centres of one grid cell in one row: `span` holds the column sums of the
        /// columns `first - WINDOW_HALF .. first + n + WINDOW_HALF` for the `n` centres
        /// `first..first + n`; keeps the best pixel passing the thresholds in `cell`.
        #[inline(always)]
        fn score_cell(
            span: &[[i32; 3]],
            first: usize,
            y: usize,
            cell: &mut Candidate,
            min_interest: f64,
            min_roundness: f64,
        ) {
            const W: usize = 2 * WINDOW_HALF;
            // Window sums in i32: a gradient product is at most 255^2, a column sum five of them, a
            // window sum 25 (< 1.7e6, no overflow on any image). Their products are below 2^53, so det
            // and trace are exact in f64.
            let (mut nxx, mut nyy, mut nxy) = (0i32, 0i32, 0i32);
            for &[a, b, c] in span.iter().take(W) {
                nxx += a;
                nyy += b;
                nxy += c;
            }
            // w = det / trace <= trace / 4 (det <= (trace / 2)^2 for a 2x2 normal matrix): a pixel
            // whose trace is at most four times the cell's best cannot beat it. In integers (traces are
            // integers, interests non-negative): trace > 4 w  <=>  trace > floor(4 w).
            let bound = |interest: f32| (4.0 * f64::from(interest)) as i32;
            let mut min_trace = bound(cell.interest);
            for (k, (&[a, b, c], &[oa, ob, oc])) in span.iter().skip(W).zip(span.iter()).enumerate()
            {
                // Window over the columns centre-2..=centre+2.
                nxx += a;
                nyy += b;
                nxy += c;
                let trace = nxx + nyy;
                if trace > min_trace && trace > 0 {
                    let (fxx, fyy, fxy) = (f64::from(nxx), f64::from(nyy), f64::from(nxy));
                    let det_f = fxx * fyy - fxy * fxy;
                    let trace_f = f64::from(trace);
                    // Thresholds without divisions; the test against the cell's best comes first (most
                    // pixels fail it), the division runs only for a new best.
                    if det_f > 0.0
                        && det_f > f64::from(cell.interest) * trace_f
                        && !(det_f < min_interest * trace_f)
                        && !(4.0 * det_f < min_roundness * trace_f * trace_f)
                    {
                        let interest = (det_f / trace_f) as f32;
                        if interest > cell.interest {
                            *cell = Candidate {
                                interest,
                                x: (first + k) as u16,
                                y: y as u16,
                            };
                            min_trace = bound(interest);
                        }
                    }
                }
                nxx -= oa;
                nyy -= ob;
                nxy -= oc;
            }
        }

        pub fn process_row_masked(
            columns: &mut ColumnSums,
            cells_all: &mut [Candidate; CELL_COUNT],
            image: &Image,
            y: usize,
            config: &VoConfig,
            skip_cells: u64,
        ) {
            if y == FIRST_ROW {
                columns.fill([0; 3]);
                cells_all.fill(NO_CANDIDATE);
                for r in (FIRST_ROW - WINDOW_HALF)..=(FIRST_ROW + WINDOW_HALF) {
                    add_row(image, r, columns);
                }
            } else {
                slide_rows(image, y + WINDOW_HALF, y - WINDOW_HALF - 1, columns);
            }
            let cell_row = y / GRID_PX;
            let (min_interest, min_roundness) = (
                f64::from(config.min_interest),
                f64::from(config.min_roundness),
            );
            let cells = cells_all
                .get_mut(cell_row * GRID_COLS..(cell_row + 1) * GRID_COLS)
                .unwrap_or(&mut []);
            // Scored centres: BORDER_PX..IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF (the window of the
            // last one ends inside the border), cell by cell.
            let end = IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF;
            for (c, cell) in cells.iter_mut().enumerate() {
                if c < u64::BITS as usize && skip_cells & (1u64 << c) != 0 {
                    continue;
                }
                let first = (c * GRID_PX).max(BORDER_PX);
                let stop = (c * GRID_PX + GRID_PX).min(end);
                if first >= stop {
                    continue;
                }
                let Some(span) = columns.get(first - WINDOW_HALF..stop + WINDOW_HALF) else {
                    continue;
                };
                score_cell(span, first, y, cell, min_interest, min_roundness);
            }
        }
    }
    use rover_hal::IMAGE_PIXELS;
    use std::{boxed::Box, vec::Vec};

    #[test]
    fn vo_1_forstner_finds_corners_not_edges() {
        // Bright squares on a dark background: corners are features, edges and flats are not.
        let mut img = vec![20u8; IMAGE_PIXELS];
        let squares = [(100usize, 100usize), (300, 200), (500, 350)];
        for &(x0, y0) in &squares {
            for y in y0..y0 + 40 {
                for x in x0..x0 + 40 {
                    img[y * IMAGE_WIDTH_PX + x] = 200;
                }
            }
        }
        let image = Image::new(&img).unwrap();
        let mut det = Box::new(ForstnerDetector::default());
        let config = VoConfig::default();
        for y in FIRST_ROW..END_ROW {
            det.process_row(&image, y, &config);
        }
        let n = det.sort_candidates();
        let mut out = [(0u16, 0u16); 20];
        let k = select_with_min_distance(det.candidates(), 20.0, &mut out);
        assert_eq!(k, 12, "{n} candidates");
        for &(x, y) in &out[..k] {
            let near_corner = squares.iter().any(|&(x0, y0)| {
                [(x0, y0), (x0 + 39, y0), (x0, y0 + 39), (x0 + 39, y0 + 39)]
                    .iter()
                    .any(|&(cx, cy)| {
                        (x as i32 - cx as i32).abs() <= 2 && (y as i32 - cy as i32).abs() <= 2
                    })
            });
            assert!(near_corner, "({x},{y}) is not at a corner");
        }
        let sorted = det.candidates();
        assert!(sorted.windows(2).all(|w| w[0].interest >= w[1].interest));
    }

    #[test]
    fn vo_1_running_sums_equal_the_direct_window_sums() {
        // A noisy random image: the detector's cells equal the best pixel per cell scored by
        // direct 5x5 sums of the gradient products (the definition).
        let mut state = 0x1234_5678_9abc_def0u64;
        let img: Vec<u8> = (0..IMAGE_PIXELS)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 56) as u8
            })
            .collect();
        let image = Image::new(&img).unwrap();
        let config = VoConfig {
            min_interest: 2000.0,
            ..VoConfig::default()
        };
        let mut det = Box::new(ForstnerDetector::default());
        for y in FIRST_ROW..END_ROW {
            det.process_row(&image, y, &config);
        }
        let px = |x: usize, y: usize| i64::from(img[y * IMAGE_WIDTH_PX + x]);
        let mut cells = vec![Candidate::default(); CELL_COUNT];
        for y in FIRST_ROW..END_ROW {
            for x in BORDER_PX..IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF {
                let (mut nxx, mut nyy, mut nxy) = (0i64, 0i64, 0i64);
                for wy in y - 2..=y + 2 {
                    for wx in x - 2..=x + 2 {
                        let gx = px(wx + 1, wy) - px(wx - 1, wy);
                        let gy = px(wx, wy + 1) - px(wx, wy - 1);
                        nxx += gx * gx;
                        nyy += gy * gy;
                        nxy += gx * gy;
                    }
                }
                let (det_f, trace_f) = ((nxx * nyy - nxy * nxy) as f64, (nxx + nyy) as f64);
                let w = det_f / trace_f;
                let q = 4.0 * det_f / (trace_f * trace_f);
                let cell = &mut cells[(y / GRID_PX) * GRID_COLS + x / GRID_PX];
                if w >= f64::from(config.min_interest)
                    && q >= f64::from(config.min_roundness)
                    && (w as f32) > cell.interest
                {
                    *cell = Candidate {
                        interest: w as f32,
                        x: x as u16,
                        y: y as u16,
                    };
                }
            }
        }
        let found = cells.iter().filter(|c| c.interest > 0.0).count();
        assert!(found > 1000, "{found} cells");
        assert_eq!(det.cells[..], cells[..]);
    }

    /// The rover CPU's operator on the host: [`Interleaved`] sums and the flight row code
    /// (`interleaved_row!`).
    struct RoverOperator {
        columns: Interleaved,
        cells: [Candidate; CELL_COUNT],
        candidate_count: usize,
    }

    impl RoverOperator {
        fn process_row_masked(&mut self, image: &Image, y: usize, config: &VoConfig, skip: u64) {
            interleaved_row!(self, image, y, config, skip);
        }
    }

    /// Runs the optimised operator (the host's and the rover CPU's) and the reference on `img` with `config` and the skip mask
    /// `mask(grid_row)`; asserts equal cells after every grid row. Returns the non-empty cells.
    fn compare_with_reference(img: &[u8], config: &VoConfig, mask: impl Fn(usize) -> u64) -> usize {
        let image = Image::new(img).unwrap();
        let mut det = Box::new(ForstnerDetector::default());
        let mut columns: Box<ColumnSums> = Box::new([[0; 3]; IMAGE_WIDTH_PX]);
        let mut cells: Box<[Candidate; CELL_COUNT]> = Box::new([NO_CANDIDATE; CELL_COUNT]);
        let mut rover = Box::new(RoverOperator {
            columns: Interleaved::ZERO,
            cells: [NO_CANDIDATE; CELL_COUNT],
            candidate_count: 0,
        });
        for y in FIRST_ROW..END_ROW {
            let skip = mask(y / GRID_PX);
            det.process_row_masked(&image, y, config, skip);
            reference::process_row_masked(&mut columns, &mut cells, &image, y, config, skip);
            rover.process_row_masked(&image, y, config, skip);
            if y % GRID_PX == GRID_PX - 1 || y + 1 == END_ROW {
                // The reference keeps every interior column; the operator those a scored
                // window reaches.
                let column =
                    (SUM_FIRST_COL..SUM_END_COL).find(|&c| det.columns.column(c) != columns[c]);
                assert_eq!(column, None, "column sums differ, row {y}");
                let column =
                    (SUM_FIRST_COL..SUM_END_COL).find(|&c| rover.columns.0[c] != columns[c]);
                assert_eq!(column, None, "the rover CPU's sums differ, row {y}");
                if let Some(c) = (0..CELL_COUNT).find(|&c| rover.cells[c] != det.cells[c]) {
                    let (r, h) = (rover.cells[c], det.cells[c]);
                    panic!("row {y} cell {c}: rover CPU {r:?}, host {h:?}");
                }
                let cell = (0..CELL_COUNT).find(|&c| det.cells[c] != cells[c]);
                if let Some(c) = cell {
                    panic!("row {y} cell {c}: {:?} != {:?}", det.cells[c], cells[c]);
                }
            }
        }
        cells.iter().filter(|c| c.interest > 0.0).count()
    }

    /// xorshift64 noise image; `smooth` box-filters it horizontally over that many pixels
    /// (lower contrast, more ties near the thresholds).
    fn noise_image(seed: u64, smooth: usize) -> Vec<u8> {
        let mut state = seed;
        let raw: Vec<u8> = (0..IMAGE_PIXELS)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 56) as u8
            })
            .collect();
        (0..IMAGE_PIXELS)
            .map(|i| {
                let n = smooth.max(1).min(IMAGE_PIXELS - i);
                (raw[i..i + n].iter().map(|&v| u32::from(v)).sum::<u32>() / n as u32) as u8
            })
            .collect()
    }

    #[test]
    fn vo_1_optimised_operator_equals_the_reference() {
        // The flight operator (integer pre-tests, fixed-length cell loops, per-column slide)
        // against the straightforward one in `reference`: the same column sums and the same
        // cells (interest bits, positions) on random and rendered images, with and without skip
        // masks, for the flight thresholds and for extreme ones.
        use crate::types::Vec3;
        use crate::vo::render::{hazcam, render_pair, RoverPose};
        let configs = [
            VoConfig::default(),
            VoConfig {
                min_interest: 2000.0,
                ..VoConfig::default()
            },
            VoConfig {
                min_interest: 0.5,
                min_roundness: 0.0,
                ..VoConfig::default()
            },
            VoConfig {
                min_interest: 1.0e12,
                ..VoConfig::default()
            },
            VoConfig {
                min_interest: f32::NAN,
                min_roundness: f32::NAN,
                ..VoConfig::default()
            },
            VoConfig {
                min_interest: -5.0,
                min_roundness: 1.0,
                ..VoConfig::default()
            },
        ];
        let no_mask = |_: usize| 0u64;
        let some_mask = |row: usize| 0x5555_0f0f_00ff_1234u64.rotate_left(row as u32);
        let mut images = vec![
            noise_image(0x1234_5678_9abc_def0, 1),
            noise_image(0x0bad_cafe_dead_beef, 3),
            noise_image(42, 9),
        ];
        let cal = hazcam();
        for (yaw, x) in [(0.0, 0.0), (0.3, 0.5), (-0.2, 1.5)] {
            images
                .push(render_pair(&cal, &RoverPose::new(yaw, 0.0, 0.0, Vec3::new(x, 0.2, 0.0))).0);
        }
        let mut flight_cells = 0;
        for (i, img) in images.iter().enumerate() {
            for (k, config) in configs.iter().enumerate() {
                let n = compare_with_reference(img, config, no_mask);
                if k == 0 {
                    flight_cells += n;
                }
            }
            compare_with_reference(img, &VoConfig::default(), some_mask);
            assert!(i < images.len());
        }
        // The comparison is not vacuous: the flight thresholds find many cells.
        assert!(flight_cells > 6 * 1000, "{flight_cells} cells");
    }

    #[test]
    fn vo_1_planar_pretest_keeps_every_exact_pass() {
        // The f32 pre-test of the host's pass never rejects a centre the exact tests accept:
        // random window sums up to the largest possible (25 * 255^2 * 2), interests at and one
        // f32 step around the centre's own (the boundary), thresholds from the flight's to
        // extreme ones.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let max_sum = 25 * 255 * 255 * 2;
        let (mut exact_passes, mut checked) = (0, 0);
        for i in 0..400_000 {
            let scale = [max_sum, 1 << 16, 1 << 8][i % 3];
            let a = (next() % scale) as i32;
            let b = (next() % scale) as i32;
            let bound = ((f64::from(a) * f64::from(b)).sqrt() as i64).max(1);
            let x = (next() % (2 * bound as u64 + 1)) as i64 - bound;
            let x = x as i32;
            let (det, trace) = det_trace(a, b, x);
            if trace <= 0.0 {
                continue;
            }
            let w = (det / trace) as f32;
            let nudge = [w, f32::from_bits(w.to_bits().wrapping_sub(1)), w * 0.5, 0.0];
            let best = nudge[i % 4].max(0.0);
            let (min_interest, min_roundness) = [
                (50.0f32, 0.3f32),
                (2000.0, 0.0),
                (0.0, 1.0),
                (w, 0.5),
                (f32::NAN, f32::NAN),
            ][i % 5];
            let exact = det > f64::from(best) * trace
                && !(det < f64::from(min_interest) * trace)
                && !(4.0 * det < f64::from(min_roundness) * trace * trace);
            let floor = best.max(min_interest);
            checked += 1;
            if exact {
                exact_passes += 1;
                assert!(
                    pretest((a, b, x), floor, min_roundness),
                    "({a}, {b}, {x}) best {best} min {min_interest} {min_roundness}"
                );
            }
        }
        assert!(exact_passes > checked / 10, "{exact_passes} of {checked}");
    }

    #[test]
    fn vo_1_best_first_heap_pops_in_sorted_order() {
        // Cells with many equal interests (ties broken by row, then column), as the detector
        // leaves them: popping the best-first heap gives the full sort's order.
        let mut det = ForstnerDetector::EMPTY;
        for (k, cell) in det.cells.iter_mut().enumerate().step_by(3) {
            let k = k as u32;
            *cell = Candidate {
                interest: ((k * 7919) % 97) as f32 + 1.0,
                x: ((k * 13) % 640) as u16,
                y: ((k * 7) % 480) as u16,
            };
        }
        let mut sorted = det.clone();
        let n = sorted.sort_candidates();
        let expect = sorted.candidates().to_vec();
        assert_eq!(det.compact_candidates(), n);
        assert!(n > 900);
        for start in (0..n / 2).rev() {
            det.best_heapify_step(start);
        }
        let mut popped = Vec::new();
        let mut left = n;
        while let Some(c) = det.pop_best(left) {
            popped.push(c);
            left -= 1;
        }
        assert_eq!(popped, expect);
        assert_eq!(det.pop_best(0), None);
        assert_eq!(det.pop_best(n + 1), None);
    }

    #[test]
    fn vo_1_heap_sort_orders_and_min_distance_holds() {
        let mut list: Vec<Candidate> = (0..500u16)
            .map(|k| Candidate {
                interest: ((k as u32 * 7919) % 1000) as f32 + 1.0,
                x: (k * 13) % 640,
                y: (k * 7) % 480,
            })
            .collect();
        heap_sort_descending(&mut list);
        assert!(list.windows(2).all(|w| !ranks_before(&w[1], &w[0])));
        let mut out = [(0u16, 0u16); 100];
        let k = select_with_min_distance(&list, 30.0, &mut out);
        for i in 0..k {
            for j in 0..i {
                let dx = out[i].0 as f32 - out[j].0 as f32;
                let dy = out[i].1 as f32 - out[j].1 as f32;
                assert!(dx * dx + dy * dy >= 900.0);
            }
        }
    }
}
