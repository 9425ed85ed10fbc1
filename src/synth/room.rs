//! The synthetic room: a closed box with procedurally textured walls, floor and
//! ceiling, a few axis-aligned pieces of furniture, small very bright ceiling panels
//! and optionally a window onto a bright sky, plus the ray caster that renders it.
//!
//! Everything is a pure function of the room description and the ray, so a panorama
//! rendered at the same pose is bit-identical whatever the thread count. Shading is
//! deliberately simple (albedo times a constant ambient term plus direct diffuse light
//! from each emitter, treated as a small area light through its centre, with hard
//! shadows cast by the furniture); what matters for lumiprobe is a plausible, highly
//! dynamic, feature-rich panorama with exact ground truth at every position.

use super::rng::{cell_unit, fbm, hash3, hash_unit, value_noise, SplitMix64};
use super::SynthParams;
use crate::image::HdrImage;
use crate::sphere::uv_to_dir;
use glam::{Mat3, Vec3};
use rayon::prelude::*;
use std::f32::consts::PI;

/// Linear RGB triple.
type Rgb = [f32; 3];

#[inline]
fn scale(c: Rgb, k: f32) -> Rgb {
    [c[0] * k, c[1] * k, c[2] * k]
}

#[inline]
fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

#[inline]
fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// HSV (all in [0, 1]) to linear RGB.
fn hsv(h: f32, s: f32, v: f32) -> Rgb {
    let h6 = (h.rem_euclid(1.0)) * 6.0;
    let i = h6.floor();
    let f = h6 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    match i as i32 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

/// A random colourful albedo (saturated, mid to light).
fn vivid(rng: &mut SplitMix64) -> Rgb {
    hsv(
        rng.range_f32(0.0, 1.0),
        rng.range_f32(0.45, 0.9),
        rng.range_f32(0.35, 0.85),
    )
}

/// An axis-aligned rectangle in a wall's `(s, t)` coordinates (metres).
#[derive(Clone, Copy, Debug)]
struct Rect {
    s0: f32,
    t0: f32,
    s1: f32,
    t1: f32,
}

impl Rect {
    fn contains(&self, s: f32, t: f32) -> bool {
        s >= self.s0 && s < self.s1 && t >= self.t0 && t < self.t1
    }
    fn overlaps(&self, o: &Rect, gap: f32) -> bool {
        self.s0 < o.s1 + gap && o.s0 < self.s1 + gap && self.t0 < o.t1 + gap && o.t0 < self.t1 + gap
    }
}

/// Texture style of a piece of furniture.
#[derive(Clone, Copy, Debug)]
enum Style {
    /// Kitchen unit: door fronts with gaps and handles, speckled stone top.
    Cabinet,
    /// Table: wood grain all over.
    Wood,
    /// Crate: horizontal planks with dark gaps.
    Crate,
}

/// An axis-aligned box standing on the floor.
#[derive(Clone, Debug)]
struct Furniture {
    lo: Vec3,
    hi: Vec3,
    color: Rgb,
    style: Style,
    seed: u32,
}

/// An emissive rectangle in the ceiling plane.
#[derive(Clone, Debug)]
struct Panel {
    cx: f32,
    cy: f32,
    hx: f32,
    hy: f32,
    radiance: Rgb,
}

/// What a wall decoration looks like.
#[derive(Clone, Debug)]
enum Decor {
    /// A framed poster with one of four random patterns.
    Poster {
        pattern: u32,
        palette: [Rgb; 4],
        border: Rgb,
        seed: u32,
    },
    /// Floor-standing shelves filled with randomly coloured books.
    Bookshelf { wood: Rgb, seed: u32 },
    /// A panelled door with a handle.
    Door { color: Rgb, seed: u32 },
}

/// A decoration on one wall.
#[derive(Clone, Debug)]
struct Decal {
    wall: usize,
    rect: Rect,
    decor: Decor,
}

/// Surface finish of a wall inside a height band (plain paint elsewhere).
#[derive(Clone, Debug)]
enum Finish {
    Paint,
    Tiles {
        size: f32,
        colors: [Rgb; 3],
        grout: Rgb,
    },
    Bricks {
        w: f32,
        h: f32,
        color: Rgb,
        mortar: Rgb,
    },
}

#[derive(Clone, Debug)]
struct Wall {
    paint: Rgb,
    finish: Finish,
    band: (f32, f32),
    seed: u32,
}

/// A window opening onto the procedural sky.
#[derive(Clone, Debug)]
struct Window {
    wall: usize,
    rect: Rect,
    sky: f32,
    seed: u32,
}

/// A small area light used for direct illumination.
#[derive(Clone, Debug)]
struct Light {
    pos: Vec3,
    normal: Vec3,
    area: f32,
    radiance: Rgb,
}

/// Which surface a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Surf {
    Floor,
    Ceiling,
    /// Walls 0..4: y = min, x = max, y = max, x = min.
    Wall(usize),
    /// Furniture index and the axis of the face normal.
    Furniture(usize, usize),
}

#[derive(Clone, Copy, Debug)]
struct Hit {
    p: Vec3,
    n: Vec3,
    surf: Surf,
}

/// Inward normal of each wall: 0 at y = min, 1 at x = max, 2 at y = max, 3 at x = min.
const WALL_NORMALS: [Vec3; 4] = [
    Vec3::new(0.0, 1.0, 0.0),
    Vec3::new(-1.0, 0.0, 0.0),
    Vec3::new(0.0, -1.0, 0.0),
    Vec3::new(1.0, 0.0, 0.0),
];

