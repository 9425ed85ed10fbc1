"""Random scene layouts for the ground-truth corpus: a seed in, a plain-JSON
scene description out (boxes, spheres, materials, emitters, sky, probe and
frame poses). Pure Python, no Blender: `scene.py` builds and renders what this
describes, `build.py` drives both. The distribution is documented in
scripts/corpus/README.md.

The same seed and GENERATOR_VERSION give the same layout: every draw comes
from one `random.Random(seed)`, nothing is hashed, nothing reads the clock.
Bump GENERATOR_VERSION whenever a change alters what a seed produces; the
corpus cache is keyed by it.

World: right-handed, z up, metres (as in ../shared/data). Every box is
axis-aligned: {"min": [x, y, z], "max": [x, y, z], "mat": name}.
Radiance units: the sky's median over the upper hemisphere is 1 in daylight;
scene.py scales the sky to that, lamps and the sun are given in those units.
"""

import math
import random

GENERATOR_VERSION = "3"

# The captured HDR worlds Blender ships (datafiles/studiolights/world).
DAY_WORLDS = ["city", "courtyard", "forest", "sunrise", "sunset"]

WALL = 0.15  # wall thickness (m)
EYE = 1.5  # walking camera height (m)
MARGIN = 0.35  # how close a camera comes to a wall or an obstacle (m)
SUN_DIAMETER_DEG = 0.53


def pick(rng, weighted):
    t = rng.random() * sum(w for _, w in weighted)
    for item, w in weighted:
        t -= w
        if t <= 0:
            return item
    return weighted[-1][0]


def log_uniform(rng, lo, hi):
    return math.exp(rng.uniform(math.log(lo), math.log(hi)))


def hsv(h, s, v):
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]


def reflectance(rng, lum=(0.15, 0.75), sat_max=0.6):
    return [round(c, 4) for c in hsv(rng.random(), rng.uniform(0.0, sat_max), rng.uniform(*lum))]


def luminance(c):
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


def light_colour(rng):
    """Warm, neutral, cool or clearly coloured light, scaled to unit luminance;
    returns (colour, kind)."""
    kind = pick(rng, [("warm", 0.35), ("neutral", 0.25), ("cool", 0.15), ("coloured", 0.25)])
    if kind == "warm":
        c = [1.0, rng.uniform(0.7, 0.85), rng.uniform(0.45, 0.65)]
    elif kind == "neutral":
        c = [1.0, 1.0, 1.0]
    elif kind == "cool":
        c = [rng.uniform(0.75, 0.9), rng.uniform(0.85, 0.95), 1.0]
    else:
        c = [max(x, 0.05) for x in hsv(rng.random(), rng.uniform(0.5, 0.85), 1.0)]
    y = luminance(c)
    return [round(x / y, 4) for x in c], kind


def overlaps(a, b, gap=0.0):
    return a[0] < b[2] + gap and b[0] < a[2] + gap and a[1] < b[3] + gap and b[1] < a[3] + gap


def outline(rects):
    """The outer edges of a union of axis-aligned rectangles [x0, y0, x1, y1],
    as (axis, a, b, c, out): an edge along `axis` from a to b at the other
    coordinate c, with the outside on the `out` (+1 or -1) side."""
    xs = sorted({v for r in rects for v in (r[0], r[2])})
    ys = sorted({v for r in rects for v in (r[1], r[3])})

    def inside(i, j):
        if i < 0 or j < 0 or i >= len(xs) - 1 or j >= len(ys) - 1:
            return False
        cx, cy = (xs[i] + xs[i + 1]) / 2, (ys[j] + ys[j + 1]) / 2
        return any(r[0] < cx < r[2] and r[1] < cy < r[3] for r in rects)

    runs = {}
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            if not inside(i, j):
                continue
            for di, dj, key, seg in (
                (0, -1, ("x", ys[j], -1), (xs[i], xs[i + 1])),
                (0, 1, ("x", ys[j + 1], 1), (xs[i], xs[i + 1])),
                (-1, 0, ("y", xs[i], -1), (ys[j], ys[j + 1])),
                (1, 0, ("y", xs[i + 1], 1), (ys[j], ys[j + 1])),
            ):
                if not inside(i + di, j + dj):
                    runs.setdefault(key, []).append(seg)
    edges = []
    for (axis, c, out), segs in sorted(runs.items()):
        segs.sort()
        a, b = segs[0]
        for s0, s1 in segs[1:]:
            if abs(s0 - b) < 1e-9:
                b = s1
            else:
                edges.append((axis, a, b, c, out))
                a, b = s0, s1
        edges.append((axis, a, b, c, out))
    return edges


