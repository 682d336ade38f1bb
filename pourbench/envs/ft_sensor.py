"""The Movo's wrist force/torque sensor as the thesis reads it (§3.2.3, Table 3.2).

The BotaSys SensONE sits between the Jaco2's last link and the gripper. What it measures is
the force that holds everything distal to it: gripper, sensor flange and camera (1.435 kg,
centre of mass (−1.1, 0.8, 78.6) mm in the sensor frame), the held container and its
contents. *Gravity compensation* removes the first part, given the sensor's orientation:
the gripper's weight, expressed in the sensor frame, is subtracted from the reading; what
is left is the held load's weight (and, for the torque, its moment about the sensor). The
remaining vertical force, tared on the empty container at reset, goes through the same
noise and 2nd-order Butterworth low-pass (100 Hz samples, 1 Hz cut-off) as Pour-v0's scale:
:class:`pourbench.envs.observation.WeightFilter`, reused here.

Arrays are batched over worlds (leading axis), though ``PourRobot-v0`` uses one world.
"""

from __future__ import annotations

import numpy as np

from pourbench.envs.observation import GRAVITY

GRIPPER_MASS = 1.435
"""Gripper + sensor + camera mass carried by the wrist sensor, kg (Table 3.2)."""
GRIPPER_COM = np.array([-1.1e-3, 0.8e-3, 78.6e-3])
"""Its centre of mass in the sensor frame, m (Table 3.2)."""


def gravity_compensate(
    force: np.ndarray,
    torque: np.ndarray,
    rotation: np.ndarray,
    mass: float = GRIPPER_MASS,
    com: np.ndarray = GRIPPER_COM,
) -> tuple[np.ndarray, np.ndarray]:
    """Remove the gripper's own weight from F/T readings.

    Args:
        force: (n, 3) sensor force in the sensor frame, N (MuJoCo's convention: the force
            the distal side receives from the wrist; at rest it points up and equals the
            distal weight).
        torque: (n, 3) sensor torque in the sensor frame, N·m.
        rotation: (n, 3, 3) sensor frame → world rotations.
        mass: compensated mass, kg.
        com: its centre of mass in the sensor frame, m.

    Returns:
        The compensated force and torque, (n, 3) each, in the sensor frame.
    """
    up_world = np.array([0.0, 0.0, 1.0])
    # the support force that carries the gripper at rest: m g up, in the sensor frame
    support = mass * GRAVITY * np.einsum("nji,j->ni", rotation, up_world)
    moment = np.cross(com, support)
    return np.asarray(force) - support, np.asarray(torque) - moment


def vertical_load(force: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(n,) upward component in the world of (n, 3) sensor-frame forces, N: the held load's
    weight once gravity-compensated."""
    return np.einsum("nij,nj->ni", rotation, force)[:, 2]


__all__ = ["GRIPPER_COM", "GRIPPER_MASS", "gravity_compensate", "vertical_load"]
