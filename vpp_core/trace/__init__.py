"""Trace stage: every candidate's pixel rays traced against the part → R (SPEC §3).

rays (what a backend is), pixels (SPEC §3 checks on a window of hits), embree (one Embree
ray per pixel: the reference), packets (Embree packets on 4 × 4 tiles), raster (numba
z-buffer, the default), raytrace (pixel windows in blocks on a thread pool → sparse R).
Imports: camera, mesh and the shared leaves.
"""