class Layout:
    """Accumulates one scene. Geometry goes through `box`/`sphere`; the
    footprints cameras must keep out of through `obstacle`."""

    def __init__(self, seed):
        self.rng = random.Random(seed)
        self.seed = seed
        self.boxes, self.spheres, self.emitters = [], [], []
        self.materials = {}
        self.obstacles = []  # [x0, y0, x1, y1, z0, z1]
        self.regions = []  # walkable rectangles
        self.passages = []  # doorways: walkable although next to a wall
        self.lights = []  # what lights the scene, for the summary
        self.world = {"kind": "black"}
        self.sun = None
        self.portals = []  # openings the sky comes in through (Cycles light portals)

    # -- materials -------------------------------------------------------
    def material(self, role):
        rng = self.rng
        if role == "mirror":
            surface = "mirror"
        elif role == "ball":
            surface = pick(rng, [("glossy", 0.4), ("mirror", 0.4), ("diffuse", 0.2)])
        elif role in ("prop", "facade", "floor"):
            surface = pick(rng, [("diffuse", 0.72), ("glossy", 0.22), ("mirror", 0.06)])
        else:
            surface = pick(rng, [("diffuse", 0.88), ("glossy", 0.12)])
        textures = [("none", 0.2), ("noise", 0.2), ("voronoi", 0.15), ("checker", 0.15), ("brick", 0.2), ("wave", 0.1)]
        if role == "ceiling":
            textures = [("none", 0.6), ("noise", 0.4)]
        m = {
            "surface": surface,
            "base": reflectance(rng, lum=(0.55, 0.85) if role == "ceiling" else (0.15, 0.8)),
            "alt": reflectance(rng, lum=(0.04, 0.7)),
            "texture": pick(rng, textures),
            "scale": round(log_uniform(rng, 0.6, 8.0), 3),
            "roughness": round(rng.uniform(0.05, 0.3), 3) if surface == "glossy" else (0.0 if surface == "mirror" else 0.8),
        }
        if surface == "mirror":
            m.update(base=[0.9, 0.9, 0.9], texture="none")
        name = f"{role}{len(self.materials)}"
        self.materials[name] = m
        return name

    # -- geometry --------------------------------------------------------
    def box(self, lo, hi, mat, obstacle=False):
        lo, hi = [round(v, 4) for v in lo], [round(v, 4) for v in hi]
        if any(h - l <= 1e-4 for l, h in zip(lo, hi)):
            return
        self.boxes.append({"min": lo, "max": hi, "mat": mat})
        if obstacle:
            self.obstacle(lo[0], lo[1], hi[0], hi[1], lo[2], hi[2])

    def obstacle(self, x0, y0, x1, y1, z0, z1):
        self.obstacles.append([x0, y0, x1, y1, z0, z1])

    def sphere(self, c, r, mat):
        self.spheres.append({"center": [round(v, 4) for v in c], "radius": round(r, 4), "mat": mat})
        self.obstacle(c[0] - r, c[1] - r, c[0] + r, c[1] + r, c[2] - r, c[2] + r)

    def run_with_openings(self, axis, a, b, c0, c1, z0, z1, openings, mat):
        """Boxes filling [a, b] along `axis` ('x' or 'y'), [c0, c1] across it and
        [z0, z1] in height, less the openings [(s0, s1, oz0, oz1)]."""
        pieces, pos = [], a
        for s0, s1, oz0, oz1 in sorted(openings):
            s0, s1 = max(a, s0), min(b, s1)
            if s0 > pos:
                pieces.append((pos, s0, z0, z1))
            pieces += [(s0, s1, z0, oz0), (s0, s1, oz1, z1)]
            pos = max(pos, s1)
        if pos < b:
            pieces.append((pos, b, z0, z1))
        for s0, s1, pz0, pz1 in pieces:
            lo, hi = ([s0, c0, pz0], [s1, c1, pz1]) if axis == "x" else ([c0, s0, pz0], [c1, s1, pz1])
            self.box(lo, hi, mat)

    def plate(self, x0, y0, x1, y1, z0, z1, mat, hole=None):
        """A horizontal slab, with an optional rectangular hole [hx0, hy0, hx1, hy1]."""
        if hole is None:
            self.box([x0, y0, z0], [x1, y1, z1], mat)
            return
        hx0, hy0, hx1, hy1 = hole
        self.box([x0, y0, z0], [hx0, y1, z1], mat)
        self.box([hx1, y0, z0], [x1, y1, z1], mat)
        self.box([hx0, y0, z0], [hx1, hy0, z1], mat)
        self.box([hx0, hy1, z0], [hx1, y1, z1], mat)

    def in_regions(self, x, y, margin):
        return any(r[0] + margin <= x <= r[2] - margin and r[1] + margin <= y <= r[3] - margin for r in self.regions) or \
            any(p[0] <= x <= p[2] and p[1] <= y <= p[3] for p in self.passages)

    def free(self, x, y, margin=MARGIN, band=(0.0, 2.1)):
        """Whether a camera may stand at (x, y): in a walkable region, away from
        every obstacle reaching into the height band."""
        if not self.in_regions(x, y, margin):
            return False
        return not any(o[0] - margin < x < o[2] + margin and o[1] - margin < y < o[3] + margin
                       for o in self.obstacles if o[5] > band[0] and o[4] < band[1])

    def segment_free(self, p, q, step=0.1):
        n = max(1, int(math.dist(p, q) / step))
        return all(self.free(p[0] + (q[0] - p[0]) * k / n, p[1] + (q[1] - p[1]) * k / n) for k in range(n + 1))

    def footprint(self, w, d, region, gap=0.45, tries=60, wall_side=0.6):
        """A free footprint [x0, y0, x1, y1] of w x d (either way round) inside
        region, against a wall with probability wall_side; None if none fits."""
        rng = self.rng
        x0, y0, x1, y1 = region
        for _ in range(tries):
            if rng.random() < 0.5:
                w, d = d, w
            if x1 - x0 < w + 0.1 or y1 - y0 < d + 0.1:
                continue
            if rng.random() < wall_side:
                edge = rng.randrange(4)
                px = [x0 + 0.02, x1 - w - 0.02, rng.uniform(x0, x1 - w), rng.uniform(x0, x1 - w)][edge]
                py = [rng.uniform(y0, y1 - d), rng.uniform(y0, y1 - d), y0 + 0.02, y1 - d - 0.02][edge]
            else:
                px, py = rng.uniform(x0, x1 - w), rng.uniform(y0, y1 - d)
            r = [px, py, px + w, py + d]
            if not any(overlaps(r, o, gap) for o in self.obstacles):
                return r
        return None

    def emit_sphere(self, c, r, radiance, col, kind):
        self.emitters.append({"shape": "sphere", "center": [round(v, 4) for v in c], "radius": round(r, 4),
                              "colour": col, "radiance": round(radiance, 3)})
        self.lights.append({"type": kind, "position": [round(v, 3) for v in c], "radius_m": round(r, 4),
                            "radiance": round(radiance, 1), "colour": col})
        if c[2] - r < 2.1:
            self.obstacle(c[0] - r, c[1] - r, c[0] + r, c[1] + r, c[2] - r, c[2] + r)

    def emit_panel(self, lo, hi, radiance, col):
        self.emitters.append({"shape": "box", "min": [round(v, 4) for v in lo], "max": [round(v, 4) for v in hi],
                              "colour": col, "radiance": round(radiance, 3)})
        self.lights.append({"type": "panel", "position": [round((a + b) / 2, 3) for a, b in zip(lo, hi)],
                            "size_m": [round(b - a, 3) for a, b in zip(lo, hi)], "radiance": round(radiance, 1),
                            "colour": col})

    def portal(self, centre, rotation_deg, size_x, size_y):
        self.portals.append({"center": [round(v, 4) for v in centre], "rotation_deg": rotation_deg,
                             "size": [round(size_x, 4), round(size_y, 4)]})

    # -- sky -------------------------------------------------------------
    def daylight(self, sun_prob=0.85, elevation=(8.0, 65.0)):
        rng = self.rng
        if rng.random() < 0.5:
            elev, azim = rng.uniform(*elevation), rng.uniform(0.0, 360.0)
            has_sun = rng.random() < sun_prob
            self.world = {"kind": "sky", "sun_elevation_deg": round(elev, 3), "sun_azimuth_deg": round(azim, 3),
                          "air": round(rng.uniform(0.5, 2.0), 3), "dust": round(rng.uniform(0.0, 3.0), 3)}
            self.lights.append({"type": "sky", "model": "nishita"})
            if has_sun:
                e, a = math.radians(elev), math.radians(azim)
                # Blender's sky model puts its sun at azimuth a from +y towards +x.
                d = [math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)]
                self.sun = {"direction": [round(v, 6) for v in d], "diameter_deg": SUN_DIAMETER_DEG,
                            "radiance": round(log_uniform(rng, 6e4, 5e5), 1), "colour": [1.0, 0.96, 0.9]}
                self.lights.append({"type": "sun", "direction": self.sun["direction"],
                                    "radiance": self.sun["radiance"]})
        else:
            name = rng.choice(DAY_WORLDS)
            self.world = {"kind": "hdri", "name": name, "rotation_deg": round(rng.uniform(0.0, 360.0), 3)}
            self.lights.append({"type": "sky", "model": f"captured:{name}"})

    def night(self, seen=True):
        """A night sky: the captured night world, or the sky model at dusk (sun
        2-8 degrees below the horizon), dimmed to a median of 1e-3-2e-2. A sky
        that is seen is never black: a black sky and the median-metered gain
        clipped half of a night street. A closed room's sky is never seen."""
        rng = self.rng
        if rng.random() < 0.5:
            self.world = {"kind": "hdri", "name": "night", "rotation_deg": round(rng.uniform(0, 360), 3),
                          "median": round(log_uniform(rng, 1e-3, 2e-2), 5)}
            self.lights.append({"type": "sky", "model": "captured:night"})
        elif seen:
            self.world = {"kind": "sky", "sun_elevation_deg": round(-rng.uniform(2.0, 8.0), 3),
                          "sun_azimuth_deg": round(rng.uniform(0.0, 360.0), 3), "air": 1.0, "dust": 1.0,
                          "median": round(log_uniform(rng, 1e-3, 2e-2), 5)}
            self.lights.append({"type": "sky", "model": "nishita:dusk"})
        else:
            self.world = {"kind": "black"}

    # -- the walk and the probes ----------------------------------------
    def random_free_point(self, tries=400):
        rng = self.rng
        for _ in range(tries):
            r = rng.choice(self.regions)
            p = (rng.uniform(r[0], r[2]), rng.uniform(r[1], r[3]))
            if self.free(*p):
                return p
        return None

    def walk_polyline(self, length):
        rng = self.rng
        for _ in range(200):
            start = self.random_free_point()
            if start is None:
                break
            pts, total = [start], 0.0
            for _ in range(40):
                if total >= length:
                    break
                ang = rng.uniform(0, 2 * math.pi)
                if len(pts) > 1:  # mostly onwards
                    prev = math.atan2(pts[-1][1] - pts[-2][1], pts[-1][0] - pts[-2][0])
                    ang = prev + rng.uniform(-1.3, 1.3)
                step = min(rng.uniform(1.2, 5.0), length - total)
                q = (pts[-1][0] + step * math.cos(ang), pts[-1][1] + step * math.sin(ang))
                if self.segment_free(pts[-1], q):
                    pts.append(q)
                    total += step
            if total >= 0.8 * length:
                return pts
        raise RuntimeError(f"seed {self.seed}: no free walk of {length:.1f} m")

    def camera_path(self, n_frames, length):
        """Frame poses along a smoothed walk, heading along it with hand-held
        wobble, and the polyline (for placing probes)."""
        rng = self.rng
        pts = None
        while pts is None:
            try:
                pts = self.walk_polyline(length)
            except RuntimeError:
                if length < 2.0:
                    raise
                length *= 0.75
        for _ in range(2):  # Chaikin smoothing, kept only where it stays free
            sm = [pts[0]]
            for a, b in zip(pts, pts[1:]):
                sm += [(0.75 * a[0] + 0.25 * b[0], 0.75 * a[1] + 0.25 * b[1]),
                       (0.25 * a[0] + 0.75 * b[0], 0.25 * a[1] + 0.75 * b[1])]
            sm.append(pts[-1])
            if all(self.segment_free(a, b) for a, b in zip(sm, sm[1:])):
                pts = sm
        cum = [0.0]
        for a, b in zip(pts, pts[1:]):
            cum.append(cum[-1] + math.dist(a, b))

        def at(s):
            for k in range(len(pts) - 1):
                if s <= cum[k + 1] or k == len(pts) - 2:
                    t = (s - cum[k]) / max(cum[k + 1] - cum[k], 1e-9)
                    a, b = pts[k], pts[k + 1]
                    return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])), (b[0] - a[0], b[1] - a[1])
            return pts[-1], (1.0, 0.0)

        amp = [rng.uniform(1.0, 4.0), rng.uniform(0.5, 2.5), rng.uniform(0.5, 2.5)]
        per = [rng.uniform(3.0, 9.0) for _ in range(3)]
        phase = [rng.uniform(0, 2 * math.pi) for _ in range(3)]
        height = EYE + rng.uniform(-0.1, 0.1)
        frames = []
        for i in range(n_frames):
            s = cum[-1] * i / (n_frames - 1)
            (x, y), (tx, ty) = at(s)
            wob = [amp[k] * math.sin(2 * math.pi * i / per[k] + phase[k]) + rng.gauss(0, 0.3) for k in range(3)]
            yaw = math.degrees(math.atan2(-tx, ty)) + wob[0]
            z = height + 0.02 * math.sin(2 * math.pi * i / 2.0)
            frames.append({"position": [round(x, 4), round(y, 4), round(z, 4)],
                           "yaw_pitch_roll_deg": [round(yaw, 4), round(wob[1], 4), round(wob[2], 4)]})
        return frames, at, cum[-1]

    def probes_along(self, n, at, length):
        """n probes, each 0.2-2.2 m to the side of a random point of the walk
        (half the time leaving the walk's ends beyond every probe)."""
        rng = self.rng
        lo, hi = (0.15, 0.85) if rng.random() < 0.5 else (0.0, 1.0)
        probes = []
        for _ in range(n):
            spot = None
            for _ in range(80):
                (x, y), (tx, ty) = at(length * rng.uniform(lo, hi))
                norm = math.hypot(tx, ty) or 1.0
                side = rng.choice([-1, 1]) * rng.uniform(0.2, 2.2)
                p = (x - ty / norm * side, y + tx / norm * side)
                if self.free(*p) and all(math.dist(p, q["position"][:2]) > 0.5 for q in probes):
                    spot = p
                    break
            if spot is None:
                spot = self.random_free_point()
            if spot is None:
                continue
            probes.append({"position": [round(spot[0], 4), round(spot[1], 4), round(rng.uniform(1.2, 1.7), 4)],
                           "yaw_pitch_roll_deg": [round(rng.uniform(-180, 180), 4), 0.0, 0.0]})
        if len(probes) < 2:
            raise RuntimeError(f"seed {self.seed}: room for fewer than two probes")
        return probes


