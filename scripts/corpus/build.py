#!/usr/bin/env python3
"""Builds the ground-truth scene corpus: one scene per seed, rendered by
Blender Cycles (CPU, headless) and written in the layout of
../shared/data/scenes/* so that every lumiprobe command runs on it unchanged.

  build.py --out DIR --seeds 0-23 [--size 256x128] [--samples 64] [--background]
  build.py --out DIR --summary          # the corpus summary table (text)

Each scene goes to DIR/s<seed>_<W>x<H>/: poses.json, probes/probe_XX.exr with
both bracket sets (JPEG with Exif exposure), path/frame_XXX.jpg SDR frames,
path/frame_XXX_gt.exr ground truth, summary.json (lights, dynamic range,
clipped fraction, distances to the probes, render time) and the layout it was
made from (spec.json). DIR/corpus.json lists every finished scene with its
split: seeds divisible by 3 are validation scenes, the others development.

Resumable and cached: a scene whose .done stamp matches the generator version,
seed, size, samples and Blender version is skipped; an interrupted scene keeps
the panoramas it finished. Only one build runs on a folder at a time.
Needs Blender (Debian: blender) and Python 3 with numpy and OpenCV (Debian:
python3-numpy, python3-opencv). Never part of the Rust product's run path.
"""

import argparse
import fcntl
import json
import math
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import layout  # noqa: E402

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

BRACKETS = list(range(-3, 4))  # the thesis's seven brackets, 1 EV apart
BRACKETS_WIDE = list(range(-12, 3, 2))  # a light-probe photographer's set, 2 EV apart
BASE_EXPOSURE_S = 1.0 / 60.0
F_NUMBER = 2.2
ISO = 100
# Bump when scene.py or finish() change what a layout renders to.
RENDER_VERSION = "1"
CLIP_CODE = 250  # lumiprobe's clipped code (warp::CLIP_CODE), for the summary
RESPONSE = ("f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2))), x = exposure-scaled linear radiance; "
            "Gaussian noise sigma = 0.002 + 0.01*sqrt(x) added before the response; 8-bit")


def need_numpy():
    try:
        import cv2  # noqa: F401
        import numpy  # noqa: F401
    except ImportError:
        sys.exit("build.py needs numpy and OpenCV for Python (Debian: apt install python3-numpy python3-opencv)")


def write_atomic(path, data):
    tmp = path + ".part"
    with open(tmp, "wb" if isinstance(data, bytes) else "w") as f:
        f.write(data)
    os.replace(tmp, path)


def write_json(path, obj):
    write_atomic(path, json.dumps(obj, indent=1) + "\n")


def seeds_of(text):
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        try:
            lo, hi = int(a), int(b or a)
        except ValueError:
            sys.exit(f"--seeds {text}: not a list of seeds such as 0-23,40")
        if lo > hi or lo < 0:
            sys.exit(f"--seeds {text}: {part} is not an increasing range of non-negative seeds")
        out += range(lo, hi + 1)
    return out


def blender_version(blender):
    try:
        out = subprocess.run([blender, "--version"], capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.TimeoutExpired) as e:
        sys.exit(f"{blender}: cannot run Blender ({e}); Debian: apt install blender")
    line = out.strip().splitlines()[0] if out.strip() else ""
    if not line.startswith("Blender"):
        sys.exit(f"{blender}: does not answer --version like Blender")
    return line


def split_of(seed):
    return "val" if seed % 3 == 0 else "dev"


