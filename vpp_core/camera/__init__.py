"""Camera stage: the pinhole sensor (SPEC §2) and viewpoints with their frames (mm, radians).

sensor (intrinsics, pixel rays, depth of field), pose (position, gaze, up → camera-to-world).
Imports: the shared leaves only.
"""
