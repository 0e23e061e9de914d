"""Report stage: what is made from plans for people and studies.

studies (resolution sweep, decimation study), pointcloud (simulated point cloud), plots
(matplotlib PNGs), scene (the viewer's packed arrays). Imports: plan and every stage below.
"""
