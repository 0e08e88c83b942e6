"""The Kalman update every core shares: gain and Joseph-form covariance (PI-LIEKF eqs. (11), (13)), the innovation
covariance and the normalised innovation squared (NIS), and the 3x3 covariance test of the input checks.

Compiled (numba) kernels are the implementation (plain Python where numba is missing); test/oracles.py keeps the
numpy formulas as the reference the tests compare against.
"""

from __future__ import annotations

import math

import numpy as np

from ..core import mechanization_numba as nb


@nb._jit
def _joseph_nb(P, H, N):
    """Kalman gain and Joseph-form covariance (the products of eqs. (11), (13), LAPACK solve); returns (L, P_new, S)."""
    HP = H @ P
    S = HP @ np.ascontiguousarray(H.T) + N
    S = 0.5 * (S + S.T)
    L = np.ascontiguousarray(np.linalg.solve(S, HP).T)
    IKH = np.eye(P.shape[0]) - L @ H
    P_new = IKH @ P @ np.ascontiguousarray(IKH.T) + L @ N @ np.ascontiguousarray(L.T)
    return L, 0.5 * (P_new + P_new.T), S


@nb._jit
def _prediction_nb(P, H, N, z):
    """``BatchedEciCore._prediction`` compiled: ``S = H P H^T + N`` symmetrised (the products of :func:`_joseph_nb`)
    and the NIS; returns (S, nis)."""
    S = (H @ P) @ np.ascontiguousarray(H.T) + N
    S = 0.5 * (S + S.T)
    return S, _nis_nb(S, z)


@nb._jit
def _nis_nb(S, z):
    """z^T S^-1 z (LAPACK solve)."""
    y = np.linalg.solve(S, z)
    s = 0.0
    for i in range(z.shape[0]):
        s += z[i] * y[i]
    return s


@nb._jit
def _spd3_nb(R) -> bool:
    """Whether the symmetric part of a 3x3 matrix has a Cholesky factor (the test of ``np.linalg.cholesky``)."""
    A = 0.5 * (R + R.T)
    L = np.zeros((3, 3))
    for j in range(3):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, 3):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


def joseph_update(P: np.ndarray, H: np.ndarray, N: np.ndarray):
    """Kalman gain and Joseph-form covariance (PI-LIEKF eqs. (11), (13)); returns (L, P_new, S)."""
    return _joseph_nb(np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(H, dtype=float),
                      np.ascontiguousarray(N, dtype=float))


def prediction(P: np.ndarray, H: np.ndarray, N: np.ndarray, z: np.ndarray):
    """(S, NIS) a measurement (z, H, N) would have now: ``S = H P H^T + N`` symmetrised, ``z^T S^-1 z``."""
    S, nis_v = _prediction_nb(np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(H, dtype=float),
                              np.ascontiguousarray(N, dtype=float), np.ascontiguousarray(z, dtype=float))
    return S, float(nis_v)


def nis(S: np.ndarray, z: np.ndarray) -> float:
    """Normalised innovation squared z^T S^-1 z."""
    return float(_nis_nb(np.ascontiguousarray(S, dtype=float), np.ascontiguousarray(z, dtype=float)))


def spd3(R: np.ndarray) -> bool:
    """Whether the symmetric part of a 3x3 covariance is positive definite (has a Cholesky factor)."""
    return bool(_spd3_nb(np.ascontiguousarray(R, dtype=float)))