# -- indoor scenes --------------------------------------------------------
def floor_plan(L, kind):
    rng = L.rng
    if kind == "room":
        w = rng.uniform(3.0, 12.0)
        d = rng.uniform(max(3.0, w / 3), min(12.0, w * 3))
        return [[0.0, 0.0, w, d]], []
    if kind == "lroom":
        w, d = rng.uniform(5.0, 12.0), rng.uniform(5.0, 12.0)
        cw, cd = w * rng.uniform(0.35, 0.6), d * rng.uniform(0.35, 0.6)
        return [[0.0, 0.0, w, d - cd], [0.0, d - cd, w - cw, d]], []
    wa, wb = rng.uniform(3.0, 7.0), rng.uniform(3.0, 7.0)
    da, db = rng.uniform(3.0, 8.0), rng.uniform(3.0, 8.0)
    yb = rng.uniform(-(db - 1.6), da - 1.6)
    a, b = [0.0, 0.0, wa, da], [wa, yb, wa + wb, yb + db]
    o0, o1 = max(0.0, yb), min(da, yb + db)
    dw = rng.uniform(0.8, 1.2)
    ds = rng.uniform(o0 + 0.1, o1 - dw - 0.1)
    door = (ds, ds + dw, 0.0, rng.uniform(2.0, 2.2))
    return [a, b], [("y", o0, o1, wa, door)]


