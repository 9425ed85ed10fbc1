#!/usr/bin/env python3
"""Stress variants of an evaluation scene, to see how lumiprobe does on captures
unlike the shared ones. A cross-check tool: never used by the product.

  scene_variants.py probes SCENE OUT 0,2,4
      OUT/poses.json with only the listed probes (by position in poses.json);
      `probes/` and `path/` are symlinks to SCENE's. Frames then lie farther from
      the nearest probe.

  scene_variants.py exposure SCENE OUT 2.0
      SDR frames re-made from each frame's ground truth with `path_gain` times
      the factor, through the response, noise model and 8-bit quantisation the
      data's README documents, then JPEG (quality 90); `poses.json` carries the
      new gain, `probes/` is a symlink and the ground-truth EXRs are linked.

Then, for example:

  lumiprobe run OUT --out PRED --method fusion && lumiprobe eval OUT --pred PRED

Needs Python 3 with numpy and OpenCV (Debian: python3-opencv).
"""
import json
import os
import sys


def fresh(scene, out):
    """Refuses an OUT that exists (a symlinked `path/` there would let new frames
    overwrite the scene's own) or that is the scene itself."""
    if os.path.lexists(out):
        sys.exit(f"{out}: already exists; give a new folder (nothing written)")
    if not os.path.isfile(os.path.join(scene, "poses.json")):
        sys.exit(f"{scene}: no poses.json here")


def link(src, dst):
    if not os.path.lexists(dst):
        os.symlink(os.path.abspath(src), dst)


def probes(scene, out, keep):
    fresh(scene, out)
    poses = json.load(open(os.path.join(scene, "poses.json")))
    try:
        wanted = [int(k) for k in keep.split(",")]
    except ValueError:
        sys.exit(f"{keep}: not a comma-separated list of probe numbers")
    bad = [k for k in wanted if not 0 <= k < len(poses["probes"])]
    if bad:
        sys.exit(f"{scene}: no probe number {bad} (it has {len(poses['probes'])})")
    poses["probes"] = [p for i, p in enumerate(poses["probes"]) if i in wanted]
    os.makedirs(out, exist_ok=True)
    for sub in ("probes", "path"):
        link(os.path.join(scene, sub), os.path.join(out, sub))
    json.dump(poses, open(os.path.join(out, "poses.json"), "w"), indent=1)


def exposure(scene, out, factor):
    fresh(scene, out)
    try:
        factor = float(factor)
    except ValueError:
        sys.exit(f"{factor}: not a number")
    if not factor > 0 or factor == float("inf"):
        sys.exit(f"{factor}: the gain factor must be a positive finite number")
    os.environ["OPENCV_IO_ENABLE_OPENEXR"] = "1"
    try:
        import cv2
        import numpy as np
    except ImportError:
        sys.exit("needs numpy and OpenCV for Python (Debian: apt install python3-opencv)")

    poses = json.load(open(os.path.join(scene, "poses.json")))
    gain = poses["camera"]["path_gain"] * factor
    poses["camera"]["path_gain"] = gain
    os.makedirs(os.path.join(out, "path"), exist_ok=True)
    link(os.path.join(scene, "probes"), os.path.join(out, "probes"))
    noise = np.random.default_rng(0)
    for f in poses["frames"]:
        truth = os.path.join(scene, "path", f["id"] + "_gt.exr")
        e = cv2.imread(truth, cv2.IMREAD_UNCHANGED)
        if e is None:
            sys.exit(f"{truth}: cannot read")
        x = gain * e.astype(np.float64)
        x = x + noise.normal(size=x.shape) * (0.002 + 0.01 * np.sqrt(np.maximum(x, 0.0)))
        y = np.maximum(x, 0.0) ** (1.0 / 2.2)
        code = np.round(np.minimum(1.0, 1.08 * y / (1.0 + 0.08 * y)) * 255.0)
        jpg = os.path.join(out, "path", f["id"] + ".jpg")
        if not cv2.imwrite(jpg, code.astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90]):
            sys.exit(f"{jpg}: cannot write")
        link(truth, os.path.join(out, "path", f["id"] + "_gt.exr"))
    json.dump(poses, open(os.path.join(out, "poses.json"), "w"), indent=1)


if __name__ == "__main__":
    if len(sys.argv) != 5 or sys.argv[1] not in ("probes", "exposure"):
        sys.exit(__doc__)
    {"probes": probes, "exposure": exposure}[sys.argv[1]](*sys.argv[2:])
