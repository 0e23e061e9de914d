"""The bundled arms: URDFs that the PyPI package `example-robot-data` ships (no network).

`example-robot-data` (Gepetto/LAAS, BSD-3, the robot set of Pinocchio's examples) installs
plain URDF files with their collision meshes under `cmeel.prefix/share/example-robot-data`;
they are read from there. Each arm's tip is its flange (the tool mounting face), where the
request's `flange_to_camera` starts.
"""

from __future__ import annotations

import importlib.metadata
from dataclasses import dataclass
from pathlib import Path

from vpp_core.errors import RobotError

PACKAGE = "example-robot-data"
PREFIX = "cmeel.prefix/share/example-robot-data"


@dataclass(frozen=True)
class Arm:
    """A bundled arm: its URDF inside the package, the flange link and what it is."""

    urdf: str
    tip: str
    title: str


ARMS: dict[str, Arm] = {
    "ur3": Arm("robots/ur_description/urdf/ur3_robot.urdf", "tool0", "Universal Robots UR3"),
    "ur5": Arm("robots/ur_description/urdf/ur5_robot.urdf", "tool0", "Universal Robots UR5"),
    "ur10": Arm("robots/ur_description/urdf/ur10_robot.urdf", "tool0", "Universal Robots UR10"),
    "panda": Arm("robots/panda_description/urdf/panda.urdf", "panda_link8", "Franka Emika Panda"),
}
"""Bundled arms by request name (`setup.robot.name`)."""


def package_root() -> Path:
    """The directory `example-robot-data` installed its robots under."""
    try:
        dist = importlib.metadata.distribution(PACKAGE)
    except importlib.metadata.PackageNotFoundError as exc:
        raise RobotError(
            f"bundled arms need the package {PACKAGE!r} (pip install 'vpp[robot]')"
        ) from exc
    return Path(str(dist.locate_file(PREFIX)))


def arm_urdf(name: str) -> tuple[str, str, Path]:
    """(URDF text, tip link, directory its `package://` mesh names resolve under)."""
    if name not in ARMS:
        raise RobotError(f"unknown arm {name!r}; bundled: {', '.join(sorted(ARMS))}")
    root = package_root()
    path = root / ARMS[name].urdf
    if not path.is_file():
        raise RobotError(f"{PACKAGE} has no {ARMS[name].urdf} (version changed?)")
    return path.read_text(), ARMS[name].tip, root