def indoor(L, kind):
    rng = L.rng
    H = rng.uniform(2.4, 4.0)
    rects, inner = floor_plan(L, kind)
    L.regions = [list(r) for r in rects]
    lighting = pick(rng, [("night", 0.3), ("day", 0.3), ("roof", 0.15), ("mixed", 0.25)])
    wall_mat, floor_mat, ceil_mat = L.material("wall"), L.material("floor"), L.material("ceiling")
    xs = [v for r in rects for v in (r[0], r[2])]
    ys = [v for r in rects for v in (r[1], r[3])]
    bbox = [min(xs), min(ys), max(xs), max(ys)]

    # Floor inside, ground outside (seen through windows), a little lower.
    L.box([bbox[0] - WALL, bbox[1] - WALL, -0.1], [bbox[2] + WALL, bbox[3] + WALL, 0.0], floor_mat)
    L.box([bbox[0] - 80, bbox[1] - 80, -0.3], [bbox[2] + 80, bbox[3] + 80, -0.02], L.material("floor"))

    windows = lighting in ("day", "mixed") or (lighting == "night" and rng.random() < 0.3)
    edges = outline(rects)
    openings = {k: [] for k in range(len(edges))}
    if windows:
        for _ in range(rng.randint(1, 4)):
            k = rng.randrange(len(edges))
            axis, a, b, c, out = edges[k]
            if b - a < 1.4:
                continue
            w = rng.uniform(0.8, min(2.6, b - a - 0.4))
            s = rng.uniform(a + 0.2, b - w - 0.2)
            sill = rng.uniform(0.5, 1.0) if rng.random() < 0.8 else 0.0
            top = min(H - 0.15, sill + rng.uniform(1.0, 2.0))
            if any(s < o[1] + 0.3 and o[0] < s + w + 0.3 for o in openings[k]):
                continue
            openings[k].append((s, s + w, sill, top))
            # A portal on the wall's inner face, its emitting side (local -z) inwards.
            mid, zc = s + w / 2, (sill + top) / 2
            if axis == "x":
                L.portal([mid, c, zc], [-90.0 * out, 0.0, 0.0], w, top - sill)
            else:
                L.portal([c, mid, zc], [0.0, 90.0 * out, 0.0], top - sill, w)
            L.lights.append({"type": "window", "size_m": [round(w, 3), round(top - sill, 3)]})
    for k, (axis, a, b, c, out) in enumerate(edges):
        c0, c1 = sorted((c, c + out * WALL))
        L.run_with_openings(axis, a - WALL, b + WALL, c0, c1, 0.0, H, openings[k], wall_mat)
    for axis, a, b, c, door in inner:
        L.run_with_openings(axis, a, b, c - WALL / 2, c + WALL / 2, 0.0, H, [door], wall_mat)
        L.obstacle(c - WALL / 2, a, c + WALL / 2, door[0], 0.0, H)
        L.obstacle(c - WALL / 2, door[1], c + WALL / 2, b, 0.0, H)
        L.passages.append([c - 0.5, door[0] + 0.25, c + 0.5, door[1] - 0.25])
        # A door frame: posts that hide part of the next room.
        L.box([c - 0.12, door[0] - 0.05, 0.0], [c + 0.12, door[0], door[3]], wall_mat)
        L.box([c - 0.12, door[1], 0.0], [c + 0.12, door[1] + 0.05, door[3]], wall_mat)

    # Ceilings, one with a roof opening and a shaft above it.
    hole_rect = None
    if lighting == "roof":
        r = rng.choice(rects)
        hw, hd = rng.uniform(0.6, min(2.2, r[2] - r[0] - 1.0)), rng.uniform(0.6, min(2.2, r[3] - r[1] - 1.0))
        hx, hy = rng.uniform(r[0] + 0.5, r[2] - hw - 0.5), rng.uniform(r[1] + 0.5, r[3] - hd - 0.5)
        hole_rect = (r, [hx, hy, hx + hw, hy + hd])
        shaft = rng.uniform(0.1, 1.6)
        z0, z1 = H + 0.15, H + 0.15 + shaft
        L.box([hx - 0.1, hy - 0.1, z0], [hx, hy + hd + 0.1, z1], wall_mat)
        L.box([hx + hw, hy - 0.1, z0], [hx + hw + 0.1, hy + hd + 0.1, z1], wall_mat)
        L.box([hx, hy - 0.1, z0], [hx + hw, hy, z1], wall_mat)
        L.box([hx, hy + hd, z0], [hx + hw, hy + hd + 0.1, z1], wall_mat)
        L.portal([hx + hw / 2, hy + hd / 2, H], [0.0, 0.0, 0.0], hw, hd)
        L.lights.append({"type": "roof_opening", "size_m": [round(hw, 3), round(hd, 3)], "shaft_m": round(shaft, 3)})
    for r in rects:
        hole = hole_rect[1] if hole_rect and hole_rect[0] is r else None
        L.plate(r[0] - WALL, r[1] - WALL, r[2] + WALL, r[3] + WALL, H, H + 0.15, ceil_mat, hole)

    furnish(L, rects, H, edges)
    if lighting in ("day", "mixed", "roof"):
        L.daylight(elevation=(10.0, 60.0) if lighting != "roof" else (35.0, 80.0))
    else:
        L.night(seen=windows)
    n_lamps = {"night": rng.randint(1, 5), "day": rng.randint(0, 2), "roof": rng.randint(1, 2), "mixed": rng.randint(1, 3)}[lighting]
    n_panels = {"night": rng.randint(0, 2), "day": rng.randint(0, 1), "roof": 0, "mixed": rng.randint(0, 2)}[lighting]
    if lighting == "night" and n_lamps + n_panels == 0:
        n_lamps = 1
    lamps(L, rects, H, n_lamps, n_panels)
    return {"kind": kind, "lighting": lighting, "ceiling_m": round(H, 3), "floor_plan": [[round(v, 3) for v in r] for r in rects],
            # Daylight indoors comes mostly off small sunlit patches and through
            # openings: twice the samples for a comparable noise level.
            "samples_factor": 2 if lighting in ("day", "mixed", "roof") else 1}


