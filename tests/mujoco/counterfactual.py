"""What a recording can show of its concealed effect: from the engine's state at each frame, the
same scene played on for the diagnosis's horizon without the effect (the robot on the same
joint angles), and the distance between where each object ends with and without it. A window
the robot does not touch in which the effect moves an object by millimetres is one a diagnosis
that fits free motion can name it from; where there are none, no diagnosis from the images can
tell the effect from the model, and "not enough evidence" is the right verdict. Owns the
counterfactual replays only; the scene's run is simulate.py's, the files write.py's.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

import simulate
from scenes import Scene

HORIZON_S = 1.0  # the diagnosis's open-loop horizon
SHOWN_MM = 5.0  # an object's end moved this far by the effect: the window shows it
MOVING_MM = 5.0  # windows in which the object moves less than this are not fitted (pegs's rule)


def without_effect(scene: Scene) -> Scene:
    """`scene` with its concealed effect removed: what pegs's model is told."""
    plain = copy.deepcopy(scene)
    plain.gravity = (0.0, 0.0, -9.81)
    plain.drag = 0.0
    plain.patch = None
    plain.spring = None
    plain.restitution = None
    plain.engine_friction = None
    for o in plain.objects:
        o.true_mass = o.mass
        o.com_offset = (0.0, 0.0, 0.0)
    return plain


def shown(scene: Scene, run: simulate.Run, urdf: str) -> dict:
    """Per object: over the windows (one starting at each frame) in which it moves, how many the
    robot does not touch (`free_windows`), how many of those the effect shows in (its end moved
    by `SHOWN_MM` or more: `free_shown`) and the most it moved it there (`free_max_mm`); the same
    for the windows the robot touches it in (`pushed_*`)."""
    plain = without_effect(scene)
    model, _ = simulate.build(plain, urdf, 8, 8, np.random.default_rng(0))
    data = mujoco.MjData(model)
    bodies = [model.body(o.name).id for o in plain.objects]
    kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    frames = len(run.states)
    horizon = int(round(HORIZON_S * simulate.FRAME_RATE))
    nq = 7
    dt = model.opt.timestep
    positions = {o.name: np.array([p for _, n, p, _ in run.poses if n == o.name]) for o in scene.objects}
    out = {o.name: {"free_windows": 0, "free_shown": 0, "free_max_mm": 0.0,
                    "pushed_windows": 0, "pushed_shown": 0, "pushed_max_mm": 0.0} for o in scene.objects}
    for f in range(frames - horizon):
        mujoco.mj_setState(model, data, run.states[f], kind)
        mujoco.mj_forward(model, data)
        first = f * simulate.SUBSTEPS
        for k in range(first, first + horizon * simulate.SUBSTEPS):
            simulate.apply_effects(model, data, plain, bodies)
            if plain.hand:
                data.mocap_pos[0] = simulate.hand_pose(plain, (k + 1) * dt)
            data.qpos[:nq] = run.plan[k]
            data.qvel[:nq] = (run.plan[k + 1] - run.plan[k]) / dt
            mujoco.mj_step(model, data)
        touched = set().union(*run.robot_touch[f:f + horizon])
        for o, b in zip(scene.objects, bodies):
            path = positions[o.name][f:f + horizon + 1]
            if 1000 * np.max(np.linalg.norm(path - path[0], axis=1)) < MOVING_MM:
                continue
            moved = 1000 * float(np.linalg.norm(data.xpos[b] - path[-1]))
            tally = out[o.name]
            which = "pushed" if o.name in touched else "free"
            tally[f"{which}_windows"] += 1
            tally[f"{which}_shown"] += moved >= SHOWN_MM
            tally[f"{which}_max_mm"] = round(max(tally[f"{which}_max_mm"], moved), 1)
    return out
