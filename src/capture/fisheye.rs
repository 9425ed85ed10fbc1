//! Dual-fisheye input: turning the side-by-side image that two-lens 360° cameras
//! (Samsung Gear 360 and the like) store into an equirectangular panorama.
//!
//! **Layout.** The input holds two lens images side by side and is about twice
//! as wide as high. The *left* half is the front lens, looking along `-z` (the
//! centre of the output panorama); the *right* half is the back lens, looking
//! along `+z`. In both halves image "up" is `+y`. The back lens is the front lens
//! rotated 180° about `y`, so its image is *not* mirrored: its right-hand side
//! sees world `-x`, as a camera turned round would.
//!
//! **Lens model.** Each lens is an equidistant fisheye, `r = f · α`, with `α` the
//! angle from the optical axis and `r` the distance from the centre of the image
//! circle in pixels. The image circle is centred in its half and its diameter is
//! the image height, unless [`DualFisheye`] overrides centres or radius; its rim
//! (`r = radius`) is at `α = fov / 2`, which fixes `f`.
//!
//! **Seam.** With a field of view of at least 180° every direction is seen by at
//! least one lens; directions whose angle from the front axis lies between
//! `180° − fov/2` and `fov/2` are seen by both. There the two samples are blended
//! linearly across a band of [`DualFisheye::blend_deg`] centred on 90° (clamped
//! to the overlap, `fov − 180°`), so exposure or vignetting differences between
//! the lenses fade instead of showing a step.
//!
//! **Sampling.** Bilinear, clamped to the lens's own half so a sample never reads
//! the other lens. HDR input stays float and unclamped; 8-bit input is
//! interpolated and blended in float on its code values and rounded once at the
//! end. The output panorama follows [`crate::sphere`]'s convention.

use crate::error::{Error, Result};
use crate::image::{HdrImage, SdrImage};
use crate::sphere::pixel_to_dir;
use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::FRAC_PI_2;

/// Default tolerance on the input's aspect: `width / (2 · height)` may differ
/// from 1 by this fraction (2 %), enough for an odd pixel column or a cropped row.
pub const DEFAULT_ASPECT_TOLERANCE: f32 = 0.02;

/// Default seam blend width in degrees.
pub const DEFAULT_BLEND_DEG: f32 = 10.0;

/// Geometry of a dual-fisheye image: what [`dual_fisheye_to_equirect`] needs to
/// know about the camera. Build it with [`DualFisheye::new`] and override fields
/// when a camera's image circles are not where the default layout puts them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DualFisheye {
    /// Field of view of each lens in degrees (the full cone, e.g. 195 for a Gear
    /// 360). Must be in `[180, 360]`: below 180 the lenses leave a gap.
    pub fov_deg: f32,
    /// Width in degrees of the band around 90° from the axes over which the two
    /// lenses are cross-faded. Clamped to the overlap `fov_deg − 180`; 0 gives a
    /// hard switch at 90°.
    pub blend_deg: f32,
    /// Centre of the front image circle in pixels of the whole input (`x` right,
    /// `y` down, pixel `(i, j)` spans `[i, i+1] x [j, j+1]`). `None`: the centre
    /// of the left half. Must lie inside the left half.
    pub front_centre: Option<[f32; 2]>,
    /// Centre of the back image circle, as [`front_centre`](Self::front_centre).
    /// `None`: the centre of the right half. Must lie inside the right half.
    pub back_centre: Option<[f32; 2]>,
    /// Radius of both image circles in pixels (the rim is at `fov_deg / 2`).
    /// `None`: half the image height.
    pub radius_px: Option<f32>,
    /// Allowed relative deviation of `width / (2 · height)` from 1.
    pub aspect_tolerance: f32,
}

impl DualFisheye {
    /// The default layout for lenses of `fov_deg` degrees: circles centred in
    /// their halves, diameter = image height, [`DEFAULT_BLEND_DEG`] seam blend,
    /// [`DEFAULT_ASPECT_TOLERANCE`].
    pub fn new(fov_deg: f32) -> Self {
        DualFisheye {
            fov_deg,
            blend_deg: DEFAULT_BLEND_DEG,
            front_centre: None,
            back_centre: None,
            radius_px: None,
            aspect_tolerance: DEFAULT_ASPECT_TOLERANCE,
        }
    }

    /// The blend width actually used, in degrees: `blend_deg` clamped to the
    /// overlap `fov_deg − 180` (both lenses must see the whole band).
    pub fn effective_blend_deg(&self) -> f32 {
        self.blend_deg.min(self.fov_deg - 180.0).max(0.0)
    }
}

impl Default for DualFisheye {
    /// 195° lenses, the Gear 360's nominal field of view.
    fn default() -> Self {
        DualFisheye::new(195.0)
    }
}

