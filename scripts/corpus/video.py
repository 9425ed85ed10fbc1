#!/usr/bin/env python3
"""The corpus as consumer 360-degree video (issue 20): a video variant of every
scene (scripts/consumer_variant.py, seeded by the scene's own seed), fused with
one gain for the walk and with each frame's own, scored with `lumiprobe eval`,
summarised per split: irradiance error mean (of scene means), p95 (mean of scene
p95s), worst frame, flicker mean / worst (frame-to-frame irradiance change the
truth does not make), and the linearised SDR frame's error.

  video.py CORPUS OUT [--lumiprobe BIN] [--modes off,on,vig] [--seeds-from CORPUS]
           [--only s0001,s0003] [-- consumer_variant options]

OUT/variants/<scene> holds the variants (made once; delete to remake),
OUT/runs/<scene>-<mode> the fusion outputs with eval.txt, OUT/video.txt the
summary. Reruns reuse what is there.  A tool for measuring lumiprobe, never used
by the product.
"""
import argparse
import glob
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))


def parse_eval(path):
    """The fusion and SDR rows of `lumiprobe eval`'s worst-case table."""
    out = {}
    for line in open(path).read().splitlines():
        parts = line.split()
        if not parts or "@" not in line:
            continue
        if parts[0] == "fusion":
            out["mean"], out["p95"], out["worst"] = map(float, parts[1:4])
            plain = [p for p in parts if not p.startswith("@")]
            out["flicker_mean"], out["flicker_worst"] = float(plain[-2]), float(plain[-1])
        elif parts[0] == "baseline:sdr":
            out["sdr"] = float(parts[1])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("corpus")
    ap.add_argument("out")
    ap.add_argument("--lumiprobe", default=os.path.join(ROOT, "target", "release", "lumiprobe"))
    ap.add_argument("--modes", default="off,on")
    ap.add_argument("--only", default="")
    ap.add_argument("variant_args", nargs="*")
    a = ap.parse_args()
    modes = a.modes.split(",")
    scenes = sorted(d for d in glob.glob(os.path.join(a.corpus, "s*")) if os.path.isfile(os.path.join(d, "summary.json")))
    if a.only:
        keep = set(a.only.split(","))
        scenes = [d for d in scenes if os.path.basename(d).split("_")[0] in keep]
    if not scenes:
        sys.exit(f"{a.corpus}: no corpus scene (a folder with summary.json)")
    rows = {}
    for d in scenes:
        name = os.path.basename(d)
        summary = json.load(open(os.path.join(d, "summary.json")))
        var = os.path.join(a.out, "variants", name)
        if not os.path.isfile(os.path.join(var, "variant.json")):
            subprocess.run(
                [sys.executable, os.path.join(ROOT, "scripts", "consumer_variant.py"), d, var,
                 "--seed", str(summary["seed"])] + a.variant_args,
                check=True,
            )
        for m in modes:
            run = os.path.join(a.out, "runs", f"{name}-{m}")
            ev = os.path.join(run, "eval.txt")
            if not os.path.isfile(ev):
                # Mode "vig": each frame's own gain with the lens vignetting
                # fitted and divided out (`run --vignetting`).
                exposure = ["--frame-exposure", "on", "--vignetting"] if m == "vig" else ["--frame-exposure", m]
                subprocess.run([a.lumiprobe, "run", var, "--method", "fusion", "--out", run,
                                "--calibrate", "-q"] + exposure, check=True)
                text = subprocess.run([a.lumiprobe, "eval", var, "--pred", f"fusion={run}", "-q"],
                                      check=True, capture_output=True, text=True).stdout
                with open(ev + ".tmp", "w") as f:
                    f.write(text)
                os.replace(ev + ".tmp", ev)
            rows[(summary["split"], name, m)] = parse_eval(ev)
    lines = ["split mode  scenes  irr_mean  irr_p95  irr_worst  flicker_mean  flicker_worst  sdr_mean"]
    for split in ("dev", "val"):
        for m in modes:
            r = [v for (s, _, mm), v in rows.items() if s == split and mm == m and "mean" in v]
            if not r:
                continue
            mean = lambda k: sum(x[k] for x in r) / len(r)
            lines.append(
                f"{split:5} {m:5} {len(r):6}  {mean('mean'):8.4f}  {mean('p95'):7.4f}  "
                f"{max(x['worst'] for x in r):9.3f}  {mean('flicker_mean'):12.4f}  "
                f"{max(x['flicker_worst'] for x in r):13.3f}  {mean('sdr'):8.4f}"
            )
    lines.append("")
    lines.append("scene  split  " + "  ".join(f"{m}: irr / flicker" for m in modes))
    for name in sorted({n for _, n, _ in rows}):
        split = next(s for s, n, _ in rows if n == name)
        cells = []
        for m in modes:
            v = rows.get((split, name, m), {})
            cells.append(f"{v.get('mean', float('nan')):.3f} / {v.get('flicker_mean', float('nan')):.3f}")
        lines.append(f"{name}  {split}  " + "  ".join(cells))
    text = "\n".join(lines) + "\n"
    with open(os.path.join(a.out, "video.txt"), "w") as f:
        f.write(text)
    print(text, end="")


if __name__ == "__main__":
    main()
