"""The one error hierarchy of the project; shells map it to exit codes and problem+json.

VppError                 anything the caller can fix by changing the input
├── MeshError            the file is not a usable triangle mesh (empty, corrupt, NaN, bad index)
├── SensorError          the camera specification is nonsense (fov >= 180, near >= far, ...)
├── ViewpointError       a viewpoint is malformed (zero gaze, up parallel to gaze, NaN)
│                        or stands where the setup forbids it (below the floor, ...)
├── SetupError           the cell setup is invalid or references a mesh that cannot be read
├── RegionError          a region does not fit the mesh (face id out of range, unknown label)
├── RobotError           the robot cannot be used (bad URDF, unknown arm, no chain to the tip)
├── LimitError           the request exceeds a configured limit (faces, candidates, rays)
│   └── TooLargeError    an upload exceeds the byte limit
├── SolverError          the set cover cannot be solved (no coverable face, infeasible model)
├── NotFoundError        a referenced resource (mesh, plan, job, artifact) does not exist
├── AuthError            the request is not authorised (the service's API keys)
│   ├── UnauthenticatedError  no usable `Authorization: Bearer <key>` header
│   └── ForbiddenError        a bearer key that is not one of the configured keys
└── UnavailableError     a dependency (queue, store) cannot be reached; retry later
"""

from __future__ import annotations


class VppError(Exception):
    """Base of all input errors; `title` is a short class name, `detail` the one-line reason."""

    title = "Invalid input"

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class MeshError(VppError):
    """The mesh bytes do not hold a usable triangle mesh."""

    title = "Invalid mesh"


class SensorError(VppError):
    """The sensor specification is invalid."""

    title = "Invalid sensor"


class ViewpointError(VppError):
    """A viewpoint (position, gaze, up) is invalid."""

    title = "Invalid viewpoint"


class SetupError(VppError):
    """The cell setup (issue 35) is invalid or one of its meshes cannot be read."""

    title = "Invalid setup"


class RegionError(VppError):
    """A region of interest does not fit the mesh (face id out of range, unknown label)."""

    title = "Invalid region"


class RobotError(VppError):
    """The robot description (URDF, bundled name, mount, limits) cannot be used."""

    title = "Invalid robot"


class LimitError(VppError):
    """The request exceeds a configured limit."""

    title = "Limit exceeded"


class SolverError(VppError):
    """The covering problem cannot be solved as posed."""

    title = "Unsolvable cover"


class TooLargeError(LimitError):
    """An upload exceeds the configured byte limit."""

    title = "Payload too large"


class NotFoundError(VppError):
    """A referenced resource does not exist."""

    title = "Not found"


class UnavailableError(VppError):
    """A dependency (queue, store) cannot be reached."""

    title = "Service unavailable"


class AuthError(VppError):
    """The request is not authorised."""

    title = "Not authorised"


class UnauthenticatedError(AuthError):
    """No credentials, or credentials not in the `Authorization: Bearer <key>` form."""

    title = "Authentication required"


class ForbiddenError(AuthError):
    """Credentials given, but not a configured API key."""

    title = "Forbidden"
