"""Object poses from video and physics from pixels (paper §VI-A, and its limitations iii and iv).

:func:`load_video` reads frames, one camera and masks (given, or by background subtraction);
:func:`track` fits each frame's pose by silhouettes (and optionally colour) rendered by
:mod:`dano.render`; :func:`write_track_outputs` writes the poses as a dano trajectory (ready
for ``dano sysid``), a table, an overlay video and a report; :func:`identify_from_pixels`
identifies contact parameters through simulator and renderer together.
"""

from .inputs import VideoInput, load_video, masks_from_background
from .outputs import tracked_trajectory, write_track_outputs
from .pixels import PixelFitResult, identify_from_pixels
from .track import TrackConfig, TrackedObject, TrackResult, initial_velocity, pose_errors, track

__all__ = ["PixelFitResult", "TrackConfig", "TrackResult", "TrackedObject", "VideoInput", "identify_from_pixels",
           "initial_velocity", "load_video", "masks_from_background", "pose_errors", "track", "tracked_trajectory",
           "write_track_outputs"]
