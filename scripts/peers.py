#!/usr/bin/env python3
"""lumiprobe against the plain Python/OpenCV renditions of the thesis's methods
(issue 21): whole processes on one thread, in one run, alternating, each into an
empty output folder; prints each side's median wall and CPU time per run and
the ratios.

  peers.py SCENE [--reference ../shared/reference] [--lumiprobe BIN] [--rounds 3]
           [--pairs fusion:flow_ref,flow:flow_ref,warp:thesis_warp]

One thread: OMP_NUM_THREADS, OPENCV_FOR_THREADS_NUM and OPENBLAS_NUM_THREADS are 1
for every process, and lumiprobe runs with `--threads 1`. CPU time is the
children's user + system time (resource.getrusage). A tool for measuring
lumiprobe, never used by the product.
"""
import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def timed(cmd, env):
    """Wall and CPU seconds of one process (its children included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--reference", default=os.path.join(ROOT, "..", "shared", "reference"))
    ap.add_argument("--lumiprobe", default=os.path.join(ROOT, "target", "release", "lumiprobe"))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--pairs", default="fusion:flow_ref,flow:flow_ref,warp:thesis_warp")
    a = ap.parse_args()
    py = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENCV_FOR_THREADS_NUM="1", OPENBLAS_NUM_THREADS="1",
               RAYON_NUM_THREADS="1")
    peers = {
        "flow_ref": lambda out: [py, os.path.join(a.reference, "flow_ref.py"), a.scene, out, "fast"],
        "thesis_warp": lambda out: [py, os.path.join(a.reference, "thesis_warp.py"), a.scene, out],
    }
    for p in peers:
        script = os.path.join(a.reference, p + ".py")
        if not os.path.isfile(script):
            sys.exit(f"{script}: no such peer rendition (--reference)")
    if not os.path.isfile(a.lumiprobe):
        sys.exit(f"{a.lumiprobe}: no lumiprobe binary (cargo build --release)")
    pairs = [tuple(x.split(":")) for x in a.pairs.split(",")]
    for method, peer in pairs:
        if peer not in peers:
            sys.exit(f"--pairs: unknown peer {peer!r} (flow_ref, thesis_warp)")
    work = tempfile.mkdtemp(prefix="peers_")
    times = {}
    try:
        for r in range(a.rounds):
            for method, peer in pairs:
                # Alternate which side goes first from round to round.
                sides = [("lumiprobe " + method, None), (peer, peer)]
                if r % 2:
                    sides.reverse()
                for label, p in sides:
                    out = os.path.join(work, f"{label.replace(' ', '_')}_{r}")
                    shutil.rmtree(out, ignore_errors=True)
                    os.makedirs(out)
                    if p is None:
                        cmd = [a.lumiprobe, "run", a.scene, "--method", method, "--threads", "1", "-q", "--out", out]
                    else:
                        cmd = peers[p](out)
                    times.setdefault((method, label), []).append(timed(cmd, env))
                    shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"{a.scene}: {a.rounds} rounds, whole processes, one thread, alternating")
    print(f"{'run':28} {'wall s':>8} {'cpu s':>8}")
    for (method, label), v in times.items():
        name = label if label.startswith("lumiprobe") else f"{label} (against {method})"
        print(f"{name:28} {statistics.median(w for w, _ in v):8.2f} {statistics.median(c for _, c in v):8.2f}")
    for method, peer in pairs:
        ours = times[(method, "lumiprobe " + method)]
        theirs = times[(method, peer)]
        wall = statistics.median(w for w, _ in theirs) / statistics.median(w for w, _ in ours)
        cpu = statistics.median(c for _, c in theirs) / statistics.median(c for _, c in ours)
        print(f"lumiprobe {method} is {wall:.2f}x faster than {peer} in wall time, {cpu:.2f}x in CPU time")


if __name__ == "__main__":
    main()