def furnish(L, rects, H, edges):
    rng = L.rng
    for _ in range(rng.randint(2, 8)):
        r = rng.choice(rects)
        what = pick(rng, [("table", 0.25), ("shelf", 0.25), ("cabinet", 0.2), ("sofa", 0.1), ("partition", 0.12), ("pillar", 0.08)])
        size = {"table": (rng.uniform(0.8, 1.6), rng.uniform(0.6, 1.0), rng.uniform(0.72, 0.8)),
                "shelf": (rng.uniform(0.8, 2.0), rng.uniform(0.3, 0.45), rng.uniform(1.6, 2.2)),
                "cabinet": (rng.uniform(0.8, 2.4), rng.uniform(0.5, 0.6), rng.uniform(0.85, 0.95)),
                "sofa": (rng.uniform(1.6, 2.4), rng.uniform(0.8, 1.0), 0.45),
                "partition": (rng.uniform(1.2, 2.6), 0.1, rng.uniform(1.9, 2.4)),
                "pillar": (0.3, 0.3, H)}[what]
        f = L.footprint(size[0], size[1], r, wall_side=0.0 if what in ("pillar", "partition") else 0.7)
        if f is None:
            continue
        mat = L.material("prop")
        x0, y0, x1, y1 = f
        h = size[2]
        if what == "table":
            L.box([x0, y0, h - 0.04], [x1, y1, h], mat)
            for lx, ly in ((x0, y0), (x1 - 0.05, y0), (x0, y1 - 0.05), (x1 - 0.05, y1 - 0.05)):
                L.box([lx, ly, 0.0], [lx + 0.05, ly + 0.05, h - 0.04], mat)
            L.obstacle(x0, y0, x1, y1, 0.0, h)
            if rng.random() < 0.5:
                rad = rng.uniform(0.08, 0.2)
                L.sphere([(x0 + x1) / 2 + rng.uniform(-0.2, 0.2), (y0 + y1) / 2, h + rad], rad, L.material("ball"))
        elif what == "sofa":
            L.box([x0, y0, 0.0], [x1, y1, h], mat, obstacle=True)
            if x1 - x0 > y1 - y0:
                L.box([x0, y0, h], [x1, y0 + 0.2, 0.85], mat, obstacle=True)
            else:
                L.box([x0, y0, h], [x0 + 0.2, y1, 0.85], mat, obstacle=True)
        else:
            L.box([x0, y0, 0.0], [x1, y1, h], mat, obstacle=True)
    for _ in range(rng.randint(0, 3)):  # balls on the floor
        p = L.random_free_point()
        if p:
            rad = rng.uniform(0.1, 0.3)
            L.sphere([p[0], p[1], rad], rad, L.material("ball"))
    for _ in range(rng.randint(1, 5)):  # posters and mirrors on the walls
        axis, a, b, c, out = rng.choice(edges)
        if b - a < 1.0:
            continue
        w = rng.uniform(0.4, min(1.6, b - a - 0.4))
        s = rng.uniform(a + 0.2, b - w - 0.2)
        z0 = rng.uniform(0.9, 1.5)
        z1 = min(H - 0.1, z0 + rng.uniform(0.4, 1.2))
        mat = L.material("mirror") if rng.random() < 0.2 else L.material("prop")
        c0, c1 = sorted((c, c - out * 0.015))
        lo, hi = ([s, c0, z0], [s + w, c1, z1]) if axis == "x" else ([c0, s, z0], [c1, s + w, z1])
        L.box(lo, hi, mat)


