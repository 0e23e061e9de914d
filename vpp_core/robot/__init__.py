"""Robots that carry the camera: reachability, collisions, turntables and joint-space tours.

    model       the request's robot (bundled arm or uploaded URDF, base, mount, limits) and
                turntable, as pydantic models
    urdf        URDF text → the serial chain to the flange (origins, axes, limits, speeds,
                collision geometry), forward kinematics of every link (numpy, vectorised)
    arms        the bundled arms (`example-robot-data`: UR3, UR5, UR10, Franka Panda)
    kinematics  inverse kinematics (roboticstoolbox-python's compiled Levenberg-Marquardt)
    collision   the arm's links against the part, fixtures and floor (python-fcl)
    reach       reachability of N camera poses: IK with seeds and rolls, limits, collisions
    turntable   the part on a rotary table in front of a fixed (or linear-axis) camera
    jointtour   travel time in joint space, the visiting order, sampled path checks

Lengths are mm and angles radians inside; the API's angles are degrees. URDFs are in metres
and are converted when loaded.
"""
