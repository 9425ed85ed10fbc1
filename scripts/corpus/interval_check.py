#!/usr/bin/python3
"""Does the fusion's reported irradiance interval contain the truth?

For every frame of every scene under an output folder of `lumiprobe corpus`
(OUT/<scene>/fusion/frame_XXX.json), the true irradiance averaged over all
orientations (a quarter of the ground truth's luminance power) is compared with
the report's `irradiance` {lower, estimate, upper}. Frames the corpus summary
flags as unanswerable (light no probe saw) are counted apart.

    /usr/bin/python3 scripts/corpus/interval_check.py OUT CORPUS_DIR [SHARED_DIR] [--upper booked_upper]

A tool for reading results, not part of the product.
"""
import glob
import json
import os
import sys

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402


def mean_irradiance(path):
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        sys.exit(f"{path}: cannot read")
    img = img[:, :, ::-1].astype(np.float64)
    h, w = img.shape[:2]
    lum = 0.2126 * img[:, :, 0] + 0.7152 * img[:, :, 1] + 0.0722 * img[:, :, 2]
    theta0 = np.pi * np.arange(h) / h
    theta1 = np.pi * (np.arange(h) + 1) / h
    sa = (2 * np.pi / w) * (np.cos(theta0) - np.cos(theta1))
    return float((lum * sa[:, None]).sum() / 4.0)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    args = sys.argv[1:]
    # --upper booked_upper: check the ledger's upper end instead.
    field = "upper"
    if "--upper" in args:
        k = args.index("--upper")
        field = args[k + 1]
        del args[k : k + 2]
    out, roots = args[0], args[1:]
    scene_dirs, split = {}, {}
    for root in roots:
        cj = os.path.join(root, "corpus.json")
        if os.path.exists(cj):
            for sc in json.load(open(cj)).get("scenes", []):
                split[sc.get("name")] = sc.get("split")
        for p in glob.glob(os.path.join(root, "*", "poses.json")):
            scene_dirs[os.path.basename(os.path.dirname(p))] = os.path.dirname(p)
    counts = {}
    for name, sdir in sorted(scene_dirs.items()):
        reports = sorted(glob.glob(os.path.join(out, name, "fusion", "frame_*.json")))
        if not reports:
            continue
        flagged = set()
        summ = os.path.join(sdir, "summary.json")
        if os.path.exists(summ):
            flagged = {f["id"] for f in json.load(open(summ)).get("unanswerable_frames", [])}
        below = above = 0
        for rp in reports:
            fid = os.path.basename(rp)[:-5]
            iv = json.load(open(rp))["fusion"]["irradiance"]
            t = mean_irradiance(os.path.join(sdir, "path", f"{fid}_gt.exr"))
            kind = "unanswerable" if fid in flagged else "answerable"
            c = counts.setdefault(f"{split.get(name, 'shared')} {kind}", [0, 0, 0, 0])
            c[0] += 1
            if t < iv["lower"] * 0.98:
                c[1] += 1
                below += 1
            elif t > iv.get(field, 0.0) * 1.02:
                c[2] += 1
                above += 1
            else:
                c[3] += 1
        print(f"{name}: {len(reports)} frames, truth below {below}, above {above}")
    for k, (n, lo, hi, inside) in sorted(counts.items()):
        print(f"{k}: {n} frames, inside {inside}, truth below lower {lo}, above upper {hi} (2% tolerance)")


if __name__ == "__main__":
    main()