/// A procedurally generated closed room with its lights, ready to be ray cast.
///
/// The room spans `x in [-W/2, W/2]`, `y in [-D/2, D/2]`, `z in [0, H]` (world
/// axes of the evaluation data: right-handed, z up, metres). [`super::synthesize`]
/// builds one from the seed; query it with [`Room::radiance`] or [`Room::render`].
#[derive(Clone, Debug)]
pub struct Room {
    lo: Vec3,
    hi: Vec3,
    walls: [Wall; 4],
    floor_seed: u32,
    rug: Option<(Rect, [Rgb; 4], u32)>,
    ceiling: Rgb,
    furniture: Vec<Furniture>,
    panels: Vec<Panel>,
    window: Option<Window>,
    decals: Vec<Decal>,
    lights: Vec<Light>,
    ambient: f32,
}

/// Slab test of a ray against a box: entry and exit parameters, or `None` when the
/// line misses it. Also returns the axis of the entry face.
#[inline]
fn slab(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, f32, usize)> {
    let mut t0 = f32::NEG_INFINITY;
    let mut t1 = f32::INFINITY;
    let mut axis = 0;
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let (mut ta, mut tb) = ((lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv);
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        if ta > t0 {
            t0 = ta;
            axis = a;
        }
        t1 = t1.min(tb);
        if t0 > t1 {
            return None;
        }
    }
    Some((t0, t1, axis))
}

