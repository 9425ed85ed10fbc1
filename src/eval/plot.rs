//! Small scatter plots as PNG images (error against distance, error against run
//! time), drawn here so reports need no plotting library. Text uses a built-in
//! 5x7 pixel font (digits, upper-case letters and a few symbols; lower case is
//! drawn as upper case).

use crate::image::SdrImage;

/// One named set of points.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// `(x, y)` points; non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// Connect the points in x order (a front or a curve) instead of dots only.
    pub line: bool,
    /// A label beside each point (empty: none), in the series' colour.
    pub labels: Vec<String>,
}

/// A scatter plot.
#[derive(Clone, Debug)]
pub struct Plot {
    /// Title above the plot.
    pub title: String,
    /// X axis label.
    pub x_label: String,
    /// Y axis label.
    pub y_label: String,
    /// Logarithmic x axis (base 10).
    pub log_x: bool,
    /// Logarithmic y axis (base 10); points with y <= 0 are skipped.
    pub log_y: bool,
    /// Names of categories on the x axis: when not empty, x value `i` is
    /// category `x_names[i]`, which labels the ticks instead of numbers (shortened
    /// to fit); x runs from -0.5 to `len - 0.5` (offsets within a category place
    /// series side by side), left of the legend.
    pub x_names: Vec<String>,
    /// The series, drawn in order with distinct colours.
    pub series: Vec<Series>,
}

const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [255, 127, 14],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [23, 190, 207],
];

/// 5x7 glyphs, one byte per row, bit 4 = leftmost column.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        'A' => [14, 17, 17, 31, 17, 17, 17],
        'B' => [30, 17, 17, 30, 17, 17, 30],
        'C' => [14, 17, 16, 16, 16, 17, 14],
        'D' => [28, 18, 17, 17, 17, 18, 28],
        'E' => [31, 16, 16, 30, 16, 16, 31],
        'F' => [31, 16, 16, 30, 16, 16, 16],
        'G' => [14, 17, 16, 23, 17, 17, 15],
        'H' => [17, 17, 17, 31, 17, 17, 17],
        'I' => [14, 4, 4, 4, 4, 4, 14],
        'J' => [7, 2, 2, 2, 2, 18, 12],
        'K' => [17, 18, 20, 24, 20, 18, 17],
        'L' => [16, 16, 16, 16, 16, 16, 31],
        'M' => [17, 27, 21, 21, 17, 17, 17],
        'N' => [17, 17, 25, 21, 19, 17, 17],
        'O' => [14, 17, 17, 17, 17, 17, 14],
        'P' => [30, 17, 17, 30, 16, 16, 16],
        'Q' => [14, 17, 17, 17, 21, 18, 13],
        'R' => [30, 17, 17, 30, 20, 18, 17],
        'S' => [15, 16, 16, 14, 1, 1, 30],
        'T' => [31, 4, 4, 4, 4, 4, 4],
        'U' => [17, 17, 17, 17, 17, 17, 14],
        'V' => [17, 17, 17, 17, 17, 10, 4],
        'W' => [17, 17, 17, 21, 21, 21, 10],
        'X' => [17, 17, 10, 4, 10, 17, 17],
        'Y' => [17, 17, 17, 10, 4, 4, 4],
        'Z' => [31, 1, 2, 4, 8, 16, 31],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        ',' => [0, 0, 0, 0, 12, 4, 8],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        '+' => [0, 4, 4, 31, 4, 4, 0],
        '=' => [0, 0, 31, 0, 31, 0, 0],
        ':' => [0, 12, 12, 0, 12, 12, 0],
        '/' => [1, 1, 2, 4, 8, 16, 16],
        '(' => [2, 4, 8, 8, 8, 4, 2],
        ')' => [8, 4, 2, 2, 2, 4, 8],
        '%' => [24, 25, 2, 4, 8, 19, 3],
        '_' => [0, 0, 0, 0, 0, 0, 31],
        _ => [0; 7],
    }
}

struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = 3 * (y as usize * self.w + x as usize);
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }
    fn text(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (r, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits & (16 >> col) != 0 {
                        self.set(x + 6 * k as i64 + col, y + r as i64, c);
                    }
                }
            }
        }
    }
    /// Text rotated 90° counter-clockwise, reading bottom to top from `(x, y)`.
    fn text_up(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (r, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits & (16 >> col) != 0 {
                        self.set(x + r as i64, y - 6 * k as i64 - col, c);
                    }
                }
            }
        }
    }
    fn line(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        let n = (x1 - x0).abs().max((y1 - y0).abs()).max(1);
        for t in 0..=n {
            self.set(x0 + (x1 - x0) * t / n, y0 + (y1 - y0) * t / n, c);
        }
    }
}

