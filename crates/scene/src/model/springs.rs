//! Listed springs (structure of arrays) and each particle's springs in compressed sparse rows.

/// Springs as a structure of arrays; spring s joins `a[s]` and `b[s]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Springs {
    /// First particle.
    pub a: Vec<u32>,
    /// Second particle.
    pub b: Vec<u32>,
    /// Rest length r, metres.
    pub rest: Vec<f64>,
    /// Stiffness k_s, N/m.
    pub stiffness: Vec<f64>,
    /// Damping k_d, N·s/m.
    pub damping: Vec<f64>,
}

impl Springs {
    /// Number of springs.
    pub fn len(&self) -> usize {
        self.a.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }
    /// The end points [a, b] of every spring, in order.
    pub fn pairs(&self) -> Vec<[u32; 2]> {
        self.a.iter().zip(&self.b).map(|(&a, &b)| [a, b]).collect()
    }
    pub(super) fn with_capacity(n: usize) -> Springs {
        Springs {
            a: Vec::with_capacity(n),
            b: Vec::with_capacity(n),
            rest: Vec::with_capacity(n),
            stiffness: Vec::with_capacity(n),
            damping: Vec::with_capacity(n),
        }
    }
    pub(super) fn push(&mut self, a: u32, b: u32, rest: f64, stiffness: f64, damping: f64) {
        self.a.push(a);
        self.b.push(b);
        self.rest.push(rest);
        self.stiffness.push(stiffness);
        self.damping.push(damping);
    }
}

/// Each particle's springs in compressed sparse rows: particle i's entries are
/// `entries[offsets[i]..offsets[i + 1]]`, each `2·s + side` with side 0 when i is `a[s]` (the
/// spring force acts with a + sign) and 1 when i is `b[s]` (− sign), in ascending spring order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Adjacency {
    /// n + 1 offsets into `entries`.
    pub offsets: Vec<u32>,
    /// 2·springs entries.
    pub entries: Vec<u32>,
}

impl Adjacency {
    /// Builds the adjacency of `n` particles by a counting sort over the springs.
    pub fn build(n: usize, springs: &Springs) -> Adjacency {
        let mut adjacency = Adjacency::default();
        adjacency.rebuild(n, springs.a.iter().copied().zip(springs.b.iter().copied()));
        adjacency
    }

    /// Rebuilds in place (reusing the buffers) the adjacency of `n` particles joined by `ends`,
    /// the (a, b) of each link in link order, by a counting sort.
    pub fn rebuild(&mut self, n: usize, ends: impl Iterator<Item = (u32, u32)> + Clone) {
        let (offsets, entries) = (&mut self.offsets, &mut self.entries);
        offsets.clear();
        offsets.resize(n + 1, 0);
        let mut links = 0;
        for (a, b) in ends.clone() {
            offsets[a as usize + 1] += 1;
            offsets[b as usize + 1] += 1;
            links += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        entries.clear();
        entries.resize(2 * links, 0);
        // offsets[p] walks to p's end (the start of p + 1's run), then is shifted back below.
        for (s, (a, b)) in ends.enumerate() {
            for (p, side) in [(a, 0), (b, 1)] {
                let next = &mut offsets[p as usize];
                entries[*next as usize] = 2 * s as u32 + side;
                *next += 1;
            }
        }
        offsets.copy_within(0..n, 1);
        offsets[0] = 0;
    }

    /// The entries of particle i.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.entries[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjacency_lists_every_spring_twice_in_order() {
        let mut s = Springs::default();
        for (a, b) in [(0, 1), (1, 2), (0, 2), (2, 3)] {
            s.push(a, b, 1.0, 1.0, 0.0);
        }
        let adj = Adjacency::build(4, &s);
        assert_eq!(adj.offsets, vec![0, 2, 4, 7, 8]);
        assert_eq!(adj.of(0), &[0, 4]); // spring 0 side a, spring 2 side a
        assert_eq!(adj.of(1), &[1, 2]); // spring 0 side b, spring 1 side a
        assert_eq!(adj.of(2), &[3, 5, 6]);
        assert_eq!(adj.of(3), &[7]);
    }
}
