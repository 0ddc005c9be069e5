"""Eq. 1 forward model: analytic Jacobian, batching, linearity, trig-free kernel."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes import (
    Cosine,
    CosinePower,
    CustomSensitivity,
    InputError,
    Model,
    Plate,
    Ring,
    Scene,
    Sphere,
)

SIGMA = 0.01


def _smooth_law():
    """A user law with a smooth (kink-free) derivative: g(c) = (1 + c)^2 / 4."""
    return CustomSensitivity(lambda c: 0.25 * (1.0 + c) ** 2, lambda c: 0.5 * (1.0 + c),
                             name="cardioid2")


LAWS = {"cosine": Cosine(), "cosine_power3": CosinePower(3.0), "custom": _smooth_law()}


def _params(kind: str, rng: np.random.Generator, k: int, batch: tuple[int, ...] = ()):
    """Random flat parameters of ``k`` sources in the model layout."""
    inten = rng.uniform(0.3, 2.0, batch + (k, 1))
    if kind == "angle":
        loc = rng.uniform(-np.pi, np.pi, batch + (k, 1))
    elif kind == "lonlat":
        loc = np.stack([rng.uniform(-np.pi, np.pi, batch + (k,)),
                        rng.uniform(-1.2, 1.2, batch + (k,))], axis=-1)
    else:
        loc = np.stack([rng.uniform(-1.5, 1.5, batch + (k,)), rng.uniform(-1.5, 1.5, batch + (k,)),
                        rng.uniform(0.5, 3.0, batch + (k,))], axis=-1)
    return np.concatenate([loc, inten], axis=-1).reshape(batch + (-1,))


ARRAYS = {
    "ring": lambda: Ring(24, offset=0.1),
    "sphere": lambda: Sphere.grid(6, 8),
    "plate": lambda: Plate.grid(4, 5, pitch=0.7),
}


def _central_difference(model: Model, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        cols.append((model.response(x + e) - model.response(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


def _away_from_kink(model: Model, x: np.ndarray, h: float) -> bool:
    """Finite differences across the clipped cosine's kink are meaningless."""
    return not model.sensitivity.kink or np.abs(model.cosines(x)).min() > 1e3 * h


@pytest.mark.parametrize("law", sorted(LAWS))
@pytest.mark.parametrize("geometry", sorted(ARRAYS))
def test_jacobian_matches_central_differences(geometry, law):
    model = Model(ARRAYS[geometry](), SIGMA, LAWS[law])
    rng = np.random.default_rng(11)
    h = 1e-6
    checked = 0
    while checked < 3:
        x = _params(model.kind, rng, k=2)
        if not _away_from_kink(model, x, h):
            continue
        jac = model.jacobian(x)
        fd = _central_difference(model, x, h)
        assert jac.shape == (model.n_sensors, x.size)
        # truncation O(h^2 g''') ~ 1e-12 plus round-off O(eps / h) ~ 1e-10
        np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-7)
        checked += 1


