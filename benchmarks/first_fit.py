"""The first ML fit on a new large array: the model's set-up paid by its first call.

A model's first ``fit_ml`` builds what every later fit reuses: the candidate grid,
its atoms (the responses of every candidate source) and, for K >= 2, the coarse
subsets of the tuple search, picked by farthest-point sampling over the atoms.  A
plate for near sources has a 3-D grid of candidate positions (39,690 on a 32 x 32
plate), so this set-up dominates its first call.

Each measurement runs in a new process (the set-up is cached per model and per
atom set), after a fit on a small plate so that the compiled kernels are loaded
outside the clock.  The farthest-point sampling is timed both ways, interleaved:
lazily (the default beyond ``LAZY_SAMPLING_ENTRIES`` atom entries: a max-heap of
distance bounds, only the top atoms brought up to date) and plainly (every
atom's distance updated at every step, one matrix-vector product each).  Both
must give the same fit.

A large sphere's set-up is mostly its atoms' Gram matrix (M^2 N multiply-adds for
its 2,048 default atoms), formed for the search's projections: its first fits are
timed too (one BLAS thread, as the plates'), and so are those of large rings, whose
Gram matrix comes from the arcs of sub-sensors their atoms light (O(M^2 + N)).

Goal: no call blocks for more than ~5 s without saying what it is doing.  A
first fit should stay under ~5 s CPU, or print the set-up's line on stderr (atom
sets beyond ``olsbayes.ml.atoms.NOTICE_ENTRIES`` entries, or whose Gram matrix
costs more than ``NOTICE_GRAM`` multiply-adds; column "said so").

Usage::

    python benchmarks/first_fit.py             # 32 x 32 plate, K = 1..4, 2 rounds;
                                               # 10,000-sphere, 30,000- and
                                               # 100,000-rings, K = 1, 4
    python benchmarks/first_fit.py --rounds 3 --side 24 --spheres 5000,20000 --rings 3000
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np

__all__ = ["main"]

POSITIONS = [[3.0, -2.0, 6.0], [-5.0, 4.0, 8.0], [6.0, 7.0, 5.0], [-6.0, -8.0, 7.0]]
INTENSITIES = [1.0, 0.8, 0.9, 0.7]

DIRECTIONS = [[0.3, 0.2], [2.0, -0.4], [-1.9, 0.7], [-0.8, -1.0]]
ANGLES = [0.3, 2.0, -1.9, -0.8]

_CHILD = """
import json, os, sys, time, warnings
os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"
import olsbayes as ob
from olsbayes.ml.fast import coarse
warnings.simplefilter("ignore")
sampling, k, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if sampling == "plain":
    coarse.LAZY_SAMPLING_ENTRIES = 10**18
small = ob.Model(ob.Plate.grid(4, 4, 1.0), 1e-2)
scene = ob.Scene(positions=[[0.3, 0.2, 2.0]], intensities=[1.0])
ob.fit_ml(small, small.simulate(scene, rng=1), n_sources=1)
if sampling in ("sphere", "ring"):
    array = ob.Sphere.fibonacci(size) if sampling == "sphere" else ob.Ring(size)
    model = ob.Model(array, 1e-2)
    scene = ob.Scene(directions=json.loads(sys.argv[4]), intensities=json.loads(sys.argv[5]))
else:
    model = ob.Model(ob.Plate.grid(size, size, 1.0), 1e-2)
    scene = ob.Scene(positions=json.loads(sys.argv[4]), intensities=json.loads(sys.argv[5]))
data = model.simulate(scene, rng=1)
c = time.process_time()
first = ob.fit_ml(model, data, n_sources=k)
c1 = time.process_time() - c
c = time.process_time()
ob.fit_ml(model, data, n_sources=k)
print(c1, time.process_time() - c, repr(float(first.log_likelihood)))
"""


def first_fit(sampling: str, k: int, size: int) -> tuple[float, float, float, bool]:
    """CPU seconds of the first and second fit in a new process, the first's log L, and
    whether the set-up said so on stderr.

    ``sampling``: "lazy" or "plain" (a plate of ``size`` x ``size``), "sphere" (a
    Fibonacci sphere of ``size`` sub-sensors) or "ring" (a ring of ``size``).
    """
    where = {"sphere": DIRECTIONS, "ring": ANGLES}.get(sampling, POSITIONS)
    out = subprocess.run([sys.executable, "-c", _CHILD, sampling, str(k), str(size),
                          json.dumps(where[:k]), json.dumps(INTENSITIES[:k])],
                         capture_output=True, text=True, check=True)
    first, second, logl = out.stdout.split()[-3:]
    return float(first), float(second), float(logl), "olsbayes: building" in out.stderr


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--side", type=int, default=32, help="the plate's sub-sensors per side")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--spheres", default="10000", help="sphere sizes, comma-separated")
    p.add_argument("--rings", default="30000,100000", help="ring sizes, comma-separated")
    args = p.parse_args(argv)
    print(f"first ML fit on a new {args.side} x {args.side} plate, CPU s (median of "
          f"{args.rounds} interleaved rounds in ABBA order, each fit in a new process)")
    print("K  lazy first  plain first  plain/lazy  later fit  same fit  said so")
    ok = True
    for k in range(1, 5):
        runs: dict[str, list] = {"lazy": [], "plain": []}
        for r in range(args.rounds):  # ABBA order: no method always goes first
            for sampling in (("lazy", "plain") if r % 2 == 0 else ("plain", "lazy")):
                runs[sampling].append(first_fit(sampling, k, args.side))
        lazy, plain = (np.median([r[0] for r in runs[s]]) for s in ("lazy", "plain"))
        later = np.median([r[1] for r in runs["lazy"]])
        same = len({r[2] for rs in runs.values() for r in rs}) == 1
        said = all(r[3] for r in runs["lazy"])
        ok &= lazy <= 5.0 or said
        print(f"{k}  {lazy:10.2f}  {plain:11.2f}  {plain / lazy:10.2f}  {later:9.2f}  "
              f"{'yes' if same else 'NO':>8}  {'yes' if said else 'no':>7}")
    for kind, sizes in (("sphere", args.spheres), ("ring", args.rings)):
        title = "Fibonacci spheres" if kind == "sphere" else "Rings"
        print(f"\n{title}, CPU s (one new process per fit)")
        print("     N  K  first  later fit  said so")
        for n in (int(v) for v in sizes.split(",") if v):
            for k in (1, 4):
                first, later, _, said = first_fit(kind, k, n)
                ok &= first <= 5.0 or said
                print(f"{n:6d}  {k}  {first:5.2f}  {later:9.2f}  {'yes' if said else 'no':>7}")
    print(f"every first fit under ~5 s or said so on stderr: {'met' if ok else 'not met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
