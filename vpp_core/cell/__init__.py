"""The cell a part is planned in (issue 35): where it rests, what hides it, where cameras may be.

    setup     the request's `setup` (SETUP.json): part_to_cell, floor, fixtures, workspace,
              keep_out; validated strictly (rigid transforms, finite numbers, min < max)
    geometry  the setup resolved: fixture and keep-out meshes loaded, transforms as arrays
    scene     the occluders in the part frame (a floor quad and the fixtures), which every ray
              backend traces with the part, and the part faces the setup touches
    reach     where a camera centre may be: one predicate for the generator, the retries, the
              adaptive candidates, the view sphere and explicit viewpoints

All lengths are mm; `cell` is the cell frame, `part` the part's (mesh) frame.

Extending (a robot arm, issue 36): a new optional key of `setup.Setup` (e.g. `robot`), what it
needs loaded in `geometry.Cell`, and one more (name, test) entry in `reach.constraints`; the
generator, the adaptive rounds, the view sphere and the explicit-viewpoint check then honour
it without change. Geometry that blocks rays goes into `scene.occluders`.
"""