@pytest.mark.parametrize("geometry", sorted(ARRAYS))
def test_batched_equals_loop_of_single_calls(geometry):
    model = Model(ARRAYS[geometry](), SIGMA, CosinePower(2.0))
    rng = np.random.default_rng(5)
    x = _params(model.kind, rng, k=3, batch=(4, 3))
    data = model.simulate(_params(model.kind, rng, k=3), rng=rng)
    resp, jac, fish = model.response(x), model.jacobian(x), model.fisher(x)
    logl = model.log_likelihood(x, data)
    assert resp.shape == (4, 3, model.n_sensors)
    assert jac.shape == (4, 3, model.n_sensors, x.shape[-1])
    assert logl.shape == (4, 3)
    for idx in np.ndindex(4, 3):
        np.testing.assert_allclose(resp[idx], model.response(x[idx]), rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(jac[idx], model.jacobian(x[idx]), rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(fish[idx], model.fisher(x[idx]), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(logl[idx], model.log_likelihood(x[idx], data), rtol=1e-13)


@pytest.mark.parametrize("law", sorted(LAWS))
@pytest.mark.parametrize("geometry", sorted(ARRAYS))
def test_one_vector_equals_a_batch_of_one_to_the_bit(geometry, law):
    """The single-vector short paths repeat the batched arithmetic exactly."""
    model = Model(ARRAYS[geometry](), SIGMA, LAWS[law])
    rng = np.random.default_rng(21)
    for k in range(7):
        data = model.simulate(_params(model.kind, rng, k=2), rng=rng)
        for _ in range(5):
            x = _params(model.kind, rng, k=k)
            one = x[None]  # a batch of one takes the batched path
            assert np.array_equal(model.response(x), model.response(one)[0])
            assert np.array_equal(model.jacobian(x), model.jacobian(one)[0])
            logl = model.log_likelihood(one, data)[0]
            assert model.log_likelihood(x, data) == logl
            assert model.log_likelihood(list(x), data) == logl


@pytest.mark.parametrize("geometry", ["ring", "sphere"])
def test_one_vector_short_paths_refuse_what_the_general_path_refuses(geometry):
    """Bad single vectors and readings raise the general path's InputError, word for word."""
    model = Model(ARRAYS[geometry](), SIGMA)
    rng = np.random.default_rng(4)
    x = _params(model.kind, rng, k=2)
    data = model.simulate(x, rng=rng)
    bad_calls = [
        lambda: model.log_likelihood(x[:-1], data),          # not a multiple of d + 1
        lambda: model.log_likelihood(x, data[:-1]),          # wrong number of readings
        lambda: model.log_likelihood(x, data.astype(complex)),
        lambda: model.log_likelihood(x.astype(complex), data),
        lambda: model.response(x[:-1]),
        lambda: model.jacobian(x[:-1]),
    ]
    for call in bad_calls:
        with pytest.raises(InputError) as fast:
            call()
        assert "must" in str(fast.value)
    # the same messages as a batch of one (which never takes a short path)
    with pytest.raises(InputError, match=r"last axis a multiple") as one:
        model.response(x[:-1])
    with pytest.raises(InputError) as batch:
        model.response(x[None, :-1])
    assert str(one.value).split("; got")[0] == str(batch.value).split("; got")[0]
    with pytest.raises(InputError) as one:
        model.log_likelihood(x, data[:-1])
    with pytest.raises(InputError) as batch:
        model.log_likelihood(x[None], data[:-1])
    assert str(one.value) == str(batch.value)


def test_one_vector_log_likelihood_is_a_float_equal_to_the_general_path():
    """The short path's value is the measurement layer's, to the bit, as a numpy float."""
    from olsbayes import measurement

    model = Model(Ring(30), SIGMA)
    rng = np.random.default_rng(6)
    for k in (1, 2, 4):
        x = _params(model.kind, rng, k=k)
        data = model.simulate(x, rng=rng)
        fast = model.log_likelihood(x, data)
        general = measurement.log_likelihood(model, x, data)
        assert fast == general and np.ndim(fast) == 0
        assert model.log_likelihood(x, data.tolist()) == fast  # a list takes the general path


@pytest.mark.parametrize("geometry", sorted(ARRAYS))
def test_response_is_linear_in_intensities(geometry):
    model = Model(ARRAYS[geometry](), SIGMA)
    rng = np.random.default_rng(8)
    x = _params(model.kind, rng, k=3)
    blocks = x.reshape(3, -1)
    scaled = blocks.copy()
    scaled[:, -1] *= 2.5
    np.testing.assert_allclose(model.response(scaled.ravel()), 2.5 * model.response(x),
                               rtol=1e-13)
    # superposition: the response of K sources is the sum of single-source responses
    singles = sum(model.response(b) for b in blocks)
    np.testing.assert_allclose(model.response(x), singles, rtol=1e-13, atol=1e-15)


def test_ring_response_equals_eq1_written_with_trigonometry():
    ring = Ring(30, offset=0.05)
    model = Model(ring, SIGMA)
    theta, inten = np.array([0.37, -2.0, 1.1]), np.array([1.0, 0.2, 0.5])
    scene = Scene(directions=theta, intensities=inten)
    gamma = theta[:, None] - ring.angles[None, :]
    expect = (inten[:, None] * np.maximum(np.cos(gamma), 0.0)).sum(axis=0)
    np.testing.assert_allclose(model.response(scene), expect, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(model.cosines(scene), np.cos(gamma), rtol=0, atol=1e-15)


def test_sphere_cosines_equal_spherical_law_of_cosines():
    sphere = Sphere.grid(5, 7)
    model = Model(sphere, SIGMA)
    lon, lat = np.array([0.3, -2.0]), np.array([0.4, -1.0])
    scene = Scene(directions=np.column_stack([lon, lat]), intensities=[1.0, 1.0])
    expect = (np.sin(lat[:, None]) * np.sin(sphere.lat) + np.cos(lat[:, None])
              * np.cos(sphere.lat) * np.cos(lon[:, None] - sphere.lon))
    np.testing.assert_allclose(model.cosines(scene), expect, rtol=0, atol=1e-14)


def test_plate_response_falls_as_inverse_square():
    model = Model(Plate.grid(3, 3), SIGMA)
    near = model.response(Scene(positions=[[0.0, 0.0, 1.0]], intensities=[1.0]))
    far = model.response(Scene(positions=[[0.0, 0.0, 2.0]], intensities=[1.0]))
    centre = 4  # sub-sensor at the origin, facing the source: g = 1
    assert near[centre] == pytest.approx(1.0, rel=1e-14)
    assert far[centre] == pytest.approx(0.25, rel=1e-14)


def test_kernel_is_trig_free_per_sensor_source_pair(monkeypatch):
    """cos/sin are evaluated per source (O(W K)), never per sensor-source pair."""
    counted = {"n": 0}
    for name in ("cos", "sin"):
        ufunc = getattr(np, name)

        def counting(a, *args, _f=ufunc, **kw):
            counted["n"] += np.size(a)
            return _f(a, *args, **kw)

        monkeypatch.setattr(np, name, counting)
    for array in (Ring(500), Sphere.fibonacci(500)):
        model = Model(array, SIGMA)
        x = _params(model.kind, np.random.default_rng(0), k=4, batch=(64,))
        counted["n"] = 0
        model.response(x)
        model.jacobian(x)
        # at most a handful of trig calls per source and batch member
        assert 0 < counted["n"] <= 16 * 64 * 4, counted["n"]


def test_log_likelihood_broadcasts_and_matches_gaussian():
    model = Model(Ring(12), 0.05)
    rng = np.random.default_rng(2)
    x = _params("angle", rng, k=1)
    data = model.simulate(x, rng=rng, size=3)
    logl = model.log_likelihood(x, data)
    resid = data - model.response(x)
    expect = (-0.5 * (resid**2).sum(-1) / 0.05**2
              - 12 * np.log(0.05) - 6 * np.log(2 * np.pi))
    np.testing.assert_allclose(logl, expect, rtol=1e-13)


def test_simulate_noise_has_sigma_and_is_reproducible():
    model = Model(Ring(30), 0.02)
    scene = Scene(directions=[0.5], intensities=[1.0])
    a = model.simulate(scene, rng=3, size=4000)
    np.testing.assert_array_equal(a, model.simulate(scene, rng=np.random.default_rng(3), size=4000))
    resid = a - model.response(scene)
    sd = resid.std()
    # sampling sd of a std estimate from M = 120000 draws: sigma / sqrt(2 M)
    assert abs(sd - 0.02) < 5 * 0.02 / np.sqrt(2 * resid.size)
    assert abs(resid.mean()) < 5 * 0.02 / np.sqrt(resid.size)


def test_pack_unpack_round_trip_and_canonical_order():
    model = Model(Ring(10), SIGMA)
    scene = Scene(directions=[2.0, -1.0], intensities=[0.5, 1.5])
    x = model.pack(scene)
    assert model.param_names(2) == ["theta[0]", "I[0]", "theta[1]", "I[1]"]
    assert model.unpack(x) == scene
    canon = model.canonical(x + np.array([2 * np.pi, 0, 0, 0]))
    np.testing.assert_allclose(canon, [-1.0, 1.5, 2.0, 0.5], atol=1e-14)


def test_model_rejects_bad_parameter_layout():
    model = Model(Sphere.fibonacci(20), SIGMA)
    with pytest.raises(InputError, match="multiple of 3"):
        model.response(np.zeros(4))
    with pytest.raises(InputError, match="'angle'"):
        Model(Ring(10), SIGMA).pack(Scene(directions=[[0.1, 0.2]], intensities=[1.0]))


@pytest.mark.parametrize("p", [1.0, 1.5, 2.0, 3.0, 5.5, 7.0, 12.25, 64.0])
def test_cosine_power_fast_power_matches_numpy(p):
    """CosinePower uses repeated squaring; it must agree with ``**`` to a few ulp."""
    law = CosinePower(p)
    c = np.linspace(-1.0, 1.0, 2001)
    cp = np.maximum(c, 0.0)
    np.testing.assert_allclose(law.value(c), cp**p, rtol=1e-14, atol=0)
    if p > 1:
        np.testing.assert_allclose(law.derivative(c), p * cp ** (p - 1), rtol=1e-14, atol=0)


def test_empty_scene_is_the_noise_only_model():
    """K = 0 (a candidate of select_k) packs to no parameters and reads zeros."""
    model = Model(Ring(30), SIGMA)
    empty = Scene(directions=[], intensities=[])
    assert model.pack(empty).shape == (0,)
    np.testing.assert_array_equal(model.response(empty), np.zeros(30))
    assert model.unpack(model.pack(empty)).n_sources == 0


# -- immutability: nothing a cache is derived from can change ------------------------
def _attribute_names(obj) -> list[str]:
    return [n for n in vars(obj) if n != "_frozen"]


@pytest.mark.parametrize("make", [
    lambda: ob.Model(ob.Ring(12), 0.01),
    lambda: ob.Model(ob.Sphere.grid(4, 5), 0.01, ob.CosinePower(3)),
    lambda: ob.Model(ob.Plate.grid(3, 3, 0.5), 0.01),
])
def test_model_array_and_law_refuse_every_assignment(make):
    """Every attribute of a model, its array and its law -- all that the cached
    atoms, kernel arguments and designs are derived from -- refuses assignment and
    deletion, and the arrays behind them are read-only."""
    model = make()
    model.memo("probe", lambda: 1)
    for obj in (model, model.array, model.sensitivity):
        names = _attribute_names(obj)
        assert names or obj is model.sensitivity
        for name in names + ["sigma", "new_attribute"]:
            with pytest.raises(AttributeError, match="immutable"):
                setattr(obj, name, 1.0)
        for name in names:
            with pytest.raises(AttributeError, match="immutable"):
                delattr(obj, name)
    for arr in (model.array.normals, model.array.positions):
        if arr is not None:
            assert not arr.flags.writeable


def test_changed_copies_and_copies_never_share_a_cache():
    """with_sigma / with_sensitivity, copy, deepcopy and pickle give models with their
    own (empty) caches: a fit of a changed copy uses its own atoms."""
    import copy
    import pickle

    from olsbayes.ml.atoms import atoms, cached_default_grid

    model = ob.Model(ob.Ring(16), 0.01)
    grid = cached_default_grid(model)
    base = atoms(model, grid)
    sharp = model.with_sensitivity(ob.CosinePower(3))
    assert sharp.sigma == model.sigma and isinstance(sharp.sensitivity, ob.CosinePower)
    assert not np.array_equal(atoms(sharp, cached_default_grid(sharp)), base)
    np.testing.assert_allclose(atoms(sharp, grid), base**3, rtol=1e-14, atol=1e-300)
    noisy = model.with_sigma(0.5)
    assert noisy.sigma == 0.5 and noisy.sensitivity is model.sensitivity
    for other in (copy.copy(model), copy.deepcopy(model), pickle.loads(pickle.dumps(model)),
                  noisy, sharp):
        assert other is not model and other._memo is not model._memo
    for other in (copy.copy(model), copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
        assert other._memo == {} and other.sigma == model.sigma
    with pytest.raises(ob.InputError, match="sigma"):
        model.with_sigma(-1.0)


def test_memo_lookup_without_make_computes_nothing():
    from olsbayes.ml.atoms import atoms, cached_default_grid

    model = ob.Model(ob.Ring(8), 0.1)
    assert model.memo("default_grid") is None
    atoms(model, np.array([[0.1], [0.2]]))  # a user grid first: the default is not stored
    assert model.memo("default_grid") is None
    grid = cached_default_grid(model)
    assert model.memo("default_grid") is grid and grid.shape[0] >= 128
    assert atoms(model, grid) is atoms(model, grid)
