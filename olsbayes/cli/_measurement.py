"""``olsbayes fit`` with a measurement model: frames, Pearson's chi^2, the extra parameters.

The configuration sections of :mod:`olsbayes.config.measurement_sections` give
the model its noise and nuisance terms (:func:`olsbayes.build.model_from_config`);
here the readings become frames where ``[noise] frames`` says so, and the fit's
goodness and its extra parameters (an unknown sigma, a background, gains,
offsets) are reported.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..build_measurement import frames_from_config
from ..config import Config
from ..config.measurement_sections import MEASUREMENT_SECTIONS
from ..measurement import expected, is_plain, split_extra
from ..model import Model
from ._common import format_table

__all__ = ["FIT_SECTIONS", "as_frames", "pearson_chi2", "extra_payload", "extra_text"]

#: Sections ``olsbayes fit`` accepts.
FIT_SECTIONS = ("sensor", "scene", "data", *MEASUREMENT_SECTIONS)


def as_frames(cfg: Config, model: Model, data: np.ndarray) -> tuple[np.ndarray, bool]:
    """``(readings, frames)``: the rows as frames of one scene where ``[noise] frames``.

    The readings are checked against the model's noise (e.g. counts must be
    non-negative integers) before any fit: InputError names the range.
    """
    frames = frames_from_config(cfg)
    if frames and data.ndim == 1:
        data = data[None, :]
    if frames and data.ndim != 2:
        from ..errors import InputError

        raise InputError(f"[noise] frames = true takes readings of shape (F, N); got {data.shape}")
    return model.check_data(data, name="readings", frames=frames), frames


def pearson_chi2(model: Model, result: Any, data: np.ndarray, frames: bool) -> np.ndarray:
    """Pearson's chi^2 ``sum g^2 / w`` of each fit, shape () or (T,).

    ``g`` and ``w`` are the score ``d log L / d mu`` and the Fisher weights of the
    model's noise at the fitted expected readings: ``((y - mu) / sigma)^2`` for
    Gaussian noise, ``(S - lambda)^2 / lambda`` for counts; with frames, that of the
    frames' sum (its dof are those of one frame).
    """
    theta, _ = split_extra(model, result.extra) if result.extra.size else (None, None)
    mu = expected(model, np.asarray(result.params), result.extra if result.extra.size else None)
    g, w = model.noise.score(mu, np.asarray(data, float), frames=frames, theta=theta)
    return np.sum(g * g / w, axis=-1)


def extra_payload(result: Any) -> dict[str, Any]:
    """The extra parameters of an ML result, for the JSON output."""
    return {"extra_names": list(result.extra_names), "extra": result.extra,
            "extra_std": result.extra_std}


def extra_text(result: Any) -> str:
    """A table of the extra parameters of one fit (empty when the model has none).

    A per-sensor group (``g[n]``, ``o[n]``) of more than four entries is one row:
    the median estimate and bound, and the range of the estimates.
    """
    if not result.extra_names or np.ndim(result.extra) != 1:
        return ""
    groups: dict[str, list[int]] = {}
    for i, n in enumerate(result.extra_names):
        groups.setdefault(n.split("[")[0], []).append(i)
    rows = []
    for stem, idx in groups.items():
        val, sd = result.extra[idx], result.extra_std[idx]
        if len(idx) <= 4:
            rows += [[result.extra_names[i], result.extra[i], result.extra_std[i], ""]
                     for i in idx]
        else:
            rows.append([f"{stem}[0..{len(idx) - 1}]", float(np.median(val)),
                         float(np.median(sd)), f"{val.min():.4g} .. {val.max():.4g}"])
    return "Extra parameters (sd = marginal Fisher bound; groups: medians):\n" + format_table(
        ["param", "estimate", "sd", "range"], rows)


def is_general(model: Model, frames: bool) -> bool:
    """Whether the fit leaves the default path (another noise, nuisance terms, frames)."""
    return frames or not is_plain(model)