def lamps(L, rects, H, n_lamps, n_panels):
    rng = L.rng
    for _ in range(n_lamps):
        r = rng.choice(rects)
        kind = pick(rng, [("pendant", 0.35), ("ceiling", 0.25), ("floor_lamp", 0.25), ("low", 0.15)])
        rad = log_uniform(rng, 0.015, 0.1)
        x, y = rng.uniform(r[0] + 0.3, r[2] - 0.3), rng.uniform(r[1] + 0.3, r[3] - 0.3)
        z = {"pendant": H - rng.uniform(0.3, 0.9), "ceiling": H - rad - 0.01,
             "floor_lamp": rng.uniform(1.3, 1.8), "low": rng.uniform(0.3, 1.0)}[kind]
        col, _ = light_colour(rng)
        L.emit_sphere([x, y, z], rad, log_uniform(rng, 2e2, 3e4), col, "lamp")
    for _ in range(n_panels):
        r = rng.choice(rects)
        w, d = rng.uniform(0.3, 1.2), rng.uniform(0.3, 1.2)
        x, y = rng.uniform(r[0] + 0.2, r[2] - w - 0.2), rng.uniform(r[1] + 0.2, r[3] - d - 0.2)
        col, _ = light_colour(rng)
        L.emit_panel([x, y, H - 0.03], [x + w, y + d, H - 0.001], log_uniform(rng, 30.0, 1e3), col)


