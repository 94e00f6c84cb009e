"""The one exception family of depth_nodes.

Every error a user can cause (a malformed message, a bad calibration, a broken bag, an
invalid parameter) is raised as a subclass of :class:`DepthNodesError`, with a message that
names what was wrong, so nodes can count and log it and command-line tools can print one
line instead of a traceback.
"""

from __future__ import annotations

from typing import Any


class DepthNodesError(Exception):
    """Base class of every error depth_nodes raises on purpose."""


class ArgumentError(DepthNodesError, ValueError):
    """An argument a function cannot take: a wrong shape, type or value (numpy arrays and
    settings handed to ``depth_nodes.core``, options of a command). A ``ValueError`` too, so
    code that catches that keeps working."""


class MessageError(DepthNodesError):
    """A ROS message whose fields disagree with each other (sizes, step, data length)."""


class EncodingError(MessageError):
    """An image encoding that is unknown or not supported where it was used."""


class DecodeError(MessageError):
    """Compressed image data that cannot be decoded (damaged, truncated, too large, or not
    what its format says)."""


class UnsupportedFormatError(EncodingError):
    """A compressed image format (or image transport) that this package cannot read."""


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


def yaml_problem(exc: Any) -> str:
    """A YAML parser error in one line: what is wrong and where (PyYAML's own text spans
    several lines with a picture of the spot)."""
    problem = getattr(exc, 'problem', None) or getattr(exc, 'context', None)
    mark = getattr(exc, 'problem_mark', None) or getattr(exc, 'context_mark', None)
    if problem is None:
        return ' '.join(str(exc).split())
    where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
    return f'{problem}{where}'
