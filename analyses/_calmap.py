"""Scenes, posterior methods and the study trial of the calibration map.

One trial draws a scene of the cell (geometry, K, separation, SNR, distance of
the nearest pair from antipodal), simulates readings and runs ONE posterior
method on them.  Every method reports the posterior CDF at the truth of every
parameter, ``u`` (the randomised PIT: ``(rank + V) / (L + 1)`` among L draws,
V ~ U(0, 1)); a calibrated posterior gives ``u`` uniform on (0, 1), so the
central 50 % / 90 % intervals cover the truth when ``|u - 1/2| < 1/4`` /
``< 0.45``.  Parameters are compared in canonical order (angles wrapped,
sources sorted by location: :meth:`olsbayes.Model.canonical`), a fixed function
of the parameters, so no matching to the truth enters the ranks.

Studies of different methods on one group of cells use the same root seed and
the same grid, so trial t of cell c sees the same scene and readings for every
method (the scene is drawn before the method touches the generator).

Adding a method is one line in :data:`METHODS`.
"""

from __future__ import annotations

import functools
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import stats

import olsbayes as ob
from olsbayes.bounds import bound_covariance
from olsbayes.circular import wrap_angle
from olsbayes.errors import InputError
from olsbayes.studies import Setting, trial_settings
from olsbayes.studies.scoring import score

__all__ = ["METHODS", "Method", "P_MAX", "calmap_trial", "draw_scene", "antipodal_gap",
           "u_from_draws", "ANTIPODAL_BINS", "N_RING"]

#: Sub-sensors of the ring; the sphere is a Fibonacci lattice of N_SPHERE.
N_RING, N_SPHERE = 30, 64
#: Intensities of the sources: Uniform(I_LO, I_HI); the posterior's prior is Uniform(0, I_MAX).
I_LO, I_HI, I_MAX = 0.7, 1.3, 2.0
#: Parameters of the largest scene (K = 4 on a sphere: lon, lat, I), for padding.
P_MAX = 12
#: Draws per posterior used for the ranks.
N_DRAWS = 199
#: Bins of the nearest pair's distance from antipodal (sensor spacings): axis value = lower
#: edge; the last bin is the control (no pair within 2 spacings of pi).
ANTIPODAL_BINS = {0.0: (0.0, 0.5), 0.5: (0.5, 1.0), 1.0: (1.0, 2.0), 2.0: (2.0, 99.0)}
#: Smallest neighbour separation (spacings) of the antipodal scenes.
MIN_GAP = 2.0


def spacing(geometry: str) -> float:
    """Angular sensor spacing (rad): 2 pi / N on the ring, sqrt(4 pi / N) on the sphere."""
    return 2 * np.pi / N_RING if geometry == "ring" else float(np.sqrt(4 * np.pi / N_SPHERE))


def _unit(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)


def pair_angles(geometry: str, loc: np.ndarray) -> np.ndarray:
    """Angular distances (rad) of all pairs of source locations ``loc`` (K, d)."""
    k = len(loc)
    if geometry == "ring":
        d = np.abs(wrap_angle(loc[:, None, 0] - loc[None, :, 0]))
    else:
        v = _unit(loc[:, 0], loc[:, 1])
        d = np.arccos(np.clip(v @ v.T, -1, 1))
    return d[np.triu_indices(k, 1)]


def antipodal_gap(geometry: str, loc: np.ndarray) -> float:
    """Distance of the nearest pair from antipodal, in sensor spacings (inf for K = 1)."""
    d = pair_angles(geometry, loc)
    return float(np.min(np.pi - d) / spacing(geometry)) if len(d) else np.inf


def _ring_locs(k: int, settings: dict, rng: np.random.Generator) -> np.ndarray:
    h = spacing("ring")
    if float(settings.get("antipodal", -1.0)) < 0:  # a chain at the cell's separation
        th = rng.uniform(-np.pi, np.pi) + float(settings.get("separation", 3.0)) * h * np.arange(k)
        return wrap_angle(th)[:, None]
    lo, hi = ANTIPODAL_BINS[float(settings["antipodal"])]
    while True:  # rejection: uniform scenes whose nearest-to-antipodal pair is in the bin
        th = rng.uniform(-np.pi, np.pi, k)
        d = pair_angles("ring", th[:, None])
        if d.min() >= MIN_GAP * h and lo <= (np.pi - d.max()) / h < hi:
            return th[:, None]


def _sphere_locs(k: int, settings: dict, rng: np.random.Generator) -> np.ndarray:
    """First source uniform on the sphere, each next one ``separation`` further on a
    random great circle through the previous one."""
    v = rng.standard_normal(3)
    pts = [v / np.linalg.norm(v)]
    step = float(settings.get("separation", 3.0)) * spacing("sphere")
    for _ in range(k - 1):
        w = rng.standard_normal(3)
        w -= (w @ pts[-1]) * pts[-1]
        w /= np.linalg.norm(w)
        pts.append(np.cos(step) * pts[-1] + np.sin(step) * w)
    p = np.array(pts)
    return np.column_stack([np.arctan2(p[:, 1], p[:, 0]), np.arcsin(np.clip(p[:, 2], -1, 1))])


