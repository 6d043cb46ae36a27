"""Small analytic helpers shared by the tests."""
import math

import numpy as np


def pixel_rays(camera, width, height):
    """Unit world-space ray directions through every pixel centre, (H, W, 3) float64."""
    t = math.tan(math.radians(camera.fov_y) / 2)
    aspect = width / height
    xs = ((np.arange(width) + 0.5) / width * 2 - 1) * t * aspect
    ys = ((np.arange(height) + 0.5) / height * 2 - 1) * t  # NDC y down: row 0 is the top
    X, Y = np.meshgrid(xs, ys)
    d = (X[..., None] * np.asarray(camera.right) - Y[..., None] * np.asarray(camera.up_vector)
         + np.asarray(camera.forward))
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def interior(mask, margin=1):
    """Pixels of `mask` whose whole (2*margin+1)^2 neighbourhood is in the mask (away from edges)."""
    m = mask.copy()
    for dy in range(-margin, margin + 1):
        for dx in range(-margin, margin + 1):
            m &= np.roll(np.roll(mask, dy, 0), dx, 1)
    return m
