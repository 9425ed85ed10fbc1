//! Pixel masks on equirectangular panoramas: neighbours, growth and connected
//! regions, all wrapping across the `u = 0/1` seam (the poles are not joined: a
//! mask touching the top row does not continue on the opposite longitude).

/// The 4-neighbours of pixel `p` of a `w x h` panorama, wrapping across the seam;
/// `usize::MAX` for those beyond the top or bottom row.
pub fn neighbours4(p: usize, w: usize, h: usize) -> [usize; 4] {
    let (x, y) = (p % w, p / w);
    let mut nb = [usize::MAX; 4];
    nb[0] = y * w + (x + w - 1) % w;
    nb[1] = y * w + (x + 1) % w;
    if y > 0 {
        nb[2] = p - w;
    }
    if y + 1 < h {
        nb[3] = p + w;
    }
    nb
}

/// A mask grown by `steps` pixels (4-neighbours, wrapping across the seam). Work
/// grows with the mask's rim and what is added, not with the image.
pub fn dilate(mask: &[bool], w: usize, h: usize, steps: usize) -> Vec<bool> {
    let mut m = mask.to_vec();
    let neighbours = |p: usize| neighbours4(p, w, h);
    if steps == 0 {
        return m;
    }
    // The rim: mask pixels with a neighbour outside the mask.
    let mut frontier: Vec<u32> = (0..w * h)
        .filter(|&p| m[p] && neighbours(p).iter().any(|&q| q != usize::MAX && !m[q]))
        .map(|p| p as u32)
        .collect();
    for _ in 0..steps {
        let mut next = Vec::new();
        for &p in &frontier {
            for q in neighbours(p as usize) {
                if q != usize::MAX && !m[q] {
                    m[q] = true;
                    next.push(q as u32);
                }
            }
        }
        if next.is_empty() {
            break;
        }
        frontier = next;
    }
    m
}

/// Connected components (4-neighbours, wrapping across the seam) of a mask; returns
/// a label per pixel (`u32::MAX` outside) and the number of components.
pub fn components(mask: &[bool], w: usize, h: usize) -> (Vec<u32>, usize) {
    let mut lab = vec![u32::MAX; w * h];
    let mut n = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !mask[start] || lab[start] != u32::MAX {
            continue;
        }
        lab[start] = n;
        stack.push(start);
        while let Some(p) = stack.pop() {
            for q in neighbours4(p, w, h) {
                if q != usize::MAX && mask[q] && lab[q] == u32::MAX {
                    lab[q] = n;
                    stack.push(q);
                }
            }
        }
        n += 1;
    }
    (lab, n as usize)
}

/// The pixels within `steps` 4-neighbour steps of `seeds` (seeds included, each
/// once), wrapping across the seam. For growing a few small regions of a large
/// panorama: work is proportional to what is reached. `scratch` (`w * h` flags)
/// must be all false and is left all false.
pub fn grow_from(
    seeds: &[usize],
    w: usize,
    h: usize,
    steps: usize,
    scratch: &mut [bool],
) -> Vec<usize> {
    let mut out = Vec::with_capacity(seeds.len());
    for &s in seeds {
        if s < w * h && !scratch[s] {
            scratch[s] = true;
            out.push(s);
        }
    }
    let mut start = 0;
    for _ in 0..steps {
        let end = out.len();
        if start == end {
            break;
        }
        for k in start..end {
            for q in neighbours4(out[k], w, h) {
                if q != usize::MAX && !scratch[q] {
                    scratch[q] = true;
                    out.push(q);
                }
            }
        }
        start = end;
    }
    for &p in &out {
        scratch[p] = false;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_grows_by_four_neighbour_steps_across_the_seam() {
        // Against the plain definition: a pixel joins at step k when one of its
        // four neighbours (wrapping in x) was in the mask after step k - 1.
        let (w, h) = (23, 11);
        let mut seed = 7u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) % 29 == 0
        };
        let mask: Vec<bool> = (0..w * h).map(|_| rnd()).collect();
        for steps in 0..5 {
            let mut want = mask.clone();
            for _ in 0..steps {
                let prev = want.clone();
                for p in 0..w * h {
                    let (x, y) = (p % w, p / w);
                    let nb = [
                        Some(y * w + (x + w - 1) % w),
                        Some(y * w + (x + 1) % w),
                        (y > 0).then(|| p - w),
                        (y + 1 < h).then(|| p + w),
                    ];
                    if nb.iter().flatten().any(|&q| prev[q]) {
                        want[p] = true;
                    }
                }
            }
            assert_eq!(dilate(&mask, w, h, steps), want, "steps {steps}");
        }
    }

    #[test]
    fn components_join_across_the_seam_but_not_diagonally() {
        let (w, h) = (8, 4);
        let mut mask = vec![false; w * h];
        // One region across the seam (row 1, columns 7 and 0), one touching it
        // only diagonally (row 2, column 1), one alone (row 3, column 4).
        for &(x, y) in &[(7, 1), (0, 1), (1, 2), (4, 3)] {
            mask[y * w + x] = true;
        }
        let (lab, n) = components(&mask, w, h);
        assert_eq!(n, 3);
        assert_eq!(lab[w + 7], lab[w]);
        assert_ne!(lab[2 * w + 1], lab[w]);
        assert_eq!(lab[0], u32::MAX);
    }

    #[test]
    fn growing_from_seeds_reaches_what_dilation_does() {
        let (w, h) = (17, 9);
        let seeds = [0usize, 3 * w + 16, 8 * w + 5, 3 * w + 16];
        let mut mask = vec![false; w * h];
        for &s in &seeds {
            mask[s] = true;
        }
        let mut scratch = vec![false; w * h];
        for steps in 0..6 {
            let mut got = vec![false; w * h];
            let list = grow_from(&seeds, w, h, steps, &mut scratch);
            for &p in &list {
                assert!(!got[p], "pixel {p} listed twice");
                got[p] = true;
            }
            assert_eq!(got, dilate(&mask, w, h, steps), "steps {steps}");
            assert!(scratch.iter().all(|&s| !s), "scratch left dirty");
        }
    }
}
