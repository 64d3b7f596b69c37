"""What rig drivers raise: every error names the device and, where it sent one, its own error code."""
from __future__ import annotations


class RigError(RuntimeError):
    """A rig device failed. ``code`` is the device's own error or status code (None if it sent none)."""

    def __init__(self, message, device=None, code=None):
        self.device = device
        self.code = code
        prefix = f"{device}: " if device else ""
        suffix = "" if code is None else f" (device code {code})"
        super().__init__(f"{prefix}{message}{suffix}")


class CommunicationError(RigError):
    """No reply, a garbled or truncated reply, or the port went away."""


class DeviceBusy(RigError):
    """The device reported busy for longer than the driver waits."""


class MotionError(RigError):
    """A move or homing failed: mechanical timeout, out of range, or the position read back is wrong."""