impl Room {
    /// Builds a random room from the parameters' seed: wall finishes, floor planks
    /// and rug, posters, bookshelf, door, window, furniture and ceiling panels.
    /// `avoid` lists camera positions that tall furniture must keep clear of.
    pub(crate) fn generate(params: &SynthParams, rng: &mut SplitMix64, avoid: &[Vec3]) -> Room {
        let [w, d, h] = params.room_size;
        let (w, d, h) = (w.max(1.0), d.max(1.0), h.max(1.0));
        let lo = Vec3::new(-w / 2.0, -d / 2.0, 0.0);
        let hi = Vec3::new(w / 2.0, d / 2.0, h);
        let wall_len = |i: usize| if i % 2 == 0 { w } else { d };

        // Wall finishes: tiled backsplash on wall 0, bricks on wall 3, paint elsewhere.
        let mut walls: Vec<Wall> = (0..4)
            .map(|_| Wall {
                paint: hsv(
                    rng.range_f32(0.0, 1.0),
                    rng.range_f32(0.05, 0.3),
                    rng.range_f32(0.55, 0.8),
                ),
                finish: Finish::Paint,
                band: (0.0, 0.0),
                seed: rng.seed32(),
            })
            .collect();
        walls[0].finish = Finish::Tiles {
            size: rng.range_f32(0.15, 0.22),
            colors: [
                hsv(rng.range_f32(0.0, 1.0), 0.15, 0.85),
                vivid(rng),
                hsv(rng.range_f32(0.0, 1.0), 0.5, 0.45),
            ],
            grout: [0.7, 0.7, 0.68],
        };
        walls[0].band = (0.9, (1.75f32).min(h - 0.3));
        walls[3].finish = Finish::Bricks {
            w: rng.range_f32(0.28, 0.36),
            h: rng.range_f32(0.12, 0.16),
            color: hsv(rng.range_f32(0.0, 0.08), rng.range_f32(0.45, 0.7), 0.5),
            mortar: [0.68, 0.66, 0.62],
        };
        walls[3].band = (0.09, h);
        let walls: [Wall; 4] = walls.try_into().expect("four walls");

        // Reserved rectangles per wall, so decorations do not overlap.
        let mut reserved: Vec<Vec<Rect>> = vec![Vec::new(); 4];
        let mut decals = Vec::new();
        let place = |rng: &mut SplitMix64,
                     reserved: &mut Vec<Vec<Rect>>,
                     wall: usize,
                     rw: f32,
                     t_lo: f32,
                     t_hi: f32,
                     rh: f32|
         -> Option<Rect> {
            let len = wall_len(wall);
            if rw + 0.4 > len || t_lo + rh > t_hi {
                return None;
            }
            for _ in 0..40 {
                let s0 = rng.range_f32(0.2, len - 0.2 - rw);
                let t0 = rng.range_f32(t_lo, t_hi - rh);
                let r = Rect {
                    s0,
                    t0,
                    s1: s0 + rw,
                    t1: t0 + rh,
                };
                if reserved[wall].iter().all(|o| !r.overlaps(o, 0.1)) {
                    reserved[wall].push(r);
                    return Some(r);
                }
            }
            None
        };

        // Furniture. Order: table, counter, tall cabinet, crate.
        let mut furniture = Vec::new();
        let n_boxes = params.n_boxes.min(4);
        if n_boxes >= 1 {
            let (tw, td) = (rng.range_f32(1.0, 1.4), rng.range_f32(0.7, 0.9));
            let cx = rng.range_f32(-0.4, 0.4) * (w / 5.0);
            let cy = rng.range_f32(-0.3, 0.3) * (d / 4.0);
            furniture.push(Furniture {
                lo: Vec3::new(cx - tw / 2.0, cy - td / 2.0, 0.0),
                hi: Vec3::new(cx + tw / 2.0, cy + td / 2.0, 0.74f32.min(h * 0.4)),
                color: hsv(rng.range_f32(0.05, 0.11), 0.55, 0.45),
                style: Style::Wood,
                seed: rng.seed32(),
            });
        }
        if n_boxes >= 2 {
            // Counter along wall 0 (y = min), under the tiled band.
            let len = rng.range_f32(1.6, 2.4).min(w - 0.4);
            let x0 = rng.range_f32(lo.x + 0.1, hi.x - 0.1 - len);
            furniture.push(Furniture {
                lo: Vec3::new(x0, lo.y, 0.0),
                hi: Vec3::new(x0 + len, lo.y + 0.6, 0.9f32.min(h * 0.45)),
                color: vivid(rng),
                style: Style::Cabinet,
                seed: rng.seed32(),
            });
            // Its front hides the wall behind up to 0.9 m: keep posters off it.
            reserved[0].push(Rect {
                s0: hi.x - (x0 + len),
                t0: 0.0,
                s1: hi.x - x0,
                t1: 0.9,
            });
        }
        if n_boxes >= 3 {
            // Tall cabinet against wall 1 (x = max), clear of every camera.
            let (cw, cd) = (rng.range_f32(0.6, 0.9), rng.range_f32(0.45, 0.6));
            let ch = rng.range_f32(1.85, 2.1).min(h - 0.3);
            for _ in 0..40 {
                let y0 = rng.range_f32(lo.y + 0.7, (hi.y - 0.1 - cw).max(lo.y + 0.71));
                let b = Furniture {
                    lo: Vec3::new(hi.x - cd, y0, 0.0),
                    hi: Vec3::new(hi.x, y0 + cw, ch),
                    color: vivid(rng),
                    style: Style::Cabinet,
                    seed: rng.seed32(),
                };
                let clear = avoid.iter().all(|p| {
                    let dx = (b.lo.x - p.x).max(p.x - b.hi.x).max(0.0);
                    let dy = (b.lo.y - p.y).max(p.y - b.hi.y).max(0.0);
                    dx * dx + dy * dy > 0.3 * 0.3
                });
                if clear {
                    reserved[1].push(Rect {
                        s0: hi.y - (y0 + cw),
                        t0: 0.0,
                        s1: hi.y - y0,
                        t1: ch,
                    });
                    furniture.push(b);
                    break;
                }
            }
        }
        if n_boxes >= 4 {
            // Low crate near wall 2 (y = max).
            let (bw, bd, bh) = (
                rng.range_f32(0.5, 0.8),
                rng.range_f32(0.4, 0.6),
                rng.range_f32(0.4, 0.6),
            );
            let x0 = rng.range_f32(lo.x + 0.3, hi.x - 0.3 - bw);
            let y0 = hi.y - bd - rng.range_f32(0.05, 0.3);
            furniture.push(Furniture {
                lo: Vec3::new(x0, y0, 0.0),
                hi: Vec3::new(x0 + bw, y0 + bd, bh),
                color: hsv(rng.range_f32(0.07, 0.14), 0.5, 0.55),
                style: Style::Crate,
                seed: rng.seed32(),
            });
        }

        // Window on the brick wall (3), bookshelf and door on walls 2 and 1.
        let window = if params.window {
            let ww = rng.range_f32(1.0, 1.4).min(d - 0.6);
            let wh = (1.1f32).min(h - 1.3);
            place(rng, &mut reserved, 3, ww, 0.9, 0.9 + wh + 0.01, wh).map(|rect| Window {
                wall: 3,
                rect,
                sky: params.sky_radiance,
                seed: rng.seed32(),
            })
        } else {
            None
        };
        let shelf_w = rng.range_f32(1.2, 1.8);
        if let Some(rect) = place(
            rng,
            &mut reserved,
            2,
            shelf_w,
            0.0,
            1.95f32.min(h - 0.2),
            1.95f32.min(h - 0.2),
        ) {
            decals.push(Decal {
                wall: 2,
                rect,
                decor: Decor::Bookshelf {
                    wood: hsv(rng.range_f32(0.06, 0.1), 0.5, rng.range_f32(0.3, 0.55)),
                    seed: rng.seed32(),
                },
            });
        }
        let door_h = 2.05f32.min(h - 0.2);
        let door_wall = if rng.next_f64() < 0.5 { 1 } else { 2 };
        for wall in [door_wall, 3 - door_wall] {
            if let Some(rect) = place(rng, &mut reserved, wall, 0.9, 0.0, door_h + 0.01, door_h) {
                decals.push(Decal {
                    wall,
                    rect,
                    decor: Decor::Door {
                        color: hsv(
                            rng.range_f32(0.0, 1.0),
                            rng.range_f32(0.1, 0.5),
                            rng.range_f32(0.35, 0.7),
                        ),
                        seed: rng.seed32(),
                    },
                });
                break;
            }
        }
        // Posters: spread over the walls, above furniture height.
        for k in 0..params.n_posters {
            let wall = (k + rng.below(4) as usize) % 4;
            let pw = rng.range_f32(0.4, 0.9);
            let ph = rng.range_f32(0.4, 0.9);
            let top = (h - 0.2).min(2.4);
            for attempt in 0..4 {
                let wall = (wall + attempt) % 4;
                if let Some(rect) = place(rng, &mut reserved, wall, pw, 1.0, top, ph) {
                    let palette = [vivid(rng), vivid(rng), vivid(rng), vivid(rng)];
                    let border = if rng.next_f64() < 0.5 {
                        [0.05, 0.05, 0.05]
                    } else {
                        [0.8, 0.8, 0.78]
                    };
                    decals.push(Decal {
                        wall,
                        rect,
                        decor: Decor::Poster {
                            pattern: rng.below(4) as u32,
                            palette,
                            border,
                            seed: rng.seed32(),
                        },
                    });
                    break;
                }
            }
        }

        // A patterned rug on the floor.
        let rug = {
            let (rw, rd) = (
                rng.range_f32(1.6, 2.2).min(w - 1.0),
                rng.range_f32(1.0, 1.4).min(d - 1.0),
            );
            let cx = rng.range_f32(-0.3, 0.3);
            let cy = rng.range_f32(-0.2, 0.2);
            let r = Rect {
                s0: cx - rw / 2.0,
                t0: cy - rd / 2.0,
                s1: cx + rw / 2.0,
                t1: cy + rd / 2.0,
            };
            Some((
                r,
                [vivid(rng), vivid(rng), vivid(rng), hsv(0.1, 0.2, 0.8)],
                rng.seed32(),
            ))
        };

        // Ceiling panels, well apart, warm white, very bright.
        let mut panels: Vec<Panel> = Vec::new();
        let warm = [1.0f32, 0.9, 0.76];
        let warm_lum = crate::image::luminance(warm);
        for _ in 0..params.n_lights {
            for _ in 0..60 {
                let cx = rng.range_f32(lo.x + 0.8, hi.x - 0.8);
                let cy = rng.range_f32(lo.y + 0.7, hi.y - 0.7);
                let min_gap = if panels.len() < 3 { 1.4 } else { 0.8 };
                if panels
                    .iter()
                    .all(|p| ((p.cx - cx).powi(2) + (p.cy - cy).powi(2)).sqrt() > min_gap)
                {
                    let l = params.light_radiance * params.light_scale * rng.range_f32(0.8, 1.2);
                    panels.push(Panel {
                        cx,
                        cy,
                        hx: rng.range_f32(0.09, 0.15),
                        hy: rng.range_f32(0.09, 0.15),
                        radiance: scale(warm, l / warm_lum),
                    });
                    break;
                }
            }
        }

        let mut room = Room {
            lo,
            hi,
            walls,
            floor_seed: rng.seed32(),
            rug,
            ceiling: [0.8, 0.79, 0.76],
            furniture,
            panels,
            window,
            decals,
            lights: Vec::new(),
            ambient: params.ambient,
        };
        room.lights = room.make_lights();
        room
    }

