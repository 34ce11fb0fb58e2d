"""The pixels the contact classification (:mod:`.contact`) works on: the frame's, or 2 x 2 block means of
large frames, smoothed inside the gel (normalised convolution), and how much that smoothing scales the
images' noise (in the gel and near its edge).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from . import threads

BLOCK_MIN_SIDE = 480
"""Short side, pixels, of the frames that :func:`.contact.classify_contact` classifies on 2 x 2 block means
(:func:`classify_block`). Why: it smooths by 1.5 px anyway, and what it gives -- a box with an 8-pixel margin,
the pixels to anchor, the contact left out of a refit -- moves by a pixel or two, while its whole-frame passes
over the LED images (blur, the misfit's sums, the undeformed model and its light) read a quarter of the
pixels. Measured on the one-bounce 640x480 twin presses with ``--roi auto``: the two classifications of a
solve took 0.17 s of CPU instead of 1.2 s (in process, on the shared 2-core machine); the boxes moved by 1-2 px
(sphere [281, 173, 216, 210] -> [280, 172, 218, 210]); contact AAE / MabsE / depth RMSE sphere 0.525 deg /
0.0044 / 0.0384 mm -> 0.524 / 0.0044 / 0.0372, cube 0.427 / 0.0036 / 0.0900 -> 0.427 / 0.0036 / 0.0896.
Smaller frames keep every pixel: their classification costs little, and a 96x72 dent is a few blocks wide."""


def classify_block(shape: tuple[int, int]) -> int:
    """Block side, pixels, that :func:`.contact.classify_contact` works on for a frame of ``shape`` = (H, W): 2 from
    :data:`BLOCK_MIN_SIDE` on (both sides even), else 1 (every pixel)."""
    H, W = shape
    return 2 if min(H, W) >= BLOCK_MIN_SIDE and H % 2 == 0 and W % 2 == 0 else 1


@dataclasses.dataclass(frozen=True)
class ContactGrid:
    """The pixels :func:`.contact.classify_contact` works on: the frame's, or the means of square blocks of them."""

    pixels: np.ndarray
    """(H, W) bool -- the gel's pixels."""
    block: int
    """Block side, pixels (1: every pixel)."""
    valid: np.ndarray
    """(H / block, W / block) bool -- blocks holding a gel pixel."""
    sigma: float
    """Gaussian blur, in blocks, of :meth:`smooth`."""
    gain: float
    """How much block mean and blur scale white pixel noise (L2 norm of their kernel)."""

    @classmethod
    def of(cls, pixels: np.ndarray, block: int, blur_px: float) -> ContactGrid:
        """The grid of ``block`` x ``block`` blocks of ``pixels`` (H, W) bool that smooths like a blur of ``blur_px``.

        The blur on the blocks is ``blur_px`` / b blocks. A block mean's noise is the pixels' over b (b^2
        independent samples), white again, so the noise gain is the blur's over b. Why not a blur that makes up
        only the rest of ``blur_px``^2 after the block mean's own box (variance (b^2 - 1) / 12 px^2, 0.71 blocks
        for b = 2): on the 640x480 one-bounce sphere press its noise-only misfit came out 7.5 % above the
        per-pixel classification's and its undeformed pixels 7 % more; with 1.5 px / 2 both are within 1 %
        (median misfit 2.550e-3 against 2.549e-3)."""
        if block == 1:
            return cls(pixels, 1, pixels, blur_px, _gain(blur_px))
        H, W = pixels.shape
        if H % block or W % block:
            raise ValueError(f"a {W}x{H} frame is not a whole number of {block}x{block} blocks")
        valid = pixels.reshape(H // block, block, W // block, block).any(axis=(1, 3))
        sigma = blur_px / block
        return cls(pixels, block, valid, sigma, _gain(sigma) / block)

    def means(self, stack: np.ndarray, index: Sequence[int]) -> np.ndarray:
        """(n, h, w, 3) float32 -- the images ``stack[index]`` ((L, H, W, 3), or a sequence of L (H, W, 3) images
        read one at a time, :class:`radiosity.Upsampled`; any real or bool dtype) averaged
        over each block's gel pixels (0 where it has none); ``stack[index]`` as float32 on a grid of pixels."""
        if self.block == 1:
            return np.asarray(stack, np.float32)[list(index)]
        import cv2

        index = list(index)
        h, w = self.valid.shape
        whole = bool(self.pixels.all())
        weight = None if whole else self.pixels.astype(np.float32)[..., None]
        if not whole:  # 1 / the gel's share of each block
            share = cv2.resize(weight[..., 0], (w, h), interpolation=cv2.INTER_AREA)
            norm = np.where(share > 0, 1.0 / np.maximum(share, 1e-6), 0.0).astype(np.float32)[..., None]
        out = np.empty((len(index), h, w, 3), np.float32)

        def one(k: int):
            x = np.asarray(stack[index[k]], np.float32)  # one image at a time: no float32 copy of the stack
            if weight is None:
                out[k] = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA)  # the block mean (integer factor)
            else:
                out[k] = cv2.resize(x * weight, (w, h), interpolation=cv2.INTER_AREA) * norm

        threads.map_items(one, range(len(index)))
        return out

    def smooth(self, stack: np.ndarray) -> np.ndarray:
        """:func:`gel_blur` of an (n, h, w, 3) stack on this grid."""
        return gel_blur(stack, self.valid, self.sigma)

    def per_pixel(self, values: np.ndarray) -> np.ndarray:
        """(H, W) -- each pixel gets its block's value of ``values`` (h, w)."""
        b = self.block
        return values if b == 1 else np.repeat(np.repeat(values, b, axis=0), b, axis=1)


def gel_blur(stack: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of (L, H, W, 3) images inside ``valid`` (normalised convolution), float32."""
    if sigma <= 0:
        return stack
    import cv2

    w = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), sigma)
    inv = np.where(valid, 1.0 / np.maximum(w, 1e-6), 0.0)[..., None]
    out = np.empty(stack.shape, np.float32)

    def blur(i: int):
        out[i] = cv2.GaussianBlur(np.where(valid[..., None], stack[i], 0).astype(np.float32), (0, 0), sigma) * inv

    threads.map_items(blur, range(len(stack)))
    return out


def _gain(sigma: float) -> float:
    """How much a Gaussian blur of ``sigma`` pixels scales white noise: the kernel's L2 norm."""
    if sigma <= 0:
        return 1.0
    import cv2

    k = cv2.getGaussianKernel(2 * int(np.ceil(3 * sigma)) + 1, sigma)[:, 0]
    return float(np.sum(k**2))  # separable: (sum k^2)^(1/2) per axis, squared over two axes


def edge_noise_gain(valid: np.ndarray, sigma: float) -> np.ndarray:
    """How much more white noise :func:`gel_blur` leaves at each pixel than inside the gel: near the gel's
    silhouette and the image border its normalised convolution averages fewer pixels (and the border's reflected
    ones twice), 1.7 times the noise in an image corner at 1.5 px.

    Parameters
    ----------
    valid : (H, W) bool -- the gel's pixels.
    sigma : float -- the blur, pixels.

    Returns
    -------
    (H, W) float64 -- >= about 1 on the gel (1 far from its edge); 1 off it.

    Exact for :func:`gel_blur`: its blur is separable, so the squared weights of a pixel's average are
    ``Gy**2 valid Gx**2.T`` with ``Gy``, ``Gx`` the 1-D blurs as matrices (OpenCV's kernel and border, got by
    blurring identity matrices), and the average's weights sum to ``Gy valid Gx.T``."""
    if sigma <= 0:
        return np.ones(valid.shape)
    import cv2

    def matrix(n: int) -> np.ndarray:  # (n, n): row i = the weights that output i takes from each input
        eye = np.eye(n, dtype=np.float32)
        # blurred along its columns only: entry (j, i) is what input j gives output i (asymmetric at the border)
        return cv2.GaussianBlur(eye, (0, 0), sigmaX=sigma, sigmaY=1e-6).astype(np.float64).T

    Gx, Gy = matrix(valid.shape[1]), matrix(valid.shape[0])
    v = valid.astype(np.float64)
    weights = Gy @ v @ Gx.T
    squares = (Gy**2) @ v @ (Gx**2).T
    gain = np.sqrt(squares) / np.maximum(weights, 1e-12)
    return np.where(valid, gain / _gain(sigma), 1.0)  # over the gain far from any edge
