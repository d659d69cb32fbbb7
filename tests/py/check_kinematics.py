#!/usr/bin/env python3
"""Independent forward kinematics for awl's arm tables (no awl code).

Two references per joint vector:
- "rtb": Peter Corke's roboticstoolbox-python `DHRobot` of `RevoluteDH(d, a, alpha, offset)` rows
  (standard DH) built from the table awl sends, with `tool = T_dh6_flange`;
- "urdf": for the built-in arms, the vendors' ROS joint chains transcribed here from their
  descriptions (not from awl's DH tables): UR's ur_description `config/<model>/default_kinematics.yaml`
  (shoulder .. wrist_3, then wrist_3 -> flange -> tool0) and Techman's tmr_ros2 tm_description
  `xacro/macro.<model>-nominal.urdf.xacro` (link_0 .. link_6 = flange), each joint
  `T(origin xyz) * R(origin rpy) * Rz(q)`. This checks the DH tables themselves. The yaml files
  round pi/2 to 1.570796327 and carry ~2e-11 m residues of UR's calibration tool: exact values here.

stdin:  {"arms": [{"name": "ur5e", "dh": [{"a", "alpha", "d", "theta_offset"} x 6],
                   "T_dh6_flange": 4x4 rows, "q": [[q1..q6], ...]}]}
stdout: {"arms": [{"name": "ur5e", "rtb": [4x4, ...], "urdf": [4x4, ...] | null}], "rtb_version": "..."}
Exit 0 on success, 2 on unusable input.
"""
import json
import math
import sys

import numpy as np
import roboticstoolbox as rtb
from spatialmath import SE3

H = math.pi / 2


def rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def frame(xyz, r):
    m = np.eye(4)
    m[:3, :3] = rpy(*r)
    m[:3, 3] = xyz
    return m


# (d1, a2, a3, d4, d5, d6) as they appear in default_kinematics.yaml (shoulder z, forearm x,
# wrist_1 x and z, wrist_2 -y, wrist_3 y); UR10e from UR's DH article (same layout).
UR_YAML = {
    "ur3e": (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
    "ur5e": (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    "ur10e": (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
    "ur16e": (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
    "ur20": (0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543),
    "ur30": (0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543),
}

# tm_description 1.12.5 joint origins: joint_1 z, joint_3 x, joint_4 x and z, joint_5 -y, joint_6 -y
TM_XACRO = {
    "tm5-700": (0.1452, 0.329, 0.3115, -0.1223, 0.106, 0.11315),
    "tm5-900": (0.1452, 0.429, 0.4115, -0.1223, 0.106, 0.11315),
    "tm12": (0.1652, 0.6361, 0.5579, -0.1563, 0.106, 0.11315),
    "tm14": (0.1652, 0.5361, 0.4579, -0.1563, 0.106, 0.11315),
}


def urdf_chain(name):
    """(joint origins, fixed frame after the last joint) of a built-in arm, or None."""
    if name in UR_YAML:
        d1, a2, a3, d4, d5, d6 = UR_YAML[name]
        joints = [
            ([0, 0, d1], (0, 0, 0)),
            ([0, 0, 0], (H, 0, 0)),
            ([a2, 0, 0], (0, 0, 0)),
            ([a3, 0, d4], (0, 0, 0)),
            ([0, -d5, 0], (H, 0, 0)),
            ([0, d6, 0], (H, math.pi, math.pi)),
        ]
        # ur.urdf.xacro: wrist_3_link -> flange rpy (0, -pi/2, -pi/2), flange -> tool0 rpy (pi/2, 0, pi/2)
        tail = frame([0, 0, 0], (0, -H, -H)) @ frame([0, 0, 0], (H, 0, H))
        return joints, tail
    if name in TM_XACRO:
        d1, a2, a3, d4, d5, d6 = TM_XACRO[name]
        joints = [
            ([0, 0, d1], (0, 0, 0)),
            ([0, 0, 0], (-H, -H, 0)),
            ([a2, 0, 0], (0, 0, 0)),
            ([a3, 0, d4], (0, 0, H)),
            ([0, -d5, 0], (H, 0, 0)),
            ([0, -d6, 0], (H, 0, 0)),
        ]
        return joints, np.eye(4)
    return None


def urdf_fk(chain, q):
    joints, tail = chain
    m = np.eye(4)
    for (xyz, r), qi in zip(joints, q):
        m = m @ frame(xyz, r) @ frame([0, 0, 0], (0, 0, qi))
    return m @ tail


def main() -> int:
    try:
        req = json.load(sys.stdin)
        out = []
        for arm in req["arms"]:
            rows = arm["dh"]
            if len(rows) != 6:
                raise ValueError(f"{arm['name']}: {len(rows)} DH rows")
            links = [
                rtb.RevoluteDH(d=r["d"], a=r["a"], alpha=r["alpha"], offset=r.get("theta_offset", 0.0)) for r in rows
            ]
            tool = SE3(np.asarray(arm.get("T_dh6_flange", np.eye(4)), dtype=np.float64), check=False)
            robot = rtb.DHRobot(links, name=arm["name"], tool=tool)
            qs = np.asarray(arm["q"], dtype=np.float64).reshape(-1, 6)
            poses = [robot.fkine(q).A.tolist() for q in qs]
            chain = urdf_chain(arm["name"])
            urdf = None if chain is None else [urdf_fk(chain, q).tolist() for q in qs]
            out.append({"name": arm["name"], "rtb": poses, "urdf": urdf})
    except (KeyError, ValueError, TypeError) as e:
        print(f"check_kinematics.py: unusable input: {e}", file=sys.stderr)
        return 2
    version = getattr(rtb, "__version__", "unknown")
    json.dump({"arms": out, "rtb_version": version}, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