/// A compact decimal label for a tick value.
fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.0e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}

/// About five round tick positions covering `[lo, hi]`.
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).max(1e-12);
    let raw = span / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| span / s <= 8.0)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut v = Vec::new();
    while t <= hi + 1e-9 * step && v.len() < 20 {
        v.push(t);
        t += step;
    }
    v
}

impl Plot {
    /// Draws the plot into a `width x height` RGB image.
    pub fn draw(&self, width: usize, height: usize) -> SdrImage {
        let (w, h) = (width.max(200), height.max(150));
        let mut cv = Canvas {
            w,
            h,
            px: vec![255; w * h * 3],
        };
        let fx = |x: f64| if self.log_x { x.max(1e-300).log10() } else { x };
        let fy = |y: f64| if self.log_y { y.max(1e-300).log10() } else { y };
        let keep = |&(x, y): &(f64, f64)| {
            x.is_finite() && y.is_finite() && (!self.log_x || x > 0.0) && (!self.log_y || y > 0.0)
        };
        let pts: Vec<(f64, f64)> = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(keep)
            .map(|(x, y)| (fx(x), fy(y)))
            .collect();
        let (mut x0, mut x1, mut y0, mut y1) = (0.0, 1.0, 0.0, 1.0);
        if !pts.is_empty() {
            x0 = pts.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
            x1 = pts.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
            y0 = pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
            y1 = pts.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        }
        let pad = |a: f64, b: f64| {
            let d = if b > a {
                (b - a) * 0.06
            } else {
                a.abs().max(1.0) * 0.1
            };
            (a - d, b + d)
        };
        let (x0, x1) = if self.x_names.is_empty() {
            pad(x0, x1)
        } else {
            // Every category gets its place, with or without points.
            (-0.5, self.x_names.len() as f64 - 0.5)
        };
        let (y0, y1) = pad(y0, y1);
        let (l, r, t, b) = (70i64, w as i64 - 20, 30i64, h as i64 - 45);
        // Categories end left of the legend, so no point hides under it.
        let legend_w = self
            .series
            .iter()
            .map(|s| 6 * s.name.chars().count() as i64 + 24)
            .max()
            .unwrap_or(0);
        let r_data = if self.x_names.is_empty() {
            r
        } else {
            (r - legend_w).max(l + (r - l) / 2)
        };
        let px = |x: f64| l + ((x - x0) / (x1 - x0) * (r_data - l) as f64).round() as i64;
        let py = |y: f64| b - ((y - y0) / (y1 - y0) * (b - t) as f64).round() as i64;
        let grey = [200, 200, 200];
        let black = [0, 0, 0];
        if self.x_names.is_empty() {
            for tx in ticks(x0, x1) {
                let x = px(tx);
                cv.line(x, t, x, b, grey);
                let s = if self.log_x {
                    tick_label(10f64.powf(tx))
                } else {
                    tick_label(tx)
                };
                cv.text(x - 3 * s.len() as i64, b + 6, &s, black);
            }
        } else {
            // Category names, each shortened to the room between two ticks.
            let n = self.x_names.len();
            let room = if n > 1 {
                ((px(1.0) - px(0.0)) / 6 - 1).max(1) as usize
            } else {
                ((r - l) / 6) as usize
            };
            for (i, name) in self.x_names.iter().enumerate() {
                let x = px(i as f64);
                cv.line(x, t, x, b, grey);
                let s: String = name.chars().take(room).collect();
                cv.text(x - 3 * s.chars().count() as i64, b + 6, &s, black);
            }
        }
        let y_ticks = if self.log_y {
            // Powers of ten when the range spans them, else the plain ticks.
            let decades: Vec<f64> = (y0.ceil() as i64..=y1.floor() as i64)
                .map(|e| e as f64)
                .collect();
            if decades.len() >= 2 {
                decades
            } else {
                ticks(y0, y1)
            }
        } else {
            ticks(y0, y1)
        };
        for ty in y_ticks {
            let y = py(ty);
            cv.line(l, y, r, y, grey);
            let s = if self.log_y {
                tick_label(10f64.powf(ty))
            } else {
                tick_label(ty)
            };
            cv.text(l - 6 - 6 * s.len() as i64, y - 3, &s, black);
        }
        cv.line(l, b, r, b, black);
        cv.line(l, t, l, b, black);
        cv.text(l, 10, &self.title, black);
        let xl = if self.log_x {
            format!("{} (log)", self.x_label)
        } else {
            self.x_label.clone()
        };
        cv.text((l + r) / 2 - 3 * xl.len() as i64, h as i64 - 16, &xl, black);
        let yl = if self.log_y {
            format!("{} (log)", self.y_label)
        } else {
            self.y_label.clone()
        };
        cv.text_up(8, (t + b) / 2 + 3 * yl.len() as i64, &yl, black);
        for (k, s) in self.series.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let mut p: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(keep)
                .map(|(x, y)| (fx(x), fy(y)))
                .collect();
            if s.line {
                p.sort_by(|a, b| a.0.total_cmp(&b.0));
                for q in p.windows(2) {
                    cv.line(px(q[0].0), py(q[0].1), px(q[1].0), py(q[1].1), c);
                }
            }
            for &(x, y) in &p {
                let (cx, cy) = (px(x), py(y));
                for dy in -2..=2 {
                    for dx in -2..=2 {
                        if dx * dx + dy * dy <= 5 {
                            cv.set(cx + dx, cy + dy, c);
                        }
                    }
                }
            }
            // Labels, above right of their points (in the points' own order:
            // a line's sorting above does not apply).
            for (&(x, y), label) in s.points.iter().zip(&s.labels) {
                if keep(&(x, y)) && !label.is_empty() {
                    cv.text(px(fx(x)) + 4, py(fy(y)) - 10, label, c);
                }
            }
            // Legend, top right.
            let ly = t + 4 + 11 * k as i64;
            let lx = r - 6 * s.name.len() as i64 - 16;
            for dy in -2..=2 {
                for dx in -2..=2 {
                    cv.set(lx + dx, ly + 3 + dy, c);
                }
            }
            cv.text(lx + 6, ly, &s.name, black);
        }
        SdrImage::from_vec(w, h, cv.px).expect("sizes match by construction")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        let t = ticks(0.13, 1.47);
        assert!(t.len() >= 3 && t.len() <= 7, "{t:?}");
        assert!(t
            .iter()
            .all(|v| (v * 10.0 - (v * 10.0).round()).abs() < 1e-9));
        assert!(t[0] >= 0.13 && *t.last().unwrap() <= 1.47);
    }

    #[test]
    fn points_land_in_their_colour_and_empty_plots_still_draw() {
        let p = Plot {
            title: "error against distance".into(),
            x_label: "distance (m)".into(),
            y_label: "PSNR".into(),
            log_x: false,
            log_y: false,
            x_names: Vec::new(),
            series: vec![Series {
                name: "flow".into(),
                points: vec![(0.3, 20.0), (1.5, 30.0), (f64::NAN, 1.0)],
                line: false,
                labels: Vec::new(),
            }],
        };
        let img = p.draw(400, 300);
        let blue = img
            .data()
            .chunks_exact(3)
            .filter(|c| c == &PALETTE[0])
            .count();
        assert!(blue > 20, "{blue} blue pixels");
        let empty = Plot {
            series: vec![],
            ..p
        };
        let e = empty.draw(10, 10);
        assert_eq!((e.width(), e.height()), (200, 150));
    }

    #[test]
    fn log_y_and_named_categories_draw_their_points() {
        let p = Plot {
            title: "worst".into(),
            x_label: "scene".into(),
            y_label: "error".into(),
            log_x: false,
            log_y: true,
            x_names: vec!["kitchen".into(), "flat".into(), "outdoor".into()],
            series: vec![Series {
                name: "warp".into(),
                // A non-positive y cannot be drawn on a log axis and is skipped.
                points: vec![(0.0, 0.01), (1.0, 0.5), (2.0, 0.0)],
                line: false,
                labels: Vec::new(),
            }],
        };
        let img = p.draw(400, 300);
        let blue = |img: &SdrImage| {
            img.data()
                .chunks_exact(3)
                .filter(|c| c == &PALETTE[0])
                .count()
        };
        let n = blue(&img);
        let one = Plot {
            series: vec![Series {
                points: vec![(0.0, 0.01)],
                ..p.series[0].clone()
            }],
            ..p.clone()
        };
        // Two dots of 21 pixels and the legend's 25 against one dot and the legend.
        assert!(n > blue(&one.draw(400, 300)) + 15, "{n}");
        // Labels are drawn beside their points, in the series' colour.
        let labelled = Plot {
            series: vec![Series {
                labels: vec!["12".into(), "7".into(), "3".into()],
                ..p.series[0].clone()
            }],
            ..p.clone()
        };
        let m = blue(&labelled.draw(400, 300));
        assert!(m > n + 20, "{m} vs {n}");
    }
}
