"""The camera's roll about its gaze: turned where that frames more of the surface.

A 1920 × 1200 image is 1.6 times as wide as it is high. With the world's +Z as image-up
(`vpp_core.camera.pose`) the long side lies level whatever the part: a crankshaft lying
along x fills the width of a view from its side, the same crankshaft standing along z only
its height, and needs more views along its length. `fitted` tries each camera at ROLLS
turns about its gaze and counts the surface samples facing it that fall in its frame; it
takes the turn that frames the most where that is at least GAIN more than the world's up
frames (and more than the samples' noise), and keeps the world's up elsewhere: where the
surface fills the frame whichever way it is turned (a large face, a housing) the views keep
one orientation and tile as a grid on a face whose normal is level (on a face looking up or
down, +Z on the image of a tilted gaze points the way it tilts, so there the frames lie at
every angle; levelling them was measured and not kept, docs/quality.md "Level frames"),
and a part that lies inside the circle within the frame is not judged at all; where a long
part runs across the frame, the image turns along it, and the count no longer depends on
how the part lies in its file. A thin bar longer than the frame is framed along the image's
diagonal, its longest line. Of the two rolls that frame the same, the one nearer the world's
up is taken (images stay as upright as they can).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import Part

SAMPLES = 4_000
"""Area-uniform surface samples the frames are judged on (a field holds a few hundred on a
part a few fields across)."""
ROLLS = 12
"""Turns tried, evenly over 180° (a frame turned by 180° frames the same): every 15°."""
GAIN = 0.1
"""A turn is taken where it frames at least this share more samples than the world's up."""
NOISE = 3.0
"""...and at least this many standard deviations of the samples the world's up frames."""
REACH = 1.5
"""Samples farther than this many field half-diagonals from the aimed point are not judged."""
CHUNK = 64
"""Views judged at a time (the samples near them are held together: at most CHUNK · SAMPLES)."""


def surface_samples(part: Part, count: int = SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) points (mm) spread uniformly by area over the part, seeded, and the (count, 3)
    outward unit normals of their faces."""
    points, faces = trimesh.sample.sample_surface(
        part.trimesh(), count, seed=np.random.default_rng(7)
    )
    return np.asarray(points, dtype=np.float64), part.normals[faces]


def fitted(
    views: Viewpoints,
    sensor: Sensor,
    samples: tuple[np.ndarray, np.ndarray],
    depth_mm: float | np.ndarray,
) -> Viewpoints:
    """`views` turned about their gazes where a turn frames GAIN more of the surface
    `samples` (points, normals: (K, 3) each) facing them than the world's up does; each view
    aims at the point `depth_mm` (one, or (N,)) ahead of it."""
    if not len(views) or sensor.width_px == sensor.height_px:
        return views
    depth = np.broadcast_to(np.asarray(depth_mm, dtype=np.float64), (len(views),))
    half = np.array(sensor.half_tangents)
    radius = REACH * depth * float(np.hypot(*half))
    points, normals = samples
    rot, tree = views.rotations(), cKDTree(points)
    framed = np.zeros((len(views), ROLLS))
    judged = np.flatnonzero(~_whole_in_frame(views, points, float(half.min())))
    for ids in np.array_split(judged, -(-len(judged) // CHUNK)) if len(judged) else []:
        aims = views.positions[ids] + depth[ids, None] * views.gazes[ids]
        near = tree.query_ball_point(aims, radius[ids])
        view = np.repeat(np.arange(len(ids)), [len(n) for n in near])
        idx = np.concatenate(near).astype(np.int64)
        d = points[idx] - views.positions[ids][view]
        cam = np.einsum("kij,ki->kj", rot[ids][view], d)  # camera x, y, z of each sample (mm)
        facing = np.einsum("ij,ij->i", normals[idx], views.gazes[ids][view]) < 0
        framed[ids] = _framed(view, cam, facing & (cam[:, 2] > 0), half, len(ids))
    best = np.argmax(framed, axis=1)
    most, level = framed[np.arange(len(views)), best], framed[:, 0]
    gain = most - level  # more than sampling noise: Poisson spread of the samples framed
    turn = (best > 0) & (gain >= GAIN * level) & (gain >= NOISE * np.sqrt(level + 1))
    angle = best * np.pi / ROLLS
    x = np.cos(angle)[:, None] * rot[:, :, 0] + np.sin(angle)[:, None] * rot[:, :, 1]
    up = -np.cross(views.gazes, x)  # y = z × x, up = -y
    up *= np.where(np.einsum("ij,ij->i", up, views.ups) >= 0, 1.0, -1.0)[:, None]
    up /= np.linalg.norm(up, axis=1)[:, None]
    # the views not turned keep their up to the bit (a re-normalised one moves rays by 1e-15,
    # enough to change which triangle edge a few rays land on, and a timed cover with them)
    return Viewpoints(views.positions, views.gazes, np.where(turn[:, None], up, views.ups))


def _whole_in_frame(views: Viewpoints, points: np.ndarray, half_tan: float) -> np.ndarray:
    """(N,) bool: the ball around `points` (K, 3) lies within each view's cone of half-angle
    atan(`half_tan`), the circle inside its frame: framed whole at every turn."""
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    radius = float(np.linalg.norm(points - centre, axis=1).max())
    to = centre - views.positions
    dist = np.linalg.norm(to, axis=1)
    off = np.arccos(np.clip(np.einsum("ij,ij->i", to, views.gazes) / dist, -1.0, 1.0))
    spread = np.arcsin(np.clip(radius / np.maximum(dist, 1e-9), 0.0, 1.0))
    return np.asarray((dist > radius) & (off + spread <= np.arctan(half_tan)))


def _framed(
    view: np.ndarray, cam: np.ndarray, ok: np.ndarray, half: np.ndarray, n: int
) -> np.ndarray:
    """(n, ROLLS) samples of each view (`view`: its index per sample; `cam`: camera
    coordinates, mm; `ok`: facing it, in front) inside its frame (half-tangents `half`)
    turned by each of ROLLS angles over 180°."""
    u, v = cam[ok, 0] / cam[ok, 2], cam[ok, 1] / cam[ok, 2]
    out = np.zeros((n, ROLLS))
    for k in range(ROLLS):
        c, s = np.cos(k * np.pi / ROLLS), np.sin(k * np.pi / ROLLS)
        inside = (np.abs(c * u + s * v) <= half[0]) & (np.abs(c * v - s * u) <= half[1])
        out[:, k] = np.bincount(view[ok][inside], minlength=n)
    return out
