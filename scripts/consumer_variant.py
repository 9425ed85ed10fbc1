#!/usr/bin/env python3
"""Re-makes a scene's walk as a consumer 360-degree camera records it, from the
scene's ground truth: auto-exposure that meters the view and lags it, white
balance that drifts, lens vignetting, sensor noise, the documented response and
8-bit quantisation, then H.264 in 4:2:0 at a chosen quality, decoded back into
frames. A tool for measuring lumiprobe (issue 20), never used by the product.

  consumer_variant.py SCENE OUT [--seed N] [--lag 0.6] [--ev-range 2]
                      [--wb 0.03] [--vignette 0.25] [--crf 26] [--fps 10]
                      [--hunt 0] [--dual-fisheye FOV] [--video-response srgb]

SCENE is a folder with `poses.json` and a ground truth per frame
(`path/<id>_gt.exr`), as the shared scenes and the corpus have. OUT gets:

  walk.mp4       the walk as the camera would store it (H.264, yuv420p)
  path/          the decoded frames (PNG) and links to the ground truths
  probes/        a link to the scene's probes
  poses.json     the scene's, the frames pointing at the decoded PNGs; the
                 camera's `path_gain` stays the nominal one (what a user knows)
  variant.json   what the camera did, per frame: its exposure (EV against the
                 nominal gain), its white balance (per channel, green 1) and
                 the true gain per channel (nominal x 2^EV x balance), so a
                 recovered per-frame gain can be scored

The meter: each frame the camera wants the mean of the image it records at
0.18 (mean metering) within +-`ev_range` EV of the nominal gain, and moves a
fraction 1 - `lag` of the way there from its last exposure. White balance: a
random walk in log gain per channel (red and blue; green fixed), `wb` per frame.
`--video-response srgb` records the walk through the sRGB curve instead of the
documented one (the brackets' response stays documented): a video mode's own
tone curve. A meter that hunts: `hunt` EV added to its target, a sine of 8 frames' period.
Vignetting: each lens (front and back, the camera's -z and +z) darkens towards
its rim as 1 - `vignette` (theta / 90 degrees)^2, theta the angle from its axis.
With `--dual-fisheye FOV` the video holds the two lenses' circles side by side
(front lens left, equidistant, FOV degrees each, diameter the frame height), as
two-lens cameras record it, and OUT also gets `scene.toml`: a manifest that reads
walk.mp4 at the walk's rate, stitches it (`layout = "dual-fisheye"`) and takes the
poses from `poses_video.json` (the frames renamed as the extraction names them,
frame_00001 ..., their `sdr` still the decoded files). path/ then holds the
decoded dual-fisheye frames.

Needs Python 3 with numpy and OpenCV (Debian: python3-opencv) and ffmpeg.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

from scene_variants import fresh, link


def encode(code_linear):
    """The documented response f(x) = 1.08 y / (1 + 0.08 y), y = x^(1/2.2), to codes."""
    import numpy as np

    y = np.maximum(code_linear, 0.0) ** (1.0 / 2.2)
    return np.round(np.minimum(1.0, 1.08 * y / (1.0 + 0.08 * y)) * 255.0)


def encode_srgb(code_linear):
    """The sRGB curve to codes: a video mode's tone curve other than the photos'."""
    import numpy as np

    x = np.clip(code_linear, 0.0, 1.0)
    y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(y * 255.0)


def vignette_map(h, w, amount):
    """Per pixel of an equirect (camera axes: -z at the centre column, +y up), the
    darkening of the nearer of two fisheye lenses looking along -z and +z."""
    import numpy as np

    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    lon = (u - 0.5) * 2.0 * math.pi
    lat = (0.5 - v) * math.pi
    # Direction's z component: -cos(lat) cos(lon) at the centre column's -z.
    z = -np.cos(lat)[:, None] * np.cos(lon)[None, :]
    theta = np.arccos(np.clip(np.abs(z), 0.0, 1.0))
    return 1.0 - amount * (theta / (math.pi / 2.0)) ** 2


def to_dual_fisheye(code, fov_deg):
    """An equirect image (H x W x 3 codes) as two equidistant fisheye circles side
    by side (front lens, looking along -z, on the left; each circle's diameter the
    image height; black outside), written independently of lumiprobe's stitcher."""
    import cv2
    import numpy as np

    h, w = code.shape[:2]
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    back = x >= w / 2
    cx = np.where(back, 0.75 * w, 0.25 * w)
    dx, dy = x - cx, y - h / 2.0
    r = np.hypot(dx, dy)
    half = math.radians(fov_deg) / 2.0
    alpha = r / (h / 2.0) * half
    ux = np.where(r > 0, dx / np.maximum(r, 1e-12), 0.0)
    uy = np.where(r > 0, dy / np.maximum(r, 1e-12), 0.0)
    lx, ly, lz = np.sin(alpha) * ux, -np.sin(alpha) * uy, -np.cos(alpha)
    gx, gy, gz = np.where(back, -lx, lx), ly, np.where(back, -lz, lz)
    phi = np.arctan2(gx, -gz)
    theta = np.arcsin(np.clip(gy, -1.0, 1.0))
    mx = ((phi / (2 * math.pi) + 0.5) * w - 0.5).astype(np.float32)
    my = ((0.5 - theta / math.pi) * h - 0.5).astype(np.float32)
    out = cv2.remap(code, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    out[alpha > half] = 0
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lag", type=float, default=0.6)
    ap.add_argument("--ev-range", type=float, default=2.0)
    ap.add_argument("--wb", type=float, default=0.03)
    ap.add_argument("--vignette", type=float, default=0.25)
    ap.add_argument("--crf", type=int, default=26)
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--hunt", type=float, default=0.0)
    ap.add_argument("--dual-fisheye", type=float, default=0.0, metavar="FOV")
    ap.add_argument("--video-response", choices=["documented", "srgb"], default="documented")
    a = ap.parse_args()
    if a.dual_fisheye and not 180.0 <= a.dual_fisheye <= 270.0:
        sys.exit(f"--dual-fisheye {a.dual_fisheye}: a lens field of view in [180, 270] degrees")
    if not 0.0 <= a.lag < 1.0:
        sys.exit(f"--lag {a.lag}: must be in [0, 1)")
    if not (0.0 <= a.vignette < 1.0 and a.ev_range >= 0.0 and a.wb >= 0.0 and a.fps > 0):
        sys.exit("--vignette must be in [0, 1); --ev-range, --wb and --fps non-negative")
    if shutil.which("ffmpeg") is None:
        sys.exit("ffmpeg not found (Debian: apt install ffmpeg)")
    fresh(a.scene, a.out)
    os.environ["OPENCV_IO_ENABLE_OPENEXR"] = "1"
    try:
        import cv2
        import numpy as np
    except ImportError:
        sys.exit("needs numpy and OpenCV for Python (Debian: apt install python3-opencv)")

    poses = json.load(open(os.path.join(a.scene, "poses.json")))
    nominal = poses["camera"]["path_gain"]
    rng = np.random.default_rng(a.seed)
    out_path = os.path.join(a.out, "path")
    os.makedirs(out_path)
    link(os.path.join(a.scene, "probes"), os.path.join(a.out, "probes"))
    tmp = tempfile.mkdtemp(prefix="variant_", dir=a.out)
    ev, log_wb = None, np.zeros(3)
    rows, vig = [], None
    for k, f in enumerate(poses["frames"]):
        f.setdefault("ground_truth", "path/" + f["id"] + "_gt.exr")
        truth = os.path.join(a.scene, f["ground_truth"])
        e = cv2.imread(truth, cv2.IMREAD_UNCHANGED)
        if e is None:
            sys.exit(f"{truth}: cannot read")
        e = e[:, :, ::-1].astype(np.float64)  # RGB
        h, w = e.shape[:2]
        if vig is None:
            vig = vignette_map(h, w, a.vignette)
        if (h, w) != vig.shape or h % 2 or w % 2:
            sys.exit(f"{truth}: frames of mixed or odd sizes ({w}x{h})")
        # Mean metering of what the sensor would record at the nominal gain.
        lum = 0.2126 * e[..., 0] + 0.7152 * e[..., 1] + 0.0722 * e[..., 2]
        mean = float(np.mean(nominal * lum * vig))
        want = math.log2(0.18 / mean) if mean > 0 else a.ev_range
        want += a.hunt * math.sin(2.0 * math.pi * k / 8.0)
        want = max(-a.ev_range, min(a.ev_range, want))
        ev = want if ev is None else ev + (1.0 - a.lag) * (want - ev)
        if k > 0:
            log_wb[[0, 2]] += rng.normal(size=2) * a.wb
        wb = np.exp(log_wb)
        gain = nominal * 2.0 ** ev * wb
        x = e * gain[None, None, :] * vig[:, :, None]
        x = x + rng.normal(size=x.shape) * (0.002 + 0.01 * np.sqrt(np.maximum(x, 0.0)))
        curve = encode_srgb if a.video_response == "srgb" else encode
        code = curve(x)[:, :, ::-1].astype(np.uint8)  # BGR for OpenCV
        if a.dual_fisheye:
            code = to_dual_fisheye(code, a.dual_fisheye)
        png = os.path.join(tmp, f"{k:05d}.png")
        if not cv2.imwrite(png, code):
            sys.exit(f"{png}: cannot write")
        rows.append({"id": f["id"], "ev": ev, "white_balance": wb.tolist(), "gain": gain.tolist()})
    mp4 = os.path.join(a.out, "walk.mp4")
    enc = ["ffmpeg", "-v", "error", "-y", "-framerate", str(a.fps), "-i", os.path.join(tmp, "%05d.png"),
           "-c:v", "libx264", "-crf", str(a.crf), "-pix_fmt", "yuv420p", mp4]
    if subprocess.run(enc).returncode != 0:
        sys.exit(f"{mp4}: ffmpeg could not encode the walk")
    dec = ["ffmpeg", "-v", "error", "-y", "-i", mp4, "-start_number", "0", os.path.join(tmp, "dec_%05d.png")]
    if subprocess.run(dec).returncode != 0:
        sys.exit(f"{mp4}: ffmpeg could not decode the walk")
    for k, f in enumerate(poses["frames"]):
        src = os.path.join(tmp, f"dec_{k:05d}.png")
        if not os.path.isfile(src):
            sys.exit(f"{mp4}: decoded {k} frames, the walk has {len(poses['frames'])}")
        os.replace(src, os.path.join(out_path, f["id"] + ".png"))
        f["sdr"] = "path/" + f["id"] + ".png"
        gt = os.path.join(a.out, f["ground_truth"])
        os.makedirs(os.path.dirname(gt), exist_ok=True)
        link(os.path.join(a.scene, f["ground_truth"]), gt)
    shutil.rmtree(tmp)
    variant = {
        "scene": os.path.abspath(a.scene),
        "nominal_gain": nominal,
        "settings": {"seed": a.seed, "lag": a.lag, "ev_range": a.ev_range, "wb": a.wb,
                     "vignette": a.vignette, "hunt": a.hunt, "crf": a.crf, "fps": a.fps, "codec": "libx264 yuv420p",
                     "video_response": a.video_response},
        "frames": rows,
    }
    json.dump(variant, open(os.path.join(a.out, "variant.json"), "w"), indent=1)
    json.dump(poses, open(os.path.join(a.out, "poses.json"), "w"), indent=1)
    if a.dual_fisheye:
        video = json.loads(json.dumps(poses))
        for k, f in enumerate(video["frames"]):
            f["id"] = f"frame_{k + 1:05d}"
        json.dump(video, open(os.path.join(a.out, "poses_video.json"), "w"), indent=1)
        probes = "".join(
            f'[[probe]]\nid = "{p["id"]}"\nhdr = "probes/{p["id"]}.exr"\n\n' for p in poses["probes"]
        )
        with open(os.path.join(a.out, "scene.toml"), "w") as m:
            m.write(
                f'name = "{os.path.basename(os.path.abspath(a.out))}"\n\n[camera]\nresponse = "documented"\n'
                f'gain = {nominal!r}\n\n{probes}[frames]\nvideo = "walk.mp4"\nfps = {a.fps!r}\n'
                f'layout = "dual-fisheye"\nfov = {a.dual_fisheye!r}\n\n[poses]\nfile = "poses_video.json"\n\n'
                f'[output]\nfolder = "out"\n'
            )
    evs = [r["ev"] for r in rows]
    print(f"{a.out}: {len(rows)} frames, exposure {min(evs):+.2f} to {max(evs):+.2f} EV, walk.mp4 "
          f"{os.path.getsize(mp4) // 1024} KiB")


if __name__ == "__main__":
    main()