# -- outdoor scenes -------------------------------------------------------
def outdoor(L, kind):
    rng = L.rng
    ground = L.material("floor")
    if kind == "courtyard":
        X, Y = rng.uniform(10.0, 24.0), rng.uniform(10.0, 24.0)
    else:
        X, Y = rng.uniform(20.0, 40.0), rng.uniform(6.0, 12.0)
    L.regions = [[0.0, 0.0, X, Y]]
    L.box([-150, -150, -0.3], [X + 150, Y + 150, 0.0], ground)
    sides = ("x-", "x+", "y-", "y+") if kind == "courtyard" else ("y-", "y+")
    for side in sides:
        along = X if side[0] == "x" else Y
        pos = rng.uniform(-4.0, 0.0)
        while pos < along + 4.0:
            w = rng.uniform(4.0, 12.0)
            if rng.random() < 0.25:  # a street between blocks
                pos += rng.uniform(3.0, 7.0)
                continue
            depth, h = rng.uniform(4.0, 10.0), rng.uniform(4.0, 18.0)
            mat = L.material("facade")
            if side == "y-":
                L.box([pos, -depth, 0.0], [pos + w, 0.0, h], mat)
            elif side == "y+":
                L.box([pos, Y, 0.0], [pos + w, Y + depth, h], mat)
            elif side == "x-":
                L.box([-depth, pos, 0.0], [0.0, pos + w, h], mat)
            else:
                L.box([X, pos, 0.0], [X + depth, pos + w, h], mat)
            pos += w
    for _ in range(rng.randint(3, 8)):  # far buildings
        ang, dist = rng.uniform(0, 2 * math.pi), rng.uniform(30.0, 70.0)
        cx, cy = X / 2 + dist * math.cos(ang), Y / 2 + dist * math.sin(ang)
        s, h = rng.uniform(6.0, 20.0), rng.uniform(6.0, 30.0)
        L.box([cx - s / 2, cy - s / 2, 0.0], [cx + s / 2, cy + s / 2, h], L.material("facade"))
    for _ in range(rng.randint(4, 12)):
        what = pick(rng, [("container", 0.2), ("crate", 0.35), ("pole", 0.15), ("car", 0.15), ("bench", 0.15)])
        size = {"container": (6.0, 2.4, 2.6), "crate": (rng.uniform(0.5, 1.2),) * 2 + (rng.uniform(0.5, 1.2),),
                "pole": (0.12, 0.12, rng.uniform(3.0, 6.0)), "car": (4.2, 1.8, 1.4), "bench": (1.8, 0.5, 0.45)}[what]
        f = L.footprint(size[0], size[1], L.regions[0], gap=0.8, wall_side=0.4)
        if f:
            L.box([f[0], f[1], 0.0], [f[2], f[3], size[2]], L.material("prop"), obstacle=True)
            if what == "crate" and rng.random() < 0.4:
                t = size[0] * 0.8
                L.box([f[0] + 0.05, f[1] + 0.05, size[2]], [f[0] + 0.05 + t, f[1] + 0.05 + t, size[2] + t],
                      L.material("prop"), obstacle=True)
    for _ in range(rng.randint(0, 3)):
        p = L.random_free_point()
        if p:
            rad = rng.uniform(0.2, 0.5)
            L.sphere([p[0], p[1], rad], rad, L.material("ball"))
    lighting = "night" if rng.random() < 0.25 else "day"
    if lighting == "day":
        L.daylight(sun_prob=0.9, elevation=(5.0, 70.0))
        n = rng.randint(0, 1)
    else:
        L.night()
        n = rng.randint(2, 6)
    for _ in range(n):  # street lamps on poles
        p = L.random_free_point()
        if not p:
            continue
        h = rng.uniform(3.0, 6.0)
        L.box([p[0] - 0.05, p[1] - 0.05, 0.0], [p[0] + 0.05, p[1] + 0.05, h], L.material("prop"), obstacle=True)
        col, _ = light_colour(rng)
        L.emit_sphere([p[0], p[1], h + 0.15], rng.uniform(0.06, 0.2), log_uniform(rng, 1e2, 2e4), col, "street_lamp")
    return {"kind": kind, "lighting": lighting, "site_m": [round(X, 3), round(Y, 3)], "samples_factor": 1}


