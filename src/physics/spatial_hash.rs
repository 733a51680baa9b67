//! Uniform-grid spatial hash and per-particle contact candidate lists (CSR), rebuilt once per
//! substep from the predicted positions and reused by every Jacobi iteration of that substep.

use glam::{IVec3, Vec3};
use rayon::prelude::*;

/// Particles sorted by hashed grid cell (counting sort).
#[derive(Default)]
pub struct SpatialHash {
    inv_cell: f32,
    mask: u32,
    cell_start: Vec<u32>,
    sorted: Vec<u32>,
    keys: Vec<u32>,
    /// Grid cell of each particle (by particle index).
    cells: Vec<IVec3>,
}

/// Candidate contact partners of each particle: `neighbours[offsets[i]..offsets[i + 1]]`.
#[derive(Default, Clone)]
pub struct NeighbourLists {
    pub offsets: Vec<u32>,
    pub neighbours: Vec<u32>,
}

impl NeighbourLists {
    pub fn of(&self, i: usize) -> &[u32] {
        &self.neighbours[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Number of ordered candidate pairs.
    pub fn pair_count(&self) -> usize {
        self.neighbours.len()
    }
}

fn cell_of(p: Vec3, inv_cell: f32) -> IVec3 {
    // `as` saturates and maps NaN to 0: a corrupt position lands in some cell instead of panicking.
    (p * inv_cell).floor().as_ivec3()
}

fn hash_cell(c: IVec3, mask: u32) -> u32 {
    let h = (c.x as u32).wrapping_mul(73_856_093)
        ^ (c.y as u32).wrapping_mul(19_349_663)
        ^ (c.z as u32).wrapping_mul(83_492_791);
    h & mask
}

impl SpatialHash {
    /// Sort `positions` into cells of edge `cell` (at least the largest interaction distance).
    #[cfg(test)]
    pub fn build(&mut self, positions: &[Vec3], cell: f32) {
        let everywhere = (Vec3::splat(f32::NEG_INFINITY), Vec3::splat(f32::INFINITY));
        self.build_within(positions, cell, everywhere);
    }

    /// Sort the particles inside the box `(lo, hi)` into cells of edge `cell`; the others are
    /// left out (never reported by `for_each_near`).
    pub fn build_within(&mut self, positions: &[Vec3], cell: f32, (lo, hi): (Vec3, Vec3)) {
        let inside: Vec<u32> = (0..positions.len() as u32)
            .filter(|&i| {
                let p = positions[i as usize];
                p.cmpge(lo).all() && p.cmple(hi).all()
            })
            .collect();
        let size = (2 * inside.len()).next_power_of_two().max(64);
        self.inv_cell = 1.0 / cell;
        self.mask = (size - 1) as u32;
        // Left-out particles keep a cell no query reaches; they are in no bucket anyway.
        self.cells.clear();
        self.cells.resize(positions.len(), IVec3::MIN);
        self.keys.clear();
        for &i in &inside {
            let c = cell_of(positions[i as usize], self.inv_cell);
            self.cells[i as usize] = c;
            self.keys.push(hash_cell(c, self.mask));
        }
        self.cell_start.clear();
        self.cell_start.resize(size + 1, 0);
        for &k in &self.keys {
            self.cell_start[k as usize + 1] += 1;
        }
        for b in 0..size {
            self.cell_start[b + 1] += self.cell_start[b];
        }
        let mut fill = self.cell_start.clone();
        self.sorted.clear();
        self.sorted.resize(inside.len(), 0);
        for (&i, &k) in inside.iter().zip(&self.keys) {
            self.sorted[fill[k as usize] as usize] = i;
            fill[k as usize] += 1;
        }
    }

    /// Call `f` with every particle in the 27 cells around `p`. Buckets are shared by cells whose
    /// hashes collide, so candidates are filtered by their own cell: each particle is reported once.
    pub fn for_each_near(&self, p: Vec3, mut f: impl FnMut(u32)) {
        let c = cell_of(p, self.inv_cell);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let cell = c + IVec3::new(dx, dy, dz);
                    let b = hash_cell(cell, self.mask) as usize;
                    let (s, e) = (self.cell_start[b] as usize, self.cell_start[b + 1] as usize);
                    for &j in &self.sorted[s..e] {
                        if self.cells[j as usize] == cell {
                            f(j);
                        }
                    }
                }
            }
        }
    }
}

const CHUNK: usize = 512;