# -- camera model (../shared/data/README.md) ---------------------------------
def world_from_camera(ypr):
    """Blender's camera rotation: Euler XYZ (90 + pitch, roll, yaw) degrees."""
    import numpy as np
    y, p, r = (math.radians(v) for v in ypr)
    ax = math.radians(90.0) + p
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(r), 0, math.sin(r)], [0, 1, 0], [-math.sin(r), 0, math.cos(r)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return (rz @ ry @ rx).tolist()


def camera_codes(radiance, gain, rng):
    """8-bit codes of a linear image through the documented noise and response."""
    import numpy as np
    x = gain * radiance.astype(np.float64)
    x = x + rng.normal(size=x.shape) * (0.002 + 0.01 * np.sqrt(np.maximum(x, 0.0)))
    y = np.maximum(x, 0.0) ** (1.0 / 2.2)
    return np.round(np.minimum(1.0, 1.08 * y / (1.0 + 0.08 * y)) * 255.0).astype(np.uint8)


def exif_block(exposure_s):
    """A minimal big-endian Exif APP1 segment: ExposureTime, FNumber, ISO."""
    from fractions import Fraction
    import struct
    t = Fraction(exposure_s).limit_denominator(1 << 30)
    f = Fraction(F_NUMBER).limit_denominator(100)
    # TIFF header, IFD0 with one entry (the Exif IFD pointer), then the Exif IFD.
    ifd0_at, exif_at = 8, 8 + 2 + 12 + 4
    data_at = exif_at + 2 + 3 * 12 + 4
    tiff = b"MM\x00\x2a" + struct.pack(">I", ifd0_at)
    tiff += struct.pack(">H", 1) + struct.pack(">HHII", 0x8769, 4, 1, exif_at) + struct.pack(">I", 0)
    tiff += struct.pack(">H", 3)
    tiff += struct.pack(">HHII", 0x829A, 5, 1, data_at)
    tiff += struct.pack(">HHII", 0x829D, 5, 1, data_at + 8)
    tiff += struct.pack(">HHIHH", 0x8827, 3, 1, ISO, 0)
    tiff += struct.pack(">I", 0)
    tiff += struct.pack(">II", t.numerator, t.denominator) + struct.pack(">II", f.numerator, f.denominator)
    body = b"Exif\x00\x00" + tiff
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def write_jpeg(path, codes_rgb, quality, exposure_s=None):
    import cv2
    ok, buf = cv2.imencode(".jpg", codes_rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        sys.exit(f"{path}: JPEG encoding failed")
    data = buf.tobytes()
    if exposure_s is not None:
        data = data[:2] + exif_block(exposure_s) + data[2:]
    write_atomic(path, data)


def composed(scene_dir, view_id):
    """The ground truth of one view: Blender's render plus the analytic
    footprints of the small emitters (scene.py)."""
    import numpy as np
    img = read_exr(os.path.join(scene_dir, "render", view_id + ".exr"))
    for e in json.load(open(os.path.join(scene_dir, "render", view_id + ".emitters.json"))):
        rad = np.array(e["colour"], dtype=np.float64) * e["radiance"]
        for row, col, cover in e["pixels"]:
            img[row, col] += (rad * cover).astype(np.float32)
    return img


def write_exr(path, img):
    import cv2
    tmp = path[:-4] + ".part.exr"
    if not cv2.imwrite(tmp, img[:, :, ::-1].astype("float32"), [cv2.IMWRITE_EXR_TYPE, cv2.IMWRITE_EXR_TYPE_FLOAT]):
        sys.exit(f"{path}: cannot write the EXR")
    os.replace(tmp, path)


def read_exr(path):
    import cv2
    a = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if a is None or a.ndim != 3:
        sys.exit(f"{path}: cannot read the rendered EXR")
    return a[:, :, ::-1].astype("float32")  # RGB


def lum(a):
    return a[..., 0] * 0.2126 + a[..., 1] * 0.7152 + a[..., 2] * 0.0722


# -- one scene ----------------------------------------------------------------
def finish(scene_dir, spec, size, render_s, blender):
    """Brackets, SDR frames, poses.json and summary.json from the renders."""
    import numpy as np
    w, h = size
    name = os.path.basename(scene_dir)
    gts = []
    for f in spec["frames"]:
        gts.append(composed(scene_dir, f["id"]))
        write_exr(os.path.join(scene_dir, "path", f["id"] + "_gt.exr"), gts[-1])
    all_l = np.concatenate([lum(g).ravel() for g in gts])
    median = float(np.median(all_l))
    if not median > 0:  # a mostly black walk: fall back to the mean
        median = float(np.mean(all_l))
    gain = 0.18 / median
    camera = {
        "projection": "equirectangular",
        "pixel_to_camera_direction": "phi = (u - 0.5) * 2*pi, theta = (0.5 - v) * pi with u = (col + 0.5) / W, "
                                     "v = (row + 0.5) / H; d_cam = (cos(theta) sin(phi), sin(theta), "
                                     "-cos(theta) cos(phi)) in camera axes x right, y up, -z forward",
        "world_axes": "right-handed, z up (metres)",
        "world_from_camera": "3x3 rotation, world_direction = world_from_camera @ d_cam",
        "response": RESPONSE,
        "path_gain": gain,
        "bracket_gain_at_0ev": gain,
        "bracket_base_exposure_time_s": BASE_EXPOSURE_S,
        "sdr_linear_from_8bit": "x = f^-1(code / 255) / path_gain gives scene radiance in the units of the "
                                "ground-truth EXRs",
    }
    probes = []
    for k, p in enumerate(spec["probes"]):
        hdr = composed(scene_dir, p["id"])
        write_exr(os.path.join(scene_dir, "probes", p["id"] + ".exr"), hdr)
        entry = {"id": p["id"], "position": p["position"], "yaw_pitch_roll_deg": p["yaw_pitch_roll_deg"],
                 "world_from_camera": world_from_camera(p["yaw_pitch_roll_deg"])}
        for key, evs, sub in (("brackets", BRACKETS, ""), ("brackets_wide", BRACKETS_WIDE, "wide")):
            folder = os.path.join(scene_dir, "probes", p["id"], sub)
            os.makedirs(folder, exist_ok=True)
            entry[key] = []
            for ev in evs:
                rel = os.path.join("probes", p["id"], sub, f"ev{ev:+d}.jpg")
                t = BASE_EXPOSURE_S * 2.0 ** ev
                rng = np.random.default_rng([spec["seed"], 1, k, ev + 100])
                write_jpeg(os.path.join(scene_dir, rel), camera_codes(hdr, gain * 2.0 ** ev, rng), 92, t)
                entry[key].append({"file": rel, "ev": ev, "exposure_time_s": t})
        entry["hdr"] = os.path.join("probes", p["id"] + ".exr")
        probes.append(entry)
    frames, clipped = [], []
    for k, (f, gt) in enumerate(zip(spec["frames"], gts)):
        rel = os.path.join("path", f["id"] + ".jpg")
        codes = camera_codes(gt, gain, np.random.default_rng([spec["seed"], 2, k]))
        write_jpeg(os.path.join(scene_dir, rel), codes, 90)
        clipped.append(clipped_share(os.path.join(scene_dir, rel)))
        frames.append({"id": f["id"], "position": f["position"], "yaw_pitch_roll_deg": f["yaw_pitch_roll_deg"],
                       "world_from_camera": world_from_camera(f["yaw_pitch_roll_deg"]), "sdr": rel,
                       "ground_truth": os.path.join("path", f["id"] + "_gt.exr")})
    stats = {"max_luminance": float(all_l.max()), "median_luminance": median}
    write_json(os.path.join(scene_dir, "poses.json"),
               {"scene": name, "resolution": [w, h], "probes": probes, "frames": frames, "camera": camera,
                "stats": stats})
    see_bright(scene_dir, spec, size, gain, blender)
    write_json(os.path.join(scene_dir, "summary.json"), summary(spec, gts, clipped, median, render_s, size, scene_dir))


def beyond_probes(frames, probes):
    """Frames of the walk before the first or after the last frame that is
    nearest to some probe: the stretches of the walk beyond every probe."""
    nearest = [min(range(len(frames)), key=lambda i: math.dist(frames[i]["position"], p["position"]))
               for p in probes]
    lo, hi = min(nearest), max(nearest)
    return [f["id"] for i, f in enumerate(frames) if i < lo or i > hi]


def clipped_share(jpeg):
    """Share of an SDR frame's pixels with some channel at or above CLIP_CODE,
    as the JPEG decodes (its compression smooths the noise's speckles)."""
    import cv2
    return float((cv2.imread(jpeg).max(axis=2) >= CLIP_CODE).mean())


def resummarize(scene_dir, blender):
    """Rewrites summary.json of a finished scene from its spec, ground truth and
    SDR frames (for a change to the summary alone)."""
    spec = json.load(open(os.path.join(scene_dir, "spec.json")))
    done = json.load(open(os.path.join(scene_dir, ".done")))
    gts = [read_exr(os.path.join(scene_dir, "path", f["id"] + "_gt.exr")) for f in spec["frames"]]
    clipped = [clipped_share(os.path.join(scene_dir, "path", f["id"] + ".jpg")) for f in spec["frames"]]
    poses = json.load(open(os.path.join(scene_dir, "poses.json")))
    see_bright(scene_dir, spec, tuple(poses["resolution"]), poses["camera"]["path_gain"], blender)
    write_json(os.path.join(scene_dir, "summary.json"),
               summary(spec, gts, clipped, poses["stats"]["median_luminance"], done["render_s"],
                       tuple(poses["resolution"]), scene_dir))


def pixel_directions(w, h):
    """Camera-space unit direction and solid angle of every pixel of a W x H
    equirect panorama (the conventions of ../shared/data/README.md)."""
    import numpy as np
    v, u = np.mgrid[0:h, 0:w]
    phi = ((u + 0.5) / w - 0.5) * 2 * np.pi
    theta = (0.5 - (v + 0.5) / h) * np.pi
    d = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta), -np.cos(theta) * np.cos(phi)], -1)
    return d, np.cos(theta) * (2 * np.pi / w) * (np.pi / h)


