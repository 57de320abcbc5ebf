# %% [md]
# # 08 — The robot ladder: where the kinematic model stops predicting the physics robot
#
# The controllers assume a unicycle. Here the same scenario runs on three robots of increasing
# realism: the kinematic unicycle, a lagged velocity loop, and a MuJoCo differential drive
# (wheels, contact, servos with a torque limit: DESIGN §3.7). First the physics alone: steady
# circles under constant commands, where the robot should slide once the lateral acceleration
# |v w| reaches the Coulomb bound μ g. Then one closed loop on each rung. The full study (six
# controllers, three trajectories, 20 seeds, a kinematic plant fitted to the MuJoCo logs by
# `wmr identify`, the timestep check) is `wmr analyze robots`.
#
# In the report: [Which robot model predicts the physics? The robot ladder](../paper/report.md#which-robot-model-predicts-the-physics-the-robot-ladder).
# %%
from analysis import robots

print(" μ     v    w   |vw|/(μg)  slip angle [rad]  achieved v  sliding")
for mu in (0.1, 1.0):
    for v, w in ((0.5, 1.0), (1.0, 2.0)):
        p = robots.sliding_point(mu, v, w)
        print(f"{mu:4.1f} {v:4.1f} {w:4.1f}   {p['demand']:6.2f}      {p['slip_angle']:8.4f}"
              f"        {p['v_actual']:6.3f}     {p['sliding']}")
# %% [md]
# Below the bound the robot rolls (side-slip of a few mrad, the commanded speed reached); past
# it, it slides outward and loses its forward speed.
#
# ## One closed loop per rung
#
# Backstepping on the paper's lemniscate, seed 0, the position RMSE after the 5 s transient.
# %%
from wmr.closedloop.sim import simulate

paths = {}
for rung in ("kinematic", "lagged-velocity", "mujoco"):
    sc = robots._scenario("lemniscate", rung, robots.RUNGS[rung], None)
    r = simulate(sc, "backstepping", 0)
    paths[rung] = r.q
    print(f"{rung:<16} {1e3 * r.rmse_after_transient['position']:.2f} mm")
# %%
fig, ax = plt.subplots(figsize=(5, 4))
for rung, q in paths.items():
    ax.plot(q[:, 0], q[:, 1], label=rung, lw=1)
ax.set_aspect("equal")
ax.legend()
ax.set_title("backstepping on three robots (lemniscate)")
# %% [md]
# ## The study's record
#
# The committed record's table: every controller on every rung, mean ± std over 20 seeds.
# %%
import json
from pathlib import Path

record = json.loads(Path("../paper/results/robots.json").read_text())
print(robots.table(record))
