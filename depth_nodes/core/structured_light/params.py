"""The structured-light decoder's settings, named as the structured_light node's parameters
(the node declares them from here; see :mod:`depth_nodes.core.settings`)."""

from __future__ import annotations

from dataclasses import dataclass

from depth_nodes.core.settings import check_settings, setting
from depth_nodes.core.structured_light.patterns import AXES, MODES, PatternSet
from depth_nodes.errors import ArgumentError


@dataclass(frozen=True)
class StructuredLightParams:
    """Pattern layout, decoding thresholds, depth window, speckle matching and the bounds
    of what a sequence may hold."""

    mode: str = setting('phase', 'Pattern set: gray, phase (Gray code + N-step phase shift), '
                        'opencv (cv2.structured_light.GrayCodePattern order + black, white) '
                        'or speckle', choices=MODES)
    axes: str = setting('columns', 'Coded projector axes: columns (ray-plane) or both '
                        '(ray-ray)', choices=AXES)
    phase_steps: int = setting(4, 'Phase steps N of the phase mode', low=3, high=64)
    phase_period: float = setting(16.0, 'Phase period in projector pixels', low=2.0,
                                  high=4096.0)
    shadow_threshold: float = setting(12.0, 'Minimum white - black (grey levels) of a lit '
                                      'pixel', low=0.0, high=65535.0)
    min_modulation: float = setting(4.0, 'Minimum phase amplitude (grey levels); scale of '
                                    'the confidence', low=0.0, high=65535.0)
    epipolar_tolerance: float = setting(2.0, 'axes both: projector pixels a decoded (column, '
                                        'row) may lie off its camera pixel\'s epipolar line '
                                        '(farther: a false code, no depth); 0: no check',
                                        low=0.0, high=1000.0)
    depth_min: float = setting(0.2, 'Nearest depth kept (m)', low=0.01, high=1000.0)
    depth_max: float = setting(5.0, 'Farthest depth kept (m)', low=0.01, high=1000.0)
    speckle_reference: str = setting('', 'Speckle mode: image file (PNG, 8/16-bit grey) of '
                                     'the dot pattern on a plane at speckle_reference_depth')
    speckle_reference_depth: float = setting(1.0, 'Depth of the speckle reference plane (m)',
                                             low=0.01, high=1000.0)
    speckle_window: int = setting(9, 'Speckle: side of the box the census distances are '
                                  'summed over (odd)', low=3, high=31, odd=True)
    speckle_min_score: float = setting(0.42, 'Speckle: smallest match score, 1 - 2 x the '
                                       'share of differing census bits (1 identical, 0 '
                                       'unrelated)', low=-1.0, high=1.0)
    speckle_uniqueness: float = setting(0.05, 'Speckle: how much lower (a share of it) the '
                                        'best sum must be than the best one more than a pixel '
                                        'away', low=0.0, high=1.0)
    max_sequence_frames: int = setting(128, 'Longest sequence held; a tag announcing more is '
                                       'refused (pattern_count_too_large)', low=2, high=4096)
    sequence_timeout: float = setting(5.0, 'Seconds without a frame after which an '
                                      'incomplete sequence is abandoned (sequence_incomplete); '
                                      '0: never', low=0.0, high=3600.0)

    def validate(self) -> StructuredLightParams:
        """Check every field and that the depth window is not empty; returns self.

        Raises:
            ArgumentError: The first rule broken.
        """
        check_settings(self, 'structured-light parameter')
        if self.depth_min >= self.depth_max:
            raise ArgumentError(f'depth_min ({self.depth_min}) must be smaller than depth_max '
                                f'({self.depth_max})')
        return self

    def pattern_set(self, width: int, height: int) -> PatternSet:
        """The pattern set for a projector of ``width`` x ``height``.

        Raises:
            ConfigError: The layout does not fit the projector.
        """
        return PatternSet(self.mode, width, height, self.axes, self.phase_steps,
                          self.phase_period)
