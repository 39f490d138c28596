//! How a pass divides its particles: the chunks run in parallel (a binary split of the
//! chunk range, so each task gets its own part of the outputs), the output arrays split along
//! them, and the tail-force buffer that phase A's tasks share.

use std::marker::PhantomData;
use std::ops::Range;

use glam::DVec3;

use crate::spring_forces::Sum;

/// A buffer that phase A's tasks write in disjoint ranges.
pub(super) struct Shared<'a> {
    ptr: *mut DVec3,
    len: usize,
    _buffer: PhantomData<&'a mut [DVec3]>,
}

// SAFETY: phase A hands each task a disjoint range to write and reads nothing.
unsafe impl Send for Shared<'_> {}
unsafe impl Sync for Shared<'_> {}

impl<'a> Shared<'a> {
    pub(super) fn new(buffer: &'a mut [DVec3]) -> Shared<'a> {
        Shared {
            ptr: buffer.as_mut_ptr(),
            len: buffer.len(),
            _buffer: PhantomData,
        }
    }

    /// # Safety
    /// No other reference to these elements exists while the slice lives.
    #[allow(clippy::mut_from_ref)]
    pub(super) unsafe fn range_mut(&self, r: Range<usize>) -> &mut [DVec3] {
        assert!(r.start <= r.end && r.end <= self.len);
        // SAFETY: in bounds; exclusivity is the caller's promise.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(r.start), r.end - r.start) }
    }
}

/// Per-particle output arrays that a pass writes: one `&mut [DVec3]`, or a tuple of two or four.
pub(crate) trait Outputs {
    /// The arrays, or a range of particles of them.
    type Chunk: Send;
    /// One element of each.
    type Item<'a>;
    /// All of them.
    fn whole(self) -> Self::Chunk;
    /// Particles in `c`.
    fn len(c: &Self::Chunk) -> usize;
    /// The first `mid` particles of `c` and the rest.
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk);
    /// Element k of each.
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_>;
}

impl<'o> Outputs for &'o mut [DVec3] {
    type Chunk = &'o mut [DVec3];
    type Item<'a> = &'a mut DVec3;
    fn whole(self) -> Self::Chunk {
        self
    }
    fn len(c: &Self::Chunk) -> usize {
        c.len()
    }
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk) {
        c.split_at_mut(mid)
    }
    #[inline(always)]
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        &mut c[k]
    }
}

impl<'o> Outputs for (&'o mut [DVec3], &'o mut [DVec3]) {
    type Chunk = (&'o mut [DVec3], &'o mut [DVec3]);
    type Item<'a> = (&'a mut DVec3, &'a mut DVec3);
    fn whole(self) -> Self::Chunk {
        assert_eq!(self.0.len(), self.1.len());
        self
    }
    fn len(c: &Self::Chunk) -> usize {
        c.0.len()
    }
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk) {
        let (a0, a1) = c.0.split_at_mut(mid);
        let (b0, b1) = c.1.split_at_mut(mid);
        ((a0, b0), (a1, b1))
    }
    #[inline(always)]
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        (&mut c.0[k], &mut c.1[k])
    }
}

impl<'o> Outputs
    for (
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
    )
{
    type Chunk = (
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
    );
    type Item<'a> = (&'a mut DVec3, &'a mut DVec3, &'a mut DVec3, &'a mut DVec3);
    fn whole(self) -> Self::Chunk {
        let n = self.0.len();
        assert!(self.1.len() == n && self.2.len() == n && self.3.len() == n);
        self
    }
    fn len(c: &Self::Chunk) -> usize {
        c.0.len()
    }
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk) {
        let (a0, a1) = c.0.split_at_mut(mid);
        let (b0, b1) = c.1.split_at_mut(mid);
        let (c0, c1) = c.2.split_at_mut(mid);
        let (d0, d1) = c.3.split_at_mut(mid);
        ((a0, b0, c0, d0), (a1, b1, c1, d1))
    }
    #[inline(always)]
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        (&mut c.0[k], &mut c.1[k], &mut c.2[k], &mut c.3[k])
    }
}

/// The chunks of a pass: chunk c is particles `bounds[c]..bounds[c + 1]`.
pub(super) struct Chunks<'a> {
    pub(super) bounds: &'a [usize],
}

impl Chunks<'_> {
    /// Runs `leaf(c, sums, outputs)` for chunks `c0..c1` in parallel, each with its particles'
    /// part of `sums` and `outputs`; returns the least of their results.
    pub(super) fn chunks<O: Outputs>(
        &self,
        c0: usize,
        c1: usize,
        sums: &mut [Sum],
        outputs: O::Chunk,
        leaf: &(impl Fn(usize, &mut [Sum], O::Chunk) -> Option<usize> + Sync),
    ) -> Option<usize> {
        if c1 - c0 == 1 {
            return leaf(c0, sums, outputs);
        }
        let mid = (c0 + c1) / 2;
        let at = self.bounds[mid] - self.bounds[c0];
        let (s0, s1) = sums.split_at_mut(at.min(sums.len()));
        let (o0, o1) = O::split_at(outputs, at);
        let (a, b) = rayon::join(
            || self.chunks::<O>(c0, mid, s0, o0, leaf),
            || self.chunks::<O>(mid, c1, s1, o1, leaf),
        );
        match (a, b) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}
