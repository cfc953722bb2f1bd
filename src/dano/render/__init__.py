"""Differentiable volume rendering of density and radiance fields at poses.

Pinhole :class:`Cameras` (Blender/NeRF or OpenCV convention) give rays;
:func:`render_rays` renders them through a field placed at a pose (differentiable in
the field, the pose and the rays); :class:`OccupancyGrid` skips empty space;
:func:`render_image` renders whole images. Shared by :mod:`dano.nerf` (training fields
from images) and pose tracking.
"""

from .cameras import (
    Cameras,
    blender_from_opencv,
    check_poses,
    image_rays,
    opencv_from_blender,
    pixel_rays,
    project_points,
)
from .volume import (
    OccupancyGrid,
    RenderConfig,
    RenderOptions,
    RenderOutput,
    psnr,
    render_image,
    render_rays,
    update_occupancy,
)

__all__ = [
    "Cameras",
    "OccupancyGrid",
    "RenderConfig",
    "RenderOptions",
    "RenderOutput",
    "blender_from_opencv",
    "check_poses",
    "image_rays",
    "opencv_from_blender",
    "pixel_rays",
    "project_points",
    "psnr",
    "render_image",
    "render_rays",
    "update_occupancy",
]