    /// Direct-light emitters: every ceiling panel, and the window as one cool,
    /// sky-coloured area light.
    fn make_lights(&self) -> Vec<Light> {
        let mut lights: Vec<Light> = self
            .panels
            .iter()
            .map(|p| Light {
                pos: Vec3::new(p.cx, p.cy, self.hi.z),
                normal: Vec3::NEG_Z,
                area: 4.0 * p.hx * p.hy * 0.97,
                radiance: p.radiance,
            })
            .collect();
        if let Some(win) = &self.window {
            let r = win.rect;
            let c = self.wall_point(win.wall, 0.5 * (r.s0 + r.s1), 0.5 * (r.t0 + r.t1));
            lights.push(Light {
                pos: c,
                normal: WALL_NORMALS[win.wall],
                area: (r.s1 - r.s0) * (r.t1 - r.t0) * 0.85,
                radiance: scale([0.8, 0.88, 1.0], 0.6 * win.sky),
            });
        }
        lights
    }

    /// Room extent: `(min corner, max corner)` in world metres.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (self.lo, self.hi)
    }

    /// Centres of the emissive ceiling panels (world metres), e.g. to aim a test
    /// camera at a lamp.
    pub fn lamp_centres(&self) -> Vec<Vec3> {
        self.panels
            .iter()
            .map(|p| Vec3::new(p.cx, p.cy, self.hi.z))
            .collect()
    }

    /// World point of wall `i` at wall coordinates `(s, t)`.
    fn wall_point(&self, wall: usize, s: f32, t: f32) -> Vec3 {
        let (lo, hi) = (self.lo, self.hi);
        match wall {
            0 => Vec3::new(hi.x - s, lo.y, lo.z + t),
            1 => Vec3::new(hi.x, hi.y - s, lo.z + t),
            2 => Vec3::new(lo.x + s, hi.y, lo.z + t),
            _ => Vec3::new(lo.x, lo.y + s, lo.z + t),
        }
    }

    /// Wall coordinates `(s, t)` of a point on wall `i`: `s` runs left to right as
    /// seen from inside the room, `t` is the height above the floor.
    fn wall_st(&self, wall: usize, p: Vec3) -> (f32, f32) {
        let (lo, hi) = (self.lo, self.hi);
        let s = match wall {
            0 => hi.x - p.x,
            1 => hi.y - p.y,
            2 => p.x - lo.x,
            _ => p.y - lo.y,
        };
        (s, p.z - lo.z)
    }

    /// Nearest surface along the ray `o + t d` (`o` inside the room).
    fn intersect(&self, o: Vec3, d: Vec3) -> Hit {
        let mut best_t = f32::INFINITY;
        let mut surf = Surf::Floor;
        for a in 0..3 {
            let da = d[a];
            let (t, s) = if da > 0.0 {
                ((self.hi[a] - o[a]) / da, true)
            } else if da < 0.0 {
                ((self.lo[a] - o[a]) / da, false)
            } else {
                continue;
            };
            if t < best_t {
                best_t = t;
                surf = match (a, s) {
                    (2, true) => Surf::Ceiling,
                    (2, false) => Surf::Floor,
                    (1, false) => Surf::Wall(0),
                    (0, true) => Surf::Wall(1),
                    (1, true) => Surf::Wall(2),
                    _ => Surf::Wall(3),
                };
            }
        }
        let mut normal = match surf {
            Surf::Ceiling => Vec3::NEG_Z,
            Surf::Floor => Vec3::Z,
            Surf::Wall(i) => WALL_NORMALS[i],
            Surf::Furniture(..) => unreachable!(),
        };
        for (i, f) in self.furniture.iter().enumerate() {
            if let Some((t0, t1, axis)) = slab(o, d, f.lo, f.hi) {
                if t0 > 1e-5 && t0 <= t1 && t0 < best_t {
                    best_t = t0;
                    surf = Surf::Furniture(i, axis);
                    let mut n = Vec3::ZERO;
                    n[axis] = if d[axis] > 0.0 { -1.0 } else { 1.0 };
                    normal = n;
                }
            }
        }
        let mut p = o + d * best_t;
        // Snap the hit onto its plane so textures see exact coordinates.
        match surf {
            Surf::Ceiling => p.z = self.hi.z,
            Surf::Floor => p.z = self.lo.z,
            _ => {}
        }
        p = p.clamp(self.lo, self.hi);
        Hit { p, n: normal, surf }
    }

    /// True when furniture blocks the segment from `p` to `q`.
    fn occluded(&self, p: Vec3, q: Vec3) -> bool {
        let d = q - p;
        self.furniture.iter().any(|f| match slab(p, d, f.lo, f.hi) {
            Some((t0, t1, _)) => t1 > 1e-4 && t0 < 1.0 - 1e-4 && t0 <= t1,
            None => false,
        })
    }

    /// Scene-linear radiance arriving at `o` from world direction `d` (any length):
    /// an emitter's own radiance, or the albedo-weighted ambient plus direct light.
    /// This is the ground truth the panoramas sample.
    pub fn radiance(&self, o: Vec3, d: Vec3) -> [f32; 3] {
        let d = d.normalize_or_zero();
        if d == Vec3::ZERO {
            return [0.0; 3];
        }
        let o = o.clamp(self.lo + Vec3::splat(1e-4), self.hi - Vec3::splat(1e-4));
        let hit = self.intersect(o, d);
        if let Some(e) = self.emission(&hit, d) {
            return e;
        }
        let albedo = self.albedo(&hit);
        let amb = self.ambient * (0.8 + 0.2 * (hit.p.z - self.lo.z) / (self.hi.z - self.lo.z));
        let e = self.irradiance(hit.p, hit.n);
        let mut out = [0.0; 3];
        for k in 0..3 {
            out[k] = albedo[k] * (amb + e[k] / PI);
        }
        out
    }

    /// Direct irradiance at `p` with normal `n` from all lights, each a small area
    /// light seen through its centre (`E = L A cos cos / (d^2 + A / pi)`, the exact
    /// on-axis disc formula, so it stays finite right next to a lamp) with a hard
    /// shadow test against the furniture.
    fn irradiance(&self, p: Vec3, n: Vec3) -> Rgb {
        let mut e = [0.0f32; 3];
        let start = p + n * 1e-3;
        for l in &self.lights {
            let v = l.pos - p;
            let d2 = v.length_squared();
            if d2 < 1e-12 {
                continue;
            }
            let dir = v / d2.sqrt();
            let cos_r = n.dot(dir);
            let cos_s = -l.normal.dot(dir);
            if cos_r <= 0.0 || cos_s <= 0.0 {
                continue;
            }
            if self.occluded(start, l.pos) {
                continue;
            }
            let g = l.area * cos_r * cos_s / (d2 + l.area / PI);
            for (ek, lk) in e.iter_mut().zip(l.radiance) {
                *ek += lk * g;
            }
        }
        e
    }

    /// Radiance of an emitter at the hit, if it is one (panel or window glass).
    fn emission(&self, hit: &Hit, d: Vec3) -> Option<Rgb> {
        match hit.surf {
            Surf::Ceiling => {
                for p in &self.panels {
                    let (ax, ay) = ((hit.p.x - p.cx).abs() / p.hx, (hit.p.y - p.cy).abs() / p.hy);
                    if ax < 1.0 && ay < 1.0 {
                        // Slightly dimmer towards the rim, like a diffuser.
                        let r = ax.max(ay);
                        return Some(scale(p.radiance, 1.04 - 0.12 * r * r * r * r));
                    }
                }
                None
            }
            Surf::Wall(i) => {
                let win = self.window.as_ref()?;
                if win.wall != i {
                    return None;
                }
                let (s, t) = self.wall_st(i, hit.p);
                let r = win.rect;
                if !r.contains(s, t) {
                    return None;
                }
                // Frame and mullions are opaque (shaded by `albedo`).
                let f = 0.05;
                let mid_s = 0.5 * (r.s0 + r.s1);
                let mid_t = r.t0 + 0.62 * (r.t1 - r.t0);
                if s < r.s0 + f
                    || s > r.s1 - f
                    || t < r.t0 + f
                    || t > r.t1 - f
                    || (s - mid_s).abs() < 0.025
                    || (t - mid_t).abs() < 0.025
                {
                    return None;
                }
                Some(scale(self.sky(d, win.seed), win.sky))
            }
            _ => None,
        }
    }

    /// Outdoor radiance (relative; 1 = bright horizon sky) seen through the window in
    /// world direction `d`: sky gradient with clouds above the horizon, a skyline of
    /// block buildings with lit windows and dim ground below it.
    fn sky(&self, d: Vec3, seed: u32) -> Rgb {
        let e = d.z;
        let az = d.y.atan2(d.x);
        // Skyline: building tops at an elevation that steps with azimuth.
        let cell = (az * 9.0).floor() as i32;
        let top = 0.04 + 0.2 * cell_unit(cell, 1, seed);
        if e < 0.0 {
            let g = fbm(az * 12.0, e * 30.0, seed ^ 0x55, 3);
            return scale([0.3, 0.34, 0.22], 0.3 * (0.6 + 0.8 * g));
        }
        if e < top {
            let shade = 0.15 + 0.2 * cell_unit(cell, 2, seed);
            let base = hsv(cell_unit(cell, 3, seed), 0.25, 1.0);
            let wx = (az * 9.0 * 6.0).fract();
            let wy = (e * 60.0).fract();
            let lit = if wx > 0.3 && wy > 0.35 { 0.5 } else { 0.0 };
            return scale(base, shade + lit * 0.25);
        }
        let t = e.clamp(0.0, 1.0).sqrt();
        let sky = mix([1.0, 1.0, 1.05], [0.35, 0.5, 1.0], t);
        let sky = scale(sky, 1.0 - 0.35 * t);
        let k = 1.0 / (e + 0.15);
        let c = fbm(d.x * k * 1.5, d.y * k * 1.5, seed ^ 0xC10D, 5);
        let cloud = smoothstep(0.48, 0.68, c);
        mix(sky, [1.15, 1.15, 1.15], cloud)
    }

    /// Diffuse reflectance at a (non-emitting) hit.
    fn albedo(&self, hit: &Hit) -> Rgb {
        match hit.surf {
            Surf::Floor => self.floor_albedo(hit.p.x, hit.p.y),
            Surf::Ceiling => {
                let g = fbm(hit.p.x * 2.0, hit.p.y * 2.0, self.floor_seed ^ 0xCE11, 4);
                let c = scale(self.ceiling, 0.9 + 0.15 * g);
                // A thin dark frame around each lamp.
                for p in &self.panels {
                    let ax = (hit.p.x - p.cx).abs() - p.hx;
                    let ay = (hit.p.y - p.cy).abs() - p.hy;
                    if ax < 0.035 && ay < 0.035 {
                        return [0.15, 0.15, 0.16];
                    }
                }
                c
            }
            Surf::Wall(i) => {
                let (s, t) = self.wall_st(i, hit.p);
                self.wall_albedo(i, s, t)
            }
            Surf::Furniture(i, axis) => self.furniture_albedo(&self.furniture[i], hit.p, axis),
        }
    }

    fn floor_albedo(&self, x: f32, y: f32) -> Rgb {
        let seed = self.floor_seed;
        if let Some((r, pal, rs)) = &self.rug {
            if r.contains(x, y) {
                return rug_albedo(x - r.s0, y - r.t0, r.s1 - r.s0, r.t1 - r.t0, pal, *rs);
            }
        }
        // Wooden planks along x, 19 cm wide, staggered joints.
        let s = x - self.lo.x;
        let t = y - self.lo.y;
        let pw = 0.19;
        let rowf = t / pw;
        let row = rowf.floor() as i32;
        let ti = rowf - rowf.floor();
        let len = 1.1 + 0.6 * cell_unit(row, 7, seed);
        let sx = (s + cell_unit(row, 3, seed) * len) / len;
        let k = sx.floor() as i32;
        let si = (sx - sx.floor()) * len;
        let tint = cell_unit(k, row, seed ^ 0xABC);
        let grain = fbm(s * 2.5, t * 35.0, seed ^ 0x6A, 3);
        let wood = mix([0.42, 0.27, 0.15], [0.62, 0.45, 0.28], tint);
        let c = scale(wood, 0.7 + 0.55 * grain);
        if ti < 0.05 || si < 0.012 {
            scale(c, 0.35)
        } else {
            c
        }
    }

    fn wall_albedo(&self, i: usize, s: f32, t: f32) -> Rgb {
        // Decorations, last placed on top.
        for dc in self.decals.iter().rev() {
            if dc.wall == i && dc.rect.contains(s, t) {
                return decal_albedo(dc, s, t);
            }
        }
        if let Some(win) = &self.window {
            if win.wall == i && win.rect.contains(s, t) {
                return [0.85, 0.85, 0.83]; // window frame and mullions
            }
        }
        let wall = &self.walls[i];
        if t < 0.09 {
            let n = value_noise(s * 6.0, 0.5, wall.seed ^ 0xBA5E);
            return scale([0.2, 0.18, 0.16], 0.85 + 0.3 * n);
        }
        if t >= wall.band.0 && t < wall.band.1 {
            match &wall.finish {
                Finish::Paint => {}
                Finish::Tiles {
                    size,
                    colors,
                    grout,
                } => {
                    let u = s / size;
                    let v = (t - wall.band.0) / size;
                    let (iu, iv) = (u.floor() as i32, v.floor() as i32);
                    let (fu, fv) = (u - u.floor(), v - v.floor());
                    if fu < 0.08 || fv < 0.08 {
                        return *grout;
                    }
                    let hsh = hash3(iu as u32, iv as u32, wall.seed);
                    let c = colors[(hsh % 3) as usize];
                    let glaze = 0.9 + 0.15 * value_noise(s * 30.0, t * 30.0, wall.seed);
                    return scale(c, glaze);
                }
                Finish::Bricks {
                    w,
                    h,
                    color,
                    mortar,
                } => {
                    let v = t / h;
                    let row = v.floor() as i32;
                    let off = if row & 1 == 1 { 0.5 * w } else { 0.0 };
                    let u = (s + off) / w;
                    let col = u.floor() as i32;
                    let (fu, fv) = ((u - u.floor()) * w, (v - v.floor()) * h);
                    if fu < 0.018 || fv < 0.018 {
                        return scale(*mortar, 0.9 + 0.2 * value_noise(s * 20.0, t * 20.0, 3));
                    }
                    let tint = 0.65 + 0.6 * cell_unit(col, row, wall.seed);
                    let n = fbm(s * 8.0, t * 8.0, wall.seed ^ 0xB1, 3);
                    let c = mix(*color, [0.45, 0.4, 0.35], 0.3 * cell_unit(col, row, 99));
                    return scale(c, tint * (0.8 + 0.4 * n));
                }
            }
        }
        let blot = fbm(s * 1.2, t * 1.2, wall.seed, 4);
        let fine = value_noise(s * 25.0, t * 25.0, wall.seed ^ 0xF1);
        scale(wall.paint, (0.82 + 0.3 * blot) * (0.96 + 0.08 * fine))
    }

    fn furniture_albedo(&self, f: &Furniture, p: Vec3, axis: usize) -> Rgb {
        let rel = p - f.lo;
        let size = f.hi - f.lo;
        // Face coordinates: (s, t) = (horizontal, height) or (x, y) on top.
        let (s, t, along) = match axis {
            0 => (rel.y, rel.z, size.y),
            1 => (rel.x, rel.z, size.x),
            _ => (rel.x, rel.y, size.x),
        };
        let top = axis == 2;
        match f.style {
            Style::Cabinet => {
                if top {
                    // Speckled stone.
                    let n = fbm(s * 6.0, t * 6.0, f.seed, 4);
                    let speck = value_noise(s * 70.0, t * 70.0, f.seed ^ 0x5);
                    let c = scale([0.55, 0.54, 0.52], 0.6 + 0.6 * n);
                    return if speck > 0.78 { scale(c, 0.4) } else { c };
                }
                if t < 0.08 {
                    return [0.08, 0.08, 0.08];
                }
                let n_doors = (along / 0.5).round().max(1.0);
                let dw = along / n_doors;
                let u = s / dw;
                let door = u.floor() as i32;
                let fu = (u - u.floor()) * dw;
                if fu < 0.012 || fu > dw - 0.012 || (size.z - t) < 0.012 {
                    return [0.05, 0.05, 0.05];
                }
                // Handle near the top of each door, on alternating sides.
                let hx = if door & 1 == 0 { dw - 0.06 } else { 0.06 };
                let ht = size.z - 0.18;
                if (fu - hx).abs() < 0.012 && (t - ht).abs() < 0.08 {
                    return [0.7, 0.7, 0.72];
                }
                let n = fbm(s * 3.0, t * 3.0, f.seed, 3);
                let tint = 0.92 + 0.16 * cell_unit(door, 0, f.seed);
                scale(f.color, tint * (0.88 + 0.2 * n))
            }
            Style::Wood => {
                let g = if top {
                    fbm(s * 1.5, t * 25.0, f.seed, 4)
                } else {
                    fbm(s * 1.5, t * 20.0, f.seed, 4)
                };
                let edge = !top && (size.z - t) < 0.04;
                let c = scale(f.color, 0.7 + 0.6 * g);
                if edge {
                    scale(c, 0.6)
                } else {
                    c
                }
            }
            Style::Crate => {
                let ph = 0.12;
                let v = if top { s / ph } else { t / ph };
                let row = v.floor() as i32;
                let fv = (v - v.floor()) * ph;
                if fv < 0.01 {
                    return [0.06, 0.05, 0.04];
                }
                let tint = 0.75 + 0.5 * cell_unit(row, axis as i32, f.seed);
                let g = fbm(
                    if top { t } else { s } * 2.0,
                    fv * 25.0 + row as f32 * 3.0,
                    f.seed,
                    3,
                );
                scale(f.color, tint * (0.75 + 0.45 * g))
            }
        }
    }

    /// Renders the equirectangular panorama seen from `position` with rotation
    /// `world_from_camera` at `width x height`, averaging `aa x aa` stratified,
    /// jittered rays per pixel. The jitter depends only on the pixel, so the same
    /// pose always gives the same image. Rows are rendered in parallel.
    pub fn render(
        &self,
        position: Vec3,
        world_from_camera: Mat3,
        width: usize,
        height: usize,
        aa: usize,
    ) -> HdrImage {
        let mut img = HdrImage::new(width, height);
        if width == 0 || height == 0 {
            return img;
        }
        let n = aa.max(1);
        let inv_n = 1.0 / n as f32;
        let inv_count = 1.0 / (n * n) as f32;
        let (wf, hf) = (width as f32, height as f32);
        img.data_mut()
            .par_chunks_mut(3 * width)
            .enumerate()
            .for_each(|(row, line)| {
                for col in 0..width {
                    let mut acc = [0.0f32; 3];
                    for j in 0..n {
                        for i in 0..n {
                            let k = (j * n + i) as u32;
                            let ju = hash_unit(col as u32, row as u32, 0x7177_0000 + 2 * k);
                            let jv = hash_unit(col as u32, row as u32, 0x7177_0001 + 2 * k);
                            let u = (col as f32 + (i as f32 + ju) * inv_n) / wf;
                            let v = (row as f32 + (j as f32 + jv) * inv_n) / hf;
                            let c = self.radiance(position, world_from_camera * uv_to_dir(u, v));
                            for q in 0..3 {
                                acc[q] += c[q];
                            }
                        }
                    }
                    line[3 * col..3 * col + 3].copy_from_slice(&scale(acc, inv_count));
                }
            });
        img
    }
}