def draw_scene(settings: dict, rng: np.random.Generator) -> tuple[ob.Model, np.ndarray]:
    """The cell's model (sigma = 1 / snr) and one scene (canonical flat parameters)."""
    geometry, k = str(settings.get("geometry", "ring")), int(settings["n_sources"])
    array = ob.Ring(N_RING) if geometry == "ring" else ob.Sphere.fibonacci(N_SPHERE)
    model = ob.Model(array, 1.0 / float(settings["snr"]))
    loc = (_ring_locs if geometry == "ring" else _sphere_locs)(k, settings, rng)
    inten = rng.uniform(I_LO, I_HI, k)
    return model, model.canonical(np.column_stack([loc, inten]).ravel())


def u_from_draws(truth: np.ndarray, draws: np.ndarray, rng: np.random.Generator,
                 weights: np.ndarray | None = None) -> np.ndarray:
    """Randomised PIT (P,) of ``truth`` (P,) among draws (L, P), optionally weighted.

    Unweighted: ``(#{draws < truth} + V) / (L + 1)`` with V ~ U(0, 1), exactly
    uniform when the truth is a draw of the same posterior.  Weighted: the
    posterior probability below the truth plus V times the weight of ties.
    """
    v = rng.uniform(size=truth.shape)
    if weights is None:
        return (np.sum(draws < truth, axis=0) + v) / (len(draws) + 1)
    return weights @ (draws < truth) + v * (weights @ (draws == truth))


# ---------------------------------------------------------------- the methods
# Each: method(model, data, truth, settings, rng) -> dict with "u" (P,) and optionally
# "converged" (bool), "rhat" (float), "z2" (2,), "k_hat" (int).

def emcee_default(model, data, truth, settings, rng, multimodal=None) -> dict:
    """:func:`olsbayes.sample_posterior` (uniform directions, intensities U(0, I_MAX)).

    ``multimodal``: the sampler's choice (None: automatic, the default; False: one
    ensemble; True: one ensemble per mode, :mod:`olsbayes.posterior.multimodal`).
    """
    k = model.n_sources_of(truth)
    prior = ob.default_priors(model, k, i_max=I_MAX)
    max_steps = int(settings.get("max_steps", 20000))
    opts = ob.SamplerOptions(max_steps=max_steps, multimodal=multimodal)
    res = ob.sample_posterior(model, data, k, priors=prior, options=opts, rng=rng,
                              progress=False)
    s = res.samples  # (W, D, P)
    step = max(1, int(np.ceil(np.nanmax(res.tau) / max(res.thin, 1))))
    pool = s[:, ::step].reshape(-1, s.shape[-1])
    draws = model.canonical(pool[rng.choice(len(pool), N_DRAWS, replace=len(pool) < N_DRAWS)])
    return {"u": u_from_draws(truth, draws, rng), "converged": bool(res.converged)}


def laplace(model, data, truth, settings, rng) -> dict:
    """Gaussian at the ML fit with the CRLB (inverse Fisher) covariance; also scores the
    ML fit against the CRLB at the truth and selects K by Laplace evidences."""
    k = model.n_sources_of(truth)
    fit = ob.fit_ml(model, data, k, rng=rng, warn=False)
    est = np.asarray(fit.params, float)
    sc = score(model, est[None], truth[None])
    z2 = np.array([sc["dir_z2"][0], sc["int_z2"][0]])
    k_hat = int(ob.select_k(model, data, k_max=min(k + 1, 5), method="laplace", rng=rng,
                            i_max=I_MAX, progress=False).best)
    cov, _, singular = bound_covariance(model.fisher(est))
    if np.any(singular) or not np.all(np.isfinite(cov)):
        return {"u": np.full(len(truth), np.nan), "z2": z2, "k_hat": k_hat, "converged": False}
    root = np.linalg.cholesky(0.5 * (cov + cov.T) + 1e-300 * np.eye(len(est)))
    draws = model.canonical(est + rng.standard_normal((N_DRAWS, len(est))) @ root.T)
    return {"u": u_from_draws(truth, draws, rng), "z2": z2, "k_hat": k_hat, "converged": True}


def exact_ring(model, data, truth, settings, rng) -> dict:
    """Exact posterior on a grid (K <= 2 on the ring; no chain, no missed mode)."""
    from olsbayes.studies.sbc_exact import exact_ring_posterior

    k = model.n_sources_of(truth)
    draws, w = exact_ring_posterior(model, data, k, I_MAX, rng=rng, n_grid=1024, per_cell=8)
    ess = 1.0 / np.sum(w * w)
    return {"u": u_from_draws(truth, draws, rng, weights=w), "converged": bool(ess >= 200)}