UNSEEN_SHARE = 0.2  # a light giving at least a fifth of the irradiance


def clip_radiance(gain):
    """Scene radiance at which a channel of the SDR frame reaches CLIP_CODE
    (the documented response without noise; codes are rounded)."""
    v = (CLIP_CODE - 0.5) / 255.0
    y = v / (1.08 - 0.08 * v)
    return y ** 2.2 / gain


def bright_pixels(scene_dir, view_id, gain):
    """(row, col) of the pixels of a view's render (small emitters left out)
    with some channel above the SDR frame's white point: the light the frame
    cannot measure, which must come from the probes."""
    import numpy as np
    raw = read_exr(os.path.join(scene_dir, "render", view_id + ".exr"))
    rows, cols = np.nonzero(raw.max(axis=2) >= clip_radiance(gain))
    return raw, [[int(r), int(c)] for r, c in zip(rows, cols)]


def see_bright(scene_dir, spec, size, gain, blender):
    """Writes render/<frame>.bright.json and has Blender answer, for each bright
    pixel, whether some probe sees what it sees (render/<frame>.seen.json)."""
    todo = False
    for f in spec["frames"]:
        dst = os.path.join(scene_dir, "render", f["id"] + ".bright.json")
        if not os.path.isfile(os.path.join(scene_dir, "render", f["id"] + ".seen.json")):
            write_json(dst, bright_pixels(scene_dir, f["id"], gain)[1])
            todo = True
    if not todo:
        return
    log = os.path.join(scene_dir, "render.log")
    with open(log, "a") as lf:
        r = subprocess.run([blender, "-b", "--factory-startup", "--python", os.path.join(HERE, "scene.py"), "--",
                            os.path.join(scene_dir, "spec.json"), scene_dir, str(size[0]), str(size[1]), "1",
                            "--seen"], stdout=lf, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        sys.exit(f"{scene_dir}: Blender failed on the visibility pass (exit {r.returncode}); see {log}")


def unseen_lights(scene_dir, spec, gts, gain):
    """Frames the inputs cannot answer. The light a frame cannot measure is
    what lies above its white point: the small emitters (lamps, sun) and every
    surface or sky pixel brighter than the white point. Of it, the part no
    probe sees (probes are perfect HDR captures, so seeing is measuring) is
    unseen: emitters by their footprints, bright pixels by Blender ray casts
    (see_bright). A frame is unanswerable when the unseen light gives at least
    UNSEEN_SHARE of its true irradiance at the normal facing that light (the
    unseen flux's mean direction), both from the ground truth. Returns
    (flagged frames, the unseen share of every frame)."""
    import numpy as np
    def footprints(view_id):
        return json.load(open(os.path.join(scene_dir, "render", view_id + ".emitters.json")))
    seen = {(e["kind"], e["radiance"]) for p in spec["probes"] for e in footprints(p["id"])}
    h, w = gts[0].shape[:2]
    dirs, omega = pixel_directions(w, h)
    flagged, shares = [], {}
    for f, gt in zip(spec["frames"], gts):
        raw, bright = bright_pixels(scene_dir, f["id"], gain)
        seen_px = json.load(open(os.path.join(scene_dir, "render", f["id"] + ".seen.json")))
        if len(seen_px) != len(bright):
            sys.exit(f"{scene_dir}: render/{f['id']}.seen.json does not match its bright pixels; delete it")
        d_parts, flux_parts, kinds = [], [], set()
        hidden = [p for p, s in zip(bright, seen_px) if not s]
        if hidden:
            r, c = np.array(hidden).T
            d_parts.append(dirs[r, c])
            flux_parts.append(lum(raw)[r, c] * omega[r, c])
            kinds.add("bright surface or sky")
        for e in footprints(f["id"]):
            if (e["kind"], e["radiance"]) in seen:
                continue
            px = np.array(e["pixels"])
            r, c = px[:, 0].astype(int), px[:, 1].astype(int)
            d_parts.append(dirs[r, c])
            flux_parts.append(e["radiance"] * px[:, 2] * omega[r, c])
            kinds.add(e["kind"])
        share = 0.0
        if d_parts:
            d, flux = np.concatenate(d_parts), np.concatenate(flux_parts)
            n = (d * flux[:, None]).sum(0)
            n /= np.linalg.norm(n) or 1.0
            own = float((flux * np.maximum(0.0, d @ n)).sum())
            total = float((lum(gt) * omega * np.maximum(0.0, dirs @ n)).sum())
            share = own / total if total > 0 else 0.0
        shares[f["id"]] = round(share, 4)
        if share >= UNSEEN_SHARE:
            flagged.append({"id": f["id"], "unseen": sorted(kinds), "share": round(share, 3)})
    return flagged, shares


def summary(spec, gts, clipped, median, render_s, size, scene_dir):
    import numpy as np
    flagged, shares = unseen_lights(scene_dir, spec, gts, 0.18 / median)
    dists = [min(math.dist(f["position"], p["position"]) for p in spec["probes"]) for f in spec["frames"]]
    peaks = [float(lum(g).max()) for g in gts]
    p999 = [float(np.percentile(lum(g), 99.9)) for g in gts]
    kinds = sorted({l["type"] for l in spec["lights"]})
    views = len(spec["probes"]) + len(spec["frames"])
    return {
        "seed": spec["seed"],
        "split": split_of(spec["seed"]),
        "generator_version": spec["generator_version"],
        "size": list(size),
        "scene": spec["scene"],
        "light_types": kinds,
        "lights": spec["lights"],
        "world": spec["world"],
        "probes": len(spec["probes"]),
        "frames": len(spec["frames"]),
        "walk_length_m": spec["walk_length_m"],
        "dynamic_range": {"median_luminance": median, "peak_over_median_max": max(peaks) / median,
                          "peak_over_median_mean": float(np.mean(peaks)) / median,
                          "p999_over_median_mean": float(np.mean(p999)) / median},
        "clipped_fraction": {"mean": float(np.mean(clipped)), "max": float(np.max(clipped)),
                             "frames_with_clipping": int(sum(c > 0 for c in clipped))},
        "probe_distance_m": {"min": min(dists), "median": float(np.median(dists)), "max": max(dists)},
        "frames_beyond_probes": beyond_probes(spec["frames"], spec["probes"]),
        "unanswerable_frames": flagged,
        "unseen_light_share": shares,
        "render_s": round(render_s, 1),
        "render_s_per_panorama": round(render_s / views, 2),
    }


def spec_digest(spec):
    """SHA-256 of a layout's canonical JSON: the cache key of what a seed draws."""
    import hashlib
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()


def build_scene(out, seed, size, samples, blender, bversion):
    w, h = size
    scene_dir = os.path.join(out, f"s{seed:04d}_{w}x{h}")
    spec = layout.make(seed)
    # Keyed by what the seed draws (not the generator version alone): a change
    # to the generator re-renders only the scenes whose layout it changed.
    key = {"seed": seed, "spec_sha256": spec_digest(spec), "render_version": RENDER_VERSION, "size": [w, h],
           "samples": samples, "blender": bversion}
    done = os.path.join(scene_dir, ".done")
    if os.path.isfile(done):
        try:
            if json.load(open(done)).get("key") == key:
                print(f"{scene_dir}: up to date", flush=True)
                return
        except (OSError, ValueError):
            pass
    started = os.path.join(scene_dir, "render.key")
    if os.path.isdir(scene_dir):
        try:
            same = json.load(open(started)) == key
        except (OSError, ValueError):
            same = False
        if not same:
            if not os.path.isfile(started):
                sys.exit(f"{scene_dir}: exists but was not made by this builder; move it away (nothing touched)")
            shutil.rmtree(scene_dir)  # made by an older generator or other settings: start over
    os.makedirs(scene_dir, exist_ok=True)
    write_json(started, key)
    write_json(os.path.join(scene_dir, "spec.json"), spec)
    log = os.path.join(scene_dir, "render.log")
    with open(log, "a") as lf:
        r = subprocess.run([blender, "-b", "--factory-startup", "--python", os.path.join(HERE, "scene.py"), "--",
                            os.path.join(scene_dir, "spec.json"), scene_dir, str(w), str(h), str(samples)],
                           stdout=lf, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        sys.exit(f"{scene_dir}: Blender failed (exit {r.returncode}); see {log}")
    missing = [v["id"] for v in spec["probes"] + spec["frames"]
               if not os.path.isfile(os.path.join(scene_dir, "render", v["id"] + ".exr"))]
    if missing:
        sys.exit(f"{scene_dir}: Blender finished without rendering {', '.join(missing[:5])}; see {log}")
    # Render time: the panoramas' own times as scene.py logged them, over every
    # attempt (an interrupted build resumes), plus nothing for Blender's start.
    render_s = 0.0
    for line in open(log):
        if line.startswith("rendered ") and line.rstrip().endswith(" s"):
            try:
                render_s += float(line.split(" in ")[-1][:-3])
            except ValueError:
                pass
    finish(scene_dir, spec, size, render_s, blender)
    write_json(done, {"key": key, "generator_version": layout.GENERATOR_VERSION, "render_s": round(render_s, 1)})
    print(f"{scene_dir}: done in {render_s:.0f} s ({len(spec['probes'])} probes, {len(spec['frames'])} frames)",
          flush=True)


def finished(out):
    """(folder name, cache key) of each scene of `out` finished by this
    generator and renderer; scenes left by older ones (to be rebuilt) are not."""
    for d in sorted(os.listdir(out)):
        stamp = os.path.join(out, d, ".done")
        if not os.path.isfile(stamp):
            continue
        try:
            key = json.load(open(stamp))["key"]
            if key.get("spec_sha256") == spec_digest(layout.make(key["seed"])) and \
                    key.get("render_version") == RENDER_VERSION:
                yield d, key
        except (OSError, ValueError, KeyError):
            continue


def write_corpus_index(out):
    scenes = []
    for d, key in finished(out):
        scenes.append({"name": d, "seed": key["seed"], "split": split_of(key["seed"]), "dir": d,
                       "size": key["size"], "samples": key["samples"]})
    write_json(os.path.join(out, "corpus.json"),
               {"generator_version": layout.GENERATOR_VERSION, "split_rule": "validation: seed % 3 == 0",
                "scenes": scenes})
    return scenes


def summary_table(out):
    rows = []
    for d, _ in finished(out):
        s = json.load(open(os.path.join(out, d, "summary.json")))
        rows.append("| {} | {} | {} {} | {} | {}/{} | {:.0f} | {:.2%} / {:.2%} | {:.2f} / {:.2f} / {:.2f} | {} | {} | {:.0f} ({:.1f}) |".format(
            d, s["split"], s["scene"]["kind"], s["scene"]["lighting"], ", ".join(s["light_types"]),
            s["probes"], s["frames"], s["dynamic_range"]["peak_over_median_max"], s["clipped_fraction"]["mean"],
            s["clipped_fraction"]["max"], s["probe_distance_m"]["min"], s["probe_distance_m"]["median"],
            s["probe_distance_m"]["max"], len(s["frames_beyond_probes"]),
            len({u["id"] for u in s.get("unanswerable_frames", [])}), s["render_s"],
            s["render_s_per_panorama"]))
    head = ("| scene | split | kind | lights | probes/frames | peak/median | clipped mean / max | "
            "probe distance min / median / max (m) | frames beyond probes | unanswerable frames | render s (per panorama) |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|\n")
    return head + "\n".join(rows) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="corpus folder")
    ap.add_argument("--seeds", help="seeds, e.g. 0-23,40")
    ap.add_argument("--size", default="256x128", help="panorama size WxH (2:1)")
    ap.add_argument("--samples", type=int, default=64,
                    help="Cycles samples per pixel (twice that for daylight indoors)")
    ap.add_argument("--blender", default="blender")
    ap.add_argument("--background", action="store_true", help="detach; log to OUT/build.log")
    ap.add_argument("--summary", action="store_true", help="print the corpus summary table and exit")
    ap.add_argument("--resummarize", action="store_true", help="rewrite every finished scene's summary.json")
    a = ap.parse_args()
    if a.resummarize:
        need_numpy()
        for d, _ in finished(a.out):
            resummarize(os.path.join(a.out, d), a.blender)
    if a.summary or a.resummarize:
        print(summary_table(a.out), end="")
        return
    if not a.seeds:
        ap.error("--seeds is required to build")
    try:
        w, h = (int(v) for v in a.size.lower().split("x"))
    except ValueError:
        sys.exit(f"--size {a.size}: expected WxH such as 256x128")
    if w != 2 * h or not 16 <= w <= 8192:
        sys.exit(f"--size {a.size}: an equirect panorama is twice as wide as high, 16 to 8192 wide")
    if not 1 <= a.samples <= 100000:
        sys.exit(f"--samples {a.samples}: expected 1 to 100000")
    seeds = seeds_of(a.seeds)
    os.makedirs(a.out, exist_ok=True)
    if a.background:
        log = os.path.join(a.out, "build.log")
        args = [sys.executable, os.path.abspath(__file__)] + [x for x in sys.argv[1:] if x != "--background"]
        with open(log, "a") as lf:
            p = subprocess.Popen(args, stdout=lf, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True)
        print(f"building in the background (pid {p.pid}); log: {log}")
        return
    need_numpy()
    lock = open(os.path.join(a.out, ".build.lock"), "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        sys.exit(f"{a.out}: another build is running on this folder")
    bversion = blender_version(a.blender)
    for seed in seeds:
        build_scene(a.out, seed, (w, h), a.samples, a.blender, bversion)
        write_corpus_index(a.out)
    scenes = write_corpus_index(a.out)
    print(f"{a.out}: {len(scenes)} scenes in corpus.json", flush=True)


if __name__ == "__main__":
    main()
