"""Parts like the unseen ones of issue 33, made here (none of them is in ../shared/meshes):
a four-throw crankshaft as CAD exports it and isotropically remeshed (and a one-throw one,
nearer the unseen crankshaft in how much of it hides: docs/quality.md), a 36-tooth Hirth
coupling coarse (planar flanks, one triangle strip each) and finely tessellated, and a gearbox
assembly whose gears are hidden in a housing and tessellated far below a pixel's footprint.
All in mm.

    python bench/synthetic.py OUTDIR      # writes crankshaft_cad.stl, crankshaft_fine.stl,
                                          # crankshaft1_cad.stl, crankshaft1_fine.stl,
                                          # hirth36_coarse.stl, hirth36_fine.stl, gearbox.stl,
                                          # gearbox_window.stl

The crankshaft and the gearbox need manifold3d (`pip install manifold3d`, a bench-only
dependency); the coupling is built from numpy alone. The fine versions are pymeshlab isotropic
remeshes of the coarse ones (what `vpp plan --remesh` does), so both tessellations are the
same geometry.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def crankshaft(throws: int = 4, segments: int = 64) -> trimesh.Trimesh:
    """A crankshaft (mm) of `throws` pins Ø44 at 45 mm throw, between throws + 1 main
    journals Ø50, each pin between two webs 18 mm thick, a Ø90 flange and a Ø30 nose; along
    x, 95 mm a throw: four throws about 450 mm long, one 165 mm."""
    import manifold3d as m3

    m3.set_circular_segments(segments)

    def cyl(r: float, length: float, x0: float, y: float = 0.0, z: float = 0.0) -> m3.Manifold:
        c = m3.Manifold.cylinder(length, r, r)
        return c.rotate([0, 90, 0]).translate([x0, y, z])

    pitch = 95.0
    parts = [cyl(15, 40, -40), cyl(45, 15, throws * pitch + 10)]
    for i in range(throws + 1):
        parts.append(cyl(25, 30, i * pitch))
    for i in range(throws):
        x = i * pitch + 30
        angle = np.pi if i in (1, 2) else 0.0
        y, z = 45 * np.cos(angle), 45 * np.sin(angle)
        parts.append(cyl(22, 29, x + 18, y, z))
        for xw in (x, x + 47):
            main = m3.CrossSection.circle(40)
            pin = m3.CrossSection.circle(30).translate([y, z])
            web = m3.CrossSection.batch_hull([main, pin]).extrude(18)
            parts.append(web.rotate([0, 90, 0]).translate([xw, 0, 0]))
    return _trimesh(m3.Manifold.batch_boolean(parts, m3.OpType.Add))


def hirth(
    teeth: int = 36, r_in: float = 20.0, r_out: float = 50.0, base: float = 12.0
) -> trimesh.Trimesh:
    """A Hirth coupling half (mm): a ring r_in..r_out, `base` thick, with `teeth` radial
    teeth of 60° included angle on top, ridges and valleys straight lines through the axis
    (so each flank is a plane). Coarse: each flank and wall piece is one quad (2 triangles)."""
    n = 2 * teeth
    theta = np.arange(n) * np.pi / teeth
    half_pitch = np.pi / teeth
    slope = 1 / np.tan(np.radians(30))  # flank rise per unit of arc
    ridge = np.arange(n) % 2 == 0

    def ring(r: float, z_top: bool) -> np.ndarray:
        h = np.where(ridge, r * half_pitch * slope, 0.0) if z_top else np.zeros(n)
        z = base + h if z_top else np.zeros(n)
        return np.column_stack([r * np.cos(theta), r * np.sin(theta), z])

    verts = np.vstack([ring(r_in, True), ring(r_out, True), ring(r_in, False), ring(r_out, False)])
    ti, to, bi, bo = 0, n, 2 * n, 3 * n
    faces = []
    for k in range(n):
        j = (k + 1) % n
        faces += [[ti + k, to + k, to + j], [ti + k, to + j, ti + j]]  # flank
        faces += [[to + k, bo + k, bo + j], [to + k, bo + j, to + j]]  # outer wall
        faces += [[ti + k, ti + j, bi + j], [ti + k, bi + j, bi + k]]  # bore
        faces += [[bi + k, bi + j, bo + j], [bi + k, bo + j, bo + k]]  # bottom
    mesh = trimesh.Trimesh(verts, np.array(faces))
    mesh.fix_normals()
    return mesh


def _gear(teeth: int, module: float, width: float, bore: float) -> trimesh.Trimesh:
    """A spur gear (mm) along z, `width` thick: trapezoid teeth between the root and tip
    circles, a bore of diameter `bore`."""
    import manifold3d as m3

    r_pitch = module * teeth / 2
    r_tip, r_root = r_pitch + module, r_pitch - 1.25 * module
    step = 2 * np.pi / teeth
    points = []
    for k in range(teeth):
        a = k * step
        for frac, r in ((0.0, r_root), (0.1, r_root), (0.22, r_tip), (0.38, r_tip), (0.5, r_root)):
            points.append((r * np.cos(a + frac * step), r * np.sin(a + frac * step)))
        for frac in np.linspace(0.6, 0.9, 4):
            points.append((r_root * np.cos(a + frac * step), r_root * np.sin(a + frac * step)))
    body = m3.CrossSection([points]) - m3.CrossSection.circle(bore / 2)
    return _trimesh(body.extrude(width).translate([0, 0, -width / 2]))


def gearbox(window: bool = False, gear_edge_mm: float = 0.27) -> trimesh.Trimesh:
    """A gearbox assembly (mm), separate bodies as an assembly exports them: a housing
    160 x 80 x 110 with 6 mm walls and two bearing bores (1 mm clearance around the shafts),
    with `window` a 60 x 40 inspection window in its lid; two shafts through the bores
    carrying a 20- and a 34-tooth gear (module 1.6, 10 mm wide) inside, remeshed to
    `gear_edge_mm` (0.27 mm: faces below the paper camera's pixel footprint, 0.183 mm
    square); 8 hex bolts on the lid. About 366 k faces, most of them the gears'. Without
    the window the gears and the housing's inside are hidden; with it part of them is seen
    through it, a slice per view."""
    import manifold3d as m3

    m3.set_circular_segments(96)
    box = m3.Manifold.cube([160, 80, 110], center=True)
    cavity = m3.Manifold.cube([148, 68, 98], center=True)
    holes = [m3.Manifold.cube([60, 40, 20], center=True).translate([0, 0, 50])] if window else []
    centres = ((-21.6, 7.0, _gear(20, 1.6, 10, 14)), (21.6, 10.0, _gear(34, 1.6, 10, 20)))
    axis = [90, 0, 0]  # cylinders along y
    bores = [
        m3.Manifold.cylinder(100, r + 1, r + 1, center=True).rotate(axis).translate([x, 0, 0])
        for x, r, _ in centres
    ]
    bodies = [m3.Manifold.batch_boolean([box, cavity, *holes, *bores], m3.OpType.Subtract)]
    for x, r, _ in centres:
        shaft = m3.Manifold.cylinder(140, r, r, center=True).rotate(axis)
        bodies.append(shaft.translate([x, 0, 0]))
    for k in range(8):
        x, y = -66 + (k // 2) * 44, (-32, 32)[k % 2]
        bodies.append(m3.Manifold.cylinder(5, 5, 5, circular_segments=6).translate([x, y, 55]))
    meshes = [_trimesh(body) for body in bodies]
    for x, _, gear in centres:
        gear = fine(gear, gear_edge_mm)
        gear.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        gear.apply_translation([x, 0, 0])
        meshes.append(gear)
    return trimesh.util.concatenate(meshes)


def _trimesh(solid) -> trimesh.Trimesh:
    """A manifold3d solid as a trimesh."""
    mesh = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))


def fine(mesh: trimesh.Trimesh, edge_mm: float) -> trimesh.Trimesh:
    """The same geometry isotropically remeshed to edges of about `edge_mm` (pymeshlab)."""
    from vpp_core.mesh.part import part_from_arrays
    from vpp_core.mesh.remesh import isotropic_remesh

    part = isotropic_remesh(part_from_arrays(mesh.vertices, mesh.faces), edge_mm)
    return trimesh.Trimesh(part.vertices, part.faces)


def main() -> None:
    """Write the eight parts into the folder given."""
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    crank, single = crankshaft(), crankshaft(throws=1)
    coupling = hirth()
    parts = {
        "crankshaft_cad": crank,
        "crankshaft_fine": fine(crank, 6.0),
        "crankshaft1_cad": single,
        "crankshaft1_fine": fine(single, 3.0),
        "hirth36_coarse": coupling,
        "hirth36_fine": fine(coupling, 0.5),
        "gearbox": gearbox(),
        "gearbox_window": gearbox(window=True),
    }
    for name, mesh in parts.items():
        mesh.export(out / f"{name}.stl")
        print(name, len(mesh.faces), "faces", np.round(mesh.extents, 1).tolist(), "mm")


if __name__ == "__main__":
    main()
