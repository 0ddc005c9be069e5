"""TOML configuration files: a small schema registry, strict validation, builders.

A configuration file describes a sensor, a scene and (optionally) readings::

    [sensor]
    geometry = "ring"          # ring | sphere | plate | custom
    n = 30
    sigma = 0.01               # noise std of one sub-sensor (reading units)
    sensitivity = "cosine"     # cosine (alias costn) | cosine_power (then p = ...)

    [scene]
    directions = [0.37, -2.7716]   # ring: rad; sphere: [[lon, lat], ...]
    intensities = [1.0, 0.2]

    [data]
    simulate = true            # or: file = "readings.txt" (one or more rows of N readings)
    seed = 20260123

Every section is declared by a :class:`Section` of :class:`Field` objects in a
registry; other parts of the package (``image``, ``select``, ``study``,
``posterior`` ...) declare theirs with :func:`register_section` and then call
:func:`load_config` with the sections their command accepts.  Unknown sections
or keys, wrong types, non-finite or huge numbers and malformed TOML all raise
:class:`~olsbayes.errors.ConfigError` naming the key and the accepted keys.
"""

from . import measurement_sections as _measurement  # noqa: F401  ([noise], [prior] ...)
from . import sections as _sections  # noqa: F401  (registers [sensor], [scene], [data])
from .loader import load_config, parse_config
from .readings import read_readings
from .schema import (
    MAX_ABS,
    MAX_CONFIG_BYTES,
    MAX_DATA_BYTES,
    MAX_ELEMENTS,
    Config,
    Field,
    Section,
    get_section,
    register_section,
    registered_sections,
)

__all__ = [
    "Field",
    "Section",
    "Config",
    "register_section",
    "get_section",
    "registered_sections",
    "load_config",
    "parse_config",
    "read_readings",
    "MAX_ABS",
    "MAX_ELEMENTS",
    "MAX_CONFIG_BYTES",
    "MAX_DATA_BYTES",
]
