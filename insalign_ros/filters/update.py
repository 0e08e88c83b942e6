"""The one measurement update every core runs: check -> terms -> prediction (S, NIS) -> fading -> gate -> Joseph ->
inject -> counters (PI-LIEKF eqs. (11)-(15); the adaptive fading memory of docs/inmotion_cores.md).

A core takes part through protected hooks declared on :class:`~insalign_ros.filters.base.AlignmentCore`:
``_terms(m)`` (flush, then ``m.terms(core)``), ``_fading_factor(m, nis)``, ``_inflate(lam)``, ``_gate(m)``,
``_correction(m, z, L, H, N)``, ``_inject(dx)``, ``_after_update(m, result)`` and ``_after_prediction(m, result)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .kalman import joseph_update, nis, prediction


@dataclass
class UpdateResult:
    """Outcome of a measurement update: accepted or not, innovation [m or m/s], its covariance, NIS."""

    accepted: bool
    innovation: np.ndarray = field(default_factory=lambda: np.zeros(0))
    S: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    nis: float = float("nan")
    reason: str = ""


#: (model class, convention) -> terms(model, core) -> (z, H, N): filled by the models (filters/measurements.py)
TERMS: dict[tuple[type, str], Callable] = {}


def jacobian(model: type, convention: str):
    """Register ``terms(model, core) -> (z, H, N)`` of ``model`` for cores of ``convention``."""
    def deco(fn):
        TERMS[(model, convention)] = fn
        _accepts_cache.clear()
        return fn
    return deco


_accepts_cache: dict = {}


def models_for(convention: str, state_blocks: frozenset, own_models: frozenset = frozenset()) -> frozenset:
    """The models with terms for ``convention`` whose state blocks (``model.needs``) the core keeps, and
    ``own_models`` (cached: read per measurement)."""
    key = (convention, state_blocks, own_models)
    out = _accepts_cache.get(key)
    if out is None:
        out = _accepts_cache[key] = own_models | frozenset(
            m for (m, c) in TERMS if c == convention and m.needs <= state_blocks)
    return out


def predict(core, m) -> UpdateResult:
    """The innovation, its covariance and NIS ``m`` would have now; changes nothing (the session's outlier gate)."""
    if not core.initialized:
        return UpdateResult(False, reason="not initialised")
    reason = m.check()
    if reason:
        return UpdateResult(False, reason=reason)
    z, H, N = core._terms(m)
    S, nis_v = prediction(core.P, H, N, z)
    return core._after_prediction(m, UpdateResult(False, z, S, nis_v, "prediction only"))


def update(core, m) -> UpdateResult:
    """Fuse ``m`` into ``core`` (Joseph form); counts ``m.counter`` or ``m.counter + '_rejected'``."""
    if not core.initialized:
        return UpdateResult(False, reason="not initialised")
    reason = m.check()
    if reason:
        return _reject(core, m, reason, UpdateResult(False, reason=reason))
    z, H, N = core._terms(m)
    core._P_prior = core.P
    L, P_new, S = joseph_update(core.P, H, N)
    nis_v = nis(S, z)
    core.last_fading_factor = 1.0
    lam = core._fading_factor(m, nis_v) if m.fading else 1.0
    if lam > 1.0:
        # the innovation says P is too small (linearisation error of a large initial attitude error): inflate the
        # prior and redo the gain
        core.last_fading_factor = lam
        core._inflate(lam)
        core._P_prior = core.P
        core.counters["fading"] = core.counters.get("fading", 0) + 1
        L, P_new, S = joseph_update(core.P, H, N)
    gate = core._gate(m) if m.nis_gate is None else m.nis_gate
    if gate > 0 and not nis_v <= gate:
        return _reject(core, m, f"NIS {nis_v:.1f} above gate {gate}", UpdateResult(False, z, S, nis_v, ""))
    dx = core._correction(m, z, L, H, N)
    core.P = P_new
    core._inject(dx)
    core.counters[m.counter] = core.counters.get(m.counter, 0) + 1
    return core._after_update(m, UpdateResult(True, z, S, nis_v, ""))


def _reject(core, m, reason: str, res: UpdateResult) -> UpdateResult:
    key = f"{m.counter}_rejected"
    core.counters[key] = core.counters.get(key, 0) + 1
    core.last_reject_reason = f"{m.label}: {reason}"
    res.reason = res.reason or core.last_reject_reason
    return res
