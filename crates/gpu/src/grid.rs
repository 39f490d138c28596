//! Dispatch grids: how many workgroups of [`WORKGROUP_SIZE`] threads a kernel runs, in one row
//! or, past the adapter's per-dimension limit (65,535 on most), in a 2-D grid. Kernels compute
//! their global thread index as `(workgroup.y · workgroups.x + workgroup.x) · 256 + local`
//! (`thread_of` in `shaders/shared/common.wgsl`) and return past the end of their range.

use crate::WORKGROUP_SIZE;

/// A dispatch grid: `x · y` workgroups of [`WORKGROUP_SIZE`] threads covering `threads` threads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    /// Workgroups along x (at most the per-dimension limit).
    pub x: u32,
    /// Rows of workgroups (1 unless more than the per-dimension limit are needed).
    pub y: u32,
}

impl Grid {
    /// The grid for `threads` threads, or `None` if it would need more than `max_dim` rows of
    /// `max_dim` workgroups.
    pub fn new(threads: u64, max_dim: u32) -> Option<Grid> {
        Grid::with_width(threads, max_dim, max_dim)
    }

    /// The grid for `threads` threads in rows of at most `width` workgroups, or `None` if it
    /// would need more than `max_rows` rows.
    pub fn with_width(threads: u64, width: u32, max_rows: u32) -> Option<Grid> {
        let groups = threads.div_ceil(WORKGROUP_SIZE);
        let width = u64::from(width.max(1));
        if groups <= width {
            return Some(Grid {
                x: groups as u32,
                y: if groups == 0 { 0 } else { 1 },
            });
        }
        let rows = groups.div_ceil(width);
        (rows <= u64::from(max_rows)).then_some(Grid {
            x: width as u32,
            y: rows as u32,
        })
    }

    /// Workgroups in all (a 2-D grid may have a few more than needed; they return at once).
    pub fn groups(self) -> u64 {
        u64::from(self.x) * u64::from(self.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grids_go_two_dimensional_past_the_per_dimension_limit() {
        let g = |threads| Grid::new(threads, 65_535);
        assert_eq!(g(0), Some(Grid { x: 0, y: 0 }));
        assert_eq!(g(1), Some(Grid { x: 1, y: 1 }));
        assert_eq!(g(256), Some(Grid { x: 1, y: 1 }));
        assert_eq!(g(257), Some(Grid { x: 2, y: 1 }));
        assert_eq!(g(65_535 * 256), Some(Grid { x: 65_535, y: 1 }));
        assert_eq!(g(65_535 * 256 + 1), Some(Grid { x: 65_535, y: 2 }));
        // u32::MAX particles: 16,777,216 workgroups in 257 rows.
        let most = g(u64::from(u32::MAX)).unwrap();
        assert_eq!((most.x, most.y), (65_535, 257));
        assert!(most.groups() * WORKGROUP_SIZE >= u64::from(u32::MAX));
        assert_eq!(Grid::new(65_535u64 * 65_535 * 256 + 1, 65_535), None);
    }
}
