"""Low-pass filter of the tri-colour image before it reaches NLiPsNet (or the lookup table).

NLiPsNet maps one pixel's colour to a normal, so the sensor noise of that pixel goes straight into
the normal: on the default twin (about 3 % noise per colour channel at mid-grey) the paper's net
trained on *true* normals stays at 3.3° from the truth, no better than on NLiPs labels. Shading varies
over many pixels while noise is independent per pixel, so a Gaussian of sigma 1 px cuts the noise
about 3.5x (the weights' root sum of squares is 1 / (2 sqrt(pi) sigma)) and leaves the contact's
shading nearly untouched; GelSight pipelines smooth their frames for the same reason.

The filter is normalised over the gel (``blur(image * valid) / blur(valid)``), so the dark rim
outside the dome never bleeds into pixels near its edge. The calibration dataset filters with the
sigma of its sampling options; the model file carries it and inference filters identically. OpenCV's
separable Gaussian does the work (about 1 ms for a 640x480 frame); inference filters only the window
around the changed pixels.

With a colour sigma (``SamplingConfig.smoothing_colour`` > 0) the filter stops at colour edges: OpenCV's bilateral
filter, each neighbour's Gaussian weight (same sigma, a disc of the kernel's radius) also times
``exp(-d^2 / (2 colour^2))``, d the L1 distance of its colour from the pixel's (linear units, over r, g, b). Why: next
to a steep wall (a coin's engraving) the Gaussian mixes the wall's colour into the flat gel beside it, which the
network reads as a tilt. On Q2's medium twin 39 % of the coin's flat contact samples lie within 3 px of a wall and
erred 10-19 deg there against 0.6-1.8 deg for the image model's colour at the true geometry; with a colour sigma of
0.08 Q2's unseen split went 4.73 -> 3.83 deg, the seen split unchanged (docs/experiments/RESULTS.md, s34-coinflat).
Neighbours differ by ~0.02 (L1) for sensor noise and by 0.1-1 across a wall, so 0.08 averages the first almost as
the Gaussian does and leaves out the second. Off the gel the frame is set to 0 (black), which the colour weight
leaves out too (the gel's colours are 0.3-0.9): no normalisation over the gel is needed. It costs ~2.6x the
Gaussian's CPU (a 640x480 frame 13.8 against 5.2 ms, a coin press's inference window 2.5 against 1.1 ms:
benchmarks/RESULTS.md, s34-coinflat); a window's values equal the whole frame's, as the Gaussian's do.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import ShapeError, require

MAX_SIGMA_PX = 50.0
"""Largest sigma accepted, px: a wider Gaussian averages the shading of most of the dome (the useful range
is 0-3 px), and OpenCV refuses a kernel of ~6 sigma once it exceeds an int ("Can't parse 'ksize'")."""


MAX_COLOUR_SIGMA = 1.0
"""Largest colour sigma accepted (linear units): beyond it the colour weight is ~1 for any two gel colours (0-1 per
channel), the Gaussian alone; useful values are 0.03-0.12 (Q2 medium, docs/experiments/RESULTS.md)."""


def check_colour_sigma(colour_sigma: object, where: str) -> float:
    """``colour_sigma`` as a float in [0, :data:`MAX_COLOUR_SIGMA`]; else ConfigError naming ``where``."""
    from ..core.config import is_finite_number
    from ..core.errors import ConfigError

    if not (is_finite_number(colour_sigma) and 0 <= colour_sigma <= MAX_COLOUR_SIGMA):
        raise ConfigError(f"{where} must be a colour sigma in [0, {MAX_COLOUR_SIGMA:g}], got {colour_sigma!r}")
    return float(colour_sigma)


def check_sigma(sigma_px: object, where: str) -> float:
    """``sigma_px`` as a float in [0, :data:`MAX_SIGMA_PX`]; else ConfigError naming ``where`` (an option or
    a file's key)."""
    from ..core.config import is_finite_number
    from ..core.errors import ConfigError

    if not (is_finite_number(sigma_px) and 0 <= sigma_px <= MAX_SIGMA_PX):
        raise ConfigError(f"{where} must be a sigma in [0, {MAX_SIGMA_PX:g}] px, got {sigma_px!r}")
    return float(sigma_px)


def kernel_radius(sigma_px: float) -> int:
    """Half-width of the Gaussian kernel in pixels (3 sigma; 0 when the filter is off)."""
    return int(math.ceil(3.0 * sigma_px)) if sigma_px > 0 else 0


def gaussian_kernel(sigma_px: float) -> np.ndarray:
    """(2 r + 1,) float32: the 1-D Gaussian of ``sigma_px`` (> 0) the prefilter convolves rows and columns with,
    OpenCV's (``cv2.getGaussianKernel``, r = :func:`kernel_radius`): the torch path (:mod:`.fullframe`) and the
    full-frame ONNX graph (:mod:`.onnx_fullframe`) use its weights, OpenCV's GaussianBlur makes them alike."""
    cv2 = require("cv2", "opencv-python-headless", "Filtering the tri-colour image")
    return cv2.getGaussianKernel(2 * kernel_radius(sigma_px) + 1, sigma_px, cv2.CV_32F).ravel()


def bilateral_offsets(sigma_px: float) -> list[tuple[int, int, float]]:
    """OpenCV's bilateral window of ``sigma_px``: each offset (dy, dx) within the kernel's radius (a disc) with its
    spatial Gaussian weight; empty without a radius (a model trained unfiltered has no window)."""
    r = kernel_radius(sigma_px)
    return [
        (dy, dx, float(np.exp(-(dy * dy + dx * dx) / (2 * sigma_px**2))))
        for dy in range(-r, r + 1)
        for dx in range(-r, r + 1)
        if r and dy * dy + dx * dx <= r * r
    ]


class Prefilter:
    """The tri-colour low-pass of one sensor (its gel mask), ready for many frames.

    Parameters
    ----------
    valid : (H, W) bool -- pixels that see the gel
    sigma_px : Gaussian sigma in pixels; 0 turns the filter off (frames pass unchanged)
    colour_sigma : sigma of the colour weight (linear units, L1 over r, g, b; module docstring); 0: the Gaussian
        alone, the same bits as without it
    """

    def __init__(self, valid: np.ndarray, sigma_px: float, colour_sigma: float = 0.0):
        if valid.ndim != 2:
            raise ShapeError(f"valid must be (H, W), got {valid.shape}")
        if not (0 <= sigma_px <= MAX_SIGMA_PX and math.isfinite(sigma_px)):
            raise ShapeError(f"prefilter sigma must be in [0, {MAX_SIGMA_PX:g}] px, got {sigma_px!r}")
        if not (0 <= colour_sigma <= MAX_COLOUR_SIGMA and math.isfinite(colour_sigma)):
            raise ShapeError(f"prefilter colour sigma must be in [0, {MAX_COLOUR_SIGMA:g}], got {colour_sigma!r}")
        self.sigma = float(sigma_px)
        self.colour_sigma = float(colour_sigma)
        self.radius = kernel_radius(self.sigma)
        self.valid = valid.astype(bool)
        self._weight = self._blur(self.valid.astype(np.float32)) if self.radius else None

    def __call__(self, image: np.ndarray, rows: slice | None = None, cols: slice | None = None) -> np.ndarray:
        """The filtered image, or only its window ``[rows, cols]`` (exactly the full filter's values there).

        Parameters
        ----------
        image : (H, W, 3) float, linear tri-colour image
        rows, cols : optional window of the output

        Returns
        -------
        (h, w, 3) float32; pixels off the gel keep no meaning (the filter is normalised over the gel)
        """
        if image.shape[:2] != self.valid.shape or image.ndim != 3:
            raise ShapeError(f"image {image.shape} does not match the gel mask {self.valid.shape} (+ colours)")
        rows, cols = rows or slice(0, image.shape[0]), cols or slice(0, image.shape[1])
        if not self.radius:
            return np.asarray(image[rows, cols], np.float32)
        # filter a window grown by the kernel radius and keep its inside: every kept pixel's kernel sees only
        # real neighbours or the image edge (reflected as in the full frame), so the values are identical
        r = self.radius
        y0, y1 = max(rows.start - r, 0), min(rows.stop + r, image.shape[0])
        x0, x1 = max(cols.start - r, 0), min(cols.stop + r, image.shape[1])
        grown = np.where(self.valid[y0:y1, x0:x1, None], image[y0:y1, x0:x1], 0).astype(np.float32)  # NaN-safe
        inside = (slice(rows.start - y0, rows.stop - y0), slice(cols.start - x0, cols.stop - x0))
        if self.colour_sigma:  # off the gel black: the colour weight leaves it out, no normalisation needed
            return self._edge_stopping(grown)[inside]
        out = self._blur(grown)[inside]
        return out / np.maximum(self._weight[rows, cols], np.float32(1e-6))[..., None]

    def gel_weight(self) -> np.ndarray | None:
        """(H, W) float32: what the Gaussian's sums of the gel's colours are divided by at each pixel (the blurred gel
        mask, at least 1e-6); None without a Gaussian (no radius, or the bilateral filter)."""
        if not self.radius or self.colour_sigma:
            return None
        return np.maximum(self._weight, np.float32(1e-6))

    def _edge_stopping(self, a: np.ndarray) -> np.ndarray:
        """OpenCV's bilateral filter of ``a`` (module docstring): a window's values equal the whole frame's there
        (tested), as the Gaussian's do."""
        cv2 = require("cv2", "opencv-python-headless", "Filtering the tri-colour image")
        k = 2 * self.radius + 1
        return cv2.bilateralFilter(a, k, self.colour_sigma, self.sigma, borderType=cv2.BORDER_REFLECT_101)

    def _blur(self, a: np.ndarray) -> np.ndarray:
        cv2 = require("cv2", "opencv-python-headless", "Filtering the tri-colour image")
        k = 2 * self.radius + 1
        return cv2.GaussianBlur(a, (k, k), self.sigma, borderType=cv2.BORDER_REFLECT_101)
