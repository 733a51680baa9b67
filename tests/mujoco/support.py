"""Where a pushed bar bears on the table decides how it turns: MuJoCo alone, the same push twice.

    python support.py

A 19 x 3.5 x 5 cm bar (0.373 kg, friction 0.537, the bar of control_pushed_101) is pushed 5 cm
off its centre by a kinematic rod at 3 cm/s for 3 s. MuJoCo supports a box on a plane at its four
bottom corners; the second run spreads the same support over a 12 x 3 grid of small spheres under
the bar, as pegs's particles do. Prints each run's yaw and travel: spread support gives about
half the friction torque about the vertical, so the bar turns further and travels less (the
difference between pegs's pushes and MuJoCo's that the README's diagnosis section describes).
"""

from __future__ import annotations

import math

import mujoco

HALF = (0.095, 0.0175, 0.025)  # m
MASS, MU = 0.373, 0.537
FRICTION = f'friction="{MU} 0.005 0.0001"'
GRID = (12, 3)
BALL = 0.004  # m, radius of a support sphere


def bar_geoms(spread: bool) -> str:
    lx, ly, lz = HALF
    if not spread:
        return f'<geom type="box" size="{lx} {ly} {lz}" mass="{MASS}" {FRICTION}/>'
    # The box touches only the rod (contype 2); the spheres under it touch only the table (1).
    n = GRID[0] * GRID[1]
    geoms = (f'<geom type="box" size="{lx} {ly} {lz - BALL}" pos="0 0 {BALL}" mass="{MASS * 0.8}" {FRICTION} '
             f'contype="2" conaffinity="2"/>')
    for i in range(GRID[0]):
        for j in range(GRID[1]):
            x = -lx + 2 * lx * (i + 0.5) / GRID[0]
            y = -ly + 2 * ly * (j + 0.5) / GRID[1]
            geoms += (f'<geom type="sphere" size="{BALL}" pos="{x:.4f} {y:.4f} {-lz + BALL}" '
                      f'mass="{MASS * 0.2 / n:.5f}" {FRICTION} contype="1" conaffinity="1"/>')
    return geoms


def push(spread: bool) -> tuple[float, float]:
    """Yaw (degrees) and travel (m) of the bar after the push."""
    xml = f"""<mujoco><option timestep="0.001" cone="elliptic"/><worldbody>
      <geom type="plane" size="1 1 .1" {FRICTION} contype="1" conaffinity="1"/>
      <body name="bar" pos="0 0 {HALF[2]}"><freejoint/>{bar_geoms(spread)}</body>
      <body name="rod" mocap="true" pos="0.05 -0.04 0.02">
        <geom type="capsule" size="0.008 0.02" {FRICTION} contype="3" conaffinity="3"/></body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    for k in range(3000):
        data.mocap_pos[0] = [0.05, -0.04 + 0.03 * k * model.opt.timestep, 0.02]
        mujoco.mj_step(model, data)
    w, z = data.qpos[3], data.qpos[6]
    return math.degrees(2 * math.atan2(z, w)), math.hypot(data.qpos[0], data.qpos[1])


if __name__ == "__main__":
    for spread in (False, True):
        yaw, travel = push(spread)
        print(f"support {'spread over 36 points' if spread else 'at the 4 corners'}: "
              f"turned {yaw:.1f} degrees, travelled {100 * travel:.1f} cm")
