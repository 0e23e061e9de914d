"""Candidates stage: where cameras may stand and where they look (SPEC §2).

generator (spaced surface samples, gazes along the smoothed normal, occluded gazes tested
with a ray backend). Imports: trace, camera, mesh and the shared leaves.
"""
