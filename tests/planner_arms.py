"""Small inline MJCF arms for the planner tests (mink's testing style)."""

from __future__ import annotations

import mujoco
import numpy as np

_COL = 'group="3" contype="0" conaffinity="0"'
_VIS = 'type="sphere" size="0.02" contype="0" conaffinity="0" group="1"'


def arm7_xml(limited: bool = False) -> str:
    """A 7-DoF arm, 0.15 + 0.35 + 0.3 + 0.15 m long, three collision capsules, site ``ee``.

    With ``limited``, joints get Panda-like position ranges.
    """
    rng = ' limited="true" range="-2.8 2.8"' if limited else ' limited="false"'
    rng4 = ' limited="true" range="-3.0 -0.1"' if limited else ' limited="false"'
    return f"""
<mujoco model="arm7">
  <compiler angle="radian"/>
  <worldbody>
    <body name="base" pos="0 0 0.5">
      <site name="arm_base"/>
      <geom {_VIS}/>
      <body name="l1">
        <joint name="j1" axis="0 0 1"{rng}/>
        <geom {_VIS}/>
        <body name="l2" pos="0 0 0.15">
          <joint name="j2" axis="0 1 0"{rng}/>
          <geom name="col_1" type="capsule" fromto="0 0 0.05 0 0 0.35" size="0.04" {_COL}/>
          <geom {_VIS}/>
          <body name="l3" pos="0 0 0.35">
            <joint name="j3" axis="0 0 1"{rng}/>
            <geom {_VIS}/>
            <body name="l4">
              <joint name="j4" axis="0 1 0"{rng4}/>
              <geom name="col_2" type="capsule" fromto="0 0 0.05 0 0 0.3" size="0.035" {_COL}/>
              <geom {_VIS}/>
              <body name="l5" pos="0 0 0.3">
                <joint name="j5" axis="0 0 1"{rng}/>
                <geom {_VIS}/>
                <body name="l6">
                  <joint name="j6" axis="0 1 0"{rng}/>
                  <geom name="col_3" type="capsule" fromto="0 0 0.03 0 0 0.15" size="0.03"
                        {_COL}/>
                  <geom {_VIS}/>
                  <body name="l7" pos="0 0 0.15">
                    <joint name="j7" axis="0 0 1"{rng}/>
                    <geom {_VIS}/>
                    <site name="ee" pos="0 0 0.05"/>
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <keyframe>
    <key name="home" qpos="0 0.4 0 -1.2 0 0.9 0"/>
  </keyframe>
</mujoco>
"""


JOINTS = tuple(f"j{i}" for i in range(1, 8))
CAPSULES = ("col_1", "col_2", "col_3")


def arm7_model(limited: bool = False) -> mujoco.MjModel:
    """Compiled :func:`arm7_xml`."""
    return mujoco.MjModel.from_xml_string(arm7_xml(limited))


def central_differences(planner, q0, goal_pos, goal_quat, obstacles, U, h: float = 1e-6):
    """Central-difference ∂f/∂U and ∂sd/∂U of ``planner.cost_and_constraints`` at ``U``."""
    grad, dsd = [], []
    for i in range(U.size):
        e = np.zeros_like(U)
        e[i] = h
        fp, _, sp, _ = planner.cost_and_constraints(q0, goal_pos, goal_quat, obstacles, U + e)
        fm, _, sm, _ = planner.cost_and_constraints(q0, goal_pos, goal_quat, obstacles, U - e)
        grad.append((fp - fm) / (2 * h))
        dsd.append((np.asarray(sp) - np.asarray(sm)) / (2 * h))
    return np.array(grad), np.stack(dsd, axis=1)