/// An RGB image the conversion can read and produce: implemented for
/// [`HdrImage`] (float, unclamped) and [`SdrImage`] (8-bit, rounded), so one
/// generic [`dual_fisheye_to_equirect`] serves both.
pub trait FisheyeImage: Sized + Sync {
    /// One channel value as stored.
    type Sample: Copy + Default + Send + Sync;
    /// `(width, height)` in pixels.
    fn dims(&self) -> (usize, usize);
    /// Interleaved RGB samples, rows top to bottom.
    fn samples(&self) -> &[Self::Sample];
    /// A stored sample as float (8-bit: the code value, 0..=255).
    fn to_f32(s: Self::Sample) -> f32;
    /// A float result as stored (8-bit: rounded and clamped to 0..=255).
    fn from_f32(v: f32) -> Self::Sample;
    /// Wraps interleaved RGB samples of a `width x height` image.
    fn from_samples(width: usize, height: usize, data: Vec<Self::Sample>) -> Result<Self>;
}

impl FisheyeImage for HdrImage {
    type Sample = f32;
    fn dims(&self) -> (usize, usize) {
        (self.width(), self.height())
    }
    fn samples(&self) -> &[f32] {
        self.data()
    }
    #[inline]
    fn to_f32(s: f32) -> f32 {
        s
    }
    #[inline]
    fn from_f32(v: f32) -> f32 {
        v
    }
    fn from_samples(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        HdrImage::from_vec(width, height, data)
    }
}

impl FisheyeImage for SdrImage {
    type Sample = u8;
    fn dims(&self) -> (usize, usize) {
        (self.width(), self.height())
    }
    fn samples(&self) -> &[u8] {
        self.data()
    }
    #[inline]
    fn to_f32(s: u8) -> f32 {
        s as f32
    }
    #[inline]
    fn from_f32(v: f32) -> u8 {
        // NaN maps to 0 (`as` saturates and sends NaN to 0).
        v.round().clamp(0.0, 255.0) as u8
    }
    fn from_samples(width: usize, height: usize, data: Vec<u8>) -> Result<Self> {
        SdrImage::from_vec(width, height, data)
    }
}

/// One lens after validation: where its circle is and which columns it owns.
#[derive(Clone, Copy, Debug)]
struct Lens {
    cx: f32,
    cy: f32,
    /// Pixels per radian of angle from the axis (`r = f · α`).
    f: f32,
    /// Columns `[col_lo, col_hi)` of the input this lens owns; samples clamp here.
    col_lo: usize,
    col_hi: usize,
    /// Back lens: local direction is the world direction rotated 180° about y.
    back: bool,
}

impl Lens {
    /// Continuous pixel position of world direction `d` (unit) in this lens.
    #[inline]
    fn project(&self, d: Vec3) -> (f32, f32) {
        let (lx, ly, lz) = if self.back {
            (-d.x, d.y, -d.z)
        } else {
            (d.x, d.y, d.z)
        };
        let s = (lx * lx + ly * ly).sqrt();
        if s <= 1e-12 {
            return (self.cx, self.cy);
        }
        let alpha = s.atan2(-lz);
        let r = self.f * alpha;
        (self.cx + r * lx / s, self.cy - r * ly / s)
    }

    /// Bilinear RGB sample at continuous pixel `(px, py)`, clamped to the lens's
    /// columns and the image rows.
    #[inline]
    fn sample<I: FisheyeImage>(
        &self,
        data: &[I::Sample],
        w: usize,
        h: usize,
        px: f32,
        py: f32,
    ) -> [f32; 3] {
        let xf = px - 0.5;
        let yf = py - 0.5;
        let x0 = xf.floor();
        let y0 = yf.floor();
        let fx = xf - x0;
        let fy = yf - y0;
        let clamp_x = |x: f32| (x.max(self.col_lo as f32) as usize).min(self.col_hi - 1);
        let clamp_y = |y: f32| (y.max(0.0) as usize).min(h - 1);
        let (xa, xb) = (clamp_x(x0), clamp_x(x0 + 1.0));
        let (ya, yb) = (clamp_y(y0), clamp_y(y0 + 1.0));
        let (ia, ib) = (3 * (ya * w + xa), 3 * (ya * w + xb));
        let (ic, id) = (3 * (yb * w + xa), 3 * (yb * w + xb));
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let a = I::to_f32(data[ia + k]);
            let b = I::to_f32(data[ib + k]);
            let c = I::to_f32(data[ic + k]);
            let d = I::to_f32(data[id + k]);
            let top = a + (b - a) * fx;
            let bot = c + (d - c) * fx;
            *o = top + (bot - top) * fy;
        }
        out
    }
}