/// Patterned rug: a border band, a diagonal lattice of lines and alternating
/// diamonds, with some wear noise. `(x, y)` from the rug's corner, size `w x h`.
fn rug_albedo(x: f32, y: f32, w: f32, h: f32, pal: &[Rgb; 4], seed: u32) -> Rgb {
    let edge = x.min(y).min(w - x).min(h - y);
    let wear = 0.85 + 0.25 * fbm(x * 5.0, y * 5.0, seed, 3);
    if edge < 0.04 {
        return scale(pal[3], wear);
    }
    if edge < 0.15 {
        // Border with a row of small squares.
        let along = if (x.min(w - x)) < (y.min(h - y)) {
            y
        } else {
            x
        };
        let sq = ((along / 0.08).floor() as i32) & 1 == 0 && (edge - 0.095).abs() < 0.03;
        return scale(if sq { pal[3] } else { pal[1] }, wear);
    }
    let a = (x + y) / 0.28;
    let b = (x - y) / 0.28;
    let (fa, fb) = (a - a.floor(), b - b.floor());
    if fa < 0.1 || fb < 0.1 {
        return scale(pal[2], wear);
    }
    let parity = (a.floor() as i32 + b.floor() as i32) & 1;
    let c = if parity == 0 {
        pal[0]
    } else {
        mix(pal[0], pal[3], 0.5)
    };
    scale(c, wear)
}

