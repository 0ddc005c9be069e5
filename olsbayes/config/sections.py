"""The foundation's sections: [sensor], [scene] and [data]."""

from __future__ import annotations

import math

from .schema import Field, Section, register_section

_PI = math.pi
register_section(Section(
    name="sensor",
    doc="sub-sensor array, angular sensitivity law and noise",
    variant_key="geometry",
    common=("sigma", "sensitivity", "p"),
    variants={
        "ring": ("n", "offset"),
        "sphere": ("layout", "n", "n_lat", "n_lon", "lat_max", "lon_min", "lon_max"),
        "plate": ("nx", "ny", "pitch"),
        "custom": ("normals", "normals_file", "positions", "positions_file"),
    },
    fields={
        "geometry": Field("str", required=True, choices=("ring", "sphere", "plate", "custom"),
                          doc="ring, sphere, plate or custom"),
        "sigma": Field("float", positive=True,
                       doc="noise std of one sub-sensor (required unless [noise] gives it)"),
        "sensitivity": Field("str", default="cosine",
                             choices=("cosine", "costn", "cosine_power"),
                             doc="angular law"),
        "p": Field("float", low=1.0, high=64.0, doc="exponent of cosine_power"),
        "n": Field("int", low=3, high=1_000_000, doc="number of sub-sensors"),
        "offset": Field("float", default=0.0, doc="angle of the first ring normal (rad)"),
        "layout": Field("str", default="grid", choices=("grid", "fibonacci"), doc="sphere layout"),
        "n_lat": Field("int", low=1, high=10_000, doc="grid latitudes"),
        "n_lon": Field("int", low=1, high=10_000, doc="grid longitudes"),
        "lat_max": Field("float", default=_PI / 2.05, positive=True, high=_PI / 2,
                         doc="largest grid latitude (rad)"),
        "lon_min": Field("float", default=-_PI, low=-2 * _PI, high=2 * _PI, doc="rad"),
        "lon_max": Field("float", default=_PI, low=-2 * _PI, high=2 * _PI, doc="rad"),
        "nx": Field("int", low=1, high=10_000, doc="plate columns"),
        "ny": Field("int", low=1, high=10_000, doc="plate rows"),
        "pitch": Field("float", default=1.0, positive=True, doc="plate spacing"),
        "normals": Field("array", ndim=(2,), doc="inline normals, shape (N, 2) or (N, 3)"),
        "normals_file": Field("path", doc="text/.npy file of normals, one per row"),
        "positions": Field("array", ndim=(2,), doc="inline sub-sensor positions (N, 3)"),
        "positions_file": Field("path", doc="text/.npy file of positions (N, 3)"),
    },
))

register_section(Section(
    name="scene",
    doc="point sources: directions (or positions) and intensities",
    fields={
        "directions": Field("array", ndim=(1, 2), doc="ring angles (K,) or (lon, lat) (K, 2)"),
        "positions": Field("array", ndim=(2,), doc="near-source positions (K, 3)"),
        "intensities": Field("array", required=True, ndim=(1,), doc="intensities (K,) >= 0"),
        "angle_unit": Field("str", default="rad", choices=("rad", "deg"),
                            doc="unit of directions"),
    },
))

register_section(Section(
    name="data",
    doc="readings: a file, or a simulation of the scene",
    fields={
        "file": Field("path", doc="text/CSV/.npy file, one row of N readings per measurement"),
        "simulate": Field("bool", default=False, doc="simulate readings from [scene]"),
        "seed": Field("int", low=0, high=2**63 - 1, doc="seed of the simulation"),
        "repeats": Field("int", default=1, low=1, high=1_000_000, doc="rows to simulate"),
    },
))