def make(seed):
    """The scene description of a seed (a dict, JSON-ready)."""
    L = Layout(seed)
    rng = L.rng
    kind = pick(rng, [("room", 0.24), ("lroom", 0.2), ("two_rooms", 0.2), ("courtyard", 0.2), ("street", 0.16)])
    info = indoor(L, kind) if kind in ("room", "lroom", "two_rooms") else outdoor(L, kind)
    indoors = kind in ("room", "lroom", "two_rooms")
    n_frames = rng.randint(15, 30)
    frames, at, length = L.camera_path(n_frames, rng.uniform(2.5, 9.0) if indoors else rng.uniform(6.0, 20.0))
    probes = L.probes_along(rng.randint(2, 6), at, length)
    for i, p in enumerate(probes):
        p["id"] = f"probe_{i:02d}"
    for i, f in enumerate(frames):
        f["id"] = f"frame_{i:03d}"
    return {
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "scene": info,
        "walk_length_m": round(length, 3),
        "materials": L.materials,
        "boxes": L.boxes,
        "spheres": L.spheres,
        "emitters": L.emitters,
        "world": L.world,
        "sun": L.sun,
        "portals": L.portals if kind in ("room", "lroom", "two_rooms") else [],
        "lights": L.lights,
        "probes": probes,
        "frames": frames,
    }


if __name__ == "__main__":
    import json
    import sys
    for s in sys.argv[1:]:
        d = make(int(s))
        print(s, d["scene"]["kind"], d["scene"]["lighting"], len(d["boxes"]), "boxes", len(d["emitters"]), "emitters",
              len(d["probes"]), "probes", len(d["frames"]), "frames", d["walk_length_m"], "m",
              json.dumps(d["world"]))
