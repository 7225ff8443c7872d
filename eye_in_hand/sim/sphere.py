"""A small anti-aliased sphere renderer: a coloured sphere drawn into an image through a
distorted camera model, for tests and examples that need a target without the whole world.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["render_sphere"]


def render_sphere(image, cam, center, radius, color_bgr, ss=4):
    """Ray-cast a sphere into ``image`` (in place) with ss x ss supersampling per pixel.

    Args:
        image: (H, W, 3) uint8 BGR, modified in place.
        cam: a :class:`~eye_in_hand.core.camera.CameraModel`.
        center: sphere centre in the camera frame, shape (3,), metres.
        radius: sphere radius, metres.
        color_bgr: flat colour of the sphere.
        ss: sub-samples per pixel and axis (coverage gives the anti-aliased edge).
    """
    c = np.asarray(center, float)
    d = np.linalg.norm(c)
    axis = c / d
    u = np.cross(axis, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    a = math.asin(radius / d)
    ang = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    rim = math.cos(a) * axis + math.sin(a) * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
    px = cam.project(rim)
    x0, y0 = np.maximum(np.floor(px.min(0)).astype(int) - 2, 0)
    x1, y1 = np.minimum(np.ceil(px.max(0)).astype(int) + 3, [cam.width, cam.height])
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    xs = (np.arange(x0, x1)[:, None] + offs).ravel()
    ys = (np.arange(y0, y1)[:, None] + offs).ravel()
    X, Y = np.meshgrid(xs, ys)
    n = cam.undistort_points(np.c_[X.ravel(), Y.ravel()])
    rays = np.c_[n, np.ones(len(n))]
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    dc = rays @ c
    hit = (dc > 0) & (d * d - dc * dc <= radius * radius)
    cov = hit.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))[..., None]
    roi = image[y0:y1, x0:x1].astype(np.float64)
    roi = roi * (1 - cov) + np.asarray(color_bgr, float) * cov
    image[y0:y1, x0:x1] = np.clip(np.rint(roi), 0, 255).astype(np.uint8)