fn decal_albedo(dc: &Decal, s: f32, t: f32) -> Rgb {
    let r = dc.rect;
    let (x, y) = (s - r.s0, t - r.t0);
    let (w, h) = (r.s1 - r.s0, r.t1 - r.t0);
    match &dc.decor {
        Decor::Poster {
            pattern,
            palette,
            border,
            seed,
        } => {
            let b = 0.03;
            if x < b || y < b || x > w - b || y > h - b {
                return *border;
            }
            poster_albedo(
                *pattern,
                x - b,
                y - b,
                w - 2.0 * b,
                h - 2.0 * b,
                palette,
                *seed,
            )
        }
        Decor::Bookshelf { wood, seed } => {
            let board = 0.03;
            let shelf = 0.36;
            if x < board || x > w - board || y > h - board {
                return *wood;
            }
            let yy = y - board;
            let row = (yy / shelf).floor() as i32;
            let fy = yy - row as f32 * shelf;
            if fy < board || y < 0.09 {
                return scale(*wood, 1.1);
            }
            let inner = shelf - board;
            let fy = fy - board;
            let xx = x - board;
            let bx = xx / 0.045 + 1.5 * value_noise(xx * 4.0, row as f32 * 7.3, *seed);
            let k = bx.floor() as i32;
            let back = scale(*wood, 0.25);
            let present = cell_unit(k, row, *seed ^ 0xB00C) > 0.07;
            let bh = inner * (0.55 + 0.4 * cell_unit(k, row, *seed ^ 0x4E16));
            if !present || fy > bh {
                return back;
            }
            if bx - bx.floor() < 0.07 {
                return scale(back, 0.5);
            }
            let hue = cell_unit(k, row, *seed ^ 0xC0);
            let c = hsv(
                hue,
                0.35 + 0.5 * cell_unit(k, row, *seed ^ 0xC1),
                0.25 + 0.5 * cell_unit(k, row, *seed ^ 0xC2),
            );
            let rel = fy / bh;
            if cell_unit(k, row, *seed ^ 0xC3) < 0.6 && (0.62..0.76).contains(&rel) {
                return [0.8, 0.76, 0.62];
            }
            c
        }
        Decor::Door { color, seed } => {
            let g = fbm(x * 2.0, y * 12.0, *seed, 3);
            let base = scale(*color, 0.85 + 0.25 * g);
            if (x - (w - 0.1)).abs() < 0.035 && (y - 1.0).abs() < 0.035 {
                return [0.6, 0.58, 0.5];
            }
            let m = 0.12;
            let in_x = x > m && x < w - m;
            let lower = y > 0.15 && y < 0.95;
            let upper = y > 1.1 && y < h - 0.15;
            if in_x && (lower || upper) {
                let (ylo, yhi) = if lower { (0.15, 0.95) } else { (1.1, h - 0.15) };
                let e = (x - m).min(w - m - x).min(y - ylo).min(yhi - y);
                return if e < 0.02 {
                    scale(base, 0.55)
                } else {
                    scale(base, 0.92)
                };
            }
            base
        }
    }
}

