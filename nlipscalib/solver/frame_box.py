"""A solve's images held as one box of the frame and the frame's own images elsewhere (:class:`FrameBox`): what
the outer interreflection loop's passes give the solver, whose images change on the mask's bounding box only."""

from __future__ import annotations

import dataclasses

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
        L, H, W, C = self.frame.shape
        out = self.frame.reshape(L, H * W, C)[:, index]
        rows, cols, inside = self._inside(index)
        out[:, inside] = self.box[:, rows[inside] - self.window[0].start, cols[inside] - self.window[1].start]
        return out

    def outside(self, index: np.ndarray) -> np.ndarray:
        """(L, n', 3), a new array -- the frame's images at those of the pixels ``index`` (flat) outside the window."""
        L, H, W, C = self.frame.shape
        return self.frame.reshape(L, H * W, C)[:, index[~self._inside(index)[2]]]

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
