"""A regression fingerprint: the package's numbers on fixed inputs, compared bit for bit.

Records ~740 arrays -- ML fits of random ring scenes (K = 1..4; fast, exact and
multistart; single and batched), sphere, odd-ring, cos^3, plate and custom-law fits,
readings far from unit scale, the ML benchmark's scenes, posteriors at fixed seeds,
``select_k`` tables, imaging and a small study -- so that a restructuring can show
that no number moved (or exactly which did)::

    python benchmarks/fingerprint.py record before.npz      # on one checkout
    python benchmarks/fingerprint.py record after.npz       # on another
    python benchmarks/fingerprint.py compare before.npz after.npz

``record --quick`` fits fewer scenes.  Each section reports its run time; a section
that fails is recorded as ``FAILED.<section>`` and the others go on.
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

import olsbayes as ob  # noqa: E402

OUT: dict[str, np.ndarray] = {}
QUICK = False


def put(name, value):
    arr = np.asarray(value)
    if arr.dtype == object:
        arr = np.asarray(arr.tolist(), dtype=float)
    OUT[name] = arr


def ml_fields(prefix, r):
    for f in ("params", "log_likelihood", "converged", "n_evaluations", "cov", "rival_gap"):
        put(f"{prefix}.{f}", getattr(r, f))


def fit(model, data, k, method="fast", rng=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if rng is None:
            return ob.fit_ml(model, data, k, method=method)
        return ob.fit_ml(model, data, k, method=method, rng=rng)


def ring_scene(rng, k, n):
    while True:
        th = rng.uniform(-np.pi, np.pi, k)
        d = np.abs((th[:, None] - th[None, :] + np.pi) % (2 * np.pi) - np.pi)
        d[np.arange(k), np.arange(k)] = 9
        if k == 1 or d.min() > 2 * np.pi / n * 0.5:
            break
    inten = rng.uniform(0.3, 1.0, k)
    return np.column_stack([th, inten]).ravel()


def section_ml_ring():
    rng = np.random.default_rng(20261125)
    per_k = 100 if QUICK else 500
    for n in (30,):
        for k in (1, 2, 3, 4):
            model = ob.Model(ob.Ring(n), sigma=float(rng.choice([1e-2, 1e-3])))
            truth = np.stack([ring_scene(rng, k, n) for _ in range(per_k)])
            sig = rng.choice([1e-1, 1e-2, 1e-3, 1e-4], size=per_k)
            data = model.response(truth) + sig[:, None] * rng.standard_normal((per_k, n))
            put(f"ring{n}.k{k}.data", data)
            ml_fields(f"ring{n}.k{k}.fast.batch", fit(model, data, k))
            singles = [fit(model, d, k) for d in data]
            for f in ("params", "log_likelihood", "n_evaluations", "rival_gap"):
                put(f"ring{n}.k{k}.fast.single.{f}", [getattr(r, f) for r in singles])
            ml_fields(f"ring{n}.k{k}.exact.batch", fit(model, data, k, "exact"))
            m_single = 40 if k == 4 else per_k
            singles = [fit(model, d, k, "exact") for d in data[:m_single]]
            for f in ("params", "log_likelihood", "n_evaluations"):
                put(f"ring{n}.k{k}.exact.single.{f}", [getattr(r, f) for r in singles])
            m = 20 if QUICK else 100
            ml_fields(f"ring{n}.k{k}.ms.batch", fit(model, data[:m], k, "multistart", rng=7))
            singles = [fit(model, d, k, "multistart", rng=i) for i, d in enumerate(data[:m // 2])]
            for f in ("params", "log_likelihood", "n_evaluations", "rival_gap"):
                put(f"ring{n}.k{k}.ms.single.{f}", [getattr(r, f) for r in singles])


def section_ml_other():
    rng = np.random.default_rng(99)
    # sphere (Fig. 2 array), K = 1, 2
    model = ob.Model(ob.Sphere.grid(15, 20), sigma=1e-2)
    n_fits = 40 if QUICK else 200
    for k in (1, 2):
        lon = rng.uniform(-np.pi, np.pi, (n_fits // 2, k))
        lat = rng.uniform(-0.6, 0.6, (n_fits // 2, k))
        inten = rng.uniform(0.5, 1.0, (n_fits // 2, k))
        truth = np.stack([lon, lat, inten], -1).reshape(n_fits // 2, -1)
        data = model.simulate(truth, rng=rng)
        ml_fields(f"sphere.k{k}.fast.batch", fit(model, data, k))
        singles = [fit(model, d, k) for d in data]
        for f in ("params", "log_likelihood", "n_evaluations"):
            put(f"sphere.k{k}.fast.single.{f}", [getattr(r, f) for r in singles])
        ml_fields(f"sphere.k{k}.ms.batch", fit(model, data[:5], k, "multistart", rng=3))
    # odd ring, power law, plate, custom law
    cases = {
        "ring31": (ob.Model(ob.Ring(31), sigma=1e-2), "angle"),
        "ring16pow3": (ob.Model(ob.Ring(16), sigma=1e-2, sensitivity=ob.CosinePower(3)), "angle"),
        "plate": (ob.Model(ob.Plate.grid(8, 8, 0.5), sigma=1e-2), "position"),
        "custom": (ob.Model(ob.Ring(24), sigma=1e-2, sensitivity=ob.CustomSensitivity(
            lambda c: np.maximum(c, 0) ** 2, lambda c: 2 * np.maximum(c, 0))), "angle"),
    }
    for name, (model, kind) in cases.items():
        for k in (1, 2, 3):
            if kind == "position" and k == 3:
                continue
            t = 30
            if kind == "angle":
                truth = np.stack([ring_scene(rng, k, model.n_sensors) for _ in range(t)])
            else:
                xy = rng.uniform(-1.5, 1.5, (t, k, 2))
                z = rng.uniform(0.5, 2.0, (t, k, 1))
                inten = rng.uniform(0.5, 1.0, (t, k, 1))
                truth = np.concatenate([xy, z, inten], -1).reshape(t, -1)
            data = model.simulate(truth, rng=rng)
            ml_fields(f"{name}.k{k}.fast.batch", fit(model, data, k))
            singles = [fit(model, d, k) for d in data[:10]]
            for f in ("params", "log_likelihood", "n_evaluations"):
                put(f"{name}.k{k}.fast.single.{f}", [getattr(r, f) for r in singles])
            if name == "ring31" and k <= 3:
                ml_fields(f"{name}.k{k}.exact.batch", fit(model, data, k, "exact"))
            ml_fields(f"{name}.k{k}.ms.batch", fit(model, data[:4], k, "multistart", rng=5))
    # units far from 1
    model = ob.Model(ob.Ring(30), sigma=1e-8)
    truth = np.array([0.3, 1e-6, 2.5, 7e-7])
    data = model.simulate(truth, rng=rng, size=10)
    for meth in ("fast", "exact"):
        ml_fields(f"units.{meth}", fit(model, data, 2, meth))
    ml_fields("units.ms", fit(model, data[:3], 2, "multistart", rng=1))


def section_bench():
    rng = np.random.default_rng(3)
    scenes = {
        "fig3": np.array([0.37, 1.0, 0.37 - np.pi, 0.2]),
        "k1": np.array([0.37, 1.0]),
        "k2": np.array([0.37, 1.0, 0.37 + np.pi + 0.13, 0.8]),
        "k3": np.array([0.37, 1.0, 0.37 + 2 * np.pi / 3 + 0.13, 0.8,
                        0.37 + 4 * np.pi / 3 + 0.26, 0.6]),
        "k4": np.array([0.37, 1.0, 0.37 + np.radians(60), 0.867, 0.37 + np.radians(150), 0.733,
                        0.37 + np.radians(260), 0.6]),
    }
    for sig in (1e-3, 1e-2, 1e-1):
        m = ob.Model(ob.Ring(30), sigma=sig)
        for name, x in scenes.items():
            k = len(x) // 2
            data = m.simulate(x, rng=rng, size=50)
            ml_fields(f"bench.{name}.{sig}.fast", fit(m, data, k))
            ml_fields(f"bench.{name}.{sig}.exact", fit(m, data, k, "exact"))
            ml_fields(f"bench.{name}.{sig}.ms", fit(m, data[:5], k, "multistart", rng=11))
            b = ob.crlb(m, ob.Model.unpack(m, x))
            put(f"bench.{name}.{sig}.crlb.cov", b.cov)


def _sample(model, data, k, **kw):
    from olsbayes import posterior
    run = {key: kw.pop(key) for key in ("n_steps", "max_steps", "n_burn") if key in kw}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return posterior.sample(model, data, k, options=posterior.SamplerOptions(**run), **kw)


def section_posterior():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    truth = np.array([0.37, 1.0, 0.37 - np.pi, 0.2])
    data = model.simulate(truth, rng=1)
    for seed in (1, 2):
        r = _sample(model, data, 2, rng=seed, progress=False, n_steps=600)
        put(f"post.fig3.{seed}.draws", r.samples)
        put(f"post.fig3.{seed}.estimate", r.estimate)
        put(f"post.fig3.{seed}.tau", r.tau)
        put(f"post.fig3.{seed}.crlb_cov", r.crlb_cov)
        put(f"post.fig3.{seed}.acc", r.acceptance_fraction)
    r = _sample(model, data, 2, rng=3, progress=False, max_steps=3000)
    put("post.fig3.conv.draws", r.samples)
    put("post.fig3.conv.n_steps", r.n_steps)
    data1 = model.simulate(np.array([1.0, 0.5]), rng=4)
    r = _sample(model, data1, 1, rng=5, progress=False, n_steps=500)
    put("post.k1.draws", r.samples)
    sph = ob.Model(ob.Sphere.grid(8, 10), sigma=1e-2)
    d2 = sph.simulate(np.array([0.3, 0.2, 1.0]), rng=6)
    r = _sample(sph, d2, 1, rng=7, progress=False, n_steps=400)
    put("post.sphere.draws", r.samples)


def _select(model, data, k_max, **kw):
    from olsbayes.select import select_k
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return select_k(model, data, k_max, **kw)


def section_select():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    scenes = [np.array([0.37, 1.0, 0.37 - np.pi, 0.2]), np.array([0.5, 1.0]),
              np.array([0.0, 1.0, 0.3, 0.8]), np.array([0.1, 1.0, 2.2, 0.9, -2.0, 0.7])]
    for i, x in enumerate(scenes):
        data = model.simulate(x, rng=10 + i)
        for meth in ("laplace", "auto", "bic"):
            if meth == "auto" and i == 2 and QUICK:
                continue
            r = _select(model, data, 3, method=meth, rng=2)
            ks = r.evidences
            put(f"sel.{i}.{meth}.k", r.best)
            put(f"sel.{i}.{meth}.p", r.probabilities)
            put(f"sel.{i}.{meth}.logz", r.log_evidence)
            put(f"sel.{i}.{meth}.err", r.error)
            put(f"sel.{i}.{meth}.laplace", [e.laplace for e in ks])
            put(f"sel.{i}.{meth}.params", np.concatenate([e.params for e in ks]))


def section_image():
    from olsbayes import imaging
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    dirs = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    truth = np.zeros(12)
    truth[[1, 5, 6]] = [1.0, 0.6, 0.3]
    x = np.column_stack([dirs, truth]).ravel()
    data = model.simulate(x, rng=3)
    sampled = imaging.ImageOptions(n_samples=200)
    calls = {"gaussian": (imaging.Gaussian(mean=1.0, sd=1.0, scale=2.0), None),
             "nonnegative": (imaging.NonNegative(scale=2.0), sampled),
             "bounded": (imaging.Bounded(i_max=2.0), sampled)}
    for prior, (obj, opts) in calls.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = imaging.image(model, data, dirs, obj, options=opts, rng=4)
        put(f"img.{prior}.mean", r.mean)
        put(f"img.{prior}.sd", r.sd)
        if getattr(r, "samples", None) is not None:
            put(f"img.{prior}.samples", r.samples)


def section_study():

    from olsbayes import run_study
    from olsbayes.studies import Estimator
    from olsbayes.studies.estimators import ring_estimate
    grid = {"estimator": [Estimator("fast"), Estimator("multistart", n_starts=5),
                          Estimator("exact")], "sigma": [1e-3, 1e-2]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = run_study(ring_estimate, grid, n_trials=12,
                       fixed={"n_sensors": 16, "n_sources": 2}, rng=1, executor="serial",
                       progress=False)
    for v in ds.data_vars:
        if v in ("seconds", "cpu_seconds"):
            continue
        put(f"study.{v}", ds[v].values)


def record(out: str) -> None:
    """Run every section and save the arrays to ``out`` (.npz)."""
    t0 = time.time()
    for sec in (section_ml_ring, section_ml_other, section_bench, section_posterior,
                section_select, section_image, section_study):
        t = time.time()
        try:
            sec()
        except Exception as exc:  # record the failure, go on
            print(f"{sec.__name__} FAILED: {type(exc).__name__}: {exc}", flush=True)
            put(f"FAILED.{sec.__name__}", 1)
        print(f"{sec.__name__}: {time.time() - t:.1f} s", flush=True)
    np.savez_compressed(out, **OUT)
    print(f"{len(OUT)} arrays, {time.time() - t0:.1f} s -> {out}")


def compare(before: str, after: str) -> int:
    """Print every array that differs between two recordings; returns their number."""
    a, b = np.load(before), np.load(after)
    same = diff = 0
    for k in sorted(set(a.files) | set(b.files)):
        if k not in a.files or k not in b.files:
            print(f"MISSING {k}: before={k in a.files} after={k in b.files}")
            diff += 1
            continue
        x, y = a[k], b[k]
        if x.shape != y.shape:
            print(f"SHAPE {k}: {x.shape} vs {y.shape}")
            diff += 1
        elif np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"):
            same += 1
        else:
            diff += 1
            bad = ~((x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind in "fc" else x == y)
            extra = ""
            if x.dtype.kind in "fc":
                with np.errstate(invalid="ignore"):
                    d = np.abs(x - y)[bad]
                extra = f", max |d| {np.nanmax(d) if np.isfinite(d).any() else 'nan'}"
            print(f"DIFF {k}: {int(bad.sum())}/{x.size} elements{extra}")
    print(f"identical: {same}, different: {diff}, total {same + diff}")
    return diff


def main() -> None:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="record this checkout's numbers")
    r.add_argument("out")
    r.add_argument("--quick", action="store_true", help="fewer ring scenes")
    c = sub.add_parser("compare", help="compare two recordings bit for bit")
    c.add_argument("before")
    c.add_argument("after")
    args = p.parse_args()
    if args.cmd == "record":
        global QUICK
        QUICK = args.quick
        record(args.out)
    else:
        raise SystemExit(1 if compare(args.before, args.after) else 0)


if __name__ == "__main__":
    main()
