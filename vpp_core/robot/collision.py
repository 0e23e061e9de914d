"""The arm's links against the cell: the part, fixtures and other meshes (python-fcl), and the
floor plane (exactly, from the links' lowest points).

Each link carries its URDF collision shapes (meshes as fcl BVH models, boxes, cylinders,
spheres, capsules); a link without any gets a capsule of `link_radius_mm` from its frame to
the next joint. fcl tests surfaces, so a link's centre inside a closed scene mesh counts too.
The root link is bolted to the cell: it is checked against the moving links only (the bundled
UR5's base mesh dips 3 mm below its mounting face). Everything is in the cell frame, mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from vpp_core.robot.model import Robot
from vpp_core.robot.urdf import Geometry, link_frames


@dataclass(frozen=True, eq=False)
class Scene:
    """What the arm must not touch, in the cell frame (mm): triangle meshes and the floor
    (solid below z = floor_z; None: no floor)."""

    meshes: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    floor_z: float | None = None
    names: list[str] = field(default_factory=list)

    def key(self) -> str:
        """Content hash of the scene (sha256 hex of the vertices, faces and floor)."""
        import hashlib

        h = hashlib.sha256(repr(self.floor_z).encode())
        for v, f in self.meshes:
            h.update(np.ascontiguousarray(v, dtype=np.float64).tobytes())
            h.update(np.ascontiguousarray(f, dtype=np.int64).tobytes())
        return h.hexdigest()


def _bvh(vertices: np.ndarray, faces: np.ndarray) -> Any:
    """An fcl BVH model of a triangle mesh."""
    import fcl

    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int32))
    model.endModel()
    return model


def _trimesh(vertices: np.ndarray, faces: np.ndarray) -> Any:
    """A trimesh of a scene mesh (for inside tests)."""
    import trimesh

    return trimesh.Trimesh(vertices, faces, process=False)


@lru_cache(maxsize=64)
def _mesh_file(path: str, scale: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(vertices mm, faces) of a URDF collision mesh file (metres × scale → mm)."""
    import trimesh

    mesh: Any = trimesh.load(path, force="mesh")
    return np.asarray(mesh.vertices) * np.asarray(scale) * 1000.0, np.asarray(mesh.faces)


@dataclass(frozen=True)
class Shape:
    """One link shape: its fcl geometry, pose in the link frame and points whose lowest
    z in the cell is the shape's lowest point (mesh vertices, box corners, capsule ends with
    their radius)."""

    geometry: Any
    origin: np.ndarray
    points: np.ndarray
    radius: float = 0.0
    faces: np.ndarray | None = None  # a mesh's triangles (for drawing)


def _shape(g: Geometry) -> Shape:
    """fcl geometry and floor points of a URDF collision shape."""
    import fcl

    if g.kind == "mesh":
        v, f = _mesh_file(g.path, g.scale)
        return Shape(_bvh(v, f), g.origin, v, faces=f)
    if g.kind == "box":
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        return Shape(fcl.Box(*g.size), g.origin, corners * np.asarray(g.size) / 2)
    if g.kind == "sphere":
        return Shape(fcl.Sphere(g.size[0]), g.origin, np.zeros((1, 3)), g.size[0])
    r, h = g.size
    ends = np.array([[0, 0, -h / 2], [0, 0, h / 2]])
    if g.kind == "capsule":
        return Shape(fcl.Capsule(r, h), g.origin, ends, r)
    rim = np.array([[np.cos(a), np.sin(a), 0] for a in np.linspace(0, 2 * np.pi, 16)]) * r
    return Shape(fcl.Cylinder(r, h), g.origin, np.vstack([rim + ends[0], rim + ends[1]]))


def _capsule(start: np.ndarray, end: np.ndarray, radius: float) -> Geometry:
    """A capsule from `start` to `end` (link frame, mm) as a URDF-like geometry."""
    d = end - start
    length = float(np.linalg.norm(d))
    origin = np.eye(4)
    origin[:3, 3] = (start + end) / 2
    if length > 1e-9:
        z, a = np.array([0.0, 0.0, 1.0]), d / length
        v, c = np.cross(z, a), float(z @ a)
        k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        origin[:3, :3] = np.eye(3) + k + k @ k / (1 + c) if c > -1 + 1e-12 else np.diag([1, -1, -1])
    return Geometry("capsule", origin, (radius, length))


