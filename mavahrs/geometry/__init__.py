"""Pure geometry: quaternions, rotation matrices, Euler angles, frames."""

from __future__ import annotations

from mavahrs.geometry import frames, quaternion, rotation

__all__ = ["frames", "quaternion", "rotation"]
