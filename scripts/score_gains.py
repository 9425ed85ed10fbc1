#!/usr/bin/env python3
"""Scores per-frame gains recovered by `lumiprobe calibrate --per-frame --json`
against the true gains of a consumer-camera variant (`consumer_variant.py`'s
`variant.json`). A tool for measuring lumiprobe, never used by the product.

  score_gains.py VARIANT_DIR GAINS.json [--measured]

With --measured the frames' own measurements are scored, before the walk pass.
Prints, per frame, the luminance gain's error in EV (log2 of recovered over
true) and each of the red and blue balances' (r/g, b/g) error in percent, then
the median and worst absolute errors.
"""
import json
import math
import os
import sys

W = (0.2126, 0.7152, 0.0722)


def main():
    if len(sys.argv) not in (3, 4) or (len(sys.argv) == 4 and sys.argv[3] != "--measured"):
        sys.exit(__doc__)
    key = "measured" if len(sys.argv) == 4 else "gain"
    truth = json.load(open(os.path.join(sys.argv[1], "variant.json")))
    got = json.load(open(sys.argv[2]))
    rows_t = {r["id"]: r for r in truth["frames"]}
    ev_err, wb_err = [], []
    print("frame      true EV   EV error  r/g err %  b/g err %")
    for r in got["frames"]:
        t = rows_t.get(r["id"])
        if t is None:
            sys.exit(f"{sys.argv[2]}: frame {r['id']} is not in the variant")
        g, tg = r[key], t["gain"]
        lum = sum(w * v for w, v in zip(W, g))
        tlum = sum(w * v for w, v in zip(W, tg))
        if not (lum > 0 and tlum > 0):
            print(f"{r['id']:<10} no gain")
            continue
        e = math.log2(lum / tlum)
        rg = 100 * ((g[0] / g[1]) / (tg[0] / tg[1]) - 1)
        bg = 100 * ((g[2] / g[1]) / (tg[2] / tg[1]) - 1)
        ev_err.append(abs(e))
        wb_err.append(max(abs(rg), abs(bg)))
        print(f"{r['id']:<10} {t['ev']:+8.3f}  {e:+8.3f}  {rg:+9.2f}  {bg:+9.2f}")
    if not ev_err:
        sys.exit("no frame scored")
    ev_err.sort()
    wb_err.sort()
    med = ev_err[len(ev_err) // 2]
    print(f"EV error: median {med:.3f}, worst {ev_err[-1]:.3f} ({len(ev_err)} frames); "
          f"balance error: median {wb_err[len(wb_err) // 2]:.2f}%, worst {wb_err[-1]:.2f}%")


if __name__ == "__main__":
    main()