/// Share of an 8-bit dual-fisheye image's pixels lying well outside both image
/// circles (beyond [`OUTSIDE_RADII`] radii from each lens's centre) that hold
/// image content (a channel above [`BLACK_CODE`]): a two-lens camera leaves
/// them black, while an equirect frame declared dual-fisheye fills them. `None`
/// when fewer than 1% of the pixels lie there (circles that fill their halves).
/// Fails as [`dual_fisheye_to_equirect`] does on a layout it cannot use.
pub fn content_outside_circles(img: &SdrImage, cfg: &DualFisheye) -> Result<Option<f64>> {
    let (w, h) = (img.width(), img.height());
    let (a, b) = lenses(cfg, w, h)?;
    let r = a.f * cfg.fov_deg.to_radians() / 2.0 * OUTSIDE_RADII;
    let data = img.data();
    let (mut n, mut lit) = (0usize, 0usize);
    for y in 0..h {
        let py = y as f32 + 0.5;
        for x in 0..w {
            let px = x as f32 + 0.5;
            let outside = |l: &Lens| (px - l.cx).hypot(py - l.cy) > r;
            if outside(&a) && outside(&b) {
                n += 1;
                let i = 3 * (y * w + x);
                if data[i..i + 3].iter().any(|&c| c > BLACK_CODE) {
                    lit += 1;
                }
            }
        }
    }
    Ok((n * 100 >= w * h).then(|| lit as f64 / n as f64))
}

/// How far outside an image circle (in its radii) a pixel must lie to count as
/// outside it: past the lens's rim fall-off and its JPEG ringing.
const OUTSIDE_RADII: f32 = 1.1;

/// The highest code a camera's black surround outside its image circles takes
/// (sensor black level and compression noise).
const BLACK_CODE: u8 = 48;

/// Checks the settings against an input of `w x h` and returns both lenses.
fn lenses(cfg: &DualFisheye, w: usize, h: usize) -> Result<(Lens, Lens)> {
    let bad = |m: String| Err(Error::Invalid(m));
    if !cfg.fov_deg.is_finite() || !(180.0..=360.0).contains(&cfg.fov_deg) {
        return bad(format!(
            "dual-fisheye lens field of view must be between 180 and 360 degrees \
             (below 180 the two lenses leave a blind band), got {}",
            cfg.fov_deg
        ));
    }
    if !cfg.blend_deg.is_finite() || cfg.blend_deg < 0.0 {
        return bad(format!(
            "dual-fisheye seam blend width must be a finite number of degrees >= 0, got {}",
            cfg.blend_deg
        ));
    }
    if !cfg.aspect_tolerance.is_finite() || cfg.aspect_tolerance < 0.0 {
        return bad(format!(
            "dual-fisheye aspect tolerance must be finite and >= 0, got {}",
            cfg.aspect_tolerance
        ));
    }
    if w == 0 || h == 0 {
        return bad(format!("dual-fisheye image is empty ({w}x{h} pixels)"));
    }
    if w < 2 {
        return bad(format!(
            "dual-fisheye image of {w}x{h} pixels is too narrow to hold two lenses"
        ));
    }
    let ratio = w as f64 / (2.0 * h as f64);
    if (ratio - 1.0).abs() > cfg.aspect_tolerance as f64 {
        return bad(format!(
            "dual-fisheye image is {w}x{h} pixels, width/height = {:.3}; two lenses side \
             by side should make it about twice as wide as high (2 ± {:.1}%)",
            w as f64 / h as f64,
            100.0 * cfg.aspect_tolerance
        ));
    }
    let radius = cfg.radius_px.unwrap_or(h as f32 / 2.0);
    if !radius.is_finite() || radius <= 0.0 {
        return bad(format!(
            "dual-fisheye image-circle radius must be a finite number of pixels > 0, got {radius}"
        ));
    }
    let half = w as f32 / 2.0;
    let split = w / 2;
    let centre = |c: Option<[f32; 2]>, default_x: f32, lo: f32, hi: f32, name: &str| {
        let [cx, cy] = c.unwrap_or([default_x, h as f32 / 2.0]);
        if !cx.is_finite() || !cy.is_finite() || cx < lo || cx > hi || cy < 0.0 || cy > h as f32 {
            return Err(Error::Invalid(format!(
                "dual-fisheye {name} image-circle centre ({cx}, {cy}) must lie inside the \
                 {name} lens's half of the {w}x{h} image (x in [{lo}, {hi}], y in [0, {h}])"
            )));
        }
        Ok((cx, cy))
    };
    let (fx, fy) = centre(cfg.front_centre, half / 2.0, 0.0, half, "front (left)")?;
    let (bx, by) = centre(cfg.back_centre, 1.5 * half, half, w as f32, "back (right)")?;
    let f = radius / (cfg.fov_deg.to_radians() / 2.0);
    let front = Lens {
        cx: fx,
        cy: fy,
        f,
        col_lo: 0,
        col_hi: split,
        back: false,
    };
    let back = Lens {
        cx: bx,
        cy: by,
        f,
        col_lo: split,
        col_hi: w,
        back: true,
    };
    Ok((front, back))
}

