#!/usr/bin/python3
"""Where a method's light went wrong, frame by frame, against the ground truth.

For each frame of a scene the SDR frame's clipped pixels (any channel at or above
code 250) are split into connected regions; the script prints the true light power
(luminance times solid angle, in the units of the ground truth) outside the clipped
pixels and inside each region, next to the prediction's and to the lower bound the
SDR frame gives (its white point). A frame whose prediction is wrong because a
region got the light of another shows as one region over and one under; a
calibration error shows outside the regions.

    /usr/bin/python3 scripts/corpus/diagnose.py SCENE_DIR PRED_DIR [--frames 0,12] [--regions 4]

PRED_DIR holds `frame_XXX.exr` in the frames' camera orientation (the output
folder of `lumiprobe run` or of one method of `lumiprobe corpus`). A tool for
reading results, not part of the product.
"""
import argparse
import json
import os
import sys

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402

CLIP = 250


def decode(code, gain):
    """Inverse of the documented response f(x) = 1.08 y / (1 + 0.08 y), y = x^(1/2.2)."""
    v = np.minimum(code.astype(np.float64) / 255.0, 0.99999)
    y = v / (1.08 - 0.08 * v)
    return y ** 2.2 / gain


def read_exr(path):
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        sys.exit(f"{path}: cannot read")
    return img[:, :, ::-1].astype(np.float64)


def lum(rgb):
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def solid_angles(h, w):
    theta = (0.5 - (np.arange(h) + 0.5) / h) * np.pi
    return (np.cos(theta) * (np.pi / h) * (2 * np.pi / w))[:, None] * np.ones((1, w))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("pred")
    ap.add_argument("--frames", default="")
    ap.add_argument("--regions", type=int, default=4)
    ap.add_argument("--brief", action="store_true",
                    help="one line per scene: mean and worst over frames of the power put in clipped regions beyond "
                         "their truth (over), missing from them (under) and the error outside them, each over the "
                         "frame's true power")
    a = ap.parse_args()
    poses = json.load(open(os.path.join(a.scene, "poses.json")))
    gain = poses["camera"]["path_gain"]
    only = {int(x) for x in a.frames.split(",") if x}
    rows = []
    if not a.brief:
        print("frame     P_true   P_pred   P_sdr | outside: true   pred | clipped: true  pred  sdr_lo | regions (px@(x,y): true / pred)")
    for k, f in enumerate(poses["frames"]):
        if only and k not in only:
            continue
        gt = read_exr(os.path.join(a.scene, f["ground_truth"]))
        pp = os.path.join(a.pred, f["id"] + ".exr")
        if not os.path.exists(pp):
            continue
        pred = read_exr(pp)
        sdr = cv2.imread(os.path.join(a.scene, f["sdr"]))[:, :, ::-1]
        h, w = gt.shape[:2]
        if pred.shape[:2] != (h, w):
            pred = cv2.resize(pred.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)
        om = solid_angles(h, w)
        lin = decode(sdr, gain)
        clipped = (sdr >= CLIP).any(axis=2)
        pt, pq, ps = (lum(x) * om for x in (gt, pred, lin))
        n, lab = cv2.connectedComponents(clipped.astype(np.uint8), connectivity=8)
        regs = []
        for r in range(1, n):
            m = lab == r
            ys, xs = np.nonzero(m)
            regs.append((f"{m.sum()}@({xs.mean():.0f},{ys.mean():.0f})", pt[m].sum(), pq[m].sum()))
        regs.sort(key=lambda t: -abs(t[2] - t[1]))
        out = ~clipped
        total = pt.sum()
        rows.append((sum(max(0.0, q - t) for _, t, q in regs) / total,
                     sum(max(0.0, t - q) for _, t, q in regs) / total,
                     abs(pq[out].sum() - pt[out].sum()) / total))
        if a.brief:
            continue
        print(
            f"{f['id']}  {pt.sum():8.3f} {pq.sum():8.3f} {ps.sum():7.3f} | {pt[out].sum():13.3f} {pq[out].sum():6.3f} |"
            f" {pt[clipped].sum():13.3f} {pq[clipped].sum():5.3f} {ps[clipped].sum():7.3f} | "
            + "  ".join(f"{c}: {t:.3f}/{q:.3f}" for c, t, q in regs[: a.regions])
        )


    if a.brief and rows:
        r = np.array(rows)
        name = os.path.basename(os.path.normpath(a.scene))
        print(f"{name:16s} over {r[:, 0].mean():6.3f} (worst {r[:, 0].max():6.3f})  under {r[:, 1].mean():6.3f} "
              f"(worst {r[:, 1].max():6.3f})  outside {r[:, 2].mean():6.3f} (worst {r[:, 2].max():6.3f})")


if __name__ == "__main__":
    main()