def link_shapes(robot: Robot) -> list[list[Shape]]:
    """Per link (root first) its collision shapes; capsules where the URDF gives none; the
    camera's body (`camera_box_mm`) on the last link."""
    chain = robot.chain
    out = []
    for i, geoms in enumerate(chain.geometry):
        if not geoms:
            end = chain.origins[i][:3, 3] if i < chain.n else chain.tip[:3, 3]
            geoms = [_capsule(np.zeros(3), end, robot.spec.link_radius_mm)]
        out.append([_shape(g) for g in geoms])
    if robot.spec.camera_box_mm is not None:
        w, h, d = robot.spec.camera_box_mm
        behind = np.eye(4)
        behind[2, 3] = -d / 2  # the body runs from the optical centre back along -z
        origin = chain.tip @ robot.flange_to_camera @ behind
        out[-1].append(_shape(Geometry("box", origin, (w, h, d))))
    return out


class Checker:
    """Collision checks of one robot in one scene: `colliding(q)` for joint vectors."""

    def __init__(self, robot: Robot, scene: Scene) -> None:
        import fcl

        self.robot, self.scene = robot, scene
        self.shapes = link_shapes(robot)
        self.objects: list[tuple[int, Shape, Any]] = []
        for link, shapes in enumerate(self.shapes):
            if link == 0:
                continue
            for s in shapes:
                self.objects.append((link, s, fcl.CollisionObject(s.geometry, fcl.Transform())))
        self.scene_objects = [
            fcl.CollisionObject(_bvh(v, f), fcl.Transform()) for v, f in scene.meshes
        ]
        self.solids = [m for m in (_trimesh(v, f) for v, f in scene.meshes) if m.is_watertight]
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        self.manager.registerObjects(self.scene_objects)
        self.manager.setup()
        self.parts = [
            (link, s, fcl.CollisionObject(s.geometry, fcl.Transform()))
            for link, shapes in enumerate(self.shapes)
            for s in shapes
        ]
        self.pairs = self._self_pairs()

    def _place(self, frames: np.ndarray) -> None:
        """Move the self-collision objects to one configuration's link frames (n + 1, 4, 4)."""
        import fcl

        for link, s, obj in self.parts:
            t = frames[link] @ s.origin
            obj.setTransform(fcl.Transform(t[:3, :3], t[:3, 3]))

    def _self_pairs(self) -> list[tuple[int, int]]:
        """Shape pairs checked against each other: of links at least two joints apart, and
        not touching at the zero configuration (clipped into the limits), as MoveIt's setup
        assistant disables pairs that are adjacent or in contact by default."""
        import fcl

        zero = np.clip(np.zeros(self.robot.n), self.robot.lower, self.robot.upper)
        self._place(link_frames(self.robot.chain, zero[None])[0])
        pairs = []
        for a, (la, _, oa) in enumerate(self.parts):
            for b, (lb, _, ob) in enumerate(self.parts[a + 1 :], start=a + 1):
                if abs(lb - la) <= 1:
                    continue
                if not fcl.collide(oa, ob, fcl.CollisionRequest(), fcl.CollisionResult()):
                    pairs.append((a, b))
        return pairs

    def self_hits(self, frames: np.ndarray, links: range | None = None) -> np.ndarray:
        """(N,) whether two links touch each other, at link frames (N, n + 1, 4, 4): the pairs
        whose later link is in `links` (default all), so that links before the last and the
        last one (which a roll turns) can be checked apart."""
        import fcl

        out = np.zeros(len(frames), dtype=bool)
        pairs = [
            (a, b)
            for a, b in self.pairs
            if links is None or max(self.parts[a][0], self.parts[b][0]) in links
        ]
        if not pairs:
            return out
        request = fcl.CollisionRequest()
        for i in range(len(frames)):
            self._place(frames[i])
            out[i] = any(
                fcl.collide(self.parts[a][2], self.parts[b][2], request, fcl.CollisionResult())
                for a, b in pairs
            )
        return out

    def frames(self, q: np.ndarray) -> np.ndarray:
        """(N, n + 1, 4, 4) link frames in the cell at joint vectors q (N, n)."""
        return np.asarray(self.robot.base_to_cell @ link_frames(self.robot.chain, q))

    def floor_hits(self, frames: np.ndarray, links: range | None = None) -> np.ndarray:
        """(N,) whether a link (of `links`; default all) dips below the floor, at cell-frame
        link frames (N, n + 1, 4, 4); the root link (it stands on the mount) is not checked."""
        if self.scene.floor_z is None:
            return np.zeros(len(frames), dtype=bool)
        low = np.full(len(frames), np.inf)
        for link, shapes in enumerate(self.shapes):
            if link < 1 or (links is not None and link not in links):
                continue
            for s in shapes:
                t = frames[:, link] @ s.origin
                z = np.einsum("nj,pj->np", t[:, 2, :3], s.points) + t[:, 2, 3:4]
                low = np.minimum(low, z.min(axis=1) - s.radius)
        return np.asarray(low < self.scene.floor_z)

    def mesh_hits(self, frames: np.ndarray, links: range | None = None) -> np.ndarray:
        """(N,) whether a link (of `links`; default all) touches one of the scene's meshes
        (fcl: each link shape against the scene's AABB tree, first hit ends), at cell-frame
        link frames (N, n + 1, 4, 4)."""
        import fcl

        out = np.zeros(len(frames), dtype=bool)
        if not self.scene_objects:
            return out
        request = fcl.CollisionRequest()
        for i in range(len(frames)):
            for link, s, obj in self.objects:
                if links is not None and link not in links:
                    continue
                t = frames[i, link] @ s.origin
                obj.setTransform(fcl.Transform(t[:3, :3], t[:3, 3]))
                data = fcl.CollisionData(request=request)
                self.manager.collide(obj, data, fcl.defaultCollisionCallback)
                if data.result.is_collision:
                    out[i] = True
                    break
        return out

    def inside(self, frames: np.ndarray, links: range | None = None) -> np.ndarray:
        """(N,) whether a link shape's centre lies inside a closed scene mesh (a link wholly
        inside a solid touches none of its triangles, which is all fcl tests), at cell-frame
        link frames (N, n + 1, 4, 4)."""
        if not self.solids:
            return np.zeros(len(frames), dtype=bool)
        centres = [
            (frames[:, link] @ s.origin)[:, :3, 3]
            for link, s, _ in self.objects
            if links is None or link in links
        ]
        points = np.stack(centres, axis=1).reshape(-1, 3)
        hit = np.zeros(len(points), dtype=bool)
        for solid in self.solids:
            hit |= solid.contains(points)
        return np.asarray(hit.reshape(len(frames), -1).any(axis=1))

    def colliding(self, q: np.ndarray, links: range | None = None) -> np.ndarray:
        """(N,) whether the arm (its `links`; default all) at q (N, n) touches the floor, a
        scene mesh or itself, or has a link inside a closed scene mesh."""
        frames = self.frames(np.atleast_2d(q))
        hit = self.floor_hits(frames, links)
        for test in (self.mesh_hits, self.inside, self.self_hits):
            rest = ~hit
            if rest.any():
                hit[rest] = test(frames[rest], links)
        return hit

    def which(self, q: np.ndarray) -> list[str]:
        """Names of the links that touch something at one joint vector q (n,) (diagnostics)."""
        import fcl

        frames = self.frames(q[None])[0]
        names = self.robot.chain.links
        hits = set()
        if self.floor_hits(frames[None])[0] and self.scene.floor_z is not None:
            for link, shapes in enumerate(self.shapes[1:], start=1):
                for s in shapes:
                    t = frames[link] @ s.origin
                    z = s.points @ t[2, :3] + t[2, 3] - s.radius
                    if z.min() < self.scene.floor_z:
                        hits.add(names[link])
        for link, s, obj in self.objects:
            t = frames[link] @ s.origin
            obj.setTransform(fcl.Transform(t[:3, :3], t[:3, 3]))
            for other in self.scene_objects:
                if fcl.collide(obj, other, fcl.CollisionRequest(), fcl.CollisionResult()):
                    hits.add(names[link])
        return sorted(hits)
