"""A solve's images held as one box of the frame and the frame's own images elsewhere (:class:`FrameBox`): what
the outer interreflection loop's passes give the solver, whose images change on the mask's bounding box only."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..core.errors import ShapeError


@dataclasses.dataclass(frozen=True, eq=False)
class FrameBox:
    """(L, H, W, 3) images, ``box`` on the frame's ``window`` and ``frame`` elsewhere, of which a solve reads the
    window's crop around its mask and the whole frame at the bright ends' sample grid only
    (:func:`.samples.exclusions`).

    Why: each pass of the outer interreflection loop subtracts its indirect light on the mask's bounding box only;
    held as a whole frame, the pass's images were a second (L, H, W, 3) float32 copy of the press's (44 MB at
    640x480 with 12 LEDs, most of it outside the box) kept through every solve, and every page of it one more for
    the process to map and free (benchmarks/RESULTS.md, s36-cubemem). The values a solve reads are the same, so
    are its bits."""

    frame: np.ndarray
    """(L, H, W, 3) float -- the images outside the window (under it never read)."""
    box: np.ndarray
    """(L, h, w, 3) float -- the images on the window, the same dtype as ``frame``."""
    window: tuple[slice, slice]
    """(rows, columns) of the frame that ``box`` holds, steps of 1 (kept with their bounds filled in)."""

    def __post_init__(self) -> None:
        rows, cols = (range(*s.indices(n)) for s, n in zip(self.window, self.frame.shape[1:3]))
        want = (self.frame.shape[0], len(rows), len(cols), self.frame.shape[-1])
        if self.frame.ndim != 4 or self.box.shape != want or rows.step != 1 or cols.step != 1:
            raise ShapeError(f"a frame box must be {want} for the frame {self.frame.shape}, got {self.box.shape}")
        if self.box.dtype != self.frame.dtype:
            raise ShapeError(f"a frame box's images are {self.box.dtype}, its frame's {self.frame.dtype}")
        object.__setattr__(self, "window", (slice(rows.start, rows.stop), slice(cols.start, cols.stop)))

    @property
    def shape(self) -> tuple[int, ...]:
        """(L, H, W, 3): the frame's."""
        return self.frame.shape

    @property
    def dtype(self) -> np.dtype:
        return self.frame.dtype

    def crop(self, crop: tuple[slice, slice]) -> np.ndarray:
        """(L, h', w', 3) view of the images on ``crop`` (rows, columns of the frame), which lies inside the window;
        ShapeError otherwise."""
        rows, cols = (slice(c.start - w.start, c.stop - w.start) for c, w in zip(crop, self.window))
        if not all(c.start >= w.start and c.stop <= w.stop for c, w in zip(crop, self.window)):
            raise ShapeError(f"a crop {crop} outside the frame box's window {self.window}")
        return self.box[:, rows, cols]

    def pixels(self, index: np.ndarray) -> np.ndarray:
        """(L, n, 3), a new array -- the images at the frame's pixels ``index`` (n,) (flat, row-major)."""
        read = self.pixel_reader(index)
        return np.stack([read(i) for i in range(self.frame.shape[0])])

    def pixel_reader(self, index: np.ndarray) -> Callable[[int], np.ndarray]:
        """``read(i)`` -> (n, 3), a new array: LED ``i``'s image at the frame's pixels ``index`` (n,) (flat,
        row-major). Where they lie is found once; one LED per call, so that a caller's pool reads the LEDs side by
        side (NumPy's indexing releases the GIL), as it reads an array's."""
        C = self.frame.shape[-1]
        rows, cols, inside = self._inside(index)
        at = (rows[inside] - self.window[0].start) * (self.window[1].stop - self.window[1].start)
        at += cols[inside] - self.window[1].start

        def read(i: int) -> np.ndarray:
            out = self.frame[i].reshape(-1, C)[index]
            out[inside] = self.box[i].reshape(-1, C)[at]
            return out

        return read

    def _inside(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, columns, whether in the window) of the frame's flat pixels ``index``."""
        rows, cols = np.divmod(index, self.frame.shape[2])
        r, c = self.window
        return rows, cols, (rows >= r.start) & (rows < r.stop) & (cols >= c.start) & (cols < c.stop)

    def whole(self) -> np.ndarray:
        """(L, H, W, 3), a new array: the images as one frame."""
        out = self.frame.copy()
        out[:, self.window[0], self.window[1]] = self.box
        return out


def frame_crop(images: np.ndarray | FrameBox, crop: tuple[slice, slice]) -> np.ndarray:
    """(L, h, w, 3) -- ``images`` (L, H, W, 3) array or :class:`FrameBox` on ``crop`` (rows, columns); a view."""
    if isinstance(images, FrameBox):
        return images.crop(crop)
    return images[:, crop[0], crop[1]]