/// Converts a side-by-side dual-fisheye image (left half front lens, right half
/// back lens; see the [module docs](self) for the conventions) into an
/// `out_w x out_h` equirectangular panorama in [`crate::sphere`]'s convention.
///
/// Works on [`SdrImage`] (a camera JPEG; interpolation and seam blending are
/// done in float on the code values, rounded once) and on [`HdrImage`] (float,
/// never clamped). Fails with [`Error::Invalid`] for a field of view outside
/// `[180, 360]`, non-finite or negative settings, an empty image or output, an
/// input that is not about twice as wide as high, or circle centres outside
/// their halves. The message does not name the file; the caller should.
pub fn dual_fisheye_to_equirect<I: FisheyeImage>(
    img: &I,
    cfg: &DualFisheye,
    out_w: usize,
    out_h: usize,
) -> Result<I> {
    let (w, h) = img.dims();
    let (front, back) = lenses(cfg, w, h)?;
    if out_w == 0 || out_h == 0 {
        return Err(Error::Invalid(format!(
            "equirect output size must be non-zero, got {out_w}x{out_h}"
        )));
    }
    let row_len = out_w.checked_mul(3).ok_or_else(|| {
        Error::limit(
            None,
            format!("equirect output of {out_w}x{out_h} pixels"),
            "the address space",
        )
    })?;
    let len = row_len.checked_mul(out_h).ok_or_else(|| {
        Error::limit(
            None,
            format!("equirect output of {out_w}x{out_h} pixels"),
            "the address space",
        )
    })?;
    let data = img.samples();
    let blend = cfg.effective_blend_deg().to_radians();
    let mut out = vec![I::Sample::default(); len];
    out.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(row, line)| {
            for col in 0..out_w {
                let d = pixel_to_dir(col, row, out_w, out_h);
                // Angle from the front axis (-z); the back axis is at pi minus it.
                let alpha = (d.x * d.x + d.y * d.y).sqrt().atan2(-d.z);
                let wf = front_weight(alpha, blend);
                let c = if wf >= 1.0 {
                    let (px, py) = front.project(d);
                    front.sample::<I>(data, w, h, px, py)
                } else if wf <= 0.0 {
                    let (px, py) = back.project(d);
                    back.sample::<I>(data, w, h, px, py)
                } else {
                    let (px, py) = front.project(d);
                    let a = front.sample::<I>(data, w, h, px, py);
                    let (px, py) = back.project(d);
                    let b = back.sample::<I>(data, w, h, px, py);
                    [
                        b[0] + (a[0] - b[0]) * wf,
                        b[1] + (a[1] - b[1]) * wf,
                        b[2] + (a[2] - b[2]) * wf,
                    ]
                };
                for k in 0..3 {
                    line[3 * col + k] = I::from_f32(c[k]);
                }
            }
        });
    I::from_samples(out_w, out_h, out)
}