/// One of four poster patterns on inner coordinates `(x, y)` in metres of a `w x h`
/// area: random discs, a Mondrian-like subdivision, stripes with a ringed disc, and a
/// little landscape with a sun.
fn poster_albedo(pattern: u32, x: f32, y: f32, w: f32, h: f32, pal: &[Rgb; 4], seed: u32) -> Rgb {
    match pattern {
        0 => {
            let mut c = scale(pal[0], 0.9);
            for k in 0..14u32 {
                let cx = hash_unit(k, 1, seed) * w;
                let cy = hash_unit(k, 2, seed) * h;
                let r = 0.03 + 0.1 * hash_unit(k, 3, seed);
                if (x - cx).powi(2) + (y - cy).powi(2) < r * r {
                    c = scale(pal[1 + (k % 3) as usize], 0.7 + 0.3 * hash_unit(k, 4, seed));
                }
            }
            c
        }
        1 => {
            let (mut x0, mut y0, mut x1, mut y1) = (0.0f32, 0.0f32, w, h);
            let mut id = 1u32;
            for level in 0..5u32 {
                let f = 0.25 + 0.5 * hash_unit(id, level, seed);
                let vertical = (x1 - x0) > (y1 - y0);
                if vertical {
                    let split = x0 + (x1 - x0) * f;
                    if (x - split).abs() < 0.008 {
                        return [0.03, 0.03, 0.03];
                    }
                    if x < split {
                        x1 = split;
                        id *= 2;
                    } else {
                        x0 = split;
                        id = 2 * id + 1;
                    }
                } else {
                    let split = y0 + (y1 - y0) * f;
                    if (y - split).abs() < 0.008 {
                        return [0.03, 0.03, 0.03];
                    }
                    if y < split {
                        y1 = split;
                        id *= 2;
                    } else {
                        y0 = split;
                        id = 2 * id + 1;
                    }
                }
            }
            let pick = hash3(id, 9, seed) % 6;
            match pick {
                0..=3 => pal[pick as usize],
                4 => [0.82, 0.82, 0.8],
                _ => [0.85, 0.8, 0.6],
            }
        }
        2 => {
            let (cx, cy) = (0.5 * w, 0.55 * h);
            let rr = 0.32 * w.min(h);
            let dx = x - cx;
            let dy = y - cy;
            let dist = (dx * dx + dy * dy).sqrt();
            if dist < rr {
                let ring = ((dist / 0.035).floor() as i32) & 1;
                return if ring == 0 { pal[2] } else { pal[3] };
            }
            let ang = hash_unit(1, 1, seed) * PI;
            let period = 0.05 + 0.05 * hash_unit(2, 2, seed);
            let q = (x * ang.cos() + y * ang.sin()) / period;
            if (q - q.floor()) < 0.5 {
                pal[0]
            } else {
                pal[1]
            }
        }
        _ => {
            let n = fbm(x * 3.0, y * 3.0, seed, 4);
            let horizon = 0.55 * h + 0.25 * h * (n - 0.5);
            if y > horizon {
                let (sx, sy) = (0.72 * w, 0.82 * h);
                if (x - sx).powi(2) + (y - sy).powi(2) < (0.09 * w.min(h)).powi(2) {
                    return [0.95, 0.85, 0.3];
                }
                return mix(pal[1], [0.9, 0.9, 0.9], 0.5);
            }
            let m = fbm(x * 6.0, y * 6.0, seed ^ 0x77, 3);
            if m < 0.4 {
                pal[0]
            } else if m < 0.55 {
                pal[3]
            } else {
                scale(pal[2], 0.5)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_hits_and_misses() {
        let lo = Vec3::new(-1.0, -1.0, 0.0);
        let hi = Vec3::new(1.0, 1.0, 1.0);
        let (t0, t1, axis) = slab(Vec3::new(-3.0, 0.0, 0.5), Vec3::X, lo, hi).unwrap();
        assert!((t0 - 2.0).abs() < 1e-6 && (t1 - 4.0).abs() < 1e-6 && axis == 0);
        assert!(slab(Vec3::new(-3.0, 0.0, 2.0), Vec3::X, lo, hi).is_none());
    }
}
