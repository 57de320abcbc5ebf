"""Boundedness of the weight filter (§3.4.1-3.4.2) and consistency of the pose EKF, along runs.

PLACEHOLDER
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from wmr import controllers
from wmr.ekf import pose_predict, pose_update
from wmr.kinematics import integrator_code, step
from wmr.references import ReferenceSampler
from wmr.scenario import Scenario
from wmr.sim import CHUNK, seed_sequences

__all__ = ["Replay", "replay"]


@dataclass
class Replay:
    """End state of a :func:`replay` (the same run as ``wmr.sim.simulate`` for the same inputs).

    ``q``, ``q_hat`` (3,), ``Pq`` (3, 3): true pose, pose estimate and its covariance after the
    last step; ``s``, ``W``, ``P``: the controller state; ``steps``: steps simulated;
    ``status``: ``(step, cause)`` as in ``wmr.sim`` (``(-1, 0)``: no divergence).
    """

    q: np.ndarray
    q_hat: np.ndarray
    Pq: np.ndarray
    s: np.ndarray
    W: np.ndarray
    P: np.ndarray
    steps: int
    status: tuple[int, int]
    extra: dict = field(default_factory=dict)

    @property
    def diverged(self) -> bool:
        return self.status[0] >= 0


def replay(scenario: Scenario, controller: str, seed: int | None = None, *, settings=None,
           probe=None) -> Replay:  # fmt: skip
    """Replay ``wmr.sim.simulate`` step by step in Python, with hooks around each piece.

    Mirrors ``wmr.sim._advance`` exactly: the same seed streams (``seed_sequences``), the same
    chunked standard-normal noise times ``pose_std``, the same reference chunks, the same jitted
    ``law``, ``pose_update``, ``pose_predict`` and ``kinematics.step``, in the same order, and the
    same divergence tests; so the end state equals ``simulate``'s bit for bit (a test checks it).

    ``probe`` may define any of (all optional; arrays are live views, copy what you keep):

    - ``before_law(k, p, s, W, P, q_hat)``: before the controller law at step ``k``;
    - ``after_law(k, p, s, W, P, q_hat, u)``: after it (``u`` saturated);
    - ``after_estimate(k, q, q_hat, Pq, nis)``: after the pose estimate at ``t_k`` (``q`` true
      pose at ``t_k``; ``nis`` of the pose update, NaN at ``k = 0`` or without the pose EKF).
    """
    ctrl = controllers.get(controller)
    settings = settings if settings is not None else scenario.settings(controller)
    seed = scenario.seed if seed is None else seed
    noise_ss, init_ss = seed_sequences(seed)
    rng_noise = np.random.default_rng(noise_ss)
    n, dt = scenario.n_steps, scenario.dt
    p, s, W, P = ctrl.pack(settings, scenario, np.random.default_rng(init_ss))
    law = ctrl.law
    q = np.array(scenario.initial_pose, dtype=float)
    q_hat = np.zeros(3)
    std = np.array(scenario.noise.pose_std)
    dists = [(d.start, d.stop, float(d.velocity[0]), float(d.velocity[1]))
             for d in scenario.disturbances]  # fmt: skip
    integ = integrator_code(scenario.integrator)
    est = scenario.estimator
    use_ekf = est.pose_source == "filtered" or (est.pose_source == "paper" and ctrl.uses_estimator)
    Qp = np.diag(np.square(est.process_std))
    Rp = np.diag(np.square(np.maximum(std, est.min_measurement_std)))
    Pq = Rp.copy()
    v_max, w_max, bound = scenario.limits.v_max, scenario.limits.w_max, scenario.divergence_bound
    before = getattr(probe, "before_law", None)
    after = getattr(probe, "after_law", None)
    on_estimate = getattr(probe, "after_estimate", None)

    sampler = ReferenceSampler(scenario.reference.kind, scenario.reference.params, dt)
    ref_prev = sampler.rows(0, 1)
    status = (-1, 0)
    k_done = n
    for k0 in range(0, n, CHUNK):
        k1 = min(k0 + CHUNK, n)
        ref = np.vstack((ref_prev[-1:], sampler.rows(k0 + 1, k1 + 1)))
        noise = rng_noise.standard_normal((k1 - k0, 3)) * std
        u = np.zeros(2)  # as in _advance: allocated per chunk
        ua = np.zeros(2)
        z = np.zeros(3)
        for k in range(k0, k1):
            i = k - k0
            for j in range(3):
                z[j] = q[j] + noise[i, j]
            nis = math.nan
            if not use_ekf:
                q_hat[:] = z
            elif k == 0:
                q_hat[:] = z
                Pq[:, :] = Rp
            else:
                nis = pose_update(q_hat, Pq, z, Rp)
            if on_estimate is not None:
                on_estimate(k, q, q_hat, Pq, nis)
            if before is not None:
                before(k, p, s, W, P, q_hat)
            law(p, s, W, P, q_hat, ref[i], dt, u)
            u[0] = min(max(u[0], -v_max), v_max)
            u[1] = min(max(u[1], -w_max), w_max)
            if after is not None:
                after(k, p, s, W, P, q_hat, u)
            if not (math.isfinite(u[0]) and math.isfinite(u[1])):
                status = (k, 1)
                break
            t = k * dt
            ua[0] = u[0]
            ua[1] = u[1]
            for start, stop, dv, dw in dists:
                if start <= t < stop:
                    ua[0] += dv
                    ua[1] += dw
            q[:] = step(q, ua, dt, integ)
            if use_ekf:
                pose_predict(q_hat, Pq, u, dt, integ, Qp)
            dx = ref[i + 1, 0] - q[0]
            dy = ref[i + 1, 1] - q[1]
            if not (math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2])):
                status = (k + 1, 1)
                break
            if dx * dx + dy * dy > bound * bound:
                status = (k + 1, 2)
                break
        ref_prev = ref
        if status[0] >= 0:
            k_done = status[0]
            break
    return Replay(q=q, q_hat=q_hat, Pq=Pq, s=s, W=W, P=P, steps=k_done, status=status)