def imaging(prior: object) -> Callable:
    """Intensities at the true (known) directions under an imaging prior."""
    def run(model, data, truth, settings, rng) -> dict:
        k = model.n_sources_of(truth)
        blocks = truth.reshape(k, -1)
        loc = blocks[:, 0] if model.kind == "angle" else blocks[:, :-1]
        res = ob.image(model, data, loc, prior, rng=rng, progress=False)
        u = np.full(len(truth), np.nan)
        if res.samples is None:  # closed form (Gaussian prior)
            u[model.n_loc::model.n_loc + 1] = stats.norm.cdf(blocks[:, -1], res.mean, res.sd)
        else:
            draws = res.samples.reshape(-1, k)
            u[model.n_loc::model.n_loc + 1] = u_from_draws(blocks[:, -1], draws, rng)
        return {"u": u, "rhat": float(res.rhat), "converged": bool(res.rhat <= 1.01)}
    run.__name__ = f"imaging_{getattr(prior, 'name', prior)}"
    return run


@dataclass(frozen=True)
class Method:
    """A posterior method of the map: its runner and the cells it applies to."""

    name: str
    run: Callable
    applies: Callable[[dict], bool] = lambda cell: True


def _ring_k12_low_snr(cell: dict) -> bool:
    # the grid posterior resolves directions to ~1/1024 turn: enough up to SNR ~ 300
    return cell.get("geometry", "ring") == "ring" and cell["n_sources"] <= 2 \
        and cell["snr"] <= 300


def _ring_k2_up(cell: dict) -> bool:
    # where one ensemble and one per mode can differ: two or more sources on a ring
    return cell.get("geometry", "ring") == "ring" and cell["n_sources"] >= 2


#: The posterior methods of the map, one line each.
METHODS: dict[str, Method] = {m.name: m for m in (
    Method("emcee", emcee_default),
    Method("emcee-single", functools.partial(emcee_default, multimodal=False), _ring_k2_up),
    Method("emcee-modes", functools.partial(emcee_default, multimodal=True), _ring_k2_up),
    Method("laplace", laplace),
    Method("exact", exact_ring, _ring_k12_low_snr),
    Method("image-bounded", imaging(ob.imaging.Bounded(i_max=I_MAX))),
    Method("image-gaussian", imaging(ob.imaging.Gaussian(mean=1.0, sd=0.5))),
)}


def _method(value: object, where: str) -> str:
    """A name of :data:`METHODS`, else InputError naming ``where`` and the accepted names."""
    if not isinstance(value, str) or value not in METHODS:
        raise InputError(f"{where} must be one of {', '.join(METHODS)}; got {value!r}")
    return value


def _geometry(value: object, where: str) -> str:
    if value not in ("ring", "sphere"):
        raise InputError(f"{where} must be 'ring' or 'sphere'; got {value!r}")
    return str(value)


@trial_settings("max_steps", geometry=_geometry, n_sources=Setting("int", 1, 4),
                separation=Setting("float", 0, 20), snr=Setting("float", 1, 1e6),
                antipodal=Setting("float", -1, 2), method=_method)
def calmap_trial(settings: dict, *, rng: np.random.Generator) -> dict:
    """One scene of the cell, one posterior method: PIT, coverage inputs and ML scores.

    Returns ``u`` (P_MAX,) NaN-padded (NaN also where the method gives no
    answer, e.g. a singular Fisher matrix for Laplace), ``converged``, ``rhat``
    (imaging; NaN otherwise), ``z2`` (2,) ML (direction, intensity) squared
    errors in CRLB units and ``k_hat`` (Laplace only; NaN / -1 otherwise),
    ``gap`` (nearest pair's distance from antipodal, spacings), ``applies``
    (False: the method does not apply to the cell, nothing ran) and ``seconds``.
    """
    method = METHODS[str(settings["method"])]
    model, truth = draw_scene(settings, rng)
    data = model.simulate(truth, rng=rng)
    loc = truth.reshape(model.n_sources_of(truth), -1)[:, :-1]
    out = {"u": np.full(P_MAX, np.nan), "converged": False, "rhat": np.nan,
           "z2": np.full(2, np.nan), "k_hat": -1,
           "gap": antipodal_gap(str(settings.get("geometry", "ring")), loc),
           "applies": bool(method.applies(settings)), "seconds": 0.0}
    if not out["applies"]:
        return out
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.errors.OlsBayesWarning)
        res = method.run(model, data, truth, settings, rng)
    out.update({k: v for k, v in res.items() if k != "u"}, seconds=time.process_time() - t0)
    out["u"][: len(truth)] = res["u"]
    return out
