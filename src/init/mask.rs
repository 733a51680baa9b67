//! Object masks from colour: an HSV band that picks out an object in an image, and the overlap
//! (intersection over union) of two masks. Used to align objects at the start and to measure
//! tracking quality on real data without ground truth.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Pixels whose hue lies in `[hue_min, hue_max]` degrees (wrapping through 0 when
/// `hue_min > hue_max`) with saturation and value (HSV, in [0, 1]) at least the minimums.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourMask {
    pub hue_min: f32,
    pub hue_max: f32,
    pub saturation_min: f32,
    pub value_min: f32,
}

/// Hue (degrees in [0, 360)), saturation and value of an RGB colour in [0, 1].
pub fn hsv(c: Vec3) -> (f32, f32, f32) {
    let (max, min) = (c.max_element(), c.min_element());
    let chroma = max - min;
    let hue = if chroma <= 0.0 {
        0.0
    } else if max == c.x {
        60.0 * ((c.y - c.z) / chroma).rem_euclid(6.0)
    } else if max == c.y {
        60.0 * ((c.z - c.x) / chroma + 2.0)
    } else {
        60.0 * ((c.x - c.y) / chroma + 4.0)
    };
    (hue, if max > 0.0 { chroma / max } else { 0.0 }, max)
}

impl ColourMask {
    pub fn contains(&self, c: Vec3) -> bool {
        let (h, s, v) = hsv(c);
        let in_band = if self.hue_min <= self.hue_max {
            (self.hue_min..=self.hue_max).contains(&h)
        } else {
            h >= self.hue_min || h <= self.hue_max
        };
        in_band && s >= self.saturation_min && v >= self.value_min
    }

    pub fn apply(&self, image: &[Vec3]) -> Vec<bool> {
        image.iter().map(|&c| self.contains(c)).collect()
    }
}

impl ColourMask {
    /// The object's pixels: the colour band, keeping only connected regions (8-neighbourhood) of
    /// at least a tenth of the largest one and 20 pixels, so stray pixels of similar colour
    /// elsewhere (reflections, lamps) do not count while an object cut in two by an occluder does.
    pub fn segment(&self, image: &[Vec3], width: u32, height: u32) -> Vec<bool> {
        let raw = self.apply(image);
        let (w, h) = (width as i64, height as i64);
        let mut label = vec![0u32; raw.len()];
        let mut sizes = vec![0usize];
        for start in 0..raw.len() {
            if !raw[start] || label[start] != 0 {
                continue;
            }
            let id = sizes.len() as u32;
            let mut stack = vec![start];
            label[start] = id;
            let mut size = 0;
            while let Some(k) = stack.pop() {
                size += 1;
                let (x, y) = (k as i64 % w, k as i64 / w);
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx >= 0 && ny >= 0 && nx < w && ny < h {
                            let n = (ny * w + nx) as usize;
                            if raw[n] && label[n] == 0 {
                                label[n] = id;
                                stack.push(n);
                            }
                        }
                    }
                }
            }
            sizes.push(size);
        }
        let largest = sizes.iter().copied().max().unwrap_or(0);
        let keep: Vec<bool> = sizes
            .iter()
            .map(|&s| s >= 20 && s * 10 >= largest)
            .collect();
        label.iter().map(|&l| l != 0 && keep[l as usize]).collect()
    }
}

/// Intersection over union of two masks of the same size (1 when both are empty).
pub fn iou(a: &[bool], b: &[bool]) -> f32 {
    let (mut inter, mut union) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        inter += (x && y) as usize;
        union += (x || y) as usize;
    }
    if union == 0 {
        1.0
    } else {
        inter as f32 / union as f32
    }
}

/// Halve a mask's resolution: a pixel is set when any of its 2 x 2 source pixels is.
pub fn downsample(mask: &[bool], width: u32, height: u32) -> (Vec<bool>, u32, u32) {
    let (w2, h2) = (width / 2, height / 2);
    let mut out = vec![false; (w2 * h2) as usize];
    for y in 0..h2 {
        for x in 0..w2 {
            let at = |dx: u32, dy: u32| mask[((2 * y + dy) * width + 2 * x + dx) as usize];
            out[(y * w2 + x) as usize] = at(0, 0) || at(1, 0) || at(0, 1) || at(1, 1);
        }
    }
    (out, w2, h2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hsv_of_primary_colours_and_a_wrapping_band() {
        assert_eq!(hsv(Vec3::new(1.0, 0.0, 0.0)), (0.0, 1.0, 1.0));
        assert_eq!(hsv(Vec3::new(0.0, 0.5, 0.0)), (120.0, 1.0, 0.5));
        assert_eq!(hsv(Vec3::new(0.0, 0.0, 1.0)).0, 240.0);
        let (h, s, v) = hsv(Vec3::new(1.0, 0.5, 0.0));
        assert!((h - 30.0).abs() < 1e-4 && s == 1.0 && v == 1.0);
        let reds = ColourMask {
            hue_min: 340.0,
            hue_max: 20.0,
            saturation_min: 0.5,
            value_min: 0.3,
        };
        assert!(
            reds.contains(Vec3::new(0.9, 0.1, 0.2)),
            "hue 353 is inside the wrapping band"
        );
        assert!(reds.contains(Vec3::new(0.9, 0.2, 0.1)));
        assert!(
            !reds.contains(Vec3::new(0.9, 0.8, 0.8)),
            "pale: not saturated"
        );
        assert!(!reds.contains(Vec3::new(0.2, 0.02, 0.02)), "too dark");
        assert!(!reds.contains(Vec3::new(0.1, 0.9, 0.1)));
    }

    #[test]
    fn segmenting_drops_small_stray_regions_and_keeps_a_split_object() {
        let red = Vec3::new(0.9, 0.1, 0.1);
        let mask = ColourMask {
            hue_min: 340.0,
            hue_max: 20.0,
            saturation_min: 0.5,
            value_min: 0.3,
        };
        let (w, h) = (40u32, 20u32);
        let mut image = vec![Vec3::splat(0.1); (w * h) as usize];
        let mut paint = |x0: u32, x1: u32, y0: u32, y1: u32| {
            for y in y0..y1 {
                for x in x0..x1 {
                    image[(y * w + x) as usize] = red;
                }
            }
        };
        paint(2, 12, 2, 12); // 100 px, one half of an object
        paint(14, 22, 2, 12); // 80 px, its other half beyond an occluder
        paint(30, 33, 15, 18); // 9 px stray reflection
        let seg = mask.segment(&image, w, h);
        assert_eq!(seg.iter().filter(|x| **x).count(), 180);
        assert!(!seg[(16 * w + 31) as usize]);
    }

    #[test]
    fn iou_and_downsampling() {
        let a = [true, true, false, false];
        let b = [false, true, true, false];
        assert!((iou(&a, &b) - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(iou(&[false; 4], &[false; 4]), 1.0);
        let (d, w, h) = downsample(
            &[false, false, true, false, false, false, false, false],
            4,
            2,
        );
        assert_eq!((d, w, h), (vec![false, true], 2, 1));
    }
}