/// Weight of the front lens at angle `alpha` (radians) from the front axis: 1
/// before the blend band, 0 after it, linear across the band of width `blend`
/// centred on 90°. A zero-width band switches at 90° (front wins the tie).
#[inline]
fn front_weight(alpha: f32, blend: f32) -> f32 {
    if blend > 0.0 {
        ((FRAC_PI_2 + 0.5 * blend - alpha) / blend).clamp(0.0, 1.0)
    } else if alpha <= FRAC_PI_2 {
        1.0
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::{dir_to_uv, sample_dir};
    use std::f32::consts::PI;

    /// Test-only forward model: renders a dual-fisheye image of `w x h` from an
    /// equirect panorama, written independently of the module's inverse mapping.
    /// Pixels outside the image circles are black.
    fn render_dual_fisheye(pano: &HdrImage, fov_deg: f32, w: usize, h: usize) -> HdrImage {
        let radius = h as f32 / 2.0;
        let half_fov = fov_deg.to_radians() / 2.0;
        HdrImage::from_fn(w, h, |x, y| {
            let is_back = x >= w / 2;
            let cx = if is_back { 0.75 } else { 0.25 } * w as f32;
            let cy = h as f32 / 2.0;
            let dx = x as f32 + 0.5 - cx;
            let dy = y as f32 + 0.5 - cy;
            let r = (dx * dx + dy * dy).sqrt();
            let alpha = r / radius * half_fov;
            if alpha > half_fov {
                return [0.0; 3];
            }
            let (sa, ca) = alpha.sin_cos();
            let (ux, uy) = if r > 0.0 {
                (dx / r, dy / r)
            } else {
                (0.0, 0.0)
            };
            // Lens frame: x right, y up (image y runs down), looking along -z.
            let local = Vec3::new(sa * ux, -sa * uy, -ca);
            let world = if is_back {
                Vec3::new(-local.x, local.y, -local.z)
            } else {
                local
            };
            sample_dir(pano, world)
        })
    }

    fn angle(a: Vec3, b: Vec3) -> f32 {
        a.normalize().dot(b.normalize()).clamp(-1.0, 1.0).acos()
    }

    /// Markers of the synthetic panorama: direction and the channel it lights.
    fn markers(w: usize, h: usize) -> [(Vec3, usize, (usize, usize)); 3] {
        let front = (w / 2, h / 2 - 10);
        let behind = (0, h / 2 + 8);
        let right = (3 * w / 4, h / 2);
        [
            (pixel_to_dir(front.0, front.1, w, h), 0, front),
            (pixel_to_dir(behind.0, behind.1, w, h), 1, behind),
            (pixel_to_dir(right.0, right.1, w, h), 2, right),
        ]
    }

    const MARKER_SIGMA: f32 = 3.0 * PI / 180.0;
    const MARKER_PEAK: f32 = 20.0;

    /// Smooth, seam-free pattern plus three bright Gaussian spots (red in front,
    /// green behind, blue at +x).
    fn synthetic_pano(w: usize, h: usize) -> HdrImage {
        let ms = markers(w, h);
        HdrImage::from_fn(w, h, |c, r| {
            let d = pixel_to_dir(c, r, w, h);
            let wave = 0.1 * (3.0 * d.x + 2.0 * d.y - d.z).sin();
            let mut v = [
                0.5 + 0.3 * d.x + wave,
                0.5 + 0.3 * d.y - wave,
                0.5 + 0.3 * d.z + 0.5 * wave,
            ];
            for &(m, ch, _) in &ms {
                let a = angle(d, m);
                v[ch] += MARKER_PEAK * (-a * a / (2.0 * MARKER_SIGMA * MARKER_SIGMA)).exp();
            }
            v
        })
    }

    #[test]
    fn round_trip_matches_source_and_markers_land() {
        let (pw, ph) = (360, 180);
        let pano = synthetic_pano(pw, ph);
        let fov = 195.0;
        let fish = render_dual_fisheye(&pano, fov, 1024, 512);
        let cfg = DualFisheye::new(fov);
        let back = dual_fisheye_to_equirect(&fish, &cfg, pw, ph).unwrap();
        assert_eq!((back.width(), back.height()), (pw, ph));
        assert_eq!(back.count_invalid(), 0);

        let ms = markers(pw, ph);
        let mut max_err = 0.0f32;
        let mut sum_err = 0.0f64;
        let mut n = 0usize;
        for r in 0..ph {
            for c in 0..pw {
                let d = pixel_to_dir(c, r, pw, ph);
                if d.y.abs() > 60f32.to_radians().sin() {
                    continue;
                }
                let (a, b) = (pano.get(c, r), back.get(c, r));
                let near_marker = ms.iter().any(|&(m, _, _)| angle(d, m) < 4.0 * MARKER_SIGMA);
                for k in 0..3 {
                    let e = (a[k] - b[k]).abs();
                    sum_err += e as f64;
                    n += 1;
                    if !near_marker {
                        max_err = max_err.max(e);
                    }
                }
            }
        }
        let mean_err = sum_err / n as f64;
        assert!(max_err < 0.01, "max error away from markers {max_err}");
        assert!(mean_err < 0.01, "mean error {mean_err}");

        // Each marker's channel peaks at the pixel it was put at (the back one
        // sits on the u = 0/1 wrap, so compare columns cyclically).
        for &(_, ch, (mc, mr)) in &ms {
            let mut best = (0.0f32, 0usize, 0usize);
            for r in 0..ph {
                for c in 0..pw {
                    let v = back.get(c, r)[ch];
                    if v > best.0 {
                        best = (v, c, r);
                    }
                }
            }
            let dc = (best.1 as i64 - mc as i64).rem_euclid(pw as i64);
            let dc = dc.min(pw as i64 - dc);
            let dr = (best.2 as i64 - mr as i64).abs();
            assert!(
                dc <= 1 && dr <= 1,
                "marker in channel {ch} at ({mc}, {mr}) came back at ({}, {})",
                best.1,
                best.2
            );
            assert!(best.0 > 0.8 * MARKER_PEAK, "marker {ch} peak {}", best.0);
        }
    }

    #[test]
    fn round_trip_sdr() {
        let (pw, ph) = (360, 180);
        let pano = synthetic_pano(pw, ph);
        let fish = render_dual_fisheye(&pano, 200.0, 1024, 512);
        let codes: Vec<u8> = fish
            .data()
            .iter()
            .map(|v| (v * 200.0).round().clamp(0.0, 255.0) as u8)
            .collect();
        let sdr = SdrImage::from_vec(1024, 512, codes).unwrap();
        let back = dual_fisheye_to_equirect(&sdr, &DualFisheye::new(200.0), pw, ph).unwrap();
        let mut max_err = 0i32;
        for r in 0..ph {
            for c in 0..pw {
                let d = pixel_to_dir(c, r, pw, ph);
                if d.y.abs() > 60f32.to_radians().sin()
                    || markers(pw, ph)
                        .iter()
                        .any(|&(m, _, _)| angle(d, m) < 4.0 * MARKER_SIGMA)
                {
                    continue;
                }
                let a = pano.get(c, r);
                let b = back.get(c, r);
                for k in 0..3 {
                    let want = (a[k] * 200.0).round().clamp(0.0, 255.0) as i32;
                    max_err = max_err.max((want - b[k] as i32).abs());
                }
            }
        }
        assert!(max_err <= 2, "max 8-bit error {max_err}");
    }

    /// Left half `front`, right half `back`, everywhere (also outside the circles).
    fn two_tone(w: usize, h: usize, front: f32, back: f32) -> HdrImage {
        HdrImage::from_fn(w, h, |x, _| {
            let v = if x < w / 2 { front } else { back };
            [v, v, v]
        })
    }

    #[test]
    fn conventions_front_right_up_and_back_not_mirrored() {
        // Left half: red right of its centre, green above it. Right half: blue
        // right of its centre.
        let (w, h) = (400, 200);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let above = (y as f32 + 0.5) < h as f32 / 2.0;
            if x < w / 2 {
                let right = (x as f32 + 0.5) > w as f32 / 4.0;
                [right as u8 as f32, above as u8 as f32, 0.0]
            } else {
                let right = (x as f32 + 0.5) > 0.75 * w as f32;
                [0.0, 0.0, right as u8 as f32]
            }
        });
        let (ow, oh) = (360, 180);
        let out = dual_fisheye_to_equirect(&img, &DualFisheye::new(190.0), ow, oh).unwrap();
        let at = |phi_deg: f32, theta_deg: f32| {
            let c = ((phi_deg / 360.0 + 0.5) * ow as f32) as usize;
            let r = ((0.5 - theta_deg / 180.0) * oh as f32) as usize;
            out.get(c, r)
        };
        // In front, to the right (+x): red; to the left: not red.
        assert_eq!(at(30.0, -10.0)[0], 1.0);
        assert_eq!(at(-30.0, -10.0)[0], 0.0);
        // In front, above: green; below: not green.
        assert_eq!(at(5.0, 30.0)[1], 1.0);
        assert_eq!(at(5.0, -30.0)[1], 0.0);
        // Behind and towards world -x (phi = -150°) is the back lens's right: blue.
        assert_eq!(at(-150.0, 10.0), [0.0, 0.0, 1.0]);
        assert_eq!(at(150.0, 10.0), [0.0, 0.0, 0.0]);
        // The exact front and back directions come from the lens centres.
        let f = out.get(ow / 2, oh / 2);
        assert_eq!(f[2], 0.0);
        let b = out.get(0, oh / 2);
        assert_eq!((b[0], b[1]), (0.0, 0.0));
    }

    #[test]
    fn seam_blends_linearly_and_continuously() {
        let (w, h) = (800, 400);
        let img = two_tone(w, h, 1.0, 2.0);
        let cfg = DualFisheye {
            blend_deg: 10.0,
            ..DualFisheye::new(195.0)
        };
        let (ow, oh) = (1440, 720);
        let out = dual_fisheye_to_equirect(&img, &cfg, ow, oh).unwrap();
        // Value as a function of the angle from the front axis: 1 up to 85°,
        // 2 from 95°, linear between.
        let mut max_dev = 0.0f32;
        for r in (0..oh).step_by(7) {
            for c in 0..ow {
                let d = pixel_to_dir(c, r, ow, oh);
                let a = angle(d, Vec3::NEG_Z).to_degrees();
                let want = 1.0 + ((a - 85.0) / 10.0).clamp(0.0, 1.0);
                max_dev = max_dev.max((out.get(c, r)[0] - want).abs());
            }
        }
        assert!(max_dev < 1e-3, "deviation from linear blend {max_dev}");
        // Along the equator across +x (phi 60°..120°, 0.25°/px): no step larger
        // than the band's slope allows (1 unit over 10° = 0.025 per pixel).
        let r = oh / 2;
        let mut max_step = 0.0f32;
        for c in (ow * 2 / 3)..(ow * 5 / 6) {
            let step = (out.get(c + 1, r)[0] - out.get(c, r)[0]).abs();
            max_step = max_step.max(step);
        }
        assert!(max_step <= 0.026, "largest step across the seam {max_step}");

        // Control: a zero-width band does make a jump, so the check above bites.
        let hard = DualFisheye {
            blend_deg: 0.0,
            ..cfg
        };
        let out = dual_fisheye_to_equirect(&img, &hard, ow, oh).unwrap();
        let jump = ((ow * 2 / 3)..(ow * 5 / 6))
            .map(|c| (out.get(c + 1, r)[0] - out.get(c, r)[0]).abs())
            .fold(0.0f32, f32::max);
        assert!(jump > 0.9, "hard seam should jump, got {jump}");

        // 8-bit: blended in float and rounded, so steps stay within a code or two.
        let sdr = SdrImage::from_vec(
            w,
            h,
            (0..w * h)
                .flat_map(|i| {
                    let v = if i % w < w / 2 { 100 } else { 200 };
                    [v, v, v]
                })
                .collect(),
        )
        .unwrap();
        let out = dual_fisheye_to_equirect(&sdr, &cfg, ow, oh).unwrap();
        let mut prev = out.get(ow * 2 / 3, r)[0] as i32;
        assert_eq!(prev, 100);
        for c in (ow * 2 / 3 + 1)..(ow * 5 / 6) {
            let v = out.get(c, r)[0] as i32;
            assert!(v >= prev && v - prev <= 3, "8-bit step {prev} -> {v}");
            prev = v;
        }
        assert_eq!(prev, 200);
    }

    #[test]
    fn blend_band_is_clamped_to_the_overlap() {
        let cfg = DualFisheye {
            blend_deg: 40.0,
            ..DualFisheye::new(190.0)
        };
        assert_eq!(cfg.effective_blend_deg(), 10.0);
        // At 180° there is no overlap: a hard switch, and every pixel is one lens.
        let img = two_tone(200, 100, 1.0, 2.0);
        for fov in [180.0, 360.0] {
            let cfg = DualFisheye::new(fov);
            let out = dual_fisheye_to_equirect(&img, &cfg, 90, 45).unwrap();
            assert_eq!(out.count_invalid(), 0);
            if fov == 180.0 {
                assert!(out.pixels().all(|p| p[0] == 1.0 || p[0] == 2.0));
            }
        }
    }

    fn invalid_msg<T: std::fmt::Debug>(r: Result<T>) -> String {
        match r {
            Err(Error::Invalid(m)) => m,
            other => panic!("expected Error::Invalid, got {other:?}"),
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let img = SdrImage::new(200, 100);
        let ok = DualFisheye::new(195.0);
        assert!(dual_fisheye_to_equirect(&img, &ok, 64, 32).is_ok());

        let m = invalid_msg(dual_fisheye_to_equirect(
            &img,
            &DualFisheye::new(170.0),
            64,
            32,
        ));
        assert!(m.contains("field of view") && m.contains("170"), "{m}");
        let m = invalid_msg(dual_fisheye_to_equirect(
            &img,
            &DualFisheye::new(f32::NAN),
            64,
            32,
        ));
        assert!(m.contains("field of view") && m.contains("NaN"), "{m}");
        let m = invalid_msg(dual_fisheye_to_equirect(
            &img,
            &DualFisheye::new(400.0),
            64,
            32,
        ));
        assert!(m.contains("field of view"), "{m}");
        let m = invalid_msg(dual_fisheye_to_equirect(
            &img,
            &DualFisheye::new(f32::INFINITY),
            64,
            32,
        ));
        assert!(m.contains("field of view"), "{m}");

        let m = invalid_msg(dual_fisheye_to_equirect(&SdrImage::new(0, 0), &ok, 64, 32));
        assert!(m.contains("empty"), "{m}");
        let m = invalid_msg(dual_fisheye_to_equirect(&HdrImage::new(0, 0), &ok, 64, 32));
        assert!(m.contains("empty"), "{m}");
        let m = invalid_msg(dual_fisheye_to_equirect(&SdrImage::new(1, 1), &ok, 64, 32));
        assert!(m.contains("narrow"), "{m}");

        // Wrong aspect: square, and a single fisheye of 4:3.
        for (w, h) in [(200, 200), (400, 300), (300, 100)] {
            let m = invalid_msg(dual_fisheye_to_equirect(&SdrImage::new(w, h), &ok, 64, 32));
            assert!(
                m.contains("twice as wide") && m.contains(&format!("{w}x{h}")),
                "{m}"
            );
        }
        // Within tolerance (an odd column) is fine; a looser tolerance admits more.
        assert!(dual_fisheye_to_equirect(&SdrImage::new(201, 100), &ok, 64, 32).is_ok());
        let loose = DualFisheye {
            aspect_tolerance: 0.2,
            ..ok
        };
        assert!(dual_fisheye_to_equirect(&SdrImage::new(220, 100), &loose, 64, 32).is_ok());

        let bad_blend = [-1.0, f32::NAN, f32::INFINITY];
        for b in bad_blend {
            let cfg = DualFisheye { blend_deg: b, ..ok };
            let m = invalid_msg(dual_fisheye_to_equirect(&img, &cfg, 64, 32));
            assert!(m.contains("blend"), "{m}");
        }
        let cfg = DualFisheye {
            aspect_tolerance: f32::NAN,
            ..ok
        };
        assert!(invalid_msg(dual_fisheye_to_equirect(&img, &cfg, 64, 32)).contains("aspect"));
        for r in [0.0, -3.0, f32::NAN] {
            let cfg = DualFisheye {
                radius_px: Some(r),
                ..ok
            };
            let m = invalid_msg(dual_fisheye_to_equirect(&img, &cfg, 64, 32));
            assert!(m.contains("radius"), "{m}");
        }
        // Centres swapped between halves, or off the image.
        let cfg = DualFisheye {
            front_centre: Some([150.0, 50.0]),
            ..ok
        };
        let m = invalid_msg(dual_fisheye_to_equirect(&img, &cfg, 64, 32));
        assert!(m.contains("front") && m.contains("centre"), "{m}");
        let cfg = DualFisheye {
            back_centre: Some([150.0, -1.0]),
            ..ok
        };
        let m = invalid_msg(dual_fisheye_to_equirect(&img, &cfg, 64, 32));
        assert!(m.contains("back") && m.contains("centre"), "{m}");
        let cfg = DualFisheye {
            back_centre: Some([f32::NAN, 50.0]),
            ..ok
        };
        assert!(invalid_msg(dual_fisheye_to_equirect(&img, &cfg, 64, 32)).contains("back"));

        let m = invalid_msg(dual_fisheye_to_equirect(&img, &ok, 0, 32));
        assert!(m.contains("output"), "{m}");
        let e = dual_fisheye_to_equirect(&img, &ok, usize::MAX, 2).unwrap_err();
        assert!(matches!(e, Error::Limit { .. }), "{e:?}");
        assert!(e.to_string().contains("exceeds the limit"), "{e}");
    }

    #[test]
    fn overrides_move_the_circles() {
        // Small circles off-centre: a front circle of radius 30 at (60, 40) and a
        // back one at (150, 55), drawn as bright discs on black.
        let (w, h) = (200, 100);
        let (fc, bc, rad) = ([60.0f32, 40.0f32], [150.0f32, 55.0f32], 30.0f32);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let c = if x < w / 2 { fc } else { bc };
            let inside = (px - c[0]).hypot(py - c[1]) < rad - 1.5;
            let v = if inside { 5.0 } else { 0.0 };
            [v, v, v]
        });
        let cfg = DualFisheye {
            front_centre: Some(fc),
            back_centre: Some(bc),
            radius_px: Some(rad),
            blend_deg: 4.0,
            ..DualFisheye::new(200.0)
        };
        let out = dual_fisheye_to_equirect(&img, &cfg, 120, 60).unwrap();
        // Inside both circles everywhere except right at their rims.
        for r in 0..60 {
            for c in 0..120 {
                let d = pixel_to_dir(c, r, 120, 60);
                let a = angle(d, Vec3::NEG_Z).to_degrees();
                if (a - 90.0).abs() < 10.0 {
                    continue;
                }
                assert_eq!(out.get(c, r)[0], 5.0, "pixel ({c}, {r}) at {a}°");
            }
        }
    }

    #[test]
    fn hdr_values_are_not_clamped() {
        let (w, h) = (200, 100);
        let mut img = two_tone(w, h, 1e5, 3.5);
        // A 50.0 spot at the front lens centre.
        for y in 45..55 {
            for x in 45..55 {
                img.set(x, y, [50.0, 1e5, 7.25]);
            }
        }
        let cfg = DualFisheye::new(195.0);
        let (ow, oh) = (360, 180);
        let out = dual_fisheye_to_equirect(&img, &cfg, ow, oh).unwrap();
        assert_eq!(out.get(ow / 2, oh / 2), [50.0, 1e5, 7.25]);
        assert_eq!(out.get(ow / 2 + 60, oh / 2 - 30), [1e5; 3]);
        assert_eq!(out.get(5, oh / 2), [3.5; 3]);
        let max = out.data().iter().copied().fold(0.0f32, f32::max);
        assert_eq!(max, 1e5);
        // In the seam band values lie strictly between the two lenses' values.
        let (u, v) = dir_to_uv(Vec3::X);
        let seam = out.get((u * ow as f32) as usize, (v * oh as f32) as usize)[0];
        assert!(seam > 3.5 && seam < 1e5, "seam value {seam}");
    }

    #[test]
    fn an_equirect_frame_fills_what_lies_outside_the_lens_circles() {
        // A textured panorama, as equirect and as two fisheye circles.
        let pano = HdrImage::from_fn(256, 128, |x, y| {
            let v = 0.3 + 0.6 * (((x / 9 + y / 7) % 2) as f32);
            [v, 0.8 * v, 0.6 * v]
        });
        let to_sdr = |img: &HdrImage| {
            let codes: Vec<u8> = img
                .data()
                .iter()
                .map(|&v| (v * 255.0).round().clamp(0.0, 255.0) as u8)
                .collect();
            SdrImage::from_vec(img.width(), img.height(), codes).unwrap()
        };
        let cfg = DualFisheye::new(195.0);
        let fisheye = to_sdr(&render_dual_fisheye(&pano, 195.0, 256, 128));
        let share = content_outside_circles(&fisheye, &cfg).unwrap().unwrap();
        assert!(share < 0.01, "a dual-fisheye frame: {share}");
        let equirect = to_sdr(&pano);
        let share = content_outside_circles(&equirect, &cfg).unwrap().unwrap();
        assert!(share > 0.9, "an equirect frame: {share}");
        // Circles as tall as the image leave corners; circles that fill their
        // halves leave too few pixels to judge.
        let big = DualFisheye {
            radius_px: Some(100.0),
            ..cfg
        };
        assert_eq!(content_outside_circles(&equirect, &big).unwrap(), None);
        // A layout the stitcher refuses is refused here too.
        let narrow = SdrImage::from_vec(100, 100, vec![0; 100 * 100 * 3]).unwrap();
        assert!(content_outside_circles(&narrow, &cfg).is_err());
    }
}
