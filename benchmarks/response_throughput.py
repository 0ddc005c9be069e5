"""Throughput of the batched Eq. 1 kernel against numpy multiply-add, in one run.

Second part: one parameter vector at a time (user loops, per-walker samplers,
scipy optimisers).  ``Model.log_likelihood``, ``response`` and ``jacobian`` on
one vector against a plain numpy implementation of Eq. 1 written for that one
case (ring: ``I @ max(cos(theta_k - theta_n), 0)``; sphere: unit vectors, then
``I @ max(u n^T, 0)``), timed interleaved in CPU time (best of many rounds);
goal: ratio <= 1.5.

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

    python benchmarks/response_throughput.py            # quick (~40 s)
    python benchmarks/response_throughput.py --full     # more cases and repeats
    python benchmarks/response_throughput.py --single-only  # the one-vector goal table
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


def plain_numpy(model: Model, x: np.ndarray, data: np.ndarray) -> dict:
    """Plain numpy Eq. 1 for one vector ``x`` of this model: {name: callable}."""
    k, s2 = x.size // (model.n_loc + 1), model.sigma**2
    const = model.n_sensors * (np.log(model.sigma) + 0.5 * np.log(2 * np.pi))
    if model.kind == "angle":
        th_n = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])

        def response(x):
            return x[1::2] @ np.maximum(np.cos(x[0::2, None] - th_n), 0.0)

        def jacobian(x):
            d = x[0::2, None] - th_n
            c = np.cos(d)
            jac = np.empty((th_n.size, x.size))
            jac[:, 0::2] = (x[1::2, None] * np.where(c > 0, -np.sin(d), 0.0)).T
            jac[:, 1::2] = np.maximum(c, 0.0).T
            return jac
    else:
        nrm = model.array.normals

        def response(x):
            lon, lat, inten = x[0::3], x[1::3], x[2::3]
            u = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], 1)
            return inten @ np.maximum(u @ nrm.T, 0.0)

        jacobian = None

    def log_likelihood(x):
        r = data - response(x)
        return -0.5 * (r @ r) / s2 - const

    out = {"log_likelihood": log_likelihood, "response": response, "jacobian": jacobian}
    assert k >= 1 and np.isclose(log_likelihood(x), model.log_likelihood(x, data))
    return out


def best_cpu(fns: dict, rounds: int, calls: int = 200) -> dict:
    """Best CPU seconds per call of each callable, the callables interleaved per round."""
    best = dict.fromkeys(fns, np.inf)
    for _ in range(rounds):
        for name, fn in fns.items():
            t0 = time.process_time()
            for _ in range(calls):
                fn()
            best[name] = min(best[name], (time.process_time() - t0) / calls)
    return best


def single_vector(rounds: int, rng: np.random.Generator) -> list[str]:
    """Goal table: one-vector calls against plain numpy (ratios <= 1.5 met)."""
    ring30, sphere = Model(Ring(30), 0.01), Model(Sphere.grid(15, 20), 0.01)
    cases = [("ring N=30 K=1", ring30, 1), ("ring N=30 K=2", ring30, 2),
             ("ring N=30 K=4", ring30, 4), ("sphere N=300 K=1", sphere, 1),
             ("sphere N=300 K=2", sphere, 2), ("sphere N=300 K=4", sphere, 4)]
    header = (f"{'one vector':20s} {'call':15s} {'olsbayes us':>11s} {'numpy us':>9s} "
              f"{'ratio':>6s}  goal <= 1.5")
    lines = [header, "-" * len(header)]
    for name, model, k in cases:
        x = random_params(model, k, 1, rng)[0]
        data = model.simulate(x, rng=rng)
        plain = plain_numpy(model, x, data)
        ours = {"log_likelihood": lambda: model.log_likelihood(x, data),
                "response": lambda: model.response(x), "jacobian": lambda: model.jacobian(x)}
        fns = {}
        for call, fn in ours.items():
            if plain[call] is not None:
                fns[("ours", call)] = fn
                fns[("numpy", call)] = (lambda f=plain[call]: f(x))
        best = best_cpu(fns, rounds)
        for call in ours:
            if ("numpy", call) not in best:
                continue
            a, b = best[("ours", call)], best[("numpy", call)]
            lines.append(f"{name:20s} {call:15s} {a * 1e6:11.2f} {b * 1e6:9.2f} {a / b:6.2f}  "
                         f"{'met' if a / b <= 1.5 else 'not met'}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="more cases and repeats")
    ap.add_argument("--out", type=Path, default=Path("out/response_throughput"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--single-only", action="store_true", help="only the one-vector goal table")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    if args.single_only:
        print("\n".join(single_vector(100 if args.full else 40, rng)), flush=True)
        return 0
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
    single = single_vector(100 if args.full else 40, rng)
    print("\n".join(single), flush=True)
    lines += [""] + single
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.txt").write_text("\n".join(lines) + "\n")
    print(f"table written to {args.out / 'throughput.txt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
