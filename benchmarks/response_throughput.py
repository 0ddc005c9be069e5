"""Throughput of the batched Eq. 1 kernel against numpy multiply-add, in one run.

For each case (array, number of sources K, batch size W) it times

* ``Model.response(x)`` with ``x`` of shape (W, K * (d + 1)),
* ``Model.log_likelihood(x, data)``,

and reports sensor-source terms per second (W * K * N / time) next to the rate
of a plain numpy multiply-add (``np.multiply(a, b, out=c); c += d``) over arrays
of the same W * K * N elements, measured in the same run.  The ratio is the
figure of merit (aim: >= 0.5): 1.0 means one Eq. 1 term costs one fused
multiply-add pass of numpy.  "trig share" is the fraction of the response time
spent turning source angles into unit vectors (2-3 cos/sin per source, ~20x the
cost of a multiply-add each): with few sub-sensors (ring N = 30) it caps the ratio.

Usage::

    python benchmarks/response_throughput.py            # quick (~20 s)
    python benchmarks/response_throughput.py --full     # more cases and repeats
    python benchmarks/response_throughput.py --out out/response_throughput
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from olsbayes import CosinePower, Model, Plate, Ring, Sphere


def best_time(fn, min_time: float, repeats: int) -> float:
    """Best-of-``repeats`` seconds per call, each repeat lasting >= ``min_time``."""
    fn()
    best = np.inf
    for _ in range(repeats):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= min_time:
                break
        best = min(best, dt / n)
    return best


def muladd_rate(size: int, min_time: float, repeats: int, rng: np.random.Generator) -> float:
    """numpy multiply-add elements per second on arrays of ``size`` float64."""
    a, b, d = (rng.standard_normal(size) for _ in range(3))
    c = np.empty(size)

    def fma() -> None:
        np.multiply(a, b, out=c)
        np.add(c, d, out=c)

    return size / best_time(fma, min_time, repeats)


def random_params(model: Model, k: int, w: int, rng: np.random.Generator) -> np.ndarray:
    inten = rng.uniform(0.2, 1.0, (w, k, 1))
    if model.kind == "angle":
        loc = rng.uniform(-np.pi, np.pi, (w, k, 1))
    elif model.kind == "lonlat":
        loc = np.stack([rng.uniform(-np.pi, np.pi, (w, k)), rng.uniform(-1.2, 1.2, (w, k))], -1)
    else:
        loc = np.stack([rng.uniform(-1, 1, (w, k)), rng.uniform(-1, 1, (w, k)),
                        rng.uniform(0.5, 2, (w, k))], -1)
    return np.concatenate([loc, inten], -1).reshape(w, -1)


def cases(full: bool) -> list[tuple[str, Model, int, int]]:
    ring30 = Model(Ring(30), 0.01)
    sphere = Model(Sphere.grid(15, 20), 0.01)
    out = [
        ("ring N=30  K=2  W=512 (emcee)", ring30, 2, 512),
        ("ring N=30  K=2  W=8192 (MC)", ring30, 2, 8192),
        ("sphere N=300 K=3 W=256", sphere, 3, 256),
        ("sphere N=300 K=3 W=2048", sphere, 3, 2048),
    ]
    if full:
        out += [
            ("ring N=1000 K=4 W=1024", Model(Ring(1000), 0.01), 4, 1024),
            ("ring N=30 cos^3 K=2 W=8192", Model(Ring(30), 0.01, CosinePower(3.0)), 2, 8192),
            ("plate 16x16 K=2 W=512", Model(Plate.grid(16, 16, 0.25), 0.01), 2, 512),
        ]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="more cases and repeats")
    ap.add_argument("--out", type=Path, default=Path("out/response_throughput"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    min_time, repeats = (0.5, 7) if args.full else (0.2, 5)
    header = (f"{'case':32s} {'terms':>9s} {'resp Mt/s':>10s} {'logL Mt/s':>10s} "
              f"{'muladd M/s':>11s} {'resp ratio':>10s} {'logL ratio':>10s} {'trig share':>10s}")
    lines = [header, "-" * len(header)]
    print(header + "\n" + lines[1], flush=True)
    for name, model, k, w in cases(args.full):
        x = random_params(model, k, w, rng)
        data = model.simulate(random_params(model, k, 1, rng)[0], rng=rng)
        terms = w * k * model.n_sensors
        t_resp = best_time(lambda: model.response(x), min_time, repeats)
        t_logl = best_time(lambda: model.log_likelihood(x, data), min_time, repeats)
        fma = muladd_rate(terms, min_time, repeats, rng)
        r_resp, r_logl = terms / t_resp, terms / t_logl
        share = "-"
        if model.kind != "position":  # cos/sin once per source: the part no kernel avoids
            loc = x.reshape(w, k, -1)[..., :-1]
            share = f"{best_time(lambda: model._units(loc), min_time, repeats) / t_resp:.2f}"
        line = (f"{name:32s} {terms:9d} {r_resp / 1e6:10.1f} {r_logl / 1e6:10.1f} "
                f"{fma / 1e6:11.1f} {r_resp / fma:10.2f} {r_logl / fma:10.2f} {share:>10s}")
        lines.append(line)
        print(line, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.txt").write_text("\n".join(lines) + "\n")
    print(f"table written to {args.out / 'throughput.txt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
