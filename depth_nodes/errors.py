"""The one exception family of depth_nodes.

Every error a user can cause (a malformed message, a bad calibration, a broken bag, an
invalid parameter) is raised as a subclass of :class:`DepthNodesError`, with a message that
names what was wrong, so nodes can count and log it and command-line tools can print one
line instead of a traceback.
"""

from __future__ import annotations


class DepthNodesError(Exception):
    """Base class of every error depth_nodes raises on purpose."""


class MessageError(DepthNodesError):
    """A ROS message whose fields disagree with each other (sizes, step, data length)."""


class EncodingError(MessageError):
    """An image encoding that is unknown or not supported where it was used."""


class CalibrationError(DepthNodesError):
    """A camera calibration that cannot be used (zero or non-finite K, wrong D length...)."""


class UncalibratedError(CalibrationError):
    """A CameraInfo whose K is all zero: the driver publishes no calibration."""


class SyncError(DepthNodesError):
    """A synchroniser was used wrongly (bad queue size, unknown input index...)."""


class BagError(DepthNodesError):
    """A bag that is missing, corrupt, or lacks the topic or type asked for."""


class ConfigError(DepthNodesError):
    """An invalid parameter value or graph configuration."""


class InputFileError(DepthNodesError):
    """An input file (image, ground truth, mask) that is missing or cannot be used."""