/// For each particle that can be pushed (`inv_mass > 0`), list the particles of *other* shapes
/// within `r_i + r_j + margin + further_j` (`further` empty: none further). Deterministic: lists
/// are in particle-index order within each bucket, and chunks are concatenated in order.
pub fn find_neighbours(
    hash: &SpatialHash,
    positions: &[Vec3],
    radius: &[f32],
    shape: &[u32],
    inv_mass: &[f32],
    (margin, further): (f32, &[f32]),
    out: &mut NeighbourLists,
) {
    let n = positions.len();
    let chunks: Vec<(Vec<u32>, Vec<u32>)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let range = c * CHUNK..((c + 1) * CHUNK).min(n);
            let mut counts = Vec::with_capacity(range.len());
            let mut list = Vec::new();
            for i in range {
                let before = list.len();
                if inv_mass[i] > 0.0 {
                    let (pi, ri, si) = (positions[i], radius[i], shape[i]);
                    hash.for_each_near(pi, |j| {
                        let j = j as usize;
                        if shape[j] != si {
                            let more = further.get(j).copied().unwrap_or(0.0);
                            let reach = ri + radius[j] + margin + more;
                            if pi.distance_squared(positions[j]) < reach * reach {
                                list.push(j as u32);
                            }
                        }
                    });
                    list[before..].sort_unstable();
                }
                counts.push((list.len() - before) as u32);
            }
            (counts, list)
        })
        .collect();
    out.offsets.clear();
    out.offsets.reserve(n + 1);
    out.offsets.push(0);
    out.neighbours.clear();
    let mut total = 0u32;
    for (counts, list) in chunks {
        for c in counts {
            total += c;
            out.offsets.push(total);
        }
        out.neighbours.extend_from_slice(&list);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_exactly_the_brute_force_pairs() {
        // A pseudo-random cloud of particles in 4 shapes; compare with the O(n^2) answer.
        let mut state = 12345u32;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state as f32 / u32::MAX as f32) * 0.3 - 0.15
        };
        let n = 1500;
        let pos: Vec<Vec3> = (0..n).map(|_| Vec3::new(rnd(), rnd(), rnd())).collect();
        let radius: Vec<f32> = (0..n).map(|i| 0.004 + 0.002 * (i % 3) as f32).collect();
        let shape: Vec<u32> = (0..n as u32).map(|i| i % 4).collect();
        let inv_mass: Vec<f32> = (0..n).map(|i| if i % 7 == 0 { 0.0 } else { 1.0 }).collect();
        let margin = 0.003;
        let mut hash = SpatialHash::default();
        hash.build(&pos, 2.0 * 0.008 + margin);
        let mut lists = NeighbourLists::default();
        find_neighbours(
            &hash,
            &pos,
            &radius,
            &shape,
            &inv_mass,
            (margin, &[]),
            &mut lists,
        );
        let mut total = 0;
        for i in 0..n {
            let mut want: Vec<u32> = Vec::new();
            if inv_mass[i] > 0.0 {
                for j in 0..n {
                    let reach = radius[i] + radius[j] + margin;
                    if j != i
                        && shape[j] != shape[i]
                        && pos[i].distance_squared(pos[j]) < reach * reach
                    {
                        want.push(j as u32);
                    }
                }
            }
            assert_eq!(lists.of(i), &want[..], "particle {i}");
            total += want.len();
        }
        assert!(
            total > 100,
            "the test cloud must actually contain contacts ({total})"
        );
        // Hashing only what lies within reach of the pushable particles finds the same lists.
        let reach = 2.0 * 0.008 + margin;
        let pushed = (0..n).filter(|&i| inv_mass[i] > 0.0 && pos[i].x < 0.0);
        let (lo, hi) = pushed.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), i| {
            (lo.min(pos[i]), hi.max(pos[i]))
        });
        let half: Vec<f32> = (0..n)
            .map(|i| if pos[i].x < 0.0 { inv_mass[i] } else { 0.0 })
            .collect();
        let mut all = NeighbourLists::default();
        find_neighbours(&hash, &pos, &radius, &shape, &half, (margin, &[]), &mut all);
        let mut near = SpatialHash::default();
        near.build_within(&pos, reach, (lo - reach, hi + reach));
        let mut within = NeighbourLists::default();
        find_neighbours(
            &near,
            &pos,
            &radius,
            &shape,
            &half,
            (margin, &[]),
            &mut within,
        );
        assert_eq!(within.offsets, all.offsets);
        assert_eq!(within.neighbours, all.neighbours);
        assert!(near.sorted.len() < n, "particles beyond reach are left out");
    }
}
