"""TOML configuration: schema registry, defaults, paths, builders for every geometry."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.build import (
    array_from_config,
    data_from_config,
    model_from_config,
    scene_from_config,
)
from olsbayes.config import (
    Field,
    Section,
    get_section,
    load_config,
    parse_config,
    read_readings,
    register_section,
    registered_sections,
)


def test_foundation_sections_registered():
    assert {"sensor", "scene", "data"} <= set(registered_sections())
    assert get_section("sensor").accepted("plate") == ("geometry", "sigma", "sensitivity", "p",
                                                       "nx", "ny", "pitch")


def test_other_commands_can_declare_their_own_section():
    sec = Section(name="_test_widget", doc="a test section", fields={
        "size": Field("int", default=3, low=1, high=10),
        "label": Field("str", choices=("a", "b")),
        "weights": Field("array", ndim=(1,)),
    })
    register_section(sec)
    register_section(sec)  # idempotent for the same declaration
    with pytest.raises(ValueError, match="already registered"):
        register_section(Section(name="_test_widget", fields={}))
    cfg = parse_config('[_test_widget]\nlabel = "B"\nweights = [1, 2.5]\n',
                       sections=["_test_widget"])
    table = cfg.section("_test_widget")
    assert table["size"] == 3 and table["label"] == "b"
    np.testing.assert_array_equal(table["weights"], [1.0, 2.5])
    # a command accepts only the sections it names
    with pytest.raises(ob.ConfigError, match=r"accepted sections: \[_test_widget\]"):
        parse_config('[sensor]\ngeometry = "ring"\n', sections=["_test_widget"])
    with pytest.raises(ob.ConfigError, match="size must be in"):
        parse_config("[_test_widget]\nsize = 11\n", sections=["_test_widget"])


def test_overrides_apply_before_validation():
    text = '[sensor]\ngeometry = "ring"\nn = 30\nsigma = 0.01\n'
    cfg = parse_config(text, overrides={"sensor.sigma": 0.5, "sensor.n": 12})
    model = model_from_config(cfg)
    assert model.sigma == 0.5 and model.n_sensors == 12
    with pytest.raises(ob.ConfigError, match="section.key"):
        parse_config(text, overrides={"sigma": 1.0})


def test_ring_scene_in_degrees_and_simulated_data():
    cfg = parse_config(
        '[sensor]\ngeometry = "ring"\nn = 12\nsigma = 0.1\nsensitivity = "cosine_power"\n'
        "p = 3\n[scene]\ndirections = [90.0, -45.0]\nintensities = [1, 2]\n"
        'angle_unit = "deg"\n[data]\nsimulate = true\nseed = 4\nrepeats = 3\n'
    )
    model = model_from_config(cfg)
    assert isinstance(model.sensitivity, ob.CosinePower) and model.sensitivity.p == 3.0
    scene = scene_from_config(cfg, model)
    np.testing.assert_allclose(scene.directions, [np.pi / 2, -np.pi / 4])
    data = data_from_config(cfg, model, scene)
    np.testing.assert_array_equal(data, model.simulate(scene, rng=4, size=3))


def test_sphere_and_plate_geometries():
    sph = array_from_config(parse_config(
        '[sensor]\ngeometry = "sphere"\nn_lat = 15\nn_lon = 20\nsigma = 0.01\n'))
    assert sph == ob.Sphere.grid(15, 20, np.pi / 2.05)
    fib = array_from_config(parse_config(
        '[sensor]\ngeometry = "sphere"\nlayout = "fibonacci"\nn = 50\nsigma = 0.01\n'))
    assert fib == ob.Sphere.fibonacci(50)
    cfg = parse_config('[sensor]\ngeometry = "plate"\nnx = 4\nny = 3\npitch = 0.5\n'
                       "sigma = 0.01\n[scene]\npositions = [[0.1, 0.2, 1.0]]\n"
                       "intensities = [2.0]\n")
    model = model_from_config(cfg)
    assert model.array == ob.Plate.grid(4, 3, 0.5) and model.kind == "position"
    assert scene_from_config(cfg, model).positions.shape == (1, 3)


def test_custom_geometry_from_files_relative_to_the_config(tmp_path):
    ang = np.linspace(0, 2 * np.pi, 7)[:-1]
    np.savetxt(tmp_path / "normals.txt", np.column_stack([np.cos(ang), np.sin(ang)]))
    readings = tmp_path / "readings.csv"
    readings.write_text("# one row\n" + ", ".join(["0.5"] * 6) + "\n")
    path = tmp_path / "c.toml"
    path.write_text('[sensor]\ngeometry = "custom"\nnormals_file = "normals.txt"\n'
                    'sigma = 0.1\n[data]\nfile = "readings.csv"\n')
    cfg = load_config(path)
    model = model_from_config(cfg)
    assert model.n_sensors == 6 and model.kind == "angle"
    np.testing.assert_array_equal(data_from_config(cfg, model), np.full(6, 0.5))
    inline = parse_config('[sensor]\ngeometry = "custom"\nsigma = 0.1\n'
                          "normals = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]\n"
                          "positions = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\n")
    assert array_from_config(inline).source_kind == "position"


def test_read_readings_shapes(tmp_path):
    p = tmp_path / "r.txt"
    p.write_text("1 2 3\n4 5 6\n")
    assert read_readings(p, 3).shape == (2, 3)
    p.write_text("1\n2\n3\n")  # one reading per line
    np.testing.assert_array_equal(read_readings(p, 3), [1.0, 2.0, 3.0])
    q = tmp_path / "r.npy"
    np.save(q, np.arange(6.0).reshape(2, 3))
    assert read_readings(q, 3).shape == (2, 3)
