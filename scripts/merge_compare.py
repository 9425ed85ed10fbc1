#!/usr/bin/env python3
"""Cross-check for `lumiprobe merge`: merge the dataset's exposure brackets with
two independent tools, so lumiprobe's own merge (Debevec & Malik 1997) can be
scored against them. Never used by the product.

For every probe of every scene and both bracket sets (`brackets`: -3..+3 EV,
`brackets_wide`: -12..+2 EV) it writes

  OUT/opencv/<scene>/<probe>_<set>.exr        OpenCV CalibrateDebevec + MergeDebevec
  OUT/opencv/<scene>/<probe>_<set>_crf.json   OpenCV's recovered response
  OUT/luminance/<scene>/<probe>_<set>.exr     luminance-hdr-cli, Debevec merge with
                                              the response it recovers itself
  OUT/luminance/<scene>/<probe>_<set>_crf.json  that response

Response files hold {"linear": [[256 values] x 3 (R, G, B)]}: the relative linear
exposure of each 8-bit code.

OpenCV: `cv2.createCalibrateDebevec()` with its defaults (70 samples, lambda 10)
and `cv2.createMergeDebevec()`, exposure times in seconds.

Luminance HDR 2.6 has no Debevec response solver; its own recovery is Robertson
et al.'s (`--hdrModel robertsonauto`). So the curve is recovered with
`robertsonauto` (written with --outputCameraResponseCurve) and the images are then
merged by its Debevec operator with that curve:

  luminance-hdr-cli --hdrModel robertsonauto --hdrWeight triangular \
      --outputCameraResponseCurve CURVE.csv -s /dev/null-ish.exr FILES...
  luminance-hdr-cli --hdrModel debevec --hdrWeight triangular \
      --hdrResponseCurve from_file --inputCameraResponseCurve CURVE.csv -s OUT.exr FILES...

Luminance HDR reads the exposure from Exif. Its curve has 4096 entries over
[0, 1]; code z is entry round(z * 4095 / 255).

Exposure times for OpenCV come from poses.json (`exposure_time_s`, the same values
as the files' Exif ExposureTime).

Usage: /usr/bin/python3 scripts/merge_compare.py [--data DIR] [--out DIR]
       [--scenes kitchen,flat,outdoor] [--tools opencv,luminance]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402

SETS = {"brackets": "std", "brackets_wide": "wide"}


def brackets_of(scene_dir, probe, key):
    """(files, times) of one bracket set, darkest first."""
    entries = sorted(probe.get(key, []), key=lambda b: b["exposure_time_s"])
    files = [os.path.join(scene_dir, b["file"]) for b in entries]
    times = [float(b["exposure_time_s"]) for b in entries]
    return files, times


def write_curve(path, linear_rgb):
    with open(path, "w") as f:
        json.dump({"linear": [list(map(float, ch)) for ch in linear_rgb]}, f)


def run_opencv(files, times, out_exr, out_crf):
    imgs = [cv2.imread(f, cv2.IMREAD_COLOR) for f in files]
    if any(i is None for i in imgs):
        raise RuntimeError(f"cannot read one of {files}")
    t = np.asarray(times, dtype=np.float32)
    crf = cv2.createCalibrateDebevec().process(imgs, t)
    hdr = cv2.createMergeDebevec().process(imgs, t, crf)
    hdr = np.nan_to_num(hdr, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)
    if not cv2.imwrite(out_exr, hdr, [cv2.IMWRITE_EXR_TYPE, cv2.IMWRITE_EXR_TYPE_FLOAT]):
        raise RuntimeError(f"cannot write {out_exr}")
    crf = crf.reshape(256, 3)  # BGR columns
    write_curve(out_crf, [crf[:, 2], crf[:, 1], crf[:, 0]])


def run_luminance(files, out_exr, out_crf):
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    with tempfile.TemporaryDirectory() as tmp:
        csv = os.path.join(tmp, "curve.csv")
        rob = os.path.join(tmp, "robertson.exr")
        subprocess.run(
            ["luminance-hdr-cli", "--hdrModel", "robertsonauto", "--hdrWeight",
             "triangular", "--outputCameraResponseCurve", csv, "-s", rob] + files,
            check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        subprocess.run(
            ["luminance-hdr-cli", "--hdrModel", "debevec", "--hdrWeight", "triangular",
             "--hdrResponseCurve", "from_file", "--inputCameraResponseCurve", csv,
             "-s", out_exr] + files,
            check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        c = np.loadtxt(csv, delimiter=",", skiprows=1)
    idx = np.rint(np.arange(256) * (c.shape[0] - 1) / 255.0).astype(int)
    write_curve(out_crf, [c[idx, 1], c[idx, 3], c[idx, 5]])


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.path.join(here, "..", "..", "shared", "data", "scenes"))
    ap.add_argument("--out", default="/tmp/merge_eval")
    ap.add_argument("--scenes", default="kitchen,flat,outdoor")
    ap.add_argument("--tools", default="opencv,luminance")
    a = ap.parse_args()
    tools = a.tools.split(",")
    timing = {t: [] for t in tools}
    for scene in a.scenes.split(","):
        scene_dir = os.path.join(a.data, scene)
        with open(os.path.join(scene_dir, "poses.json")) as f:
            poses = json.load(f)
        for tool in tools:
            os.makedirs(os.path.join(a.out, tool, scene), exist_ok=True)
        for probe in poses["probes"]:
            for key, tag in SETS.items():
                files, times = brackets_of(scene_dir, probe, key)
                if not files:
                    continue
                stem = f"{probe['id']}_{tag}"
                for tool in tools:
                    exr = os.path.join(a.out, tool, scene, stem + ".exr")
                    crf = os.path.join(a.out, tool, scene, stem + "_crf.json")
                    t0 = time.perf_counter()
                    if tool == "opencv":
                        run_opencv(files, times, exr, crf)
                    elif tool == "luminance":
                        run_luminance(files, exr, crf)
                    else:
                        sys.exit(f"unknown tool {tool}")
                    timing[tool].append(time.perf_counter() - t0)
                print(f"{scene} {stem}: done", flush=True)
    for tool, ts in timing.items():
        if ts:
            print(f"{tool}: {len(ts)} merges, mean {1e3 * sum(ts) / len(ts):.0f} ms per merge")


if __name__ == "__main__":
    main()
