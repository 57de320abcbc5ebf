# %% [md]
# # 01 — The unicycle model and the paper's errata
#
# The unicycle of eq. (1) under zero-order hold, its exact arc step beside Euler and RK4, and the
# error frame of eqs. (4)/(6): the printed matrix is not a rotation (errata E3). All code is from
# `wmr`; this notebook only calls it.
#
# In the report: [Errata of the paper and the evidence](../paper/report.md#errata-of-the-paper-and-the-evidence).
# %%
import dataclasses

from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.model import kinematics as kin

q0, u, T = np.array([0.0, 0.0, 0.3]), np.array([0.8, 0.6]), 2.0
exact = q0.copy()
for _ in range(200):
    exact = kin.step(exact, u, 0.01, kin.EXACT)
print("one exact step of 2 s vs 200 steps of 0.01 s:", np.abs(kin.step(q0, u, T) - exact).max() < 1e-12)
for name, code in (("euler", kin.EULER), ("rk4", kin.RK4)):
    errs = []
    for n in (50, 100, 200):
        q = q0.copy()
        for _ in range(n):
            q = kin.step(q, u, T / n, code)
        errs.append(np.abs(q - kin.step(q0, u, T)).max())
    print(f"{name}: error ratio per halving of dt = {errs[0] / errs[1]:.1f}, {errs[1] / errs[2]:.1f}")
# %% [md]
# ## The printed rotation of eqs. (4)/(6)
#
# The paper prints row 2 as `[sin θ, cos θ, 0]`. Its determinant is `cos 2θ`: singular at ±45°.
# %%
theta = np.linspace(-np.pi, np.pi, 721)
det_printed = np.array([np.linalg.det(kin.rotation(t, True)) for t in theta])
det_correct = np.array([np.linalg.det(kin.rotation(t, False)) for t in theta])
print("det(printed) = cos 2θ to 1e-12:", bool(np.abs(det_printed - np.cos(2 * theta)).max() < 1e-12))
print("corrected det = 1 everywhere:", bool(np.allclose(det_correct, 1.0, atol=1e-14)))
fig, ax = plt.subplots(figsize=(6, 3))
ax.plot(np.degrees(theta), det_printed, label="printed T_e: det = cos 2θ")
ax.plot(np.degrees(theta), det_correct, label="rotation: det = 1")
ax.axhline(0, color="k", lw=0.5)
ax.set(xlabel="θ [deg]", ylabel="det T_e")
_ = ax.legend()
# %% [md]
# ## What the printed matrix does to the closed loops (seed 0)
#
# Same seed (same noise), every controller with the corrected and the printed matrix, on the
# lemniscate. The ablation over 20 seeds is in `paper/report.md`.
# %%
sc = scn.load(scn.builtin("lemniscate"))
print(f"{'controller':<15}{'corrected':>11}{'printed':>11}  (position RMSE [m])")
for name in ("backstepping", "adaptive-pid", "iapid-nn-dekf", "adaptive-nn"):
    st = sc.settings(name)
    a = simulate(sc, name, seed=0)
    b = simulate(sc, name, seed=0, settings=dataclasses.replace(st, printed_rotation=True))
    pb = "diverged" if b.diverged else f"{b.rmse['position']:.4f}"
    print(f"{name:<15}{a.rmse['position']:>11.4f}{pb:>11}")
