"""URDF text → the serial chain from the root link to the flange, and its forward kinematics.

A `Chain` holds, per joint from the root to the tip link, the fixed origin transform (URDF
`<origin xyz rpy>`), the joint's type and unit axis, its limits (rad or m) and speed limit
(rad/s or m/s, URDF `<limit velocity>`). Fixed joints are folded into the next origin (or
into `tip`). Lengths are converted to mm when loaded. Each link's collision geometry (box,
cylinder, sphere, capsule or mesh file, with its origin) is kept by the link it rides on:
link 0 is the root, link i the child of moving joint i.

`link_frames` is the numpy forward kinematics of every link frame, vectorised over joint
vectors; `flange_frames` the tip's frame. Both are in the chain's root frame, mm.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vpp_core.errors import RobotError

M_TO_MM = 1000.0
MOVING = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Geometry:
    """One collision shape of a link: `kind` box | cylinder | sphere | capsule | mesh; `size`
    the box's 3 sides, (radius, length) or (radius,), mm; `path` the mesh file and `scale`;
    `origin` its 4x4 pose in the link frame (mm)."""

    kind: str
    origin: np.ndarray
    size: tuple[float, ...] = ()
    path: str = ""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True, eq=False)
class Chain:
    """The serial chain root → tip (mm, rad); arrays have one row per moving joint."""

    names: list[str]
    origins: np.ndarray  # (n, 4, 4) parent link frame → joint frame at q = 0, mm
    axes: np.ndarray  # (n, 3) unit axes in the joint frame
    prismatic: np.ndarray  # (n,) bool
    lower: np.ndarray  # (n,) rad or mm
    upper: np.ndarray  # (n,) rad or mm
    speed: np.ndarray  # (n,) rad/s or mm/s (URDF velocity; inf where not given)
    tip: np.ndarray  # (4, 4) last moving joint's frame → tip link frame, mm
    links: list[str]  # n + 1 link names: the root, then each moving joint's child
    geometry: list[list[Geometry]] = field(default_factory=list)  # per link of `links`

    @property
    def n(self) -> int:
        """Number of moving joints."""
        return len(self.names)


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, y, z; R = Rz(y) Ry(p) Rx(r)) → 3x3 rotation."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _floats(text: str | None, count: int, default: float = 0.0) -> np.ndarray:
    """`count` floats from a URDF attribute ("0 0 1"), or the default where absent."""
    if text is None:
        return np.full(count, default)
    try:
        values = np.array([float(v) for v in text.split()])
    except ValueError as exc:
        raise RobotError(f"URDF: not a list of numbers: {text!r}") from exc
    if len(values) != count or not np.isfinite(values).all():
        raise RobotError(f"URDF: expected {count} finite numbers, got {text!r}")
    return values


def _origin(element: ET.Element | None) -> np.ndarray:
    """4x4 transform (mm) of an `<origin>` child of `element` (identity where absent)."""
    t = np.eye(4)
    node = None if element is None else element.find("origin")
    if node is not None:
        t[:3, :3] = rpy_matrix(_floats(node.get("rpy"), 3))
        t[:3, 3] = _floats(node.get("xyz"), 3) * M_TO_MM
    return t


def parse_chain(
    text: str, tip: str, base_dir: Path | None = None, root: str | None = None
) -> Chain:
    """The chain from `root` (default: the URDF's root link) to the link `tip`.

    Mesh filenames resolve relative to `base_dir` (`package://name/...` to the part after the
    package name); meshes that do not resolve are dropped (the caller falls back to capsules).
    """
    try:
        doc = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotError(f"URDF is not XML: {exc}") from exc
    if doc.tag != "robot":
        raise RobotError(f"URDF root element is <{doc.tag}>, not <robot>")
    links = {str(e.get("name")): e for e in doc.findall("link")}
    by_child = {_ref(j, "child"): j for j in doc.findall("joint")}
    if tip not in links:
        raise RobotError(f"URDF has no link {tip!r} (links: {', '.join(sorted(links))})")
    path: list[ET.Element] = []
    link = tip
    while link in by_child and link != root:
        joint = by_child[link]
        path.append(joint)
        link = _ref(joint, "parent")
        if len(path) > len(by_child):
            raise RobotError("URDF: the joints form a loop")
    if root is not None and link != root:
        raise RobotError(f"URDF: link {tip!r} does not descend from {root!r}")
    return _build(list(reversed(path)), links, str(link), base_dir)


def _ref(joint: ET.Element, tag: str) -> str:
    """The link a joint's <parent> or <child> names, or RobotError."""
    node = joint.find(tag)
    name = None if node is None else node.get("link")
    if name is None:
        raise RobotError(f"URDF joint {joint.get('name')!r} has no <{tag} link=...>")
    return name


def _build(
    path: list[ET.Element], links: dict[str, ET.Element], root: str, base_dir: Path | None
) -> Chain:
    """Fold the joint path into moving joints with accumulated fixed origins."""
    names: list[str] = []
    origins: list[np.ndarray] = []
    axes: list[np.ndarray] = []
    prismatic: list[bool] = []
    lower: list[float] = []
    upper: list[float] = []
    speed: list[float] = []
    link_names, geometry = [root], [_geometry(links.get(root), base_dir)]
    pending = np.eye(4)
    for joint in path:
        kind = joint.get("type", "")
        pending = pending @ _origin(joint)
        child = _ref(joint, "child")
        if kind not in MOVING:
            if kind not in ("fixed",):
                raise RobotError(f"URDF joint {joint.get('name')!r}: type {kind!r} not supported")
            geometry[-1] += [_moved(g, pending) for g in _geometry(links.get(child), base_dir)]
            continue
        node = joint.find("axis")
        axis = np.array([1.0, 0.0, 0.0]) if node is None else _floats(node.get("xyz"), 3)
        if np.linalg.norm(axis) < 1e-9:
            raise RobotError(f"URDF joint {joint.get('name')!r}: zero axis")
        lo, hi, v = _limits(joint, kind)
        names.append(str(joint.get("name")))
        origins.append(pending)
        axes.append(axis / np.linalg.norm(axis))
        prismatic.append(kind == "prismatic")
        lower.append(lo)
        upper.append(hi)
        speed.append(v)
        link_names.append(str(child))
        geometry.append(_geometry(links.get(child), base_dir))
        pending = np.eye(4)
    if not names:
        raise RobotError("URDF: no moving joint between the root and the tip link")
    tip = pending
    return Chain(
        names, np.array(origins), np.array(axes), np.array(prismatic), np.array(lower),
        np.array(upper), np.array(speed), tip, link_names, geometry,
    )  # fmt: skip


def _limits(joint: ET.Element, kind: str) -> tuple[float, float, float]:
    """(lower, upper, speed) of a moving joint: rad or mm; continuous joints ±2π."""
    node = joint.find("limit")
    scale = M_TO_MM if kind == "prismatic" else 1.0
    speed = _floats(node.get("velocity"), 1, np.inf)[0] * scale if node is not None else np.inf
    if kind == "continuous" or node is None or node.get("lower") is None:
        if kind == "prismatic":
            raise RobotError(f"URDF prismatic joint {joint.get('name')!r} has no limits")
        return -2 * np.pi, 2 * np.pi, speed if speed > 0 else np.inf
    lo = _floats(node.get("lower"), 1)[0] * scale
    hi = _floats(node.get("upper"), 1)[0] * scale
    if not lo < hi:
        raise RobotError(f"URDF joint {joint.get('name')!r}: lower {lo} >= upper {hi}")
    return lo, hi, speed if speed > 0 else np.inf


def _moved(g: Geometry, t: np.ndarray) -> Geometry:
    """The geometry `g` of a link fixed at `t` to its carrier, in the carrier's frame."""
    return Geometry(g.kind, t @ g.origin, g.size, g.path, g.scale)


def _geometry(link: ET.Element | None, base_dir: Path | None) -> list[Geometry]:
    """Collision shapes of a URDF link (mm); unresolved meshes are left out."""
    out: list[Geometry] = []
    for col in [] if link is None else link.findall("collision"):
        geom = col.find("geometry")
        shape = None if geom is None or len(geom) == 0 else geom[0]
        if shape is None:
            continue
        origin, tag = _origin(col), shape.tag
        if tag == "box":
            out.append(Geometry("box", origin, tuple(_floats(shape.get("size"), 3) * M_TO_MM)))
        elif tag in ("cylinder", "capsule"):
            r, h = _floats(shape.get("radius"), 1)[0], _floats(shape.get("length"), 1)[0]
            out.append(Geometry(tag, origin, (r * M_TO_MM, h * M_TO_MM)))
        elif tag == "sphere":
            out.append(Geometry("sphere", origin, (_floats(shape.get("radius"), 1)[0] * M_TO_MM,)))
        elif tag == "mesh":
            path = _resolve(shape.get("filename", ""), base_dir)
            if path is not None:
                sx, sy, sz = (float(v) for v in _floats(shape.get("scale"), 3, 1.0))
                out.append(Geometry("mesh", origin, (), str(path), (sx, sy, sz)))
    return out


def _resolve(filename: str, base_dir: Path | None) -> Path | None:
    """A mesh file name as an existing path under `base_dir`, or None."""
    if base_dir is None or not filename:
        return None
    rel = filename
    if rel.startswith("package://"):
        rel = rel[len("package://") :].split("/", 1)[-1]
    elif rel.startswith("file://"):
        return None
    path = (base_dir / rel).resolve()
    if base_dir.resolve() not in path.parents or not path.is_file():
        return None
    return path


def joint_transforms(chain: Chain, q: np.ndarray) -> np.ndarray:
    """(N, n, 4, 4) motion of each joint at joint vectors q (N, n): rotation about or
    translation along its axis (Rodrigues)."""
    q = np.atleast_2d(q)
    out = np.zeros(q.shape + (4, 4))
    out[..., 3, 3] = 1.0
    a = chain.axes[None]
    angle = np.where(chain.prismatic, 0.0, q)[..., None, None]
    k = np.zeros(a.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    out[..., :3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    out[..., :3, 3] = np.where(chain.prismatic[:, None], a * q[..., None], 0.0)
    return out


def link_frames(chain: Chain, q: np.ndarray) -> np.ndarray:
    """(N, n + 1, 4, 4) frames of the root and each moving link in the root frame (mm)."""
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    motion = joint_transforms(chain, q)
    frames = np.zeros((len(q), chain.n + 1, 4, 4))
    frames[:, 0] = np.eye(4)
    for i in range(chain.n):
        frames[:, i + 1] = frames[:, i] @ chain.origins[i] @ motion[:, i]
    return frames


def flange_frames(chain: Chain, q: np.ndarray) -> np.ndarray:
    """(N, 4, 4) tip link frames in the root frame (mm) at joint vectors q (N, n)."""
    return np.asarray(link_frames(chain, q)[:, -1] @ chain.tip)
