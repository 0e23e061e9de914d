"""Mesh stage: file bytes → a validated, canonical triangle `Part` in mm (SPEC §1).

meshio (format parsing), orientation (outward normals), part (the Part and its checks),
remesh (isotropic remesh, pymeshlab), refine (area elements), tessellate (the planning mesh
of a file), labels (per-face region labels from the file or an uploaded array).
Imports: the shared leaves only (vpp_core.errors).
"""
