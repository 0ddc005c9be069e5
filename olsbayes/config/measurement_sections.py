"""Sections of the measurement model: [noise], [calibration], [background], [prior], [posterior].

::

    [noise]
    model = "poisson"        # gaussian | gaussian-unknown | poisson
    exposure = 2.0           # Poisson: seconds per frame (one number, or one per frame)
    dark = 0.0               # Poisson: dark rate added to every sub-sensor's rate
    frames = true            # the rows of the readings are frames of one static scene

    [calibration]
    file = "cal.toml"        # gains and offsets of a Calibration file (known values) ...
    infer = true             # ... or inferred around them with their standard errors
    # gain_sd = 0.05         # without a file: gains inferred, LogNormal(0, gain_sd)

    [background]
    infer = true             # an isotropic background, Uniform(0, max) ...
    max = 1.0
    value = 0.2              # known (without infer), or the truth a [data] simulation uses

    [prior]
    intensity = "uniform"    # uniform | loguniform, up to i_max
    i_max = 5.0
    sigma_min = 0.001        # gaussian-unknown: sigma ~ LogUniform(sigma_min, sigma_max)
    sigma_max = 1.0

    [posterior]
    walkers = 32
    steps = 20000            # step cap of the emcee run

With ``model = "gaussian"`` a ``sigma`` (or ``sigma_file``, one sd per sub-sensor)
may replace ``[sensor] sigma``; ``gaussian-unknown`` takes sigma as the scale of
its default prior.
"""

from __future__ import annotations

from .schema import Field, Section, register_section

__all__ = ["MEASUREMENT_SECTIONS", "NOISE_MODELS"]

#: Values of ``[noise] model``.
NOISE_MODELS = ("gaussian", "gaussian_unknown", "poisson")
#: The sections a command that builds a model accepts besides [sensor], [scene], [data].
MEASUREMENT_SECTIONS = ("noise", "calibration", "background", "prior", "posterior")

register_section(Section(
    name="noise",
    doc="noise model of the readings and repeated frames",
    fields={
        "model": Field("str", default="gaussian", choices=NOISE_MODELS,
                       doc="gaussian, gaussian-unknown (or gaussian_unknown) or poisson"),
        "sigma": Field("float", positive=True, doc="noise sd of every sub-sensor (Gaussian)"),
        "sigma_file": Field("path", doc="text/.npy file of one noise sd per sub-sensor"),
        "exposure": Field("array", ndim=(1,), doc="Poisson: exposure, one or one per frame"),
        "dark": Field("float", low=0.0, doc="Poisson: dark rate per sub-sensor (default 0)"),
        "frames": Field("bool", default=False,
                        doc="rows of the readings are frames of one static scene"),
    },
))

register_section(Section(
    name="calibration",
    doc="per-sensor gains and offsets: a calibration file or priors",
    fields={
        "file": Field("path", doc="calibration file (.toml or .nc) of this array"),
        "infer": Field("bool", default=False,
                       doc="infer the file's gains and offsets with their standard errors"),
        "gain_sd": Field("float", positive=True, high=5.0,
                         doc="without a file: gains inferred with LogNormal(0, gain_sd)"),
        "offset_sd": Field("float", positive=True,
                           doc="without a file: offsets inferred with Normal(0, offset_sd)"),
    },
))

register_section(Section(
    name="background",
    doc="isotropic diffuse background: known, or inferred with a uniform prior",
    fields={
        "value": Field("float", default=0.0, low=0.0,
                       doc="background (intensity units): known, or the truth of a simulation"),
        "infer": Field("bool", default=False, doc="infer the background"),
        "max": Field("float", positive=True, doc="upper end of its prior Uniform(0, max)"),
    },
))

register_section(Section(
    name="prior",
    doc="priors of the posterior: intensities and an unknown sigma",
    fields={
        "intensity": Field("str", default="uniform", choices=("uniform", "loguniform"),
                           doc="Uniform(0, i_max) or LogUniform(i_max / 1000, i_max)"),
        "i_max": Field("float", positive=True, doc="largest intensity (default from the data)"),
        "sigma_min": Field("float", positive=True, doc="gaussian-unknown: sigma prior's lower end"),
        "sigma_max": Field("float", positive=True, doc="gaussian-unknown: sigma prior's upper end"),
    },
))

register_section(Section(
    name="posterior",
    doc="the emcee run of fit --posterior",
    fields={
        "walkers": Field("int", low=4, high=10_000, doc="number of walkers"),
        "steps": Field("int", low=1, high=10_000_000, doc="step cap of the run"),
    },
))
