"""GelSight-style lookup-table baseline (Yuan et al. 2017): binned colour change -> normal, per image region.

The colour of a pixel minus the undeformed reference frame's colour there is quantised into
``bins`` levels per channel (range: the training samples' 0.5-99.5 percentiles); every image region
(``cells x cells``) has its own table holding the mean training normal of each filled bin. A query
falls back to the nearest filled bin of its region (in bin-index space), so the table answers every
colour.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import ShapeError
from ..core.tolerances import NORMAL_EPS


@dataclasses.dataclass
class LookupTable:
    """A fitted lookup table; build with :meth:`fit`."""

    lo: np.ndarray
    """(3,) float -- lower end of the colour-change range per channel (linear units)."""
    hi: np.ndarray
    """(3,) float -- upper end."""
    bins: int
    """Levels per channel."""
    cells: int
    """Image regions per side."""
    shape: tuple[int, int]
    """(H, W) of the sensor's images."""
    reference: np.ndarray
    """(H, W, 3) float32 -- the undeformed reference tri-colour frame (linear)."""
    tables: dict
    """region index -> (keys (K, 3) int bin indices, normals (K, 3) unit, scipy cKDTree over keys)."""

    @classmethod
    def fit(
        cls,
        pixel: np.ndarray,
        rgb: np.ndarray,
        normal: np.ndarray,
        reference: np.ndarray,
        cells: int = 8,
        bins: int = 16,
    ) -> LookupTable:
        """Fit from samples.

        Parameters
        ----------
        pixel : (N, 2) int, (u, v) ; rgb : (N, 3) float linear ; normal : (N, 3) unit, camera frame
        reference : (H, W, 3) float32, the undeformed reference tri-colour frame (linear)
        """
        if reference.ndim != 3 or len(pixel) != len(rgb) or len(rgb) != len(normal):
            raise ShapeError("LookupTable.fit: pixel, rgb, normal must have the same length; reference (H, W, 3)")
        delta = rgb - reference[pixel[:, 1], pixel[:, 0]]
        lo, hi = np.percentile(delta, 0.5, axis=0), np.percentile(delta, 99.5, axis=0)
        lut = cls(lo, hi + 1e-9, bins, cells, reference.shape[:2], reference.astype(np.float32), {})
        keys, region = lut._keys(pixel, rgb), lut._region(pixel)
        lut.tables = {r: lut._table(keys[region == r], normal[region == r]) for r in np.unique(region)}
        lut.tables[-1] = lut._table(keys, normal)  # all regions pooled: for regions without samples
        return lut

    def predict(self, pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        """(N, 3) unit normals for samples at ``pixel`` ((N, 2) (u, v)) with colours ``rgb`` ((N, 3) linear)."""
        keys, region = self._keys(pixel, rgb), self._region(pixel)
        out = np.empty((len(keys), 3))
        for r in np.unique(region):
            m = region == r
            _, normals, tree = self.tables.get(int(r), self.tables[-1])
            out[m] = normals[tree.query(keys[m])[1]]
        return out

    # ------------------------------------------------------------------ internals
    def _keys(self, pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        delta = rgb - self.reference[pixel[:, 1], pixel[:, 0]]
        q = np.floor((delta - self.lo) / (self.hi - self.lo) * self.bins).astype(np.int64)
        return np.clip(q, 0, self.bins - 1)

    def _region(self, pixel: np.ndarray) -> np.ndarray:
        H, W = self.shape
        return (pixel[:, 1].astype(np.int64) * self.cells // H) * self.cells + pixel[:, 0] * self.cells // W

    def _table(self, keys: np.ndarray, normals: np.ndarray) -> tuple:
        from scipy.spatial import cKDTree

        flat = (keys[:, 0] * self.bins + keys[:, 1]) * self.bins + keys[:, 2]
        uniq, inv = np.unique(flat, return_inverse=True)
        sums = np.zeros((len(uniq), 3))
        np.add.at(sums, inv, normals)
        mean = sums / np.maximum(np.linalg.norm(sums, axis=-1, keepdims=True), NORMAL_EPS)
        ukeys = np.stack([uniq // self.bins**2, (uniq // self.bins) % self.bins, uniq % self.bins], -1)
        return ukeys, mean, cKDTree(ukeys)
