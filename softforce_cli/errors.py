"""The one error hierarchy of softforce.

Library code raises these with a message that says what is wrong, where, and what to do; the
command line prints the message as one line and exits non-zero.
"""


class SoftforceError(Exception):
    """Base of every error a user can cause and fix."""


class ModelError(SoftforceError):
    """A robot model file or its mesh is missing, malformed or physically invalid."""


class SolverError(SoftforceError):
    """A finite element solve did not converge or met a singular system."""


class RecordingError(SoftforceError):
    """A recording is missing, corrupt, or lacks a required topic."""


class CameraError(SoftforceError):
    """No RealSense device, or the device failed."""


class ScenarioError(SoftforceError):
    """A simulation scenario file is malformed."""


class CalibrationError(SoftforceError):
    """Calibration inputs are inconsistent (markers, bounds) or it cannot converge."""


class OutputExistsError(SoftforceError):
    """An output would overwrite an existing file without --force."""


class OutputError(SoftforceError):
    """An output cannot be written where asked (a folder that cannot be made or written in)."""


class SensingError(SoftforceError):
    """Force sensing cannot run on these inputs (no robot in view, no actuation, ...)."""
